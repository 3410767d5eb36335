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


fig, ax = plt.subplots(figsize=(6, 4))
for mode in ("colour", "full"):
    pts = series(mode, lambda r: int(r["width"]) * int(r["height"]) / 1e6, threads=2, radius=10)
    ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=label[mode])
ax.set_xlabel("frame size (megapixels)")
ax.set_ylabel("seconds (2 threads, r=10, f=3)")
ax.set_title("nldenoise: time vs frame size (from memory)")
ax.grid(True, alpha=0.3)
ax.legend()
fig.tight_layout()
fig.savefig(out / "time_vs_size.png", dpi=110)

fig, ax = plt.subplots(figsize=(6, 4))
for mode in ("colour", "full"):
    pts = series(mode, lambda r: int(r["radius"]), threads=2, width=960, height=540)
    ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=label[mode])
ax.set_xlabel("search radius r (window (2r+1)^2)")
ax.set_ylabel("seconds (960x540, 2 threads, f=3)")
ax.set_title("nldenoise: time vs search radius")
ax.grid(True, alpha=0.3)
ax.legend()
fig.tight_layout()
fig.savefig(out / "time_vs_radius.png", dpi=110)
print("plots written to", out)
