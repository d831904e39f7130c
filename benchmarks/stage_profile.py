"""Where the time of ``sc3d-data render --voxelize`` goes: a stage profile of the real pipeline.

Timing hooks wrap the pipeline's own functions (nothing in ``sc3d_data`` is changed or
restructured for it): in each spawned render worker ``load_mesh`` (load), the normalisation
(``to_canonical_transform`` + ``apply_transform``), ``mesh_parts`` (CPU-side preparation of the
vertex arrays and texture images), ``MeshRenderer._texture`` (texture conversion, upload and
mipmaps), the rest of ``MeshRenderer._draw_part`` (vertex buffer upload and the draw call's
submission), the rest of ``MeshRenderer.render`` (rasterisation, which the
driver runs when the pixels are read back, and the readback), ``voxelize_triangles`` and the
worker's ``send`` of the finished object (pickling and the pipe, including any wait for the main
process to read); in the main process the ``recv`` of each object, ``write_shard``
(stacking, gzip compression and writing) and ``write_index``.

Workers are spawned, so they import this module through the benchmark script (the spawn
start method runs the parent's main module in every child): ``install_worker_hooks`` runs at
import when ``SC3D_STAGE_LOG`` names a folder, and each worker appends one JSON line per object
to ``worker-<pid>.jsonl`` there.
"""
from __future__ import annotations

import json
import os
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

ENV = "SC3D_STAGE_LOG"
WORKER_STAGES = ("load", "normalise", "prepare parts", "texture upload + mipmaps",
                 "buffer upload + draw call", "draw + readback", "voxelize", "compress chunks",
                 "send to main")
MAIN_STAGES = ("recv in main", "write shard", "write index")

_current: dict[str, float] = {}


@contextmanager
def _timed(name: str, acc: dict | None = None):
    acc = _current if acc is None else acc
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        yield
    finally:
        acc[name] = acc.get(name, 0.0) + time.perf_counter() - t0
        acc[name + " cpu"] = acc.get(name + " cpu", 0.0) + time.process_time() - c0


def _wrap(obj, attr: str, stage: str, acc: dict | None = None) -> None:
    fn = getattr(obj, attr)

    def wrapper(*args, **kwargs):
        with _timed(stage, acc):
            return fn(*args, **kwargs)

    setattr(obj, attr, wrapper)


def install_worker_hooks() -> None:
    """Wrap the worker-side pipeline functions (in this process) with timers."""
    import sc3d_data.io.meshes as mesh_io
    import sc3d_data.geometry.normalize as normalize
    import sc3d_data.render.renderer as render
    import sc3d_data.pipeline.local_pool as pool
    import sc3d_data.pipeline.render_job as job
    import sc3d_data.voxel.voxelize as voxelize

    log_dir = Path(os.environ[ENV])
    _wrap(mesh_io, "load_mesh", "load")
    _wrap(normalize, "to_canonical_transform", "normalise")
    _wrap(normalize, "apply_transform", "normalise")
    _wrap(voxelize, "voxelize_triangles", "voxelize")
    _wrap(job, "encode_arrays", "compress chunks")
    _wrap(render.MeshRenderer, "_draw_part", "upload + draw call")
    _wrap(render.MeshRenderer, "_texture", "texture upload + mipmaps")
    parts = render.mesh_parts

    def timed_parts(*args, **kwargs):  # a generator: time each step
        it = iter(parts(*args, **kwargs))
        while True:
            with _timed("prepare parts"):
                try:
                    item = next(it)
                except StopIteration:
                    return
            yield item

    render.mesh_parts = timed_parts
    _wrap(render.MeshRenderer, "render", "render (all)")
    one = job.render_one

    def render_one(renderer, task, config):
        _current.clear()
        return one(renderer, task, config)

    job.render_one = render_one
    main = pool._worker_main

    class TimedConn:
        def __init__(self, conn):
            self.conn = conn

        def recv(self):
            return self.conn.recv()

        def send(self, msg):
            with _timed("send to main"):
                self.conn.send(msg)
            if msg[0] in ("ok", "fail"):
                row = dict(_current, status=msg[0])
                with open(log_dir / f"worker-{os.getpid()}.jsonl", "a") as f:
                    f.write(json.dumps(row) + "\n")

    pool._worker_main = lambda conn, *a, **k: main(TimedConn(conn), *a, **k)


