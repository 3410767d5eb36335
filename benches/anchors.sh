#!/usr/bin/env bash
# nldenoise against Intel Open Image Denoise (PyPI pyoidn, OIDN 2.x) on the
# shared scenes, relMSE and seconds side by side, with the OpenEXR reference
# library (PyPI openexr) reading every file nldenoise writes (docs/quality.md,
# "Against OIDN"). Installs what it needs in a venv under target/.
#   bash benches/anchors.sh [SCENES_DIR]      (default ../shared/scenes)
set -euo pipefail
cd "$(dirname "$0")/.."
SCENES=${1:-../shared/scenes}
venv=target/anchors-venv
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/pip" install -q "pyoidn>=2.5" numpy "openexr>=3.3"
cargo build --release --bin nldenoise >/dev/null 2>&1
"$venv/bin/python" benches/anchors.py "$SCENES" ./target/release/nldenoise
