#!/usr/bin/env bash
# Where a run's page faults come from (docs/performance.md, "Session 15"):
# `perf record -e page-faults` with DWARF call graphs, every sample counted
# to the first function on its stack that belongs to the project or to a
# codec (`nldenoise::`, `exr::`, `zune`, `libdeflate`, `half::`), next to the
# leaf function (memcpy, memset, ...) that touched the page. Prints the
# shares of the top 20.
#
#   bash benches/page_faults.sh NLDENOISE_ARGS...
#   e.g. bash benches/page_faults.sh denoise target/ab-files-1920x1080featureslayers.exr \
#          -o /tmp/out.exr --threads 2 --layers auto
#
# Uses target/release/nldenoise (NLDENOISE=path to use another binary).
# Needs perf (Debian's linux-perf).
set -euo pipefail
cd "$(dirname "$0")/.."
command -v perf >/dev/null || { echo "needs perf (apt-get install linux-perf)"; exit 1; }
BIN=${NLDENOISE:-target/release/nldenoise}
[ -n "${NLDENOISE:-}" ] || cargo build --release --bin nldenoise >/dev/null 2>&1
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores; $(date -u +%Y-%m-%d)"
perf record -q -e page-faults -c 25 --call-graph dwarf,16384 -o "$out/perf.data" "$BIN" -q "$@" >/dev/null 2>&1
perf script -i "$out/perf.data" -F period,ip,sym 2>/dev/null | python3 -c '
import collections, re, sys

ours = ("nldenoise::", "exr::", "zune", "libdeflate", "half::")
counts, stack, total = collections.Counter(), [], 0

def flush():
    global stack, total
    if stack:
        total += 1
        owner = next((s for s in stack if any(o in s for o in ours)
                      and not any(x in s for x in ("rayon", "closure", "call_mut"))), "?")
        counts[(stack[0][:40], owner[:100])] += 1
    stack = []

for line in sys.stdin:
    parts = line.split(None, 1)
    if len(parts) == 2 and re.fullmatch(r"[0-9a-f]+", parts[0]):
        stack.append(parts[1].strip().split("+0x")[0])
    else:
        flush()
flush()
print(f"{total} samples (one per 25 faults)")
for (leaf, owner), n in counts.most_common(20):
    print(f"{100 * n / total:5.1f} %  {owner}  (in {leaf})")
'
