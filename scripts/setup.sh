#!/usr/bin/env bash
# Idempotent setup for modalfem on Debian 12.
#   With root (or passwordless sudo): Debian's FEniCSx (dolfinx, petsc4py, slepc4py), OpenBLAS,
#   the X11/GL libraries the PyPI gmsh wheel needs, then .venv on /usr/bin/python3 with
#   --system-site-packages, Debian's numpy/scipy pinned by a constraints file.
#   Without root: a pip-only .venv (scikit-fem backend, SciPy eigensolver).
# Usage: scripts/setup.sh [VENV_DIR]   (default .venv)   MODALFEM_PIP_ONLY=1 forces the pip-only path.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${1:-.venv}"
APT_PKGS="python3-dolfinx python3-slepc4py python3-petsc4py python3-venv python3-pip python3-h5py libopenblas0-pthread \
  openmpi-bin libglu1-mesa libxcursor1 libxft2 libxinerama1 libgl1 libxrender1 libxext6 chromium nodejs"

stamp_input() { cat pyproject.toml scripts/setup.sh; echo "pip_only=${MODALFEM_PIP_ONLY:-0}"; }
STAMP="$VENV/.modalfem-setup-$(stamp_input | sha256sum | cut -c1-16)"
if [ -f "$STAMP" ] && "$VENV/bin/python" -c "import modalfem" 2>/dev/null; then
  echo "setup: $VENV is up to date"
  exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then SUDO="sudo -n"; else SUDO="none"; fi
fi

PIP_ONLY="${MODALFEM_PIP_ONLY:-0}"
if [ "$PIP_ONLY" != "1" ] && [ "$SUDO" != "none" ] && command -v apt-get >/dev/null 2>&1; then
  missing=""
  for p in $APT_PKGS; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
  done
  if [ -n "$missing" ]; then
    echo "setup: installing Debian packages:$missing"
    export DEBIAN_FRONTEND=noninteractive
    $SUDO apt-get update -qq
    $SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null
  fi
  if ! /usr/bin/python3 -c "import dolfinx, petsc4py, slepc4py" 2>/dev/null; then
    echo "setup: Debian FEniCSx did not import; falling back to the pip-only venv" >&2
    PIP_ONLY=1
  fi
else
  if [ "$PIP_ONLY" != "1" ]; then
    echo "setup: no root/sudo: building a pip-only venv (scikit-fem backend, SciPy eigensolver; no FEniCSx/SLEPc)"
  fi
  PIP_ONLY=1
fi

rm -rf "$VENV"
if [ "$PIP_ONLY" = "1" ]; then
  PY=python3
  command -v "$PY" >/dev/null || PY=/usr/bin/python3
  "$PY" -m venv "$VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q -e ".[test]"
else
  /usr/bin/python3 -m venv --system-site-packages "$VENV"
  # petsc4py/dolfinx are built against Debian's numpy/scipy: pip must never replace them.
  /usr/bin/python3 -c "import numpy, scipy; print(f'numpy=={numpy.__version__}\nscipy=={scipy.__version__}')" \
    > "$VENV/constraints.txt"
  # h5py: Debian's python3-h5py is built on Debian's HDF5 1.10 like dolfinx; the PyPI wheel bundles its
  # own HDF5 and breaks once dolfinx has loaded Debian's ("ValueError: Not a datatype" at import,
  # measured). Debian names its distributions h5py._debian_h5py_serial/_mpi, so pip would not see an
  # "h5py" and would install the wheel: register Debian's under its own name and version, and pin it.
  h5ver=$(/usr/bin/python3 -c "import h5py; print(h5py.__version__)" 2>/dev/null || true)
  if [ -n "$h5ver" ]; then
    site=$("$VENV/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
    mkdir -p "$site/h5py-$h5ver.dist-info"
    printf 'Metadata-Version: 2.1\nName: h5py\nVersion: %s\nSummary: Debian python3-h5py (system site-packages)\n' \
      "$h5ver" > "$site/h5py-$h5ver.dist-info/METADATA"
    echo "debian" > "$site/h5py-$h5ver.dist-info/INSTALLER"
    : > "$site/h5py-$h5ver.dist-info/RECORD"
    echo "h5py==$h5ver" >> "$VENV/constraints.txt"
  fi
  "$VENV/bin/python" -m pip install -q -c "$VENV/constraints.txt" -e ".[test]"
fi
if [ "$PIP_ONLY" != "1" ]; then
  # Debian 12's OpenBLAS 0.3.21 does not know recent Intel cores (e.g. model 207) and falls back to
  # its SSE3 "Prescott" kernels: 2-4x slower small GEMMs (measured; see README "BLAS"). Pin the core
  # type the newer OpenBLAS of the PyPI wheels picks, for every process of this venv (a .pth runs at
  # interpreter start, before numpy/PETSc load OpenBLAS; an OPENBLAS_CORETYPE already set wins).
  core=$(OPENBLAS_VERBOSE=2 "$VENV/bin/python" -c "import numpy" 2>&1 | sed -n 's/^Core: //p' | head -1)
  want=""
  if [ "$core" = "Prescott" ] || [ "$core" = "Core2" ] || [ "$core" = "Nehalem" ]; then
    flags=$(grep -m1 '^flags' /proc/cpuinfo || true)
    if echo "$flags" | grep -qw avx512bw && echo "$flags" | grep -qw avx512vl && echo "$flags" | grep -qw avx512dq; then
      want=SkylakeX
    elif echo "$flags" | grep -qw avx2 && echo "$flags" | grep -qw fma; then
      want=Haswell
    fi
  fi
  if [ -n "$want" ]; then
    site=$("$VENV/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
    echo "import os; os.environ.setdefault('OPENBLAS_CORETYPE', '$want')" > "$site/modalfem_openblas_coretype.pth"
    echo "setup: Debian OpenBLAS detected this CPU as $core; pinned OPENBLAS_CORETYPE=$want in $VENV"
  fi
fi
# chromium: the headless-browser tests (tests/browser, Playwright drives /usr/bin/chromium); nodejs: the
# tests of the pages' JavaScript. Where npm is present, the Khronos glTF validator for the export tests.
if command -v npm >/dev/null 2>&1; then
  npm install --prefix "$VENV/npm" --no-save --no-audit --no-fund --silent gltf-validator@2.0.0-dev.3.10 >/dev/null 2>&1 \
    || echo "setup: npm could not install gltf-validator (its test will be skipped)" >&2
fi
"$VENV/bin/python" -c "import modalfem, numpy, scipy, h5py; print('setup: modalfem ready in $VENV (numpy', numpy.__version__, ', scipy', scipy.__version__, ', h5py', h5py.__version__, ', fenicsx:', modalfem.have_fenicsx(), ')')"
touch "$STAMP"
