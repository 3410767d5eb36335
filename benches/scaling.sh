#!/usr/bin/env bash
# Time vs frame size, vs search radius, and thread scaling, from memory
# through the streaming engine (examples/timing.rs), then the plots of
# docs/performance.md. Writes target/scaling.csv and docs/performance/*.png.
#   bash benches/scaling.sh            # about 12 minutes on 2 cores (ROUNDS=3)
# WARM=1: each ratio round's run is the second of two in one process (it
# reuses the first's pages, as a batch's later frames do; in session 43 a
# first run took about 1.09x a second's time at 1080p, full filter): its own
# time (`REPORT=last`), not the best of the two, which would favour a fast
# first run (until session 46 it was the best). By default each is its
# process's first (cold).
# Plotting needs matplotlib: installed in target/plot-venv on first use.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --example timing
t=target/release/examples/timing
csv=target/scaling.csv
echo "mode,width,height,threads,radius,seconds,ns_per_pixel_offset_thread" > "$csv"
# Time vs size (colour-only and full, 2 threads).
for size in "480 270" "960 540" "1280 720" "1920 1080" "2560 1440" "3840 2160"; do
  $t colour $size 2 10 2 | tee -a "$csv"
  $t full $size 2 10 1 | tee -a "$csv"
done
# Thread scaling and linearity: 1080p and 4K on 1 and 2 threads, in
# alternating rounds (ROUNDS, default 3), so that each ratio compares minima
# taken over the same minutes of this shared, noisy machine.
# Each of these lines also goes to target/scaling-rounds.csv with its round.
rounds=target/scaling-rounds.csv
runs=1
[ "${WARM:-0}" = 1 ] && runs=2 && export REPORT=last
: > "$rounds"
for round in $(seq "${ROUNDS:-3}"); do
  for mode in colour full; do
    for threads in 2 1; do
      for size in "1920 1080" "3840 2160"; do
        line=$($t $mode $size $threads 10 "$runs")
        echo "$line" | tee -a "$csv"
        echo "$round,$line" >> "$rounds"
      done
    done
  done
done
# Time vs search radius (960x540, 2 threads).
for r in 0 2 4 6 8 10 12 14; do
  $t colour 960 540 2 $r 2 | tee -a "$csv"
  $t full 960 540 2 $r 1 | tee -a "$csv"
done
if [ ! -x target/plot-venv/bin/python ]; then
  python3 -m venv target/plot-venv
  target/plot-venv/bin/pip install --quiet matplotlib
fi
target/plot-venv/bin/python benches/plot_scaling.py "$csv" docs/performance
# Minimum per configuration, then the ratios docs/performance.md quotes.
awk -F, 'NR > 1 && $5 == 10 && ($2 == 1920 || $2 == 3840) {
    k = $1 " " $2 " " $4; if (!(k in m) || $6 < m[k]) m[k] = $6 }
  END {
    for (k in m) printf "min %s threads: %.3f s\n", k, m[k]
    split("colour full", modes, " ")
    for (i = 1; i <= 2; i++) { md = modes[i]
      printf "%s: 4K thread scaling %.2fx; 4K/1080p %.2f (2 threads), %.2f (1 thread)\n", md,
        m[md " 3840 1"] / m[md " 3840 2"], m[md " 3840 2"] / m[md " 1920 2"], m[md " 3840 1"] / m[md " 1920 1"] }
  }' "$csv" | sort
# The same ratios from each round's own runs (adjacent in time), and their
# medians: on a host whose speed swings from minute to minute, minima taken
# minutes apart can pair a lucky run with an unlucky one.
awk -F, '{ t[$1 " " $2 " " $3 " " $5] = $7; r[$1] = 1 }
  function median(v, n,   i, j, x) {
    for (i = 2; i <= n; i++) { x = v[i]; for (j = i - 1; j >= 1 && v[j] > x; j--) v[j + 1] = v[j]; v[j + 1] = x }
    return n % 2 ? v[(n + 1) / 2] : (v[n / 2] + v[n / 2 + 1]) / 2
  }
  END {
    split("colour full", modes, " ")
    for (i = 1; i <= 2; i++) { md = modes[i]; n = 0; line = ""
      for (k = 1; k in r; k++) { n++
        s[n] = t[k " " md " 3840 1"] / t[k " " md " 3840 2"]
        l[n] = t[k " " md " 3840 2"] / t[k " " md " 1920 2"]
        line = line sprintf(" %.2f/%.2f", s[n], l[n]) }
      printf "%s, rounds'"'"' medians: 4K thread scaling %.2fx; 4K/1080p %.2f (2 threads); each round (scaling/ratio):%s\n", md, median(s, n), median(l, n), line }
  }' "$rounds"
