"""Rendering speed and memory: sc3d's renderer vs pyrender as its README shows it.

    python benchmarks/render.py [--meshes ../shared/meshes] [--repeat 5] [--views 24]
                                [--pipeline-repeat 6 --workers 2] [--stages --pipeline-only]
                                [--sweep 1,2,4,8,16 --copies 3 --pipeline-only]

Each side runs in its own fresh (spawned) process on the same meshes, loaded and normalised
before timing (loading is not timed). Measured per side: views/s (wall) and CPU-ms per view,
over all meshes and over the "typical" 2-30k-face ones, peak RSS, and RSS after each pass
(sc3d only: ``--repeat`` passes over the meshes; flat RSS = no leak).

- sc3d: one ``sc3d_data.render.renderer.MeshRenderer`` for all meshes (all views of an object in one
  atlas framebuffer, one instanced draw per mesh part, one readback).
- baseline: per mesh a new ``pyrender.Scene`` and ``OffscreenRenderer`` (default settings,
  4x MSAA), ``render`` per view, ``delete()`` afterwards: the README's usage.

Prints a table with the ratio sc3d / baseline (robust to machine noise: both measured in the
same run). Views/s per machine = per-process figure x cores only if cores are free.

``--stages`` first runs the pipeline as users run it (``render --voxelize --workers N``, shards
to a temporary folder) with timing hooks (``benchmarks/stage_profile.py``) and prints where the
time goes per object: load, normalise, part preparation, upload + draw call, draw + readback,
voxelize, send to the main process; in the main process receive, compress + write, index.

``--sweep 1,2,4,8,16`` runs that profiled pipeline once per worker count, each in a fresh
process (its own forkserver: start-up counts as users see it), over the meshes listed
``--copies`` times, and prints views/s end to end, the speed-up and parallel efficiency against
the first count of the sweep, and where the workers' wall time goes (forkserver start, GL
context, waiting for tasks, each stage of an object, hand-off, idle at the end; the main
process's writer): ``stage_profile.life_table``; then the forkserver's preload steps and their
seconds (``stage_profile.preload_line``).

The GL platform (``PYOPENGL_PLATFORM``) is set from ``--backend`` as the first thing this
script does, before anything can import pyrender or PyOpenGL: pyrender imported without it
goes through pyglet's GLX loader, which needs ``libGLU`` (absent on GPU machines with
NVIDIA's EGL only). A baseline that still fails is reported as a line and the script goes on.

``--pipeline-repeat N`` (N > 0) then runs the real pipeline (``render_dataset``, ``--workers``
spawned workers, shards written to a temporary folder) over the meshes listed N times (a
temporary folder of symlinks, ordered pass after pass) and samples the RSS of the worker
processes every 0.2 s: peak, and the peak and median in each N-th of the run (flat = no leak).
"""
from __future__ import annotations

import os
import sys

# before any import that could load pyrender/PyOpenGL, here and in the spawned processes (they
# run this module's top level first): see the module doc
_BACKEND = sys.argv[sys.argv.index("--backend") + 1] if "--backend" in sys.argv[:-1] else "egl"
os.environ.setdefault("PYOPENGL_PLATFORM", _BACKEND)
os.environ.setdefault("PYGLET_HEADLESS", "1")

import argparse
import multiprocessing as mp
import resource
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))
for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "LP_NUM_THREADS"):
    os.environ.setdefault(k, "1")

import stage_profile  # noqa: E402  (in spawned pipeline workers: installs the stage timers)


def _rss_mb(pid="self") -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def _children(pid: int | None = None) -> list[int]:
    """The processes below ``pid`` (default: this one), children and their children: the render
    workers are children of multiprocessing's forkserver, itself a child of this process. The
    forkserver (it has children) is left out: it is not a worker."""
    pid = os.getpid() if pid is None else pid
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            kids = [int(x) for x in f.read().split()]
    except OSError:
        return []
    out = []
    for k in kids:
        grand = _children(k)
        out += grand if grand else [k]
    return out


