#!/usr/bin/env bash
# The folder a lent GPU machine that reaches no package registry needs for
# `bash scripts/gpu_check.sh --kit DIR`: made here, where the registries are reachable.
#
#   bash scripts/gpu_kit.sh [--out .gpu] [--meshes ../shared/meshes]
#
# DIR/whl: the wheels such a machine lacks (its image has torch, numba, h5py, scipy, click, tqdm,
#   scikit-image, matplotlib, tensorboard, psutil, pyyaml; not trimesh, pyrender, PyOpenGL,
#   pyglet, freetype-py, DracoPy, submitit), for CPython 3.12 on x86-64, at the versions of this checkout's
#   .venv (the ones its tests pass with). Ray's wheel (79 MB) is left out: it alone is over the
#   64 MiB that may travel with the tree, and the tests that need it skip without it.
# DIR/gl: the GL loader packages (libglvnd's libEGL/libOpenGL and the Vulkan loader) for NVIDIA's
#   EGL, as Debian packages.
# DIR/meshes.tar.xz: the mesh folder (the folder itself is `meshes/` inside).
# The folder is added to .git/info/exclude, so it stays out of commits and travels only when a
# command names it (the device tool's `carry`). Prints the kit's size (the limit: 64 MiB with the
# tree).
set -euo pipefail
cd "$(dirname "$0")/.."
KIT=.gpu; MESHES=../shared/meshes
while [ $# -gt 0 ]; do
  case "$1" in
    --out) KIT=$2; shift 2 ;;
    --meshes) MESHES=$2; shift 2 ;;
    *) echo "gpu_kit: unknown option $1" >&2; exit 2 ;;
  esac
done
[ -d "$MESHES" ] || { echo "gpu_kit: no mesh folder $MESHES (--meshes)" >&2; exit 2; }
grep -qxF "/$KIT/" .git/info/exclude 2>/dev/null || { mkdir -p .git/info; echo "/$KIT/" >>.git/info/exclude; }
rm -rf "$KIT"; mkdir -p "$KIT/whl" "$KIT/gl"

PY=python3; [ -x .venv/bin/python ] && PY=.venv/bin/python
pins=()
for name in trimesh pyrender PyOpenGL pyglet freetype-py DracoPy submitit pytest-xdist execnet; do  # xdist: pyproject runs pytest -n 2
  v=$("$PY" -c "import importlib.metadata as m; print(m.version('$name'))" 2>/dev/null || true)
  pins+=("$name${v:+==$v}")
done
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
  --platform manylinux1_x86_64 -d "$KIT/whl" "${pins[@]}"

lists=$(mktemp -d); mkdir -p "$lists/partial"
apt=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 "-oDir::State::Lists=$lists")
apt-get "${apt[@]}" update >/dev/null
(cd "$KIT/gl" && apt-get "${apt[@]}" download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 \
  2>&1 | grep -v "couldn't be accessed by user '_apt'" || true)
rm -rf "$lists"

tar -cJf "$KIT/meshes.tar.xz" -C "$(dirname "$(cd "$MESHES" && pwd)")" --transform "s,^$(basename "$(cd "$MESHES" && pwd)"),meshes," \
  "$(basename "$(cd "$MESHES" && pwd)")"
ls "$KIT/whl" "$KIT/gl"
echo "kit $KIT: $(du -sh "$KIT" | cut -f1) (with the tracked tree $(git ls-files -z | xargs -0 cat | wc -c | numfmt --to=iec); limit 64 MiB)"
