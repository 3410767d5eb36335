#!/usr/bin/env bash
# The CLI's transparent huge pages (`engine::budget::exec_with_huge_pages`)
# off and on, in alternated pairs of one binary (docs/performance.md,
# session 51).
#
#   bash benches/huge_pages.sh [PAIRS]
#
# Each pair runs `examples/timing full 1920 1080 2 10 1` (a cold run) with
# NLDENOISE_HUGE_PAGES=0 and by default, in the reverse order every other
# pair, under /usr/bin/time, and prints the run's time, the process's
# system time, page faults and peak. With MEMORY=1 each pair also runs
# `nldenoise denoise` on an 8192x2048 frame of 19 channels under
# `--memory-limit 192M --search-radius 3 --patch-radius 1` (the budget's
# peak with and without huge pages). The binaries are built if missing;
# TIMING=... and NLDENOISE=... name others.
set -euo pipefail
cd "$(dirname "$0")/.."
PAIRS=${1:-6}
timing=${TIMING:-target/release/examples/timing}
nld=${NLDENOISE:-target/release/nldenoise}
[ -x "$timing" ] && [ -x "$nld" ] && [ -x target/release/examples/make_big_frame ] ||
  cargo build --release --bin nldenoise --example timing --example make_big_frame >/dev/null 2>&1
[ -x /usr/bin/time ] || { echo "needs /usr/bin/time (apt-get install time)"; exit 1; }
frame=target/membench/in_8192x2048.exr
if [ "${MEMORY:-0}" = 1 ] && [ ! -f "$frame" ]; then
  mkdir -p target/membench
  ./target/release/examples/make_big_frame 8192 2048 "$frame" --features >/dev/null 2>&1
fi
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores; THP $(cat /sys/kernel/mm/transparent_hugepage/enabled 2>/dev/null); $(date -u '+%Y-%m-%d %H:%M') UTC"
one() { # setting (0 or default)
  local env=(env -u NLDENOISE_HUGE_PAGES)
  [ "$1" = 0 ] && env=(env NLDENOISE_HUGE_PAGES=0)
  local run
  run=$("${env[@]}" /usr/bin/time -f '%S %R %M' -o "$out/t" "$timing" full 1920 1080 2 10 1 | cut -d, -f6)
  read -r sys faults peak < "$out/t"
  printf 'huge pages %-7s run %s s, system %s s, faults %s, peak %d MB' "$1" "$run" "$sys" "$faults" $((peak / 1024))
  if [ "${MEMORY:-0}" = 1 ]; then
    "${env[@]}" /usr/bin/time -f '%S %R %M' -o "$out/t" "$nld" -q denoise "$frame" -o "$out/out.exr" \
      --memory-limit 192M --search-radius 3 --patch-radius 1
    read -r sys faults peak < "$out/t"
    printf '; bounded run: faults %s, peak %d MB' "$faults" $((peak / 1024))
  fi
  echo
}
for i in $(seq "$PAIRS"); do
  if [ $((i % 2)) = 1 ]; then one 0; one default; else one default; one 0; fi
done
