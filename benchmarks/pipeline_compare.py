"""The render pipeline of an older source tree against the current one, end to end, in one run:
views/s of ``render --voxelize --workers N`` (the figure ``sc3d-data render`` prints) and
whether the two datasets hold the same values.

    git archive <OLD_COMMIT> | tar -x -C /tmp/old
    python benchmarks/pipeline_compare.py /tmp/old [MESH_FOLDER] [--workers 2] [--repeat 3] [--copies 1]

Each run is a fresh Python process calling ``render_dataset`` of its tree (``sys.path`` puts the
tree first) on the same meshes into a temporary folder; one uncounted run per tree first (numba
compiles a tree's kernels into its own cache, the OS caches the files), then the trees
alternate, ``--repeat`` runs each, so a change in the machine's load hits both. Prints every run and the median per tree
with the ratio, then compares the last two datasets array by array (values, not file bytes).
``--copies N`` lists the meshes N times (``stage_profile.replicate_meshes``), so that on a
many-core machine the run is long beside its start (the 16-core GPU box: ``--copies 5 --workers 16``).
"""
from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from old_tree import old_tree_parser  # benchmarks/old_tree.py (this script's folder is on sys.path)

REPO = Path(__file__).resolve().parents[1]

RUN_ONE = """
import json, sys
sys.path.insert(0, {tree!r})
from pathlib import Path
from sc3d_data.pipeline.jobs.render_run import RenderConfig, render_dataset
s = render_dataset(RenderConfig(out=Path({out!r}), meshes=Path({meshes!r}), voxelize=True,
                                workers={workers}, progress=False, bad_texture="fallback"))
import multiprocessing as mp  # where the workers' sc3d_data came from: a child of the same forkserver
with mp.get_context("forkserver").Pool(1) as pool:
    s["worker_sc3d"] = pool.apply(eval, ("__import__('sc3d_data').__file__",))
print(json.dumps({{k: s[k] for k in ("done", "failed", "seconds", "views_per_s", "worker_sc3d")}}))
"""


def run_once(tree: Path, meshes: Path, out: Path, workers: int) -> dict:
    """One ``render --voxelize`` of ``tree``'s code in a fresh process, run in ``out``'s parent
    folder with the tree first on ``PYTHONPATH`` too. The workers are forked from
    multiprocessing's forkserver, a new interpreter that on Python 3.11 does not take the
    caller's ``sys.path`` but puts its working directory first, then ``PYTHONPATH``: run from the
    repository, the workers imported the current code whatever the tree (until 2026-11-27 both
    "trees" ran the current code in their workers)."""
    import os

    code = RUN_ONE.format(tree=str(tree.resolve()), out=str(out), meshes=str(meshes.resolve()), workers=workers)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(tree.resolve()), os.environ.get("PYTHONPATH"))
                                                       if p)}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False, env=env,
                         cwd=out.parent)
    if res.returncode:
        raise SystemExit(f"{tree}: render failed:\n{res.stderr[-2000:]}")
    r = json.loads(res.stdout.strip().splitlines()[-1])
    if not Path(r["worker_sc3d"]).resolve().is_relative_to(tree.resolve()):
        raise SystemExit(f"{tree}: its render's workers imported {r['worker_sc3d']}, not this tree's code")
    return r


def differing_values(a: Path, b: Path) -> dict[str, int]:
    """Per dataset name: how many values differ between the datasets in folders ``a`` and ``b``
    (objects matched by id)."""
    import h5py
    import numpy as np

    def load(folder):
        out = {}
        for p in sorted(folder.glob("shard-*.h5")):
            with h5py.File(p) as f:
                ids = [x.decode() if isinstance(x, bytes) else x for x in f["model_id"][()]]
                for name in f:
                    if f[name].dtype.kind != "O":
                        for i, mid in enumerate(ids):
                            out[(name, mid)] = f[name][i]
        return out

    x, y = load(a), load(b)
    if x.keys() != y.keys():
        raise SystemExit(f"the datasets hold different objects or arrays: {sorted(set(x) ^ set(y))[:5]}")
    diff: dict[str, int] = {}
    for key in x:
        diff[key[0]] = diff.get(key[0], 0) + int(np.count_nonzero(x[key] != y[key]))
    return diff


def main() -> None:
    ap = old_tree_parser(__doc__)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--copies", type=int, default=1, help="list the meshes this many times")
    args = ap.parse_args()
    trees = {"old": args.old_tree, "new": REPO}
    runs: dict[str, list[dict]] = {k: [] for k in trees}
    with tempfile.TemporaryDirectory(prefix="sc3d-pipeline-") as tmp:
        if args.copies > 1:
            from sc3d_data.io.meshes import MESH_SUFFIXES
            from stage_profile import replicate_meshes  # this script's folder is on sys.path

            paths = sorted(p for p in args.meshes.rglob("*") if p.suffix.lower() in MESH_SUFFIXES)
            args.meshes = replicate_meshes(paths, args.meshes, args.copies, Path(tmp) / "meshes")
        for name, tree in trees.items():
            run_once(tree, args.meshes, Path(tmp) / f"warm-{name}", args.workers)
        for i in range(args.repeat):
            for name, tree in trees.items():
                r = run_once(tree, args.meshes, Path(tmp) / f"{name}{i}", args.workers)
                runs[name].append(r)
                print(f"run {i + 1} {name}: {r['done']} objects, {r['failed']} failed, {r['seconds']:.2f} s, "
                      f"{r['views_per_s']:.0f} views/s", flush=True)
        diff = differing_values(Path(tmp) / f"old{args.repeat - 1}", Path(tmp) / f"new{args.repeat - 1}")
    med = {k: statistics.median(r["views_per_s"] for r in v) for k, v in runs.items()}
    print(f"\n| render --voxelize --workers {args.workers}, {runs['new'][0]['done']} objects | median views/s | median s |")
    print("|---|---|---|")
    for k in trees:
        print(f"| {k} ({trees[k]}) | {med[k]:.0f} | {statistics.median(r['seconds'] for r in runs[k]):.2f} |")
    print(f"| ratio new / old | {med['new'] / med['old']:.2f}x | |")
    changed = {k: v for k, v in diff.items() if v}
    print("\nvalues differing between old and new: " + (", ".join(f"{k}: {v}" for k, v in changed.items())
                                                       if changed else "none"))


if __name__ == "__main__":
    main()
