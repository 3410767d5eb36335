#!/usr/bin/env bash
# Time vs frame size, vs search radius, and thread scaling, from memory
# through the streaming engine (examples/timing.rs), then the plots of
# docs/performance.md. Writes target/scaling.csv and docs/performance/*.png.
#   bash benches/scaling.sh            # about 6 minutes on 2 cores
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
# Thread scaling at 4K and 1080p (1 thread).
$t colour 3840 2160 1 10 1 | tee -a "$csv"
$t full 3840 2160 1 10 1 | tee -a "$csv"
$t colour 1920 1080 1 10 2 | tee -a "$csv"
$t full 1920 1080 1 10 1 | tee -a "$csv"
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
