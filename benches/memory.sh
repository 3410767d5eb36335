#!/usr/bin/env bash
# Bounded-memory benchmark of the streaming engine (docs/performance.md).
#
#   bash benches/memory.sh [WIDTH] [HEIGHT] [LIMIT] [DIR]
#
# Generates synthetic frames with colour, half buffers, variance and features
# (19 channels) of WIDTH x HEIGHT/4 and WIDTH x HEIGHT, denoises each with
# --memory-limit LIMIT, and reports the peak resident memory (/usr/bin/time -v)
# and its growth when the height is multiplied by 4. Search radius 3, patch
# radius 1 keep the run short: memory does not depend on them beyond the halo.
# With HEADLINE=1 it also denoises a frame whose decoded channels exceed this
# machine's memory.
set -euo pipefail
cd "$(dirname "$0")/.."
W=${1:-16384}; H=${2:-16384}; LIMIT=${3:-512M}; DIR=${4:-target/membench}
mkdir -p "$DIR"
cargo build --release --example make_big_frame --bin nldenoise >/dev/null 2>&1
[ -x /usr/bin/time ] || { echo "needs /usr/bin/time (apt-get install time)"; exit 1; }
FILTER=(--search-radius 3 --patch-radius 1)
run() { # width height
  local w=$1 h=$2 in="$DIR/in_${1}x${2}.exr" out="$DIR/out_${1}x${2}.exr"
  [ -f "$in" ] || ./target/release/examples/make_big_frame "$w" "$h" "$in" --features >&2
  local decoded=$(( w * h * 19 * 4 ))
  /usr/bin/time -v ./target/release/nldenoise -v denoise "$in" -o "$out" --memory-limit "$LIMIT" "${FILTER[@]}" 2> "$DIR/log_${w}x${h}.txt"
  local kb=$(grep "Maximum resident" "$DIR/log_${w}x${h}.txt" | awk '{print $NF}')
  local wall=$(grep "Elapsed (wall" "$DIR/log_${w}x${h}.txt" | awk '{print $NF}')
  printf '%s x %s: decoded channels %.1f GiB, file %.1f GiB, limit %s, peak RSS %.1f MiB, wall %s\n' \
    "$w" "$h" "$(echo "$decoded/1073741824" | bc -l)" "$(echo "$(stat -c %s "$in")/1073741824" | bc -l)" "$LIMIT" "$(echo "$kb/1024" | bc -l)" "$wall"
  grep -E "plan:" "$DIR/log_${w}x${h}.txt" | sed 's/.*INFO //' || true
  rm -f "$out"
  echo "$kb" > "$DIR/peak_${w}x${h}"
}
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores, $(free -g | awk '/Mem:/{print $2}') GiB; $(date -u +%Y-%m-%d)"
run "$W" $((H / 4))
run "$W" "$H"
a=$(cat "$DIR/peak_${W}x$((H / 4))"); b=$(cat "$DIR/peak_${W}x${H}")
printf 'peak growth for 4x the height: %+.1f %%\n' "$(echo "($b - $a) * 100 / $a" | bc -l)"
if [ "${HEADLINE:-0}" = 1 ]; then
  # 19 channels x 4 bytes x 16384 x 22000 = 27.4 GB decoded > 24 GiB of RAM.
  run 16384 22000
fi
rm -f "$DIR"/in_*.exr
