#!/usr/bin/env bash
# A/B timing of two builds of `examples/timing` on this shared, noisy
# machine (docs/performance.md's step tables).
#
#   bash benches/ab.sh alternate ROUNDS MODE WIDTH HEIGHT THREADS BIN_A BIN_B...
#   bash benches/ab.sh paired    ROUNDS MODE WIDTH HEIGHT BIN_A BIN_B
#   bash benches/ab.sh interleave PAIRS MODE WIDTH HEIGHT BIN_A BIN_B
#   bash benches/ab.sh modes ROUNDS - WIDTH HEIGHT BIN MODE...
#   bash benches/ab.sh cpus ROUNDS MODE WIDTH HEIGHT THREADS BIN_A BIN_B...
#   bash benches/ab.sh files ROUNDS - WIDTH HEIGHT THREADS NLDENOISE_A NLDENOISE_B...
#
# alternate: runs the binaries one after the other, ROUNDS times, in the
#   reverse order every other round (a binary's place in the round moved
#   the rounds' median by up to 2 % on the Zen 4 of session 42), and prints
#   each one's minimum and all its times (RUNS=N runs per process, default 1,
#   of which the binary reports the minimum; the i-th time of each binary
#   is from round i).
# paired: runs A and B at the same time, one thread each, pinned to cores 0
#   and 1 (swapped every round), so that both see the same load; prints each
#   round's B/A and the median, min and max of the ratios (RUNS default 2).
# interleave: on each core at once, PAIRS back-to-back runs of A then B (core
#   1: B then A), one thread each; prints the median and quartiles of the
#   2 x PAIRS ratios B/A of adjacent runs (RUNS default 1). Adjacent runs
#   share the load of the same seconds, so this resists slow swings of the
#   shared host better than `paired`.
# modes: one binary, its MODEs (colour, layers, features, full) run one
#   after the other ROUNDS times on each core at once, one thread each;
#   prints each mode's minimum and all its times (the cost of each part of
#   the full filter, measured over the same minutes).
# cpus: how many CPUs each binary keeps busy while it filters: `perf stat`'s
#   task-clock and the wall time of one process with 1 run and one with 5;
#   the 4 extra runs' CPU time over their wall time (the frame's synthesis,
#   single-threaded, cancels out). ROUNDS times, binaries in turn.
# files: the file run of `benches/opencv_compare.sh` (`nldenoise denoise
#   --layers auto`, EXR in and out) with each `nldenoise` binary in turn,
#   ROUNDS times (in the reverse order every other round), on a
#   WIDTHxHEIGHT frame from `examples/make_big_frame` (features and light
#   layers, 31 channels, made once under target/), or with FRAMES=N a
#   sequence of N links to it in one process (a batch: buffers reused
#   from frame to frame);
#   prints each binary's minimum wall time, all its wall times, its median
#   CPU time (user + sys), its median page faults and its output's size in
#   bytes (all frames'). FRAME="--features" changes the frame's channels (19 channels, as
#   benches/memory.sh), ARGS="--memory-limit 256M --search-radius 3
#   --patch-radius 1" the denoise options (default "--layers auto").
# RADIUS=R sets examples/timing's search radius (default 10; RADIUS=0 times
# the fixed cost: the frame's stages before the kernel and the centre
# offset); the files mode takes the radius in ARGS.
# Build an older commit's binary with e.g.
#   git worktree add /tmp/old REV && (cd /tmp/old && cargo build --release --example timing)
set -euo pipefail
# Lines "NAME SECONDS" -> each name's minimum and all its times.
minima() {
  awk '{ if (!($1 in m) || $2 < m[$1]) m[$1] = $2; s[$1] = s[$1] " " $2 }
       END { for (k in m) print k, "min", m[k], "all", s[k] }'
}
# The binaries of round $1 (of the rest): as given in odd rounds, reversed
# in even ones, so that no binary always runs first.
round_order() {
  local i=$1; shift
  if [ $((i % 2)) = 1 ]; then
    printf '%s\n' "$@"
  else
    printf '%s\n' "$@" | tac
  fi
}
how=$1; rounds=$2; mode=$3; w=$4; h=$5; shift 5
radius=${RADIUS:-10}
case "$how" in
  alternate)
    threads=$1; shift
    for i in $(seq "$rounds"); do
      mapfile -t order < <(round_order "$i" "$@")
      for b in "${order[@]}"; do
        echo "$b $("$b" "$mode" "$w" "$h" "$threads" "$radius" "${RUNS:-1}" | cut -d, -f6)"
      done
    done | minima
    ;;
  paired)
    a=$1; b=$2
    tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
    for i in $(seq "$rounds"); do
      if [ $((i % 2)) = 0 ]; then ca=0; cb=1; else ca=1; cb=0; fi
      taskset -c $ca "$a" "$mode" "$w" "$h" 1 "$radius" "${RUNS:-2}" | cut -d, -f6 > "$tmp/a" &
      taskset -c $cb "$b" "$mode" "$w" "$h" 1 "$radius" "${RUNS:-2}" | cut -d, -f6 > "$tmp/b" &
      wait
      echo "$(cat "$tmp/a") $(cat "$tmp/b")" | awk '{ print $1, $2, $2 / $1 }' | tee -a "$tmp/rounds"
    done
    awk '{ print $3 }' "$tmp/rounds" | sort -g | awk '{ r[NR] = $1 }
      END { print "median B/A", r[int((NR + 1) / 2)], "min", r[1], "max", r[NR] }'
    ;;
  interleave)
    a=$1; b=$2
    tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
    one() { taskset -c "$1" "$2" "$mode" "$w" "$h" 1 "$radius" "${RUNS:-1}" | cut -d, -f6; }
    for core in 0 1; do
      if [ "$core" = 0 ]; then first=$a; second=$b; else first=$b; second=$a; fi
      for _ in $(seq "$rounds"); do
        x=$(one "$core" "$first"); y=$(one "$core" "$second")
        if [ "$core" = 0 ]; then echo "$x $y"; else echo "$y $x"; fi
      done > "$tmp/core$core" &
    done
    wait
    cat "$tmp/core0" "$tmp/core1" | awk '{ print $2 / $1 }' | sort -g | awk '{ r[NR] = $1 }
      END { printf "pairs %d median B/A %.4f quartiles %.4f %.4f min %.4f max %.4f\n",
            NR, r[int((NR + 1) / 2)], r[int((NR + 3) / 4)], r[int((3 * NR + 1) / 4)], r[1], r[NR] }'
    ;;
  modes)
    bin=$1; shift
    tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
    for core in 0 1; do
      for _ in $(seq "$rounds"); do
        for m in "$@"; do
          echo "$m $(taskset -c "$core" "$bin" "$m" "$w" "$h" 1 "$radius" "${RUNS:-1}" | cut -d, -f6)"
        done
      done > "$tmp/core$core" &
    done
    wait
    cat "$tmp/core0" "$tmp/core1" | minima
    ;;
  cpus)
    threads=$1; shift
    tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
    # Prints "task-clock-ms wall-ms" of one process making N runs.
    measure() {
      local s e
      s=$(date +%s%N)
      perf stat -e task-clock -x, -o "$tmp/stat" "$1" "$mode" "$w" "$h" "$threads" "$radius" "$2" >/dev/null
      e=$(date +%s%N)
      echo "$(grep task-clock "$tmp/stat" | cut -d, -f1) $(( (e - s) / 1000000 ))"
    }
    for _ in $(seq "$rounds"); do
      for b in "$@"; do
        read -r t1 w1 < <(measure "$b" 1)
        read -r t5 w5 < <(measure "$b" 5)
        awk -v b="$b" -v t1="$t1" -v w1="$w1" -v t5="$t5" -v w5="$w5" \
          'BEGIN { printf "%s cpus %.3f, %.3f s per extra run\n", b, (t5 - t1) / (w5 - w1), (w5 - w1) / 4000 }'
      done
    done
    ;;
  files)
    threads=$1; shift
    tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
    command -v perf >/dev/null || { echo "needs perf (apt-get install linux-perf)" >&2; exit 1; }
    [ -x /usr/bin/time ] || { echo "needs /usr/bin/time (apt-get install time)" >&2; exit 1; }
    read -r -a frame_flags <<< "${FRAME:---features --layers}"
    read -r -a args <<< "${ARGS:---layers auto}"
    frame=target/ab-files-${w}x${h}$(printf '%s' "${frame_flags[@]}" | tr -d ' -').exr
    if [ ! -f "$frame" ]; then
      cargo build --release --example make_big_frame >/dev/null 2>&1
      target/release/examples/make_big_frame "$w" "$h" "$frame" "${frame_flags[@]}" 2>/dev/null
    fi
    # FRAMES=N: a sequence of N frames (links to the one frame), one process.
    input=("$frame"); out=out.exr
    if [ "${FRAMES:-1}" -gt 1 ]; then
      mkdir "$tmp/seq"
      for n in $(seq "$FRAMES"); do ln -s "$PWD/$frame" "$(printf '%s/seq.%04d.exr' "$tmp/seq" "$n")"; done
      input=("$tmp/seq/seq.####.exr"); out=
    fi
    median() { tr ' ' '\n' | sed '/^$/d' | sort -g | awk '{ r[NR] = $1 } END { print r[int((NR + 1) / 2)] }'; }
    for i in $(seq "$rounds"); do
      mapfile -t order < <(round_order "$i" "$@")
      for b in "${order[@]}"; do
        rm -rf "$tmp/out"; mkdir "$tmp/out"
        /usr/bin/time -f '%e %U %S' -o "$tmp/t" perf stat -e page-faults -x, -o "$tmp/pf" \
          "$b" -q denoise "${input[@]}" -o "$tmp/out/$out" --threads "$threads" "${args[@]}"
        echo "$b $(cat "$tmp/t") $(cat "$tmp/out"/* | wc -c) $(grep page-faults "$tmp/pf" | cut -d, -f1)"
      done
    done > "$tmp/runs"
    awk '{ print $1, $2 }' "$tmp/runs" | minima
    awk '{ c[$1] = c[$1] " " ($3 + $4); f[$1] = f[$1] " " $6; z[$1] = $5 }
         END { for (k in c) print k, z[k], c[k], "|", f[k] }' "$tmp/runs" |
      while read -r b bytes rest; do
        echo "$b cpu median $(echo "${rest% | *}" | median) s, page faults median $(echo "${rest#* | }" | median), output $bytes bytes"
      done
    ;;
  *) echo "usage: ab.sh alternate|paired|interleave|modes|cpus|files ROUNDS MODE WIDTH HEIGHT [THREADS] BIN_A BIN_B..." >&2; exit 2 ;;
esac
