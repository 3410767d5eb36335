#!/usr/bin/env bash
# How much of the thread-scaling shortfall is the engine's and how much the
# machine's: in each round, one frame on one thread (alone), one frame on
# two threads (ours), and two one-thread processes at once, pinned to cores
# 0 and 1 (independent processes: no memory, locks or scheduling of the
# engine's between them, only the machine: its shared caches and memory,
# and its other tenants).
#
#   bash benches/host_scaling.sh [MODE] [WIDTH] [HEIGHT]   # default: full 3840 2160
#   ROUNDS=N (default 3)
#
# Per round, from `examples/timing` (the filter from memory, one run per
# process, frame synthesis outside the timed part):
#   ours  = one / two: our two-thread scaling;
#   ceiling = 2 one / ((a + b) / 2), where a and b are the two processes' times:
#           the scaling a perfect two-thread run would reach when each core is
#           as slow as it is while the other core runs the same kernel (the
#           two-process ceiling: the machine's, for this kernel's memory traffic;
#           `cargo bench --bench peak` gives it for arithmetic alone);
#   share = ours / ceiling: the part of that ceiling we reach.
# Then the medians of the rounds' ratios. The rounds alternate so that each
# ratio compares runs from the same minutes of this shared, noisy machine.
set -euo pipefail
cd "$(dirname "$0")/.."
MODE=${1:-full}; W=${2:-3840}; H=${3:-2160}
cargo build --release --example timing >/dev/null 2>&1
t=target/release/examples/timing
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
secs() { cut -d, -f6; }
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores; $(date -u '+%Y-%m-%d %H:%M') UTC; $MODE ${W}x$H"
for round in $(seq "${ROUNDS:-3}"); do
  one=$("$t" "$MODE" "$W" "$H" 1 10 1 | secs)
  two=$("$t" "$MODE" "$W" "$H" 2 10 1 | secs)
  taskset -c 0 "$t" "$MODE" "$W" "$H" 1 10 1 > "$tmp/a" &
  pa=$!
  taskset -c 1 "$t" "$MODE" "$W" "$H" 1 10 1 > "$tmp/b" &
  pb=$!
  wait "$pa"
  wait "$pb"
  a=$(secs < "$tmp/a"); b=$(secs < "$tmp/b")
  echo "$round $one $two $a $b"
done | awk '
  function median(v, n,   i, j, x) {
    for (i = 2; i <= n; i++) { x = v[i]; for (j = i - 1; j >= 1 && v[j] > x; j--) v[j + 1] = v[j]; v[j + 1] = x }
    return n % 2 ? v[(n + 1) / 2] : (v[n / 2] + v[n / 2 + 1]) / 2
  }
  {
    ours = $2 / $3; ceiling = 2 * $2 / (($4 + $5) / 2)
    o[NR] = ours; h[NR] = ceiling; s[NR] = ours / ceiling
    printf "round %d: one thread %.3f s, two threads %.3f s, two processes %.3f and %.3f s: ours %.2fx, ceiling %.2fx, share %.3f\n", $1, $2, $3, $4, $5, ours, ceiling, ours / ceiling
    fflush()
  }
  END { printf "medians over %d rounds: ours %.2fx, ceiling %.2fx, share %.3f\n", NR, median(o, NR), median(h, NR), median(s, NR) }'
