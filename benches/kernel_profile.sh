#!/usr/bin/env bash
# Where the block kernel's time goes (docs/performance.md): `perf record` of
# one `examples/timing` run, each sample inside the kernel's tier wrapper
# (`filter_block_avx512`, `filter_block_avx2`) attributed to the innermost
# kernel function it was inlined from (`addr2line -i`), and each sample in
# a kernel function the wrapper calls out of line (an AVX2 or AVX-512
# `target_feature` function of `nldenoise::filter`) to that function, as
# shares of the kernel's samples. The timings' noise does not matter here:
# shares, not seconds.
#
#   bash benches/kernel_profile.sh [MODE] [WIDTH] [HEIGHT] [TIMING_BINARY]
#
# MODE as examples/timing (colour, layers, features, full, full-var; default
# colour), RADIUS (default 10), RUNS (default 1) and THREADS (default 1) as its arguments,
# 960x540 by default. Needs perf (Debian's linux-perf) and
# addr2line (binutils). Set LINES=1 to split each function by source line,
# FOOTPRINT=1 to print also how many 64-byte lines of the wrapper's code
# hold half, 90 % and 99 % of its samples (its hot code's size).
set -euo pipefail
cd "$(dirname "$0")/.."
MODE=${1:-colour}; W=${2:-960}; H=${3:-540}; BIN=${4:-}
command -v perf >/dev/null || { echo "needs perf (apt-get install linux-perf)"; exit 1; }
if [ -z "$BIN" ]; then
  cargo build --release --example timing >/dev/null 2>&1
  BIN=target/release/examples/timing
fi
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores; $(date -u +%Y-%m-%d)"
perf record -q -e cpu-clock -F 4000 -o "$out/perf.data" "$BIN" "$MODE" "$W" "$H" "${THREADS:-1}" "${RADIUS:-10}" "${RUNS:-1}" >/dev/null 2>&1
perf script -i "$out/perf.data" -F ip,sym,symoff 2>/dev/null \
  | awk '$2 ~ /^nldenoise::filter::.*avx(2|512)[+]0x/ { split($2, a, "[+]0x"); print a[1], a[2] }' \
  | sort | uniq -c > "$out/offsets"
python3 - "$BIN" "$out/offsets" "${LINES:-0}" "${FOOTPRINT:-0}" <<'PY'
import collections, subprocess, sys

binary, offsets, by_line = sys.argv[1], sys.argv[2], sys.argv[3] == "1"
symbols = {}
for line in subprocess.run(["nm", "-C", binary], capture_output=True, text=True).stdout.splitlines():
    parts = line.split(maxsplit=2)
    if len(parts) == 3 and parts[2].startswith("nldenoise::filter::nlmeans::filter_block_avx"):
        symbols[parts[2]] = int(parts[0], 16)
rows, own = [], collections.Counter()
for line in open(offsets):
    count, sym, off = line.split()
    if sym in symbols:
        rows.append((int(count), sym, hex(symbols[sym] + int(off, 16))))
    else:
        # A kernel the wrapper calls out of line (a `target_feature`
        # function not inlined): its samples under its own name.
        own[sym.split("::")[-1] + " (out of line)"] += int(count)
if not rows:
    sys.exit("no samples in the kernel")
print(f"tier wrapper: {', '.join(sorted({s.split('::')[-1] for _, s, _ in rows}))}")
text = subprocess.run(["addr2line", "-a", "-f", "-i", "-C", "-e", binary] + [a for _, _, a in rows],
                      capture_output=True, text=True).stdout.splitlines()
# addr2line -a prints each address, then (function, file:line) per inlined frame, innermost first.
frames, current = [], None
for line in text:
    if line.startswith("0x") and all(c in "0123456789abcdefx" for c in line):
        if current is not None:
            frames.append(current)
        current = []
    elif line:
        current.append(line)
frames.append(current)
ours = ("kernels.rs", "column_sums.rs", "nlmeans.rs")
# Helpers shared by several kernels: their samples go to the caller.
helpers = ("rows_sum", "chunk_start", "chunk_count", "chunk", "chunk_mut", "cut", "shifted", "deref", "deref_mut")
shares, total = own, sum(own.values())
for (count, _, _), chain in zip(rows, frames):
    total += count
    key = "(set-up in the block kernel)"
    functions, places = chain[0::2], chain[1::2]
    for i, (function, place) in enumerate(zip(functions, places)):
        if any(f in place for f in ours) and not any(
            f in function for f in ("filter_block_body", "run_step", "filter_block_avx")
        ):
            key = function.split("::")[-1]
            if key.split("<")[0] in helpers:
                continue
            if key.startswith("{closure") and i + 1 < len(functions):
                key = functions[i + 1].split("::")[-1] + "::" + key
            if by_line:
                key += "  " + place.rsplit("/", 1)[-1].split(" ")[0]
            break
    shares[key] += count
print(f"{total} samples in the kernel")
if sys.argv[4] == "1":
    lines = collections.Counter()
    for count, _, address in rows:
        lines[int(address, 16) // 64] += count
    held, marks, wrapper = 0, [0.5, 0.9, 0.99], sum(c for c, _, _ in rows)
    for n, (_, count) in enumerate(lines.most_common(), 1):
        held += count
        while marks and held >= marks[0] * wrapper:
            print(f"hot code: {100 * marks.pop(0):.0f} % of the samples in {n} lines of 64 bytes ({n * 64 / 1024:.1f} KiB)")
for key, count in shares.most_common(30):
    print(f"{100 * count / total:6.2f} %  {key}")
PY
