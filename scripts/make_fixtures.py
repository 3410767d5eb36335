#!/usr/bin/env python3
"""Render the small test fixtures in fixtures/ with Mitsuba 3 (scalar_rgb).

Usage (from the repository root):

    bash scripts/make_fixtures.sh          # creates a venv, installs mitsuba/numpy/openexr, runs this

Writes fixtures/cornell_0032spp.exr (noisy, 38 channels in the layout of
../shared/scenes: R,G,B, A.*/B.* halves, var.*, albedo/N/Z features with their
variances, direct/indirect light layers with variances) and
fixtures/cornell_ref.exr (R,G,B and var.*, 2048 spp with other seeds).

The scene is Mitsuba's Cornell box with a checkerboard back wall (albedo edges
for the joint filter), a box pixel filter and the independent sampler, so the
sub-render statistics are exact: K = 8 sub-renders of 4 spp each, halves are the
means of sub-renders 0-3 and 4-7, variances are the sample variance (ddof=1)
across the sub-render means divided by K. `direct` is the same tracer with
max_depth=2 and the same seeds, `indirect = colour - direct` per sub-render.
"""
import os
import sys

import numpy as np
import mitsuba as mi
import OpenEXR

mi.set_variant("scalar_rgb")

W, H = 96, 64
K, SPP_SUB = 8, 4
REF_PASSES, REF_SPP = 8, 256
OUT = sys.argv[1] if len(sys.argv) > 1 else "fixtures"


def scene():
    d = mi.cornell_box()
    d["sensor"]["film"]["width"] = W
    d["sensor"]["film"]["height"] = H
    d["sensor"]["film"]["rfilter"] = {"type": "box"}
    d["sensor"]["fov_axis"] = "larger"  # the box fills the wide frame (no black outside)
    d["back"]["bsdf"] = {
        "type": "diffuse",
        "reflectance": {
            "type": "checkerboard",
            "color0": {"type": "rgb", "value": [0.15, 0.15, 0.15]},
            "color1": {"type": "rgb", "value": [0.8, 0.75, 0.6]},
            "to_uv": mi.ScalarTransform4f().scale([6, 6, 1]),
        },
    }
    return mi.load_dict(d)


def aov_integrator(max_depth):
    return mi.load_dict({
        "type": "aov",
        "aovs": "albedo:albedo,nn:sh_normal,dd:depth",
        "integrator": {"type": "path", "max_depth": max_depth},
    })


def main():
    os.makedirs(OUT, exist_ok=True)
    sc = scene()
    full, direct = aov_integrator(6), aov_integrator(2)
    subs, dsubs = [], []
    for i in range(K):
        seed = 7000 + i
        subs.append(np.array(mi.render(sc, integrator=full, spp=SPP_SUB, seed=seed), dtype=np.float64))
        dsubs.append(np.array(mi.render(sc, integrator=direct, spp=SPP_SUB, seed=seed), dtype=np.float64))
    subs, dsubs = np.stack(subs), np.stack(dsubs)  # K x H x W x 10
    colour, dcol = subs[..., 0:3], dsubs[..., 0:3]
    indirect = colour - dcol

    def mean_var(x):
        return x.mean(0), x.var(0, ddof=1) / K

    ch = {}
    half = lambda a: a.astype(np.float16)
    f32 = lambda a: a.astype(np.float32)
    m, v = mean_var(colour)
    for c, n in enumerate("RGB"):
        ch[n] = half(m[..., c])
        ch[f"var.{n}"] = f32(v[..., c])
        ch[f"A.{n}"] = half(colour[: K // 2, ..., c].mean(0))
        ch[f"B.{n}"] = half(colour[K // 2 :, ..., c].mean(0))
    for name, x in (("direct", dcol), ("indirect", indirect)):
        m, v = mean_var(x)
        for c, n in enumerate("RGB"):
            ch[f"{name}.{n}"] = half(m[..., c])
            ch[f"var.{name}.{n}"] = f32(v[..., c])
    for name, sl, leaves in (("albedo", slice(3, 6), "RGB"), ("N", slice(6, 9), "XYZ")):
        m, v = mean_var(subs[..., sl])
        for c, n in enumerate(leaves):
            ch[f"{name}.{n}"] = half(m[..., c])
            ch[f"{name}_var.{n}"] = f32(v[..., c])
    m, v = mean_var(subs[..., 9])
    ch["Z"], ch["Z_var"] = f32(m), f32(v)

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    noisy_path = os.path.join(OUT, f"cornell_{K * SPP_SUB:04d}spp.exr")
    with OpenEXR.File(header, ch) as f:
        f.write(noisy_path)

    passes = [np.array(mi.render(sc, spp=REF_SPP, seed=90000 + p), dtype=np.float64)[..., :3] for p in range(REF_PASSES)]
    passes = np.stack(passes)
    m, v = passes.mean(0), passes.var(0, ddof=1) / REF_PASSES
    ref = {}
    for c, n in enumerate("RGB"):
        ref[n] = f32(m[..., c])
        ref[f"var.{n}"] = f32(v[..., c])
    with OpenEXR.File(header, ref) as f:
        f.write(os.path.join(OUT, "cornell_ref.exr"))
    noisy_rel = np.mean((colour.mean(0) - m) ** 2 / (m ** 2 + 0.01))
    print(f"wrote {noisy_path} ({len(ch)} channels) and cornell_ref.exr; noisy relMSE {noisy_rel:.5f}")


if __name__ == "__main__":
    main()
