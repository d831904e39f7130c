#!/usr/bin/env bash
# Everything a GPU machine should show, in one command: the machine, the whole test suite (gpu
# tests included), and every script in benchmarks/ run to its end on short inputs. Each step's
# output goes to OUT/<step>.log; a table of exit codes and seconds ends the run (and OUT/summary.md).
#
#   bash scripts/gpu_check.sh [--out gpu_check] [--meshes ../shared/meshes] [--skip-suite]
#                             [--skip-benchmarks] [--limit 40]
#
# Run it after `bash scripts/setup.sh --gpu` (or with sc3d installed in the python on PATH). On a
# CPU machine it runs too (the gpu tests skip, train_step uses the tiny network): that is how the
# script itself is checked. Exit code 1 when any step failed.
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=gpu_check; MESHES=../shared/meshes; SUITE=1; BENCH=1; LIMIT=40
while [ $# -gt 0 ]; do
  case "$1" in
    --out) OUT=$2; shift 2 ;;
    --meshes) MESHES=$2; shift 2 ;;
    --limit) LIMIT=$2; shift 2 ;;
    --skip-suite) SUITE=0; shift ;;
    --skip-benchmarks) BENCH=0; shift ;;
    *) echo "gpu_check: unknown option $1" >&2; exit 2 ;;
  esac
done
[ -x .venv/bin/python ] && PY=.venv/bin/python || PY=python3
SC3D_DATA=$(dirname "$(command -v "$PY")")/sc3d-data
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
export PYTHONUNBUFFERED=1
ROWS=()
FAILED=0

step() {  # step NAME COMMAND...: run, log to OUT/NAME.log, remember exit code and seconds
  local name=$1; shift
  local t0=$SECONDS
  echo "== $name: $*"
  "$@" >"$OUT/$name.log" 2>&1
  local code=$?
  ROWS+=("| $name | $code | $((SECONDS - t0)) | \`$*\` |")
  [ "$code" -eq 0 ] || { FAILED=1; echo "   exit $code (see $OUT/$name.log)"; tail -5 "$OUT/$name.log"; }
}

CUDA=$($PY -c "import torch; print(int(torch.cuda.is_available()))" 2>/dev/null || echo 0)
step machine bash -c "nvidia-smi -L 2>&1; nproc; $PY -c 'import torch; print(torch.__version__, torch.version.cuda, torch.cuda.is_available() and torch.cuda.get_device_name(0))'; \
  for b in egl osmesa; do $PY -c \"from sc3d_data.render.probe import probe_backend; print('\$b', probe_backend('\$b'))\" 2>&1 | tail -1; done"

if [ "$SUITE" = 1 ]; then
  step suite "$PY" -m pytest -q -p no:cacheprovider -rs
fi

if [ "$BENCH" = 1 ]; then
  [ -d "$MESHES" ] || { echo "gpu_check: no mesh folder $MESHES (--meshes)" >&2; exit 2; }
  SUB="$WORK/meshes"; mkdir -p "$SUB"   # about LIMIT meshes, the same number from each category folder
  CATS=$(find "$(cd "$MESHES" && pwd)" -mindepth 1 -maxdepth 1 -type d | sort)
  PER=$(( (LIMIT + $(echo "$CATS" | wc -l) - 1) / $(echo "$CATS" | wc -l) ))
  for cat in $CATS; do
    find "$cat" -type f \( -name '*.glb' -o -name '*.obj' -o -name '*.ply' -o -name '*.off' -o -name '*.stl' \) | sort | head -n "$PER" |
      while read -r f; do c=$(basename "$cat"); mkdir -p "$SUB/$c"; ln -s "$f" "$SUB/$c/$(basename "$f")"; done
  done
  step shards "$SC3D_DATA" render --meshes "$SUB" --out "$WORK/shards" --voxelize --no-progress
  if [ "$CUDA" = 1 ]; then
    step train_step "$PY" benchmarks/train_step.py --shards "$WORK/shards" --batch-size 48 --profile
  else
    step train_step "$PY" benchmarks/train_step.py --shards "$WORK/shards" --tiny --batch-size 8 --steps 2 --skip-sc
  fi
  step render "$PY" benchmarks/render.py --meshes "$SUB" --repeat 1
  SWEEP=1; n=2; while [ "$n" -le "$(nproc)" ]; do SWEEP="$SWEEP,$n"; n=$((n * 2)); done
  [ "$(( $(nproc) & ($(nproc) - 1) ))" -eq 0 ] || SWEEP="$SWEEP,$(nproc)"   # 1,2,4,8,16 on 16 cores
  step render_sweep "$PY" benchmarks/render.py --meshes "$MESHES" --sweep "$SWEEP" --pipeline-only
  step voxelize "$PY" benchmarks/voxelize.py "$SUB"
  step shard_write "$PY" benchmarks/shard_write.py "$WORK/shards" --repeat 1
  step pose_search "$PY" benchmarks/pose_search.py --shards "$WORK/shards"
  step scale "$PY" benchmarks/scale.py --meshes "$SUB" --workers 4
  step faults "$PY" benchmarks/faults.py --meshes "$SUB" --files 60 --workers 4
  mkdir -p "$WORK/old" && git archive HEAD | tar -x -C "$WORK/old"   # the *_compare scripts against HEAD itself
  step pipeline_compare "$PY" benchmarks/pipeline_compare.py "$WORK/old" "$SUB" --repeat 1
  step voxelize_compare "$PY" benchmarks/voxelize_compare.py "$WORK/old" "$SUB" --repeat 1
fi

{
  echo "gpu_check $(date -u +%F) commit $(git rev-parse --short HEAD 2>/dev/null) on $(nproc) cores, CUDA $CUDA"
  echo
  echo "| step | exit | seconds | command |"
  echo "|---|---|---|---|"
  printf '%s\n' "${ROWS[@]}"
} | tee "$OUT/summary.md"
exit $FAILED
