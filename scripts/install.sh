#!/usr/bin/env bash
# Installs everything skyloc needs on a fresh Debian 12 machine with Python 3.11:
# apt packages (GDAL, GRASS for cross-checks, Chromium for the status-page test),
# a .venv with the package (editable) and every optional component (bpy, Dask, FastAPI...).
# Idempotent: re-running it on an installed machine only checks.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
"$PY" -c 'import sys; assert sys.version_info[:2] == (3, 11), "skyloc needs Python 3.11 (bpy 5.0.1 exists only for 3.11)"'

APT_PKGS="libgdal-dev gdal-bin grass-core chromium"
missing=""
for p in $APT_PKGS; do dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"; done
if [ -n "$missing" ]; then
  if [ "$(id -u)" = 0 ]; then
    echo "install.sh: apt-get install$missing"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >/dev/null
  else
    echo "install.sh: missing apt packages:$missing (run as root or: sudo apt-get install$missing)" >&2
    exit 1
  fi
fi

if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
STAMP=.venv/.skyloc-installed
if [ ! -f "$STAMP" ] || [ pyproject.toml -nt "$STAMP" ] || [ constraints.txt -nt "$STAMP" ] \
   || [ scripts/install.sh -nt "$STAMP" ]; then
  .venv/bin/pip install -q --upgrade pip wheel "setuptools>=67"
  # constraints.txt: the dependency versions the suite last passed with, so that a release made after
  # that day cannot turn a clean clone's CI red (`make lock` refreshes it)
  .venv/bin/pip install -q -c constraints.txt -e ".[ground,blender,test]"
  GDAL_VERSION=$(gdal-config --version)
  .venv/bin/python -c "from osgeo import gdal_array" 2>/dev/null || \
    .venv/bin/pip install -q --no-build-isolation "GDAL==${GDAL_VERSION}"
  .venv/bin/python -c "from osgeo import gdal, gdal_array; import bpy, numba, zarr, cv2, dask.distributed, fastapi"
  touch "$STAMP"
fi
echo "install.sh: environment ready (.venv)"
