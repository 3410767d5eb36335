#!/usr/bin/env bash
# Simulated L1 data-cache misses of the filter by source line
# (docs/performance.md): which passes of the block kernel miss L1 most.
#
#   bash benches/cache_misses.sh [MODE] [TIMING_BINARY]
#
# Runs `examples/timing MODE 512 136 1 10 1` (MODE colour by default; one
# 512-wide block column, as a 512x128 block of a large frame) under
# `valgrind --tool=cachegrind --cache-sim=yes` with this machine's L1d
# (48 KiB, 12-way) and L2 (2 MiB per core, 16-way) on the AVX2 tier
# (valgrind has no AVX-512), then prints the totals and the source lines
# with the most L1 read misses and write misses. Needs valgrind. About 2
# minutes.
set -euo pipefail
cd "$(dirname "$0")/.."
command -v valgrind >/dev/null || { echo "needs valgrind (apt-get install valgrind)"; exit 1; }
mode=${1:-colour}
bin=${2:-}
if [ -z "$bin" ]; then
  cargo build --release --example timing >/dev/null 2>&1
  bin=target/release/examples/timing
fi
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores; $(date -u +%Y-%m-%d)"
NLDENOISE_HUGE_PAGES=0 NLDENOISE_SIMD=avx2 valgrind --tool=cachegrind --cache-sim=yes --D1=49152,12,64 --LL=2097152,16,64 \
  --cachegrind-out-file="$out/cg.out" "$bin" "$mode" 512 136 1 10 1 >"$out/log" 2>&1
grep -E 'D1  misses|LL misses|D   refs' "$out/log" | sed 's/^==[0-9]*== //'
cg_annotate --show=D1mr,D1mw,Ir "$out/cg.out" src/filter/kernels.rs src/filter/nlmeans.rs \
  src/filter/column_sums.rs >"$out/annotated.txt" 2>/dev/null
# Lines of the annotated sources: D1mr, D1mw, Ir (each possibly with a
# percentage), then the source text.
python3 - "$out/annotated.txt" <<'PY'
import re, sys
rows = []
num = r'([0-9,]+|\.)\s+(?:\([ 0-9.]+%\)\s+)?'
source = None
for line in open(sys.argv[1]):
    f = re.match(r'-- (?:User|Auto)-annotated source: .*/(src/.*)', line)
    if f:
        source = f.group(1) if f.group(1).startswith('src/filter/') else None
        continue
    m = re.match(r'\s*' + num + num + num + r'(.*)', line)
    if not source or not m or 'events annotated' in line or m.group(4).startswith('<counts'):
        continue
    v = [0 if g == '.' else int(g.replace(',', '')) for g in m.groups()[:3]]
    rows.append((v[0], v[1], source.split('/')[-1] + ': ' + m.group(4).strip()[:80]))
for k, name in ((0, 'L1 read misses'), (1, 'L1 write misses')):
    total = sum(r[k] for r in rows)
    print(f'\n{name} by source line (of {total:,} in the kernel sources):')
    for r in sorted(rows, key=lambda r: -r[k])[:8]:
        print(f'{r[k]:>12,} {100 * r[k] / max(total, 1):5.1f} %  {r[2]}')
PY
