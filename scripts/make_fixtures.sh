#!/usr/bin/env bash
# Regenerate fixtures/ with Mitsuba 3 (scalar_rgb variant: no system libraries needed).
set -euo pipefail
cd "$(dirname "$0")/.."
venv=${VENV:-target/fixtures-venv}
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/pip" install -q "mitsuba==3.*" numpy "openexr>=3.3"
"$venv/bin/python" scripts/make_fixtures.py fixtures
