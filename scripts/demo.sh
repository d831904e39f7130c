#!/usr/bin/env bash
# The main job on the bundled sample meshes: render + voxelize, check, preview, a short training
# run and an evaluation. Outputs go to demo/ (pictures: demo/*.png).
set -euo pipefail
cd "$(dirname "$0")/.."
. .venv/bin/activate
echo "demo: see steps below"