def profile_pipeline(meshes: Path, workers: int, views: int, voxelize: bool = True) -> dict:
    """Run ``render_dataset`` (as ``sc3d-data render --voxelize --workers N``, shards to a
    temporary folder) with the hooks; per-stage seconds summed over objects, worker and main."""
    from multiprocessing import connection

    import sc3d_data.pipeline.local_pool as pool
    import sc3d_data.pipeline.render_run as rp
    from sc3d_data.pipeline.render_run import RenderConfig, render_dataset

    main_acc: dict[str, float] = {}
    saved = (pool.write_shard, rp.write_index_file, connection.Connection.recv)
    _wrap(pool, "write_shard", "write shard", main_acc)
    pool.PRELOAD_EXTRA.append(__name__)  # the forkserver imports this module (the hooks) too
    _wrap(rp, "write_index_file", "write index", main_acc)
    recv = connection.Connection.recv

    def timed_recv(self):
        acc: dict[str, float] = {}
        with _timed("recv in main", acc):
            msg = recv(self)
        if isinstance(msg, tuple) and msg and msg[0] == "ok":
            for k, v in acc.items():
                main_acc[k] = main_acc.get(k, 0.0) + v
        return msg

    connection.Connection.recv = timed_recv
    try:
        with tempfile.TemporaryDirectory(prefix="sc3d-stages-") as tmp:
            os.environ[ENV] = tmp
            cfg = RenderConfig(out=Path(tmp) / "out", meshes=meshes, num_views=views, workers=workers,
                               voxelize=voxelize, bad_texture="fallback", progress=False)
            summary = render_dataset(cfg)
            rows = [json.loads(line) for p in Path(tmp).glob("worker-*.jsonl") for line in open(p)]
    finally:
        os.environ.pop(ENV, None)
        pool.write_shard, rp.write_index_file, connection.Connection.recv = saved
        pool.PRELOAD_EXTRA.remove(__name__)
    ok = [r for r in rows if r.get("status") == "ok"]
    worker = {s + c: 0.0 for s in WORKER_STAGES for c in ("", " cpu")}
    for r in ok:
        for c in ("", " cpu"):
            inner = sum(r.get(k + c, 0.0) for k in ("prepare parts", "upload + draw call"))
            r["draw + readback" + c] = r.get("render (all)" + c, 0.0) - inner
            r["buffer upload + draw call" + c] = r.get("upload + draw call" + c, 0.0) \
                - r.get("texture upload + mipmaps" + c, 0.0)
        for s in worker:
            worker[s] += r.get(s, 0.0)
    return {"summary": summary, "objects": len(ok), "worker": worker,
            "main": {s + c: main_acc.get(s + c, 0.0) for s in MAIN_STAGES for c in ("", " cpu")}}


def stage_table(p: dict, workers: int) -> str:
    """Markdown table per stage: wall and CPU ms per object (CPU time of the whole process, so
    the renderer's driver threads count) and the share of all CPU time of workers + main."""
    sm, n = p["summary"], max(p["objects"], 1)
    wall = sm["seconds"]
    stages = [(s, "worker", p["worker"]) for s in WORKER_STAGES] + [(s, "main", p["main"]) for s in MAIN_STAGES]
    cpu_total = sum(acc[s + " cpu"] for s, _, acc in stages)
    lines = [f"pipeline: {sm['done']} objects, {sm['failed']} failed, {sm['views']} views in {wall:.1f} s = "
             f"{sm['views_per_s']:.0f} views/s with {workers} workers; timed stages use "
             f"{1000 * cpu_total / n:.1f} CPU-ms per object = {1000 * cpu_total / n / max(sm['views'] / n, 1):.2f} "
             f"CPU-ms per view",
             "", "| stage | process | wall ms / object | CPU ms / object | share of timed CPU |",
             "|---|---|---|---|---|"]
    for s, where, acc in stages:
        lines.append(f"| {s} | {where} | {1000 * acc[s] / n:.2f} | {1000 * acc[s + ' cpu'] / n:.2f} | "
                     f"{100 * acc[s + ' cpu'] / max(cpu_total, 1e-9):.1f}% |")
    busy = workers * wall - sum(p["worker"][s] for s in WORKER_STAGES)
    lines.append(f"| (workers outside the timed stages: start-up, idle, waiting) | worker | "
                 f"{1000 * busy / n:.2f} | - | - |")
    return "\n".join(lines)


if os.environ.get(ENV) and __name__ != "__main__":
    install_worker_hooks()
