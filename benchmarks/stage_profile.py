"""Where the time of ``sc3d-data render --voxelize`` goes: a stage profile of the real pipeline.

Timing hooks wrap the pipeline's own functions (nothing in ``sc3d_data`` is changed or
restructured for it): in each spawned render worker ``load_mesh`` (load), the normalisation
(``to_canonical_transform`` + ``apply_transform``), ``mesh_parts`` (CPU-side preparation of the
vertex arrays and texture images), ``MeshRenderer._texture`` (texture conversion, upload and
mipmaps), ``MeshRenderer._upload`` and the rest of ``MeshRenderer._draw_part`` (the vertex
buffers' upload and the draw calls' submission), the rest of ``MeshRenderer.draw`` and ``MeshRenderer.read`` (the flush, the
rasterisation that the driver has not finished while the job voxelized between the two, and the
readback; on llvmpipe the raster thread's CPU during voxelizing counts to voxelize, as all CPU
time of the process counts to the stage running), ``voxelize_triangles`` and the
worker's ``send`` of the finished object (pickling and the pipe, including any wait for the main
process to read); in the main process the ``recv`` of each object, ``write_shard``
(stacking, gzip compression and writing) and ``write_index``.

Workers are spawned, so they import this module through the benchmark script (the spawn
start method runs the parent's main module in every child): ``install_worker_hooks`` runs at
import when ``SC3D_STAGE_LOG`` names a folder, and each worker appends one JSON line per object
to ``worker-<pid>.jsonl`` there, and at its end one line with its life: when it entered its main
function (against when the main process started the pool: the forkserver's start and the fork),
how long ``Job.start`` took (the GL context, the renderer), how long it waited for tasks in its
pipe and handed results over, and when it ended. :func:`life_table` turns them into the
per-worker wall-time breakdown that ``render.py --sweep`` prints.
"""
from __future__ import annotations

import json
import os
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

ENV = "SC3D_STAGE_LOG"
#: ``time.monotonic()`` (system-wide on Linux) when the main process started the pool
T0_ENV = "SC3D_STAGE_T0"
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
    import sc3d_data.pipeline.executors.job as job_mod
    import sc3d_data.pipeline.executors.pool_worker as worker
    import sc3d_data.pipeline.jobs.render_job as job
    import sc3d_data.voxel.voxelize as voxelize

    log_dir = Path(os.environ[ENV])
    _wrap(mesh_io, "load_mesh", "load")
    _wrap(normalize, "to_canonical_transform", "normalise")
    _wrap(normalize, "apply_transform", "normalise")
    _wrap(voxelize, "voxelize_triangles", "voxelize")
    _wrap(job, "encode_arrays", "compress chunks")
    _wrap(render.MeshRenderer, "_upload", "upload + draw call")  # all parts' vertex data, once per object
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
    _wrap(render.MeshRenderer, "draw", "render (all)")  # the job voxelizes between the two
    _wrap(render.MeshRenderer, "read", "render (all)")
    one = job.render_one

    def render_one(renderer, task, config):
        _current.clear()
        return one(renderer, task, config)

    job.render_one = render_one
    task_fn = job.render_task

    def render_task(config, backend, task):
        t = time.monotonic()
        try:
            return task_fn(config, backend, task)
        finally:
            _current["task"] = time.monotonic() - t

    job.render_task = render_task  # the worker unpickles RENDER's ``run`` by this name
    main = worker.worker_main
    life: dict[str, float] = {}
    _wrap(job_mod.Job, "start", "job start", life)

    class TimedConn:
        def __init__(self, conn):
            self.conn = conn

        def recv(self):
            t = time.monotonic()
            msg = self.conn.recv()
            now = time.monotonic()
            life["last wait"] = now - t  # the wait for the final None is the idle tail
            life["waiting for tasks"] = life.get("waiting for tasks", 0.0) + now - t
            return msg

        def send(self, msg):
            with _timed("send to main"):
                self.conn.send(msg)
            if msg[0] in ("ok", "fail"):
                life["hand-off"] = life.get("hand-off", 0.0) + _current["send to main"]
                life["in objects"] = life.get("in objects", 0.0) + _current.get("task", 0.0)
                row = dict(_current, status=msg[0])
                with open(log_dir / f"worker-{os.getpid()}.jsonl", "a") as f:
                    f.write(json.dumps(row) + "\n")

    def timed_main(conn, *args, **kwargs):
        environ = args[3] if len(args) > 3 else kwargs.get("environ") or {}
        life["entered"] = time.monotonic()
        life["pool started"] = float(environ.get(T0_ENV, life["entered"]))
        from sc3d_data.pipeline.executors.worker_preload import PRELOAD_SECONDS

        life["preload"] = dict(PRELOAD_SECONDS)  # the server's, inherited through the fork
        try:
            return main(TimedConn(conn), *args, **kwargs)
        finally:
            life["ended"] = time.monotonic()
            with open(log_dir / f"life-{os.getpid()}.json", "w") as f:
                json.dump(life, f)

    worker.worker_main = timed_main


def replicate_meshes(paths: list[Path], root: Path, copies: int, dest: Path) -> Path:
    """``dest`` filled with symlinks ``rK_CAT/NAME.ext`` to ``paths`` (under ``root``), ``copies``
    times: a collection of ``copies x len(paths)`` objects whose plan renders pass after pass."""
    for k in range(copies):
        for p in paths:
            rel = p.relative_to(root)
            cat = rel.parts[0] if len(rel.parts) > 1 else "thing"
            dst = dest / f"r{k}_{cat}" / f"{p.stem}{p.suffix}"
            dst.parent.mkdir(parents=True, exist_ok=True)
            dst.symlink_to(p.resolve())
    return dest


