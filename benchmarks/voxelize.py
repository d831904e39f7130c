"""Benchmark: sc3d's solid voxelizer vs trimesh ``voxelized(pitch).fill()`` at 32^3.

    python benchmarks/voxelize.py [MESH_FOLDER] [--resolution 32] [--limit N] [--repeat R] [--cpu-time]

For every mesh under MESH_FOLDER (default ../shared/meshes): load it as ``render`` does
(``mesh_io.load_mesh_triangles``, ``fit`` normalisation), time both voxelizers on the same
canonical triangles (trimesh's grid is shifted by half a voxel so its voxel centres coincide
with sc3d's), and compare them:

- ms per mesh (median, mean, p90) and the speed ratio, measured in the same run (with
  ``--repeat R`` each voxelizer runs R times per mesh and the fastest run counts, for both);
- sc3d's time per stage (surface SAT test, axis-ray crossings, enclosed fill, winding numbers,
  final fill) and the number of winding-number queries;
- IoU between the two grids on the watertight meshes (``manifest.json`` "watertight", else
  trimesh's own ``is_watertight``), where both should be right;
- on the open meshes, the share of surface sample points that land in an occupied voxel
  (1.0 = the grid contains the whole surface) and the solid volume found relative to sc3d.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
import trimesh  # noqa: E402

from sc3d_data.formats.discover import discover_meshes  # noqa: E402
from sc3d_data.io.meshes import load_mesh_triangles  # noqa: E402
from sc3d_data.geometry.normalize import apply_transform, to_canonical_transform  # noqa: E402
from sc3d_data.voxel.voxelize import voxelize_triangles  # noqa: E402


def trimesh_fill(vertices, faces, G):
    """trimesh ``voxelized(pitch).fill()`` mapped onto sc3d's grid indices."""
    h = 0.5 / G
    mesh = trimesh.Trimesh(vertices + h, faces, process=False)
    vg = mesh.voxelized(pitch=1.0 / G).fill()
    pts = vg.points  # voxel centres (shifted frame)
    idx = np.round((pts - h + 0.5) * G - 0.5).astype(int)
    idx = idx[((idx >= 0) & (idx < G)).all(1)]
    out = np.zeros((G, G, G), bool)
    out[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    return out


def surface_coverage(vertices, faces, grid, n=20000, seed=0):
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    G = grid.shape[0]
    idx = np.clip(np.floor((pts + 0.5) * G).astype(int), 0, G - 1)
    return float(grid[idx[:, 0], idx[:, 1], idx[:, 2]].mean())


def timed(fn, *args, repeat=1, clock=time.perf_counter, **kw):
    best = float("inf")
    for _ in range(repeat):
        t = clock()
        out = fn(*args, **kw)
        best = min(best, (clock() - t) * 1e3)
    return out, best


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("meshes", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared" / "meshes"))
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--limit", type=int, default=0, help="only the first N meshes (0 = all)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per mesh and voxelizer; the fastest counts")
    ap.add_argument("--cpu-time", action="store_true",
                    help="time with this process's CPU time instead of the wall clock (both voxelizers "
                         "run on one thread; on a loaded machine wall time counts other processes' turns)")
    args = ap.parse_args()
    clock = time.process_time if args.cpu_time else time.perf_counter
    G = args.resolution
    root = Path(args.meshes)
    entries, _ = discover_meshes(root)
    if args.limit:
        entries = entries[:args.limit]
    watertight = {}
    manifest = root / "manifest.json"
    if manifest.is_file():
        watertight = {str((root / m["file"]).resolve()): bool(m["watertight"]) for m in json.loads(manifest.read_text())}
    rows = []
    for e in entries:
        try:
            v, f = load_mesh_triangles(e.path)
        except Exception as ex:  # noqa: BLE001
            print(f"skip {e.path}: {ex}", file=sys.stderr)
            continue
        v = apply_transform(v, to_canonical_transform(v, f))
        if not rows:  # warm-up: imports, loading the compiled kernels (one open triangle)
            voxelize_triangles(np.array([[-.3, -.3, 0], [.3, -.3, 0], [0, .3, 0.]]), np.array([[0, 1, 2]]), G)
            trimesh_fill(v, f, G)
        stages = {}
        ours, t_ours = timed(voxelize_triangles, v, f, G, repeat=args.repeat, clock=clock, timings=stages)
        stages = {k: x / args.repeat for k, x in stages.items()}
        theirs, t_theirs = timed(trimesh_fill, v, f, G, repeat=args.repeat, clock=clock)
        wt = watertight.get(str(Path(e.path).resolve()))
        if wt is None:
            wt = trimesh.Trimesh(v, f).is_watertight
        inter, union = (ours & theirs).sum(), (ours | theirs).sum()
        row = {"mesh": f"{e.category}/{e.model_id}", "faces": len(f), "watertight": wt,
               "ms_ours": t_ours, "ms_trimesh": t_theirs, "iou": inter / union if union else 1.0,
               "vox_ours": int(ours.sum()), "vox_trimesh": int(theirs.sum()), "stages": stages}
        if not wt:
            row["cov_ours"] = surface_coverage(v, f, ours)
            row["cov_trimesh"] = surface_coverage(v, f, theirs)
        rows.append(row)
    if not rows:
        sys.exit("no meshes")

    def med(k, sel=rows):
        return statistics.median(r[k] for r in sel)

    def mean(k, sel=rows):
        return statistics.fmean(r[k] for r in sel)

    wt_rows = [r for r in rows if r["watertight"]]
    open_rows = [r for r in rows if not r["watertight"]]
    def p90(k, sel=rows):
        return float(np.percentile([r[k] for r in sel], 90))

    print(f"{len(rows)} meshes ({len(wt_rows)} watertight), {G}^3, one process, "
          f"fastest of {args.repeat} run(s) per mesh, {'CPU' if args.cpu_time else 'wall'} time")
    print(f"{'':<34} {'sc3d':>10} {'trimesh':>10} {'ratio':>8}")
    for label, fn in (("median", med), ("mean", mean), ("p90", p90)):
        print(f"{'ms per mesh, ' + label:<34} {fn('ms_ours'):>10.1f} {fn('ms_trimesh'):>10.1f} "
              f"{fn('ms_trimesh') / fn('ms_ours'):>7.1f}x")
    if wt_rows:
        print(f"{'watertight: IoU sc3d vs trimesh':<34} mean {mean('iou', wt_rows):.3f}  "
              f"min {min(r['iou'] for r in wt_rows):.3f}  (n={len(wt_rows)})")
    if open_rows:
        print(f"{'open: surface samples covered':<34} {mean('cov_ours', open_rows):>10.4f} "
              f"{mean('cov_trimesh', open_rows):>10.4f}   (n={len(open_rows)}; mean share of 20k "
              f"surface samples in occupied voxels)")
        print(f"{'open: fully covered meshes':<34} {sum(r['cov_ours'] == 1.0 for r in open_rows):>10d} "
              f"{sum(r['cov_trimesh'] == 1.0 for r in open_rows):>10d}")
        print(f"{'open: voxels (sum)':<34} {sum(r['vox_ours'] for r in open_rows):>10d} "
              f"{sum(r['vox_trimesh'] for r in open_rows):>10d}   IoU mean {mean('iou', open_rows):.3f}")
    names = sorted({k for r in rows for k in r["stages"] if k != "winding_points"},
                   key=["surface", "rays", "enclosed", "winding", "fill"].index)
    print("sc3d per stage, ms (median / mean / p90):  " + "  ".join(
        f"{k} {np.median([r['stages'].get(k, 0) for r in rows]):.2f} / "
        f"{np.mean([r['stages'].get(k, 0) for r in rows]):.2f} / "
        f"{np.percentile([r['stages'].get(k, 0) for r in rows], 90):.2f}" for k in names))
    q = [r["stages"].get("winding_points", 0) for r in rows]
    print(f"winding-number queries per mesh: median {np.median(q):.0f}, mean {np.mean(q):.0f}, max {max(q):.0f}")
    worst = sorted(rows, key=lambda r: -r["ms_ours"])[:5]
    print("slowest for sc3d: " + ", ".join(f"{r['mesh']} ({r['faces']} faces, {r['ms_ours']:.0f} ms)" for r in worst))


if __name__ == "__main__":
    main()
