"""End-to-end rendering time against the size of the collection, and the projection to ShapeNetCore.

    python benchmarks/corpus_size.py [--meshes ../shared/meshes] [--sizes 84,1000,5000] [--workers 16]

For each size N, the meshes listed as often as needed (``stage_profile.replicate_meshes``:
symlinks ``rK_CAT/NAME``, cut to the first N) are rendered by ``sc3d-data render --voxelize
--workers W --no-progress`` in its own process, shards to a temporary folder, timed from the
command to its exit (Python's start-up, the forkserver and the numba kernels' cache load
included: what a user waits for). The sizes run smallest first, after one untimed warm-up run
of the smallest size, so every timed run finds the numba cache written.

Prints per size: objects, views, wall seconds, views/s end to end, milliseconds per object
the cost of each object added since the size before (the slope: the fixed start-up cancels),
and the ratio of the size's views/s to the largest size's (issue 22: a run of 84 objects within
2x of the steady-state rate, i.e. a ratio of at least 0.5). The per-object cost is flat when the
slopes of successive sizes agree (nothing grows with the collection). The projection for
ShapeNetCore's 51,300 objects: the largest run's wall time plus its slope times the objects it
lacks.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

SHAPENET_OBJECTS = 51_300


def corpus(paths: list[Path], root: Path, size: int, dest: Path) -> Path:
    """``dest`` holding the first ``size`` objects of ``paths`` listed pass after pass."""
    import stage_profile

    copies = -(-size // len(paths))
    listed = [(k, p) for k in range(copies) for p in paths][:size]
    for k in range(copies):
        chosen = [p for kk, p in listed if kk == k]
        stage_profile.replicate_meshes(chosen, root, 1, dest / f"c{k}")
    return dest


def timed_render(meshes: Path, out: Path, workers: int, views: int) -> tuple[float, int]:
    """Wall seconds of ``sc3d-data render --voxelize`` and the objects it wrote."""
    from sc3d_data.io.shards import load_index

    cmd = [sys.executable, "-c", "from sc3d_cli.data import main; main()", "render", "--meshes", str(meshes), "--out", str(out),
           "--voxelize", "--workers", str(workers), "--views", str(views), "--no-progress"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"corpus_size: {' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    return wall, len(load_index(out)["objects"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", type=Path, default=REPO.parent / "shared" / "meshes")
    ap.add_argument("--sizes", default="84,1000,5000", help="collection sizes, comma-separated")
    ap.add_argument("--workers", type=int, default=os.cpu_count())
    ap.add_argument("--views", type=int, default=24, help="render --views (azimuths at the one default elevation)")
    a = ap.parse_args()
    from sc3d_data.io.meshes import MESH_SUFFIXES

    try:
        sizes = sorted(int(s) for s in a.sizes.split(",") if s.strip())
    except ValueError:
        raise SystemExit(f"corpus_size: --sizes {a.sizes!r}: comma-separated whole numbers, e.g. 84,1000,5000")
    paths = sorted(p for p in a.meshes.rglob("*") if p.suffix.lower() in MESH_SUFFIXES)
    if not paths or not sizes or sizes[0] < 1:
        raise SystemExit(f"corpus_size: need meshes under {a.meshes} and sizes >= 1")
    print(f"{len(paths)} meshes from {a.meshes}; sizes {sizes}; --workers {a.workers}; {os.cpu_count()} cores; "
          f"load average {os.getloadavg()[0]:.1f}", flush=True)
    rows = []
    with tempfile.TemporaryDirectory(prefix="sc3d-corpus-") as tmp:
        tmp = Path(tmp)
        warm = corpus(paths, a.meshes, sizes[0], tmp / "warm-m")
        timed_render(warm, tmp / "warm-out", a.workers, a.views)
        for n in sizes:
            src = corpus(paths, a.meshes, n, tmp / f"m{n}")
            wall, done = timed_render(src, tmp / f"out{n}", a.workers, a.views)
            rows.append((n, done, wall))
            print(f"{n} objects: {done} written in {wall:.1f} s = {done * a.views / wall:.0f} views/s", flush=True)
    steady = rows[-1][1] * a.views / rows[-1][2]
    print("\n| objects | written | views | wall s | views/s end to end | ms per object | ms per object added "
          "since the size before | vs largest |")
    print("|---|---|---|---|---|---|---|---|")
    slopes = []
    for i, (n, done, wall) in enumerate(rows):
        rate = done * a.views / wall
        if i:
            slopes.append((wall - rows[i - 1][2]) / max(done - rows[i - 1][1], 1))
        print(f"| {n} | {done} | {done * a.views} | {wall:.1f} | {rate:.0f} | {1000 * wall / max(done, 1):.1f} | "
              f"{f'{1000 * slopes[-1]:.2f}' if i else '-'} | {rate / steady:.2f} |")
    if slopes:
        print("\nthe per-object cost is flat where the last column but one agrees between sizes (nothing grows "
              "with the collection)")
        projected = rows[-1][2] + slopes[-1] * max(SHAPENET_OBJECTS - rows[-1][1], 0)
        print(f"projection for {SHAPENET_OBJECTS:,} objects x {a.views} views (the largest run plus its last "
              f"per-object cost for the rest): {projected:.0f} s ({projected / 60:.1f} min; target <= 5 min)")

if __name__ == "__main__":
    main()