def profile_pipeline(meshes: Path, workers: int, views: int, voxelize: bool = True, **options) -> dict:
    """Run ``render_dataset`` (as ``sc3d-data render --voxelize --workers N``, shards to a
    temporary folder; ``options``: more ``RenderConfig`` fields) with the hooks; per-stage
    seconds summed over objects, worker and main, and each worker's life (``life_table``)."""
    from multiprocessing import connection

    import sc3d_data.pipeline.executors.local_pool as pool
    import sc3d_data.pipeline.jobs.shard_output as rp
    from sc3d_data.pipeline.jobs.render_run import RenderConfig, render_dataset

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
    init = pool.WorkerPool.__init__

    def pool_init(self, *args, **kwargs):
        os.environ[T0_ENV] = repr(time.monotonic())  # the workers get this environment
        init(self, *args, **kwargs)

    pool.WorkerPool.__init__ = pool_init
    try:
        with tempfile.TemporaryDirectory(prefix="sc3d-stages-") as tmp:
            os.environ[ENV] = tmp
            cfg = RenderConfig(out=Path(tmp) / "out", meshes=meshes, num_views=views, workers=workers,
                               voxelize=voxelize, bad_texture="fallback", progress=False, **options)
            summary = render_dataset(cfg)
            rows = [json.loads(line) for p in Path(tmp).glob("worker-*.jsonl") for line in open(p)]
            lives = [json.loads(p.read_text()) for p in Path(tmp).glob("life-*.json")]
    finally:
        os.environ.pop(ENV, None)
        os.environ.pop(T0_ENV, None)
        pool.write_shard, rp.write_index_file, connection.Connection.recv = saved
        pool.WorkerPool.__init__ = init
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
    for r in ok:
        r["rest of the object"] = r.get("task", 0.0) - sum(r.get(st, 0.0) for st in WORKER_STAGES[:-1])
        worker["rest of the object"] = worker.get("rest of the object", 0.0) + r["rest of the object"]
    return {"summary": summary, "objects": len(ok), "worker": worker, "lives": lives,
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


def life_breakdown(p: dict) -> dict[str, float]:
    """Where the workers' wall time went, summed over workers (seconds): each worker's life runs
    from the main process starting the pool to the worker's end."""
    w, lives = p["worker"], p["lives"]
    # the part of each worker's wait that the server's imports still had to run when the pool
    # started (render_dataset starts the server before it plans, so part of them is hidden)
    preload = [max(0.0, min(x["entered"], x.get("preload", {}).get("ended", 0.0)) - x["pool started"])
               for x in lives]
    out = {"forkserver imports, after the pool's start": sum(preload),
           "fork + hand-over": sum(x["entered"] - x["pool started"] for x in lives) - sum(preload),
           "GL context + renderer (Job.start)": sum(x.get("job start", 0.0) for x in lives),
           "waiting for a task (pipe empty)": sum(x.get("waiting for tasks", 0.0) - x.get("last wait", 0.0)
                                                   for x in lives)}
    for s in WORKER_STAGES[:-1] + ("rest of the object",):
        out[s] = w.get(s, 0.0)
    out["hand-off (send to main)"] = sum(x.get("hand-off", 0.0) for x in lives)
    out["idle at the end (others finishing, last shard)"] = sum(x.get("last wait", 0.0) for x in lives)
    total = sum(x["ended"] - x["pool started"] for x in lives)
    out["unaccounted (exit, scheduling)"] = total - sum(out.values())
    out["total"] = total
    return out


def preload_line(p: dict) -> str:
    """The forkserver's preload steps and their seconds, as a worker of ``p`` inherited them."""
    steps = next((x["preload"] for x in p["lives"] if x.get("preload")), {})
    parts = [f"{k} {v:.2f} s" for k, v in steps.items() if k != "ended"]
    return "forkserver preload: " + (", ".join(parts) if parts else "not recorded")


def life_table(points: list[tuple[int, dict]]) -> str:
    """Markdown table: per worker count (``points``: ``(workers, profile_pipeline result)``), each
    part of the workers' wall time in ms per object (summed over workers) and its share, plus
    the main process's writer."""
    cols = [(n, life_breakdown(p), p) for n, p in points]
    head = "| where the workers' wall time goes (ms per object, share) | " + " | ".join(
        f"{n} workers" for n, _, _ in cols) + " |"
    lines = [head, "|---|" + "---|" * len(cols)]
    for key in cols[0][1]:
        cells = []
        for n, b, p in cols:
            k = max(p["objects"], 1)
            cells.append(f"{1000 * b[key] / k:.1f} ({100 * b[key] / max(b['total'], 1e-9):.0f}%)")
        lines.append(f"| {key} | " + " | ".join(cells) + " |")
    cells = []
    for n, b, p in cols:
        k, m = max(p["objects"], 1), p["main"]
        writer = m["write shard"] + m["write index"] + m["recv in main"]
        cells.append(f"{1000 * writer / k:.2f} ({100 * writer / max(p['summary']['seconds'], 1e-9):.0f}% of the run)")
    lines.append("| main process: recv + write shards + index | " + " | ".join(cells) + " |")
    return "\n".join(lines)
