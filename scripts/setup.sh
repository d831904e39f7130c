#!/usr/bin/env bash
# Set up sc3d on a fresh Debian/Ubuntu machine: system OpenGL packages (EGL + OSMesa, no display
# needed), a virtual environment in .venv, PyTorch (the CPU wheel unless a torch is already
# there), pyrender without its PyOpenGL pin, and sc3d itself with its test, ray and slurm extras.
# Idempotent: rerunning it only installs what is missing.
#
#   bash scripts/setup.sh          # CPU machine (CI, development)
#   bash scripts/setup.sh --gpu    # NVIDIA GPU machine: keep the CUDA PyTorch (>= 2.6) the python already
#                                  # has (the venv sees its packages), else install PyPI's CUDA
#                                  # build; fails in one line if torch then sees no GPU
set -euo pipefail
cd "$(dirname "$0")/.."
GPU=0
for arg in "$@"; do
  case "$arg" in
    --gpu) GPU=1 ;;
    *) echo "[setup] unknown option $arg (known: --gpu)" >&2; exit 2 ;;
  esac
done

# libglu1-mesa: `import pyrender` loads pyglet's GL bindings, which open libGLU (absent from GPU images
# that ship only NVIDIA's driver libraries)
APT_PACKAGES="libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 libglu1-mesa libxrender1 libosmesa6"
missing=""
for p in $APT_PACKAGES; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -n "$missing" ]; then
  echo "[setup] installing system packages:$missing"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -q
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends $missing
fi

PY="${PYTHON:-python3}"
# torch_ok PYTHON: whether PYTHON's torch is one sc3d loads checkpoints with (>= 2.6: before it,
# torch.load(weights_only=True) could run code from a crafted file, CVE-2025-32434); the rule is
# sc3d_train.settings.torch_floor.torch_is_safe, read from this tree
torch_ok() {
  "$1" -c "import sys, torch; sys.path.insert(0, '.'); from sc3d_train.settings.torch_floor import torch_is_safe
sys.exit(not torch_is_safe(torch.__version__))" 2>/dev/null
}
if [ ! -x .venv/bin/python ]; then
  if [ "$GPU" = 1 ] && "$PY" -c "import torch, sys; sys.exit(not torch.cuda.is_available())" 2>/dev/null; then
    if torch_ok "$PY"; then
      echo "[setup] --gpu: $PY has a CUDA PyTorch; the venv keeps it (--system-site-packages)"
      "$PY" -m venv --system-site-packages .venv
    else
      echo "[setup] --gpu: $PY's torch $("$PY" -c 'import torch; print(torch.__version__)') is older than 2.6 (its" \
           "weights_only loading can run code from a crafted checkpoint: CVE-2025-32434); the venv gets PyPI's torch instead" >&2
      "$PY" -m venv .venv
    fi
  else
    "$PY" -m venv .venv
  fi
fi
. .venv/bin/activate
python -m pip install -q --upgrade pip
# torch 2.13.0: a CPU wheel on these machines; PyPI's Linux wheel is the CUDA build on a GPU machine.
if python -c "import torch" 2>/dev/null && ! torch_ok python; then
  echo "[setup] .venv's torch $(python -c 'import torch; print(torch.__version__)') is older than 2.6 (CVE-2025-32434:" \
       "its weights_only loading can run code from a crafted checkpoint); upgrading it to 2.13.0" >&2
  python -m pip install -q "torch==2.13.0"
fi
python -c "import torch" 2>/dev/null || python -m pip install -q "torch==2.13.0"
if [ "$GPU" = 1 ]; then
  python -c "import torch, sys; sys.exit(not torch.cuda.is_available())" || {
    echo "[setup] --gpu: torch $(python -c 'import torch; print(torch.__version__)') in .venv sees no CUDA GPU (nvidia-smi works? a CPU wheel? remove .venv and rerun)" >&2; exit 1; }
  echo "[setup] --gpu: $(python -c 'import torch; print(torch.__version__, torch.cuda.get_device_name(0))')"
fi
# pyrender 0.1.45 pins PyOpenGL==3.1.0 (broken OSMesa); install it without deps, its deps come
# from sc3d's pyproject with PyOpenGL 3.1.10.
python -c "import importlib.util,sys; sys.exit(importlib.util.find_spec('pyrender') is None)" \
  || python -m pip install -q --no-deps "pyrender==0.1.45"
# ray + submitit: the Ray and SLURM executors, exercised by tests/test_scale.py (docs/scale.md)
python -m pip install -q -e ".[test,ray,slurm]"
# compile the voxelizer's numba kernels once per install (15-30 s; a warm start loads them in
# well under a second): numba caches them next to the sources, or in its user cache
# (~/.cache/numba) where the package folder is read-only; without this the first run pays it
echo "[setup] compiling the voxelizer's kernels (once per install)"
python -c "import sc3d_data.pipeline.executors.worker_preload"
echo "[setup] done: activate with '. .venv/bin/activate'"
