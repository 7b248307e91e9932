#!/usr/bin/env bash
# Set up lfusd on a fresh Debian machine: system libraries, then .venv/ with the package.
# Idempotent: a second run installs nothing new.
set -euo pipefail
cd "$(dirname "$0")/.."

# Shared libraries that bpy and open3d load, with the Debian package that provides each.
LIBS="libusb-1.0.so.0:libusb-1.0-0 libX11.so.6:libx11-6 libXrender.so.1:libxrender1
libXfixes.so.3:libxfixes3 libXi.so.6:libxi6 libxkbcommon.so.0:libxkbcommon0 libSM.so.6:libsm6
libICE.so.6:libice6 libGL.so.1:libgl1 libXext.so.6:libxext6 libgomp.so.1:libgomp1"
have=$(/sbin/ldconfig -p 2>/dev/null || ldconfig -p)
need=()
for pair in $LIBS; do
  grep -qF "${pair%%:*} " <<<"$have" || need+=("${pair##*:}")
done
if ((${#need[@]})); then
  if [ "$(id -u)" = 0 ]; then SUDO=""
  elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then SUDO="sudo"
  else echo "lfusd setup: missing system packages: ${need[*]}; run 'sudo apt-get install ${need[*]}' and retry" >&2; exit 1
  fi
  echo "lfusd setup: installing system packages ${need[*]}"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get install -y -q --no-install-recommends "${need[@]}" >/dev/null 2>&1 \
    || { $SUDO apt-get update -q >/dev/null && $SUDO apt-get install -y -q --no-install-recommends "${need[@]}" >/dev/null; }
fi

PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null || { echo "lfusd setup: $PY not found; lfusd needs CPython 3.11 (bpy 5.0 wheels)" >&2; exit 1; }
[ -x .venv/bin/python ] || "$PY" -m venv .venv
stamp=.venv/.lfusd-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "lfusd setup: installing Python packages into .venv (bpy, usd-core, OpenEXR, open3d, torch, ray; pytest, pytest-timeout, ruff and mkdocs for the tests)"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e ".[test]"
  touch "$stamp"
fi
# rerun-sdk (lfusd view) declares numpy>=2, which bpy's numpy<2 forbids; 0.41.0 runs with NumPy 1.26,
# so it is installed without its declared dependencies (pyproject.toml lists the ones it needs).
if ! .venv/bin/python -c "import rerun, sys; sys.exit(rerun.__version__ != '0.41.0')" 2>/dev/null; then
  .venv/bin/python -m pip install -q --no-deps rerun-sdk==0.41.0
fi
# numba's motion kernels, compiled once into its cache here rather than silently in a first render
if .venv/bin/python -c "import sys; from lfusd.truth import _motion_numba as k; sys.exit(k.kernels_cached())" 2>/dev/null; then
  echo "lfusd setup: compiling the motion kernels (numba, about 2 minutes, once)"
  .venv/bin/python -c "from lfusd.truth.motion import compile_kernels; compile_kernels()"
fi
