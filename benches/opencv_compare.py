#!/usr/bin/env python3
"""Time nldenoise against OpenCV's fastNlMeansDenoisingColored on the same frame.

Called by benches/opencv_compare.sh (which makes the venv). OpenCV gets the
frame's R,G,B tone-mapped to 8 bits (x/(1+x), gamma 1/2.2), searchWindowSize=21,
templateWindowSize=7 (the same r=10, f=3 as ours), the given thread count, from
memory. Ours, with the same thread count: `nldenoise denoise --layers auto` on
the EXR (the full default filter: albedo/normal/depth features and the direct
and indirect light layers, file in and out), and the same frame's filter from
memory (examples/timing: colour-only, full, and full-var: the full filter
with a variance per feature channel, the path real renders take; the
synthetic frame has none otherwise), each in a process of its own (cold: its
buffers' pages faulted in), and the full filter also warm (the second of two
runs in one process, as a batch's later frames or a library caller's later
calls run; OpenCV's calls after the first are warm too). All are run alternately,
ROUNDS times; the medians, the ratios to OpenCV, and each round's own
ratios (runs of the same minutes) are printed; then the CPU time (every
thread's) of OpenCV's runs and of the full filter's from memory, cold and
warm, which the host's other guests move less than the wall times (since
session 46).
"""
import statistics
import subprocess
import sys
import time

import cv2

from opencv_common import memory_times, opencv_times, tone_mapped_bgr8

exr, binary, threads, rounds, timing = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
extra = sys.argv[6:] or ["--layers", "auto"]
bgr8 = tone_mapped_bgr8(exr)


ours, theirs, mem_colour, mem_full, mem_fullvar, mem_warm = [], [], [], [], [], []
# CPU seconds (every thread's) of OpenCV's runs and of the full filter's,
# cold and warm: the host's other guests move them less than wall times.
cpu_theirs, cpu_full, cpu_warm = [], [], []
for _ in range(rounds):
    wall, cpu = opencv_times(bgr8, threads)
    theirs.append(wall)
    cpu_theirs.append(cpu)
    t = time.perf_counter()
    subprocess.run([binary, "-q", "denoise", exr, "-o", "/tmp/opencv_compare_out.exr", "--threads", str(threads), *extra], check=True)
    ours.append(time.perf_counter() - t)
    mem_colour.append(memory_times(timing, "colour", threads)[0])
    wall, cpu = memory_times(timing, "full", threads)
    mem_full.append(wall)
    cpu_full.append(cpu)
    mem_fullvar.append(memory_times(timing, "full-var", threads)[0])
    wall, cpu = memory_times(timing, "full", threads, runs=2)
    mem_warm.append(wall)
    cpu_warm.append(cpu)

h, w = bgr8.shape[:2]
mo, mt = statistics.median(ours), statistics.median(theirs)
print(f"frame {w}x{h}, {threads} threads, {rounds} alternating rounds, OpenCV {cv2.__version__}")
print(f"OpenCV fastNlMeansDenoisingColored (8-bit, r=10, f=3): median {mt:.2f} s  {['%.2f' % x for x in theirs]}")
print(f"nldenoise denoise {' '.join(extra)} (f32, file in and out): median {mo:.2f} s  {['%.2f' % x for x in ours]}")
mc, mf = statistics.median(mem_colour), statistics.median(mem_full)
print(f"nldenoise filter from memory, colour only: median {mc:.2f} s  {['%.2f' % x for x in mem_colour]}")
print(f"nldenoise filter from memory, full default: median {mf:.2f} s  {['%.2f' % x for x in mem_full]}")
mw = statistics.median(mem_warm)
print(f"nldenoise filter from memory, full default, warm (second run in the process): median {mw:.2f} s  {['%.2f' % x for x in mem_warm]}")
mv = statistics.median(mem_fullvar)
print(f"nldenoise filter from memory, full default with feature variances: median {mv:.2f} s  {['%.2f' % x for x in mem_fullvar]}")
print(
    f"ratio to OpenCV: file {mo / mt:.2f}, memory full {mf / mt:.2f}, memory full warm {mw / mt:.2f}, "
    f"memory full with feature variances {mv / mt:.2f}, "
    f"memory colour-only {mc / mt:.2f}"
)
# Each round's own ratio: its runs share the same minutes of the host's load,
# which the medians above, taken over the whole run, do not pair.
rounds_full = [f / t for f, t in zip(mem_full, theirs)]
rounds_file = [o / t for o, t in zip(ours, theirs)]
rounds_warm = [f / t for f, t in zip(mem_warm, theirs)]
print(
    f"round ratios, memory full / OpenCV: median {statistics.median(rounds_full):.2f} "
    f"{['%.2f' % x for x in rounds_full]}, faster than OpenCV in {sum(x < 1 for x in rounds_full)} of {rounds}"
)
print(
    f"round ratios, memory full warm / OpenCV: median {statistics.median(rounds_warm):.2f} "
    f"{['%.2f' % x for x in rounds_warm]}, faster than OpenCV in {sum(x < 1 for x in rounds_warm)} of {rounds}"
)
print(f"round ratios, file / OpenCV: median {statistics.median(rounds_file):.2f} {['%.2f' % x for x in rounds_file]}")
ct, cf, cw = (statistics.median(x) for x in (cpu_theirs, cpu_full, cpu_warm))
print(
    f"CPU time (every thread's), medians: OpenCV {ct:.2f} s {['%.2f' % x for x in cpu_theirs]}, "
    f"memory full {cf:.2f} s {['%.2f' % x for x in cpu_full]}, warm {cw:.2f} s {['%.2f' % x for x in cpu_warm]}; "
    f"ratios {cf / ct:.2f} and {cw / ct:.2f}"
)
