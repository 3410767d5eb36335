#!/usr/bin/env bash
# Instruction counts of the filter (docs/performance.md): a measure of a
# kernel change that does not depend on the machine's load, unlike timings.
#
#   bash benches/instructions.sh [TIMING_BINARY...]
#   MODES="colour layers features full" bash benches/instructions.sh ...
#   SIZE="960 256" BYFILE=1 MODES=full bash benches/instructions.sh ...
#
# Runs `examples/timing` (colour-only and full, or the modes in MODES;
# 480x272, r=10, 1 thread, one run) under `valgrind --tool=callgrind` on
# the AVX2 tier (valgrind has no AVX-512) and prints, per binary and mode,
# the instructions of the whole process and of the block kernel alone
# (`filter_block_avx2` and what it calls). Without arguments it builds and
# measures the working tree; given timing binaries (e.g. one built from an
# older commit), it measures each. SIZE sets the frame (default
# "480 272"); BYFILE=1 adds the kernel's own counts by source file.
# Needs valgrind (apt-get install
# valgrind). Several minutes per binary for the two default modes (session
# 11: 3 minutes for colour alone); all four take about twice as long, by
# their instruction counts.
set -euo pipefail
cd "$(dirname "$0")/.."
command -v valgrind >/dev/null || { echo "needs valgrind (apt-get install valgrind)"; exit 1; }
if [ $# -eq 0 ]; then
  cargo build --release --example timing >/dev/null 2>&1
  set -- target/release/examples/timing
fi
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores; $(date -u +%Y-%m-%d)"
printf '%-40s %-7s %15s %15s\n' binary mode process kernel
for bin in "$@"; do
  for mode in ${MODES:-colour full}; do
    log="$out/$mode.log"
    NLDENOISE_HUGE_PAGES=0 NLDENOISE_SIMD=avx2 valgrind --tool=callgrind --callgrind-out-file="$out/$mode.cg" \
      "$bin" "$mode" ${SIZE:-480 272} 1 10 1 >"$log" 2>&1
    process=$(grep -m1 'refs:' "$log" | awk '{print $NF}')
    # Inclusive count of the kernel: callgrind_annotate's inclusive column.
    callgrind_annotate --inclusive=yes "$out/$mode.cg" >"$out/$mode.txt" 2>/dev/null
    kernel=$(awk '/filter_block_avx2 /{print $1; exit}' "$out/$mode.txt")
    printf '%-40s %-7s %15s %15s\n' "$bin" "$mode" "$process" "${kernel:-?}"
    if [ "${BYFILE:-0}" = 1 ]; then
      # The kernel's own (exclusive) counts by the source file its inlined
      # code comes from: its row loops (kernels.rs), its set-up (nlmeans.rs),
      # the standard library's helpers (cmp.rs, uint_macros.rs, ...).
      callgrind_annotate --show-percs=no "$out/$mode.cg" 2>/dev/null \
        | awk '/:nldenoise::filter::nlmeans::filter_block_avx2/ { split($2, f, ":"); n = split(f[1], p, "/"); print "    " $1, p[n] }' \
        | head -12
    fi
  done
done