def run_pipeline_memory(paths, root: Path, repeat: int, workers: int, views: int) -> dict:
    """Real ``render_dataset`` over ``paths`` x ``repeat`` (symlinks ``rK_CAT/NAME.ext``, so the
    plan renders pass after pass); overall peak RSS of its worker processes and the peak and
    median in each ``repeat``-th of the run (~ one pass). Processes under 50 MB (the resource
    tracker) are left out."""
    import numpy as np

    from sc3d_data.pipeline.jobs.render_run import RenderConfig, render_dataset

    with tempfile.TemporaryDirectory(prefix="sc3d-bench-") as tmp:
        meshes = stage_profile.replicate_meshes(paths, root, repeat, Path(tmp) / "meshes")
        samples: list[tuple[float, float]] = []  # (time, rss of one worker)
        stop = threading.Event()

        def sample():
            while not stop.wait(0.2):
                now = time.monotonic()
                for pid in _children():
                    r = _rss_mb(pid)
                    if r > 50:
                        samples.append((now, r))

        th = threading.Thread(target=sample, daemon=True)
        th.start()
        cfg = RenderConfig(out=Path(tmp) / "out", meshes=meshes, num_views=views, workers=workers,
                           bad_texture="fallback", progress=False)
        summary = render_dataset(cfg)
        stop.set()
        th.join()
    t = np.array([s[0] for s in samples])
    r = np.array([s[1] for s in samples])
    parts = np.array_split(np.argsort(t, kind="stable"), repeat)
    return {"summary": summary, "peak": float(r.max()) if len(r) else float("nan"),
            "per_part": [float(r[i].max()) if len(i) else float("nan") for i in parts],
            "median_part": [float(np.median(r[i])) if len(i) else float("nan") for i in parts]}


def _load(paths):
    from sc3d_data.io.meshes import load_mesh
    from sc3d_data.geometry.normalize import to_canonical_transform

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
    from sc3d_data.geometry.camera import ViewSettings
    from sc3d_data.render.renderer import MeshRenderer

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
    from sc3d_data.render.gl_backend import activate

    activate(backend)
    import numpy as np
    import pyrender
    import trimesh

    from sc3d_data.geometry.camera import ViewSettings
    from sc3d_data.render.renderer import opengl_camera_pose

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


def _guarded(target, args, queue):
    """Run ``target(*args, queue)`` in the spawned process; an exception is put on the queue as
    ``{"error": ...}`` instead of leaving the parent waiting for a result."""
    try:
        target(*args, queue)
    except BaseException as e:  # noqa: BLE001 - reported by the parent
        queue.put({"error": f"{type(e).__name__}: {e}"})


def _spawn(target, *args):
    """``target(*args, queue)`` in a fresh spawned process; what it put on the queue, or
    ``{"error": ...}`` when it failed or died."""
    import queue as queue_mod

    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=_guarded, args=(target, args, q))
    p.start()
    while True:
        try:
            res = q.get(timeout=1.0)
            break
        except queue_mod.Empty:
            if not p.is_alive():
                res = {"error": f"the process died (exit code {p.exitcode})"}
                break
    p.join()
    return res


def run_sweep_point(meshes, copies, workers, views, queue):
    """One point of ``--sweep``: the profiled pipeline (``stage_profile.profile_pipeline``) with
    ``workers`` workers over ``meshes`` listed ``copies`` times."""
    from sc3d_data.io.meshes import MESH_SUFFIXES

    paths = sorted(p for p in meshes.rglob("*") if p.suffix.lower() in MESH_SUFFIXES)
    with tempfile.TemporaryDirectory(prefix="sc3d-sweep-") as tmp:
        src = stage_profile.replicate_meshes(paths, meshes, copies, Path(tmp) / "m") if copies > 1 else meshes
        queue.put(stage_profile.profile_pipeline(src, workers, views))


