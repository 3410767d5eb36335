#!/usr/bin/env bash
# Floating-point operations executed per pixel-offset by the block kernel,
# counted, not estimated: `valgrind --tool=callgrind` counts how often each
# machine instruction of the kernel (`filter_block_avx2` and all it calls)
# runs, `objdump` names each instruction, and each floating-point
# arithmetic instruction counts once per lane (8 for ymm, 4 for xmm, 1 for
# a scalar). Two runs of `examples/timing` on one thread, search radius R
# and 0, and their difference over the (2R+1)^2 - 1 offsets R adds: what
# the frame's set-up, the prefilters and the centre offset cost cancels
# out, and what is left is the per-offset work, block borders and the
# mirrors' widened rows included.
#
#   bash benches/op_count.sh [MODE] [WIDTH] [HEIGHT] [R]   # default: full 480 300 10
#
# 480x300 is one tile of a 1080p frame (one tile, one band, no halo
# recomputation here). Frame borders clip the offsets' windows, so a few
# per cent of the pixel-offsets of this small frame do less work than an
# interior tile's: the script prints the share. Valgrind has no AVX-512,
# so the AVX2 tier is counted (NLDENOISE_SIMD=avx2); SPEC §6 gives every
# tier the same operations per sample, the tiers differ in which samples a
# row's overlapping last chunk recomputes. Operations as docs/performance.md
# counts them: add, sub, mul, min, max, division and fused multiply-add one
# each (an FMA two flops); conversions, roundings, compares, blends and
# integer operations are listed apart. Needs valgrind (apt-get install
# valgrind) and objdump (binutils). About a minute.
set -euo pipefail
cd "$(dirname "$0")/.."
MODE=${1:-full}; W=${2:-480}; H=${3:-300}; R=${4:-10}
command -v valgrind >/dev/null || { echo "needs valgrind (apt-get install valgrind)"; exit 1; }
command -v objdump >/dev/null || { echo "needs objdump (apt-get install binutils)"; exit 1; }
cargo build --release --example timing >/dev/null 2>&1
bin=target/release/examples/timing
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs); $(date -u '+%Y-%m-%d %H:%M') UTC; commit $(git rev-parse --short HEAD 2>/dev/null || echo '?')"
for r in "$R" 0; do
  NLDENOISE_HUGE_PAGES=0 NLDENOISE_SIMD=avx2 valgrind --tool=callgrind --callgrind-out-file="$out/cg.$r" --dump-instr=yes \
    --compress-pos=no --compress-strings=no --toggle-collect='*filter_block_avx2*' \
    "$bin" "$MODE" "$W" "$H" 1 "$r" 1 >/dev/null 2>&1
done
objdump -d --no-show-raw-insn "$bin" > "$out/dis"
python3 - "$out" "$bin" "$MODE" "$W" "$H" "$R" <<'EOF'
import collections, os, re, sys

out, binary, mode, w, h, r = sys.argv[1], sys.argv[2], sys.argv[3], *map(int, sys.argv[4:])

def counts(path):
    """Executions per (instruction address, source file and line) of `binary`'s code."""
    n, ob, fl, skip = collections.Counter(), "", "", False
    name = os.path.basename(binary)
    for line in open(path):
        if line.startswith("ob="):
            ob = line[3:].strip()
        elif line.startswith(("fl=", "fi=", "fe=")):
            fl = line[3:].strip()
        elif line.startswith("calls="):
            skip = True  # the next cost line is the call's inclusive cost
        elif line.startswith("0x"):
            if skip:
                skip = False
                continue
            if os.path.basename(ob) == name:
                addr, src, ir = line.split()
                n[(int(addr, 16), f"{os.path.basename(fl)}:{src}")] += int(ir)
    return n

# Every instruction of the binary: address -> (mnemonic, operands).
insn = {}
pat = re.compile(r"^\s*([0-9a-f]+):\s+(\S+)\s*(.*)$")
for line in open(os.path.join(out, "dis")):
    m = pat.match(line)
    if m:
        insn[int(m.group(1), 16)] = (m.group(2), m.group(3))

ARITH = [
    ("fma", re.compile(r"^v?f(n)?m(add|sub)(132|213|231)(ps|ss)$")),
    ("add/sub", re.compile(r"^v?(add|sub)(ps|ss)$")),
    ("mul", re.compile(r"^v?mul(ps|ss)$")),
    ("min/max", re.compile(r"^v?(min|max)(ps|ss)$")),
    ("div", re.compile(r"^v?div(ps|ss)$")),
]
OTHER = [
    ("convert", re.compile(r"^v?cvt")),
    ("round", re.compile(r"^v?round(ps|ss)$")),
    ("compare", re.compile(r"^v?cmp.*(ps|ss)$")),
    ("blend", re.compile(r"^v?blendv?ps$")),
]

def lanes(mnemonic, operands):
    if mnemonic.endswith("ss"):
        return 1
    if "%zmm" in operands:
        return 16
    if "%ymm" in operands:
        return 8
    return 4

def tally(n):
    """Lanes per category, flops, and operations per source line."""
    t, by_line = collections.Counter(), collections.Counter()
    for (addr, src), k in n.items():
        if addr not in insn:
            continue
        mn, ops = insn[addr]
        for cat, p in ARITH + OTHER:
            if p.match(mn):
                t[cat] += k * lanes(mn, ops)
                if cat in dict(ARITH):
                    by_line[src] += k * lanes(mn, ops)
                    t["flops"] += (2 if cat == "fma" else 1) * k * lanes(mn, ops)
                break
    return t, by_line

(a, a_lines), (b, b_lines) = tally(counts(os.path.join(out, f"cg.{r}"))), tally(counts(os.path.join(out, "cg.0")))
if r < 1 or not a["fma"] or a["fma"] <= b["fma"]:
    sys.exit("no kernel instructions counted: is R at least 1, and is the kernel still "
             "`filter_block_avx2` (callgrind's --toggle-collect)?")
offsets = (2 * r + 1) ** 2 - 1
po = w * h * offsets
# Pixel-offsets whose window the frame's borders leave whole, as a share.
inside = sum((w - abs(dx)) * (h - abs(dy)) for dy in range(-r, r + 1) for dx in range(-r, r + 1) if (dx, dy) != (0, 0)) / po
print(f"{mode} {w}x{h}, r={r} against r=0: {offsets} offsets, {po / 1e6:.2f} M pixel-offsets "
      f"({100 * inside:.1f} % of them with both pixels inside the frame)")
total = 0.0
for cat, _ in ARITH:
    v = (a[cat] - b[cat]) / po
    total += v
    print(f"  {cat:8s} {v:7.2f} per pixel-offset")
print(f"  operations {total:7.2f} per pixel-offset ({(a['flops'] - b['flops']) / po:.2f} flops, an FMA two)")
for cat, _ in OTHER:
    v = (a[cat] - b[cat]) / po
    if v:
        print(f"  not counted: {cat} {v:.2f} per pixel-offset")
print("  operations by innermost source line (an FMA shows as std's f32::mul_add):")
lines = collections.Counter({k: (a_lines[k] - b_lines[k]) / po for k in a_lines})
for src, v in lines.most_common(int(os.environ.get("TOP", "12"))):
    print(f"  {v:7.2f}  {src}")
EOF
