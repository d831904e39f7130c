"""Rendering speed and memory: sc3d's renderer vs pyrender as its README shows it.

    python benchmarks/render.py [--meshes ../shared/meshes] [--repeat 5] [--views 24]

Each side runs in its own fresh (spawned) process on the same meshes, loaded and normalised
before timing (loading is not timed). Measured per side: views/s (wall) and CPU-ms per view,
over all meshes and over the "typical" 2-30k-face ones, peak RSS, and RSS after each pass
(sc3d only: ``--repeat`` passes over the meshes; flat RSS = no leak).

- sc3d: one ``sc3d_data.render.MeshRenderer`` for all meshes (swap the mesh node, move the
  camera), MSAA off.
- baseline: per mesh a new ``pyrender.Scene`` and ``OffscreenRenderer`` (default settings,
  4x MSAA), ``render`` per view, ``delete()`` afterwards: the README's usage.

Prints a table with the ratio sc3d / baseline (robust to machine noise: both measured in the
same run). Views/s per machine = per-process figure x cores only if cores are free.
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import resource
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "LP_NUM_THREADS"):
    os.environ.setdefault(k, "1")


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def _load(paths):
    from sc3d_data.mesh_io import load_mesh
    from sc3d_data.normalize import to_canonical_transform

    out = []
    for p in paths:
        try:
            scene, v, f, _ = load_mesh(p, bad_texture="fallback")
        except Exception as e:  # noqa: BLE001
            print(f"skip {p}: {e}", file=sys.stderr)
            continue
        out.append((scene, to_canonical_transform(v, f), len(f)))
    return out


def _typical(n_faces: int) -> bool:
    return 2_000 <= n_faces <= 30_000


def run_sc3d(paths, views, repeat, backend, queue):
    from sc3d_data.camera import ViewSettings
    from sc3d_data.render import MeshRenderer

    meshes = _load(paths)
    r = MeshRenderer(ViewSettings(num_views=views), backend=backend)
    r.render(meshes[0][0], meshes[0][1])  # shader compilation
    stats = {"all": [0.0, 0.0, 0], "typical": [0.0, 0.0, 0]}
    rss = []
    for _ in range(repeat):
        for scene, T, nf in meshes:
            w, c = time.perf_counter(), time.process_time()
            r.render(scene, T)
            w, c = time.perf_counter() - w, time.process_time() - c
            for key in ("all", "typical") if _typical(nf) else ("all",):
                stats[key][0] += w
                stats[key][1] += c
                stats[key][2] += views
        rss.append(_rss_mb())
    queue.put({"stats": stats, "rss": rss, "peak": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
               "meshes": len(meshes) * repeat})


def run_baseline(paths, views, backend, queue):
    from sc3d_data.gl_backend import activate

    activate(backend)
    import numpy as np
    import pyrender
    import trimesh

    from sc3d_data.camera import ViewSettings
    from sc3d_data.render import opengl_camera_pose

    meshes = _load(paths)
    cams = ViewSettings(num_views=views).cameras()
    K = cams["K"][0]
    poses = [opengl_camera_pose(R, t) for R, t in zip(cams["R"], cams["t"])]
    stats = {"all": [0.0, 0.0, 0], "typical": [0.0, 0.0, 0]}
    for scene_tm, T, nf in meshes:
        w, c = time.perf_counter(), time.process_time()
        scene = pyrender.Scene()
        for node in scene_tm.graph.nodes_geometry:
            transform, name = scene_tm.graph[node]
            geom = scene_tm.geometry[name]
            if isinstance(geom, trimesh.Trimesh) and len(geom.faces):
                scene.add(pyrender.Mesh.from_trimesh(geom), pose=T @ transform)
        cam = scene.add(pyrender.IntrinsicsCamera(K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
        light = scene.add(pyrender.DirectionalLight(color=np.ones(3), intensity=2.0))
        r = pyrender.OffscreenRenderer(64, 64)
        for pose in poses:
            scene.set_pose(cam, pose)
            scene.set_pose(light, pose)
            r.render(scene)
        r.delete()
        w, c = time.perf_counter() - w, time.process_time() - c
        for key in ("all", "typical") if _typical(nf) else ("all",):
            stats[key][0] += w
            stats[key][1] += c
            stats[key][2] += views
    queue.put({"stats": stats, "peak": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
               "meshes": len(meshes)})


def _spawn(target, *args):
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=target, args=(*args, q))
    p.start()
    res = q.get()
    p.join()
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", type=Path, default=REPO.parent / "shared" / "meshes")
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--repeat", type=int, default=5, help="passes of the sc3d renderer (memory flatness)")
    ap.add_argument("--limit", type=int, default=0, help="use only the first N meshes")
    ap.add_argument("--backend", default="egl", choices=["egl", "osmesa"])
    a = ap.parse_args()
    from sc3d_data.mesh_io import MESH_SUFFIXES

    paths = sorted(p for p in a.meshes.rglob("*") if p.suffix.lower() in MESH_SUFFIXES)
    if a.limit:
        paths = paths[:a.limit]
    print(f"{len(paths)} meshes from {a.meshes}, {a.views} views of 64x64, backend {a.backend}, "
          f"{os.cpu_count()} cores (shared machine: compare the ratios)")
    ours = _spawn(run_sc3d, paths, a.views, a.repeat, a.backend)
    base = _spawn(run_baseline, paths, a.views, a.backend)
    print(f"\n| measure | sc3d (reused renderer, MSAA off) | baseline (pyrender README usage) | ratio |")
    print("|---|---|---|---|")
    for key in ("all", "typical"):
        (w1, c1, n1), (w0, c0, n0) = ours["stats"][key], base["stats"][key]
        if not n1 or not n0:
            continue
        v1, v0 = n1 / w1, n0 / w0
        print(f"| views/s per process, {key} meshes | {v1:.0f} | {v0:.0f} | {v1 / v0:.2f}x |")
        print(f"| CPU-ms per view, {key} meshes | {1000 * c1 / n1:.2f} | {1000 * c0 / n0:.2f} | {c0 / n0 / (c1 / n1):.2f}x less |")
        print(f"| views/s per CPU-second, {key} | {n1 / c1:.0f} | {n0 / c0:.0f} | |")
    print(f"| peak RSS per process (MB) | {ours['peak']:.0f} | {base['peak']:.0f} | |")
    print(f"| meshes rendered | {ours['meshes']} | {base['meshes']} | |")
    print(f"\nsc3d RSS after each pass of {len(paths)} meshes (MB): " + ", ".join(f"{x:.0f}" for x in ours["rss"]))


if __name__ == "__main__":
    main()
