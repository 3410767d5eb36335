#!/usr/bin/env python3
"""One thread against two, for OpenCV's fastNlMeansDenoisingColored and our
full default filter from memory, on the same 1920x1080 frame.

Called by `THREAD_SCALING=1 bash benches/opencv_compare.sh 2 ROUNDS` (which
makes the venv and the frame). OpenCV gets the frame tone-mapped to 8 bits
(benches/opencv_common.py, as for benches/opencv_compare.py;
searchWindowSize=21, templateWindowSize=7);
ours is examples/timing's `full` mode (albedo/normal/depth features, the
direct and indirect light layers, r=10, f=3). Each round runs OpenCV on one
thread, then two, then ours on one thread, then two; it prints each round's
times and both thread-scaling ratios (one thread's time over two threads'),
then the medians and the rounds' own ratios ours / OpenCV per thread count.
"""
import statistics
import sys

import cv2

from opencv_common import memory_seconds, opencv_seconds, tone_mapped_bgr8

exr, rounds, timing = sys.argv[1], int(sys.argv[2]), sys.argv[3]
bgr8 = tone_mapped_bgr8(exr)


def opencv(threads):
    return opencv_seconds(bgr8, threads)


def ours(threads):
    return memory_seconds(timing, "full", threads)


runs = {"opencv 1": [], "opencv 2": [], "ours 1": [], "ours 2": []}
for r in range(rounds):
    for name, f, n in (("opencv 1", opencv, 1), ("opencv 2", opencv, 2), ("ours 1", ours, 1), ("ours 2", ours, 2)):
        runs[name].append(f(n))
    print(
        f"round {r + 1}: " + ", ".join(f"{k} {v[-1]:.2f} s" for k, v in runs.items())
        + f"; scaling OpenCV {runs['opencv 1'][-1] / runs['opencv 2'][-1]:.2f}x, ours {runs['ours 1'][-1] / runs['ours 2'][-1]:.2f}x",
        flush=True,
    )
print(f"frame 1920x1080, {rounds} rounds, OpenCV {cv2.__version__}, ours: full default filter from memory")
print("medians: " + ", ".join(f"{k} {statistics.median(v):.2f} s" for k, v in runs.items()))
for n in (1, 2):
    ratios = [o / c for o, c in zip(runs[f"ours {n}"], runs[f"opencv {n}"])]
    print(f"{n} thread(s), round ratios ours / OpenCV: median {statistics.median(ratios):.2f} {['%.2f' % x for x in ratios]}")
for k in ("opencv", "ours"):
    s = [a / b for a, b in zip(runs[f"{k} 1"], runs[f"{k} 2"])]
    print(f"{k}: two threads {statistics.median(s):.2f}x faster than one (median of rounds)")
