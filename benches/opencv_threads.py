#!/usr/bin/env python3
"""One thread against two, for OpenCV's fastNlMeansDenoisingColored and our
full default filter from memory, on the same 1920x1080 frame.

Called by `THREAD_SCALING=1 bash benches/opencv_compare.sh 2 ROUNDS` (which
makes the venv and the frame). OpenCV gets the frame tone-mapped to 8 bits
as in benches/opencv_compare.py (searchWindowSize=21, templateWindowSize=7);
ours is examples/timing's `full` mode (albedo/normal/depth features, the
direct and indirect light layers, r=10, f=3). Each round runs OpenCV on one
thread, then two, then ours on one thread, then two; it prints each round's
times and both thread-scaling ratios (one thread's time over two threads'),
then the medians and the rounds' own ratios ours / OpenCV per thread count.
"""
import statistics
import subprocess
import sys
import time

import cv2
import numpy as np
import OpenEXR

exr, rounds, timing = sys.argv[1], int(sys.argv[2]), sys.argv[3]
with OpenEXR.File(exr, separate_channels=True) as f:
    ch = f.channels()
    rgb = np.stack([np.asarray(ch[c].pixels, dtype=np.float32) for c in ("R", "G", "B")], axis=-1)
img8 = np.clip(255.0 * (np.maximum(rgb, 0) / (1.0 + np.maximum(rgb, 0))) ** (1 / 2.2) + 0.5, 0, 255).astype(np.uint8)
bgr8 = np.ascontiguousarray(img8[..., ::-1])


def opencv(threads):
    cv2.setNumThreads(threads)
    t = time.perf_counter()
    cv2.fastNlMeansDenoisingColored(bgr8, None, h=10, hColor=10, templateWindowSize=7, searchWindowSize=21)
    return time.perf_counter() - t


def ours(threads):
    out = subprocess.run([timing, "full", "1920", "1080", str(threads), "10", "1"], check=True, capture_output=True, text=True)
    return float(out.stdout.strip().split(",")[5])


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
