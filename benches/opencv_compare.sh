#!/usr/bin/env bash
# nldenoise vs OpenCV fastNlMeansDenoisingColored on a 1920x1080 frame, measured
# alternately in one run (docs/performance.md).
#   bash benches/opencv_compare.sh [THREADS] [ROUNDS] [extra nldenoise options...]
# With THREAD_SCALING=1: one thread against two for both, ROUNDS rounds
# (benches/opencv_threads.py; THREADS and the options are then unused).
set -euo pipefail
cd "$(dirname "$0")/.."
THREADS=${1:-2}; ROUNDS=${2:-3}; shift $(( $# > 2 ? 2 : $# )) || true
venv=target/opencv-venv
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
# One OpenCV release for every run, so that its time stays the same
# reference from machine to machine (docs/performance.md names the release
# of each run); OPENCV="opencv-python-headless==X" compares another.
"$venv/bin/pip" install -q "${OPENCV:-opencv-python-headless==5.1.0.95}" numpy "openexr>=3.3"
cargo build --release --bin nldenoise --example make_big_frame --example timing >/dev/null 2>&1
frame=target/opencv-compare-1080p-layers.exr
[ -f "$frame" ] || ./target/release/examples/make_big_frame 1920 1080 "$frame" --features --layers
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores; $(date -u +%Y-%m-%d)"
if [ "${THREAD_SCALING:-0}" = 1 ]; then
  exec "$venv/bin/python" benches/opencv_threads.py "$frame" "$ROUNDS" ./target/release/examples/timing
fi
"$venv/bin/python" benches/opencv_compare.py "$frame" ./target/release/nldenoise "$THREADS" "$ROUNDS" ./target/release/examples/timing "$@"
