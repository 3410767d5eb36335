"""Plots for docs/performance.md from benches/scaling.sh's CSV:
time vs frame size (megapixels) and time vs search radius, colour-only and
full default filter, 2 threads."""
import csv
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

rows = list(csv.DictReader(open(sys.argv[1])))
out = Path(sys.argv[2])
out.mkdir(parents=True, exist_ok=True)
label = {"colour": "colour only", "full": "features + 2 light layers"}


def series(mode, key, **fixed):
    pts = []
    for r in rows:
        if r["mode"] == mode and all(r[k] == str(v) for k, v in fixed.items()):
            pts.append((key(r), float(r["seconds"])))
    # Keep the best time per x (a point may be measured twice).
    best = {}
    for x, s in pts:
        best[x] = min(s, best.get(x, s))
    return sorted(best.items())


def plot(name, key, fixed, xlabel, ylabel, title):
    fig, ax = plt.subplots(figsize=(6, 4))
    for mode in ("colour", "full"):
        pts = series(mode, key, **fixed)
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=label[mode])
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / name, dpi=110)


plot(
    "time_vs_size.png",
    lambda r: int(r["width"]) * int(r["height"]) / 1e6,
    dict(threads=2, radius=10),
    "frame size (megapixels)",
    "seconds (2 threads, r=10, f=3)",
    "nldenoise: time vs frame size (from memory)",
)
plot(
    "time_vs_radius.png",
    lambda r: int(r["radius"]),
    dict(threads=2, width=960, height=540),
    "search radius r (window (2r+1)^2)",
    "seconds (960x540, 2 threads, f=3)",
    "nldenoise: time vs search radius",
)
print("plots written to", out)
