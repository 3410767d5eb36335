#!/usr/bin/env python3
"""nldenoise against Intel Open Image Denoise on the shared scenes, with the
OpenEXR reference library reading every file nldenoise writes.

Called by benches/anchors.sh (which makes the venv: pyoidn, openexr, numpy).

For each `<scene>_<spp>spp.exr` with a `<scene>_ref.exr` in SCENES:
  * nldenoise `denoise` with its defaults and with `--layers auto`
    (2 threads, wall time of the process, file in and out);
  * OIDN 2.x RT filter, HDR, `quality="high"`, with albedo (clamped to
    [0, 1]) and normals, and colour only (2 threads: the CPU device takes
    every core of this 2-core machine; timed after a warm-up call, from
    memory);
  * relMSE of R,G,B against the reference (SPEC section 8), every file read
    by OpenEXR.
Interoperability: OpenEXR must read every channel of each nldenoise output,
with the input's channel names, and every channel nldenoise does not
denoise must equal the input's bit for bit. A failure stops the script
(exit 1).

Prints a Markdown table (and the machine, date and versions).
"""
import glob
import importlib.metadata
import os
import platform
import subprocess
import sys
import tempfile
import time

import numpy as np
import OpenEXR
import pyoidn

scenes, binary = sys.argv[1], sys.argv[2]
DENOISED = {"R", "G", "B", "direct.R", "direct.G", "direct.B", "indirect.R", "indirect.G", "indirect.B"}


def channels(path):
    with OpenEXR.File(path, separate_channels=True) as f:
        return {name: np.array(c.pixels) for name, c in f.channels().items()}


def rgb(ch, prefix=""):
    return np.stack([ch[prefix + c].astype(np.float32) for c in ("R", "G", "B")], axis=-1)


def rel_mse(x, ref):
    x, ref = x.astype(np.float64), ref.astype(np.float64)
    return float(np.mean((x - ref) ** 2 / (ref**2 + 0.01)))


def ours(noisy, given, out, extra):
    t = time.perf_counter()
    subprocess.run([binary, "-q", "denoise", noisy, "-o", out, "--threads", "2", *extra], check=True)
    seconds = time.perf_counter() - t
    got = channels(out)
    if sorted(got) != sorted(given):
        sys.exit(f"{out}: OpenEXR reads channels {sorted(got)}, the input has {sorted(given)}")
    for name, values in given.items():
        if name not in DENOISED and (values.dtype != got[name].dtype or values.tobytes() != got[name].tobytes()):
            sys.exit(f"{out}: channel {name} as read by OpenEXR differs from the input's")
    return rgb(got), seconds


def oidn(colour, albedo=None, normal=None):
    pyoidn.denoise(colour, albedo, normal, hdr=True, quality="high")  # warm-up
    t = time.perf_counter()
    out = pyoidn.denoise(colour, albedo, normal, hdr=True, quality="high")
    return out, time.perf_counter() - t


rows = []
with tempfile.TemporaryDirectory() as tmp:
    for noisy in sorted(glob.glob(os.path.join(scenes, "*_*spp.exr"))):
        name = os.path.basename(noisy)[: -len(".exr")]
        ref_path = os.path.join(scenes, name.rsplit("_", 1)[0] + "_ref.exr")
        if not os.path.exists(ref_path):
            continue
        ch, ref = channels(noisy), rgb(channels(ref_path))
        colour = np.ascontiguousarray(np.maximum(rgb(ch), 0))
        albedo = np.ascontiguousarray(np.clip(rgb(ch, "albedo."), 0, 1))
        normal = np.ascontiguousarray(np.clip(np.stack([ch["N." + c] for c in "XYZ"], -1).astype(np.float32), -1, 1))
        default, t_default = ours(noisy, ch, os.path.join(tmp, "default.exr"), [])
        layers, t_layers = ours(noisy, ch, os.path.join(tmp, "layers.exr"), ["--layers", "auto"])
        o_aux, t_aux = oidn(colour, albedo, normal)
        o_col, t_col = oidn(colour)
        rows.append((name, rel_mse(rgb(ch), ref), (rel_mse(default, ref), t_default), (rel_mse(layers, ref), t_layers),
                     (rel_mse(o_aux, ref), t_aux), (rel_mse(o_col, ref), t_col)))

if not rows:
    sys.exit(f"no <scene>_<spp>spp.exr with its <scene>_ref.exr in {scenes}")
cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), platform.machine())
print(f"machine: {cpu}, {os.cpu_count()} cores; {time.strftime('%Y-%m-%d', time.gmtime())}; "
      f"OpenEXR {OpenEXR.__version__}, pyoidn {importlib.metadata.version('pyoidn')}")
print()
print("| file | noisy | nldenoise default | nldenoise --layers auto | OIDN RT + albedo + normal | OIDN RT colour only |")
print("|---|---|---|---|---|---|")
for name, noisy, *cols in rows:
    cells = " | ".join(f"{e:.5f} ({s:.2f} s)" for e, s in cols)
    print(f"| {name} | {noisy:.5f} | {cells} |")
for spp in sorted({r[0].rsplit("_", 1)[1] for r in rows}):
    sel = [r for r in rows if r[0].endswith(spp)]
    gm = [float(np.exp(np.mean([np.log(r[1] / r[k][0]) for r in sel]))) for k in range(2, 6)]
    print(f"| geometric-mean reduction, {spp} | | " + " | ".join(f"{g:.2f}x" for g in gm) + " |")
print()
print(f"OpenEXR read every channel of the {2 * len(rows)} nldenoise outputs; the channels not denoised equal the inputs'.")
