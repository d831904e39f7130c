#!/usr/bin/env bash
# The main job on the bundled sample meshes (assets/sample_meshes: 11 objects, airplane / car /
# chair / table): render 24 views + voxelize, check that voxels, masks and cameras agree, draw a
# contact sheet, train a short run of the self-consistency model and evaluate it on the test split.
# Everything lands in ${1:-demo}/; the pictures a person looks at are listed at the end.
# Rerunning resumes the rendering (nothing is redone) and retrains from scratch.
set -euo pipefail
cd "$(dirname "$0")/.."
. .venv/bin/activate
OUT="${1:-demo}"
STEPS="${DEMO_STEPS:-300}"
export OPENBLAS_NUM_THREADS=1

echo "== 1/5 render + voxelize the sample meshes -> $OUT/shards"
sc3d-data render --out "$OUT/shards" --voxelize
sc3d-data info "$OUT/shards"

echo "== 2/5 check: voxels projected through the stored cameras vs rendered masks"
sc3d-data check "$OUT/shards" --png "$OUT/check_worst.png" --no-progress

echo "== 3/5 contact sheet"
sc3d-data preview "$OUT/shards" --out "$OUT/contact_sheet.png"

echo "== 4/5 train a short supervised run ($STEPS steps, small network, CPU is fine)"
rm -rf "$OUT/run" "$OUT/eval"
sc3d-train fit --shards "$OUT/shards" --out "$OUT/run" --steps "$STEPS" --tiny --batch-size 16 --lr 1e-3 \
  --checkpoint-every 100

echo "== 5/5 evaluate on the test split"
sc3d-train eval --checkpoint "$OUT/run/checkpoints/last.pt" --shards "$OUT/shards" --split test \
  --out "$OUT/eval"

echo
echo "Pictures: $OUT/contact_sheet.png  $OUT/check_worst.png  $OUT/run/curves.png  $OUT/eval/predictions.png"
echo "Numbers:  $OUT/shards/index.json  $OUT/run/metrics.csv  $OUT/eval/metrics.json"
