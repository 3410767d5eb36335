"""What benches/opencv_compare.py and benches/opencv_threads.py share: the
frame as OpenCV gets it, OpenCV's timed call, and a timed run of our filter
from memory (examples/timing)."""
import os
import subprocess
import time

import cv2
import numpy as np
import OpenEXR


def tone_mapped_bgr8(exr):
    """The EXR's R, G, B tone-mapped to 8 bits (x/(1+x), gamma 1/2.2), in OpenCV's BGR order."""
    with OpenEXR.File(exr, separate_channels=True) as f:
        ch = f.channels()
        rgb = np.stack([np.asarray(ch[c].pixels, dtype=np.float32) for c in ("R", "G", "B")], axis=-1)
    x = np.maximum(rgb, 0)
    img8 = np.clip(255.0 * (x / (1.0 + x)) ** (1 / 2.2) + 0.5, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img8[..., ::-1])


def opencv_seconds(bgr8, threads):
    """One fastNlMeansDenoisingColored run (searchWindowSize=21, templateWindowSize=7: r=10, f=3)."""
    return opencv_times(bgr8, threads)[0]


def opencv_times(bgr8, threads):
    """`opencv_seconds`'s run: its wall time and the process's CPU time over
    it (every thread's: OpenCV's workers included)."""
    cv2.setNumThreads(threads)
    c, t = time.process_time(), time.perf_counter()
    cv2.fastNlMeansDenoisingColored(bgr8, None, h=10, hColor=10, templateWindowSize=7, searchWindowSize=21)
    return time.perf_counter() - t, time.process_time() - c


def memory_seconds(timing, mode, threads, runs=1):
    """`memory_times`' wall time."""
    return memory_times(timing, mode, threads, runs)[0]


def memory_times(timing, mode, threads, runs=1):
    """examples/timing's MODE on the 1920x1080 synthetic frame, r=10: one
    process, `runs` runs, the last run's own time. With runs=1 the run is the
    process's first (cold: every buffer's pages faulted in); with runs=2 it
    is the second (warm: the allocator's pages reused, as by a batch's later
    frames or a library caller's later calls). The last run's time, not the
    best of the runs (as before session 45): the best of two samples would
    pick the first run when the second happens to be slow, a bias in our
    favour that a single OpenCV run does not get. Returns its wall time and
    the process's CPU time over it (every thread's)."""
    env = dict(os.environ, SHARE="1")
    out = subprocess.run(
        [timing, mode, "1920", "1080", str(threads), "10", str(runs)],
        check=True,
        capture_output=True,
        text=True,
        env=env,
    )
    # With SHARE=1 each run prints "run SECONDS s, cpu SECONDS s, kernel ..." to stderr.
    lines = [line.split() for line in out.stderr.splitlines() if line.startswith("run ")]
    if len(lines) != runs or any(w[3] != "cpu" for w in lines):
        raise RuntimeError(f"expected {runs} run lines from {timing}, got {out.stderr!r}")
    return float(lines[-1][1]), float(lines[-1][4])
