#!/usr/bin/env bash
# Opt-in: set up .venv-infinigen/, Infinigen's own environment, for `lfusd assets bake --generator infinigen`.
# Never run by `make test` or CI. A few minutes and about 2.5 GB; a second run installs nothing new.
# Infinigen 1.15.5 pins bpy 4.2.0 (lfusd's .venv has bpy 5.0), so it lives in its own CPython 3.11
# environment that lfusd runs as a subprocess. Its declared scikit-image<0.20 has no wheel for 3.11
# and compiles from source for half an hour: the dependencies are installed as wheels with
# scikit-image 0.24 (which needs imageio >= 2.33, above Infinigen's imageio<2.32 pin; its asset factories
# run with both), then infinigen itself
# with --no-deps.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3.11}
VENV=${LFUSD_INFINIGEN_VENV:-.venv-infinigen}
command -v "$PY" >/dev/null || { echo "setup_infinigen: $PY not found; Infinigen needs CPython 3.11 (bpy 4.2 wheels)" >&2; exit 1; }
[ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
# Infinigen's asset modules import pxr (its simulation exporter), so usd-core comes along.
DEPS=("bpy==4.2.0" "numpy<2" "scikit-image==0.24.0" coacd "gin_config>=0.5.0" imageio matplotlib networkx
  "opencv-python<4.9.0" pandas psutil "scikit-learn<1.4.0" scipy "shapely<=2.0.5" tqdm "trimesh<3.23.0" OpenEXR
  submitit geomdl python-fcl rtree usd-core)
stamp=$VENV/.lfusd-infinigen-installed
want="infinigen==1.15.5 ${DEPS[*]}"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "setup_infinigen: installing bpy 4.2.0, Infinigen's dependencies (as wheels) and infinigen 1.15.5 into $VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q --only-binary=:all: "${DEPS[@]}"
  "$VENV/bin/python" -m pip install -q --no-deps "infinigen==1.15.5"
  echo "$want" > "$stamp"
fi
# Blender 4.2 downloads add-ons from extensions.blender.org when an asset module asks for one it
# lacks (rocks, snow, landscapes), even when told not to. lfusd's runner switches online access off
# and answers those requests locally before it imports Infinigen; its --check imports every asset
# module that way, offline, and counts the factories.
"$VENV/bin/python" lfusd/author/infinigen_runner.py --check | tail -1
echo "setup_infinigen: ready; bake with: lfusd assets bake --generator infinigen FACTORY --seed N --catalogue FILE"
