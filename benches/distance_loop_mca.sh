#!/usr/bin/env bash
# A static throughput model of the AVX2 colour-distance loop (docs/performance.md):
# finds, in `filter_block_avx2` of an `examples/timing` binary, the innermost
# loops that hold the three channels' reciprocal guesses of a 16-sample chunk
# (six `vpsubd`, no inner loop), and runs `llvm-mca` on each for a CPU
# model, default AMD Zen 3. Prints each loop's instructions, its fused
# multiply-adds and adds/subtractions, and the modelled cycles per iteration
# (one iteration: 16 pixels of a pair of offsets, three channels).
#
#   bash benches/distance_loop_mca.sh [TIMING_BINARY] [MCPU]
#
# Needs llvm-mca (Debian's llvm) and objdump (binutils).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${1:-}; MCPU=${2:-znver3}
command -v llvm-mca >/dev/null || { echo "needs llvm-mca (apt-get install llvm)"; exit 1; }
if [ -z "$BIN" ]; then
  cargo build --release --example timing >/dev/null 2>&1
  BIN=target/release/examples/timing
fi
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
objdump -d --no-show-raw-insn "$BIN" |
  awk '/<[^>]*filter_block_avx2[^>]*>:$/ { f = 1; next } f && /^$/ { f = 0 } f' > "$out/body"
python3 - "$out" "$MCPU" <<'PY'
import re, subprocess, sys

out, mcpu = sys.argv[1], sys.argv[2]
ins = []
for line in open(f"{out}/body"):
    m = re.match(r"\s+([0-9a-f]+):\s+(.*)", line)
    if m:
        ins.append((int(m.group(1), 16), re.sub(r"\s+<[^>]*>", "", m.group(2)).strip()))
loops = []
for i, (addr, text) in enumerate(ins):
    m = re.match(r"j\w+\s+([0-9a-f]+)$", text)
    if m and int(m.group(1), 16) < addr:
        start = int(m.group(1), 16)
        span = [(a, t) for a, t in ins if start <= a <= addr]
        body = [t for _, t in span]
        # Innermost: no other backward jump inside the span.
        inner = not any((j := re.match(r"j\w+\s+([0-9a-f]+)$", t)) and start <= int(j.group(1), 16) < a
                        for a, t in span[:-1])
        if inner and sum("vpsubd" in t for t in body) == 6 and len(body) < 400:
            loops.append((start, body))
if not loops:
    sys.exit("no AVX2 distance loop found")
for start, body in loops:
    text = ".L0:\n" + "\n".join("\t" + re.sub(r"^(j\w+)\s+[0-9a-f]+$", r"\1 .L0", t) for t in body) + "\n"
    open(f"{out}/loop.s", "w").write(text)
    mca = subprocess.run(["llvm-mca", f"-mcpu={mcpu}", "-iterations=300", f"{out}/loop.s"],
                         capture_output=True, text=True).stdout
    cycles = int(re.search(r"Total Cycles:\s+(\d+)", mca).group(1))
    fma = sum(bool(re.match(r"vfn?m(add|sub)", t)) for t in body)
    adds = sum(bool(re.match(r"v(add|sub)ps", t)) for t in body)
    print(f"loop at {start:#x}: {len(body)} instructions, {fma} FMAs, {adds} adds/subtractions, "
          f"{cycles / 300:.1f} cycles per iteration ({mcpu})")
PY