def sweep(meshes: Path, counts: list[int], copies: int, views: int) -> str:
    """The ``--sweep`` report: views/s, speed-up and parallel efficiency per worker count
    (against the first count) and the workers' wall-time breakdown."""
    points = []
    for n in counts:
        p = _spawn(run_sweep_point, meshes, copies, n, views)
        if "error" in p:
            print(f"{n} workers: failed: {p['error']}")
            continue
        sm = p["summary"]
        print(f"{n} workers: {sm['done']} objects ({sm['failed']} failed) in {sm['seconds']:.1f} s = "
              f"{sm['views_per_s']:.0f} views/s", flush=True)
        points.append((n, p))
    if not points:
        return "no point of the sweep ran"
    n0, v0 = points[0][0], points[0][1]["summary"]["views_per_s"]
    lines = ["| workers | objects | wall s | views/s end to end | speed-up | parallel efficiency |",
             "|---|---|---|---|---|---|"]
    for n, p in points:
        sm = p["summary"]
        up = sm["views_per_s"] / v0
        lines.append(f"| {n} | {sm['done']} | {sm['seconds']:.1f} | {sm['views_per_s']:.0f} | {up:.2f}x | "
                     f"{up / (n / n0):.2f} |")
    return ("\n".join(lines) + "\n\n" + stage_profile.life_table(points) + "\n\n"
            + "\n".join(f"{n} workers: {stage_profile.preload_line(p)}" for n, p in points))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", type=Path, default=REPO.parent / "shared" / "meshes")
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--repeat", type=int, default=5, help="passes of the sc3d renderer (memory flatness)")
    ap.add_argument("--limit", type=int, default=0, help="use only the first N meshes")
    ap.add_argument("--backend", default="egl", choices=["egl", "osmesa"])
    ap.add_argument("--pipeline-repeat", type=int, default=0,
                    help="also run the real pipeline over the meshes listed N times (worker RSS)")
    ap.add_argument("--workers", type=int, default=2, help="pipeline workers (--pipeline-repeat)")
    ap.add_argument("--pipeline-only", action="store_true", help="skip the speed comparison")
    ap.add_argument("--stages", action="store_true",
                    help="stage profile of the pipeline as users run it (render --voxelize --workers N)")
    ap.add_argument("--sweep", default="",
                    help="worker counts, e.g. 1,2,4,8,16: views/s, efficiency and wall-time breakdown per count")
    ap.add_argument("--copies", type=int, default=1, help="--sweep: list the meshes this many times")
    a = ap.parse_args()
    from sc3d_data.io.meshes import MESH_SUFFIXES

    paths = sorted(p for p in a.meshes.rglob("*") if p.suffix.lower() in MESH_SUFFIXES)
    if a.limit:
        paths = paths[:a.limit]
    print(f"{len(paths)} meshes from {a.meshes}, {a.views} views of 64x64, backend {a.backend}, "
          f"{os.cpu_count()} cores (shared machine: compare the ratios)")
    if a.stages:
        print()
        print(stage_profile.stage_table(stage_profile.profile_pipeline(a.meshes, a.workers, a.views), a.workers))
    if a.sweep:
        counts = [int(x) for x in a.sweep.split(",") if x.strip()]
        print(f"\nsweep over {a.copies} x {len(paths)} objects, worker counts {counts}, load average "
              f"{os.getloadavg()[0]:.1f} at the start")
        print(sweep(a.meshes, counts, a.copies, a.views))
        print(f"load average at the end: {os.getloadavg()[0]:.1f}")
    if not a.pipeline_only:
        ours = _spawn(run_sc3d, paths, a.views, a.repeat, a.backend)
        base = _spawn(run_baseline, paths, a.views, a.backend)
        for side, res in (("sc3d", ours), ("baseline (pyrender)", base)):
            if "error" in res:
                print(f"\n{side} failed: {res['error']}")
        if "error" in ours or "error" in base:
            ours = base = None
    if not a.pipeline_only and ours is not None:
        print("\n| measure | sc3d (atlas renderer) | baseline (pyrender README usage) | ratio |")
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
    if a.pipeline_repeat > 0:
        m = run_pipeline_memory(paths, a.meshes, a.pipeline_repeat, a.workers, a.views)
        sm = m["summary"]
        print(f"\npipeline: {sm['done']} objects ({sm['failed']} failed) x {a.views} views with {sm['workers']} "
              f"workers in {sm['seconds']:.0f} s = {sm['views_per_s']:.0f} views/s per machine (incl. loading, "
              f"voxel-free, HDF5 writing)")
        print(f"worker RSS (MB): peak {m['peak']:.0f}; peak in each 1/{a.pipeline_repeat} of the run (~ one pass "
              f"over the meshes each): " + ", ".join(f"{x:.0f}" for x in m["per_part"])
              + "; median in each: " + ", ".join(f"{x:.0f}" for x in m["median_part"]))


if __name__ == "__main__":
    main()
