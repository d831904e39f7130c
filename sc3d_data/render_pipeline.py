"""``sc3d-data render`` as a library: discover meshes, render (and optionally voxelize) them in
worker processes, write HDF5 shards and ``index.json``.

Design
------
- The objects to render (``plan``) are the discovered meshes that have a split, ordered by
  ``(category, model_id)``. The plan is cut into chunks of ``objects_per_shard`` objects;
  chunk ``c`` becomes ``shard-{c:05d}.h5`` (objects that fail are left out of it).
- Workers are ``spawn``-ed processes (never forked after a GL context exists: the main process
  never creates one). Each keeps ONE ``MeshRenderer`` and handles one object at a time; the
  main process sends objects in plan order, collects results by position and writes chunk
  after chunk in order, so the output does not depend on the number of workers.
- Per-object time limit (``timeout_s``): a worker that takes longer (a loader that hangs, a
  huge mesh) is killed and replaced and the object is recorded as a failure; a worker that
  crashes is handled the same way.
- Resume: the index is rewritten atomically after every shard. Rerunning with the same
  settings skips chunks that are complete (their shard is listed, exists and matches the size
  and SHA-256 in the index: a truncated or corrupted shard is rendered again); stale ``*.tmp``
  files are deleted. Since shards are written in plan order, complete chunks are a prefix of
  the plan and the resumed output equals an uninterrupted run. Ctrl-C or a kill loses at most
  the chunks in progress (they only live in memory).
- Retry: by default a rerun renders the recorded failures of complete chunks again (a worker
  killed by the OOM killer or a preempted node is not the object's fault) and rewrites their
  shard with the objects that now succeed, in plan order; each failure records its
  ``attempts``. ``retry_failed=False`` (``--no-retry-failed``) keeps them as they are.
- One writer: the run holds ``sc3d_data.io.outlock.exclusive_lock(out)``; a second render into
  the same ``--out`` is refused with one line and does not disturb the first.
- Validation: ``RenderConfig.validate`` bounds the options by what the renderer and the
  machine's memory can do (message names the option); an object whose silhouettes are empty
  in every view (geometry collapsed by an outlier vertex, ...) is a failure, not a success.
"""
from __future__ import annotations

import json
import multiprocessing as mp
import os
import time
from collections import defaultdict
from dataclasses import asdict, dataclass, field
from multiprocessing.connection import wait
from pathlib import Path

import numpy as np

from sc3d_data.geometry.camera import DEFAULT_DISTANCE, DEFAULT_FOV_DEG, DEFAULT_IMAGE_SIZE, DEFAULT_NUM_VIEWS, ViewSettings
from sc3d_data.io.meshes import DEFAULT_MAX_FACES, MESH_SUFFIXES
from sc3d_data.io.shards import (INDEX_NAME, SHARD_PATTERN, ObjectRecord, add_shard_to_index, border_clipped,
                              write_shard)
from sc3d_data.io.shards import write_index as write_index_file

REPO_ROOT = Path(__file__).resolve().parents[1]
SAMPLE_MESHES = REPO_ROOT / "assets" / "sample_meshes"
#: settings that do not change the output; they may differ between a run and its resume
RUNTIME_ONLY = ("workers", "progress", "timeout_s", "retry_failed")
#: largest framebuffer side the renderer asks for (GL_MAX_RENDERBUFFER_SIZE of Mesa and NVIDIA)
MAX_ATLAS_SIDE = 16384
MAX_VOXEL_RESOLUTION = 512
THREAD_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "LP_NUM_THREADS": "1"}


@dataclass
class RenderConfig:
    """Every option of ``sc3d-data render`` (see ``cli/data_render.py`` for their meaning)."""

    out: Path
    meshes: Path = SAMPLE_MESHES
    num_views: int = DEFAULT_NUM_VIEWS
    elevations: tuple[float, ...] = (30.0,)
    image_size: int = DEFAULT_IMAGE_SIZE
    fov_deg: float = DEFAULT_FOV_DEG
    distance: float = DEFAULT_DISTANCE
    background: tuple[int, int, int] = (255, 255, 255)
    depth: bool = False
    normalize: str = "fit"
    up: str = "+Y"
    front: str = "auto"
    backend: str = "auto"
    voxelize: bool = False
    voxel_resolution: int = 32
    categories: str | None = None
    category: str | None = None
    split: str = "random:0.7,0.1,0.2"
    split_file: str | None = None
    seed: int = 0
    objects_per_shard: int = 256
    max_faces: int = DEFAULT_MAX_FACES
    bad_texture: str = "fail"
    outside_textures: str = "warn"
    timeout_s: float = 120.0
    workers: int = 0  # 0 = number of CPU cores
    overwrite: bool = False
    progress: bool = True
    retry_failed: bool = True

    def validate(self, n_workers: int = 1) -> None:
        """Raise ``ValueError`` naming the option when a value is out of what the renderer or
        this machine's memory can do (so a typo fails at once, not as N worker failures)."""
        import math

        views = self.num_views * len(self.elevations)
        cols = math.ceil(math.sqrt(views))
        side = self.image_size * max(cols, math.ceil(views / cols))
        if side > MAX_ATLAS_SIDE:
            most = MAX_ATLAS_SIDE // max(cols, math.ceil(views / cols))
            raise ValueError(f"--image-size {self.image_size}: {views} views need a {side}x{side} framebuffer, "
                             f"over the renderer's limit of {MAX_ATLAS_SIDE}; at most --image-size {most} "
                             f"with {views} views")
        if not 2 <= self.voxel_resolution <= MAX_VOXEL_RESOLUTION:
            raise ValueError(f"--voxel-resolution {self.voxel_resolution}: must be 2 to {MAX_VOXEL_RESOLUTION}")
        if not self.timeout_s > 0:
            raise ValueError(f"--timeout {self.timeout_s}: must be > 0 seconds")
        if self.objects_per_shard < 1 or self.max_faces < 1:
            raise ValueError("--objects-per-shard and --max-faces must be >= 1")
        per_object = views * self.image_size ** 2 * (4 + (4 if self.depth else 0))
        if self.voxelize:
            per_object += self.voxel_resolution ** 3
        # the main process holds up to 2 chunks + one object per worker (see render_dataset)
        held = per_object * (2 * self.objects_per_shard + n_workers)
        # each worker: one object's arrays + framebuffer + voxelizer work space (~16 B/voxel)
        held += n_workers * (2 * per_object + (16 * self.voxel_resolution ** 3 if self.voxelize else 0))
        import psutil

        avail = psutil.virtual_memory().available
        if held > avail:
            raise ValueError(f"--image-size {self.image_size} / --voxel-resolution {self.voxel_resolution} / "
                             f"--objects-per-shard {self.objects_per_shard} / --workers {n_workers}: "
                             f"would need about {held / 2**30:.1f} GiB of memory, {avail / 2**30:.1f} GiB available")

    def view_settings(self) -> ViewSettings:
        return ViewSettings(num_views=self.num_views, elevations_deg=tuple(self.elevations),
                            distance=self.distance, fov_deg=self.fov_deg, image_size=self.image_size)

    def settings(self, backend: str) -> dict:
        """JSON-able record of every setting that shapes the output (stored in shards and index)."""
        d = {k: v for k, v in asdict(self).items() if k not in RUNTIME_ONLY + ("out", "overwrite")}
        d["meshes"] = str(Path(self.meshes).resolve())
        d["elevations"] = [float(e) for e in self.elevations]
        d["background"] = [int(c) for c in self.background]
        d["backend"] = backend
        d["requested_backend"] = self.backend
        from sc3d_data.render.renderer import RenderSettings

        rs = RenderSettings()
        d["lighting"] = {"headlight_intensity": rs.light_intensity, "ambient": rs.ambient, "shading": rs.shading,
                         "msaa_samples": 0}
        return d


# ----------------------------------------------------------------------------- worker side
@dataclass(frozen=True)
class Task:
    pos: int
    path: str
    category: str
    model_id: str
    split: str


def render_one(renderer, task: Task, config: RenderConfig) -> tuple[ObjectRecord, list[str]]:
    """Load, validate, normalise, render (and voxelize) one object in this process.
    Returns the shard record and warnings; raises on bad input."""
    from sc3d_data.io.meshes import load_mesh
    from sc3d_data.geometry.normalize import apply_transform, to_canonical_transform
    from sc3d_data.formats.shapenet import resolve_front

    from sc3d_data.io.meshes import MeshError

    root = Path(config.meshes)
    scene, vertices, faces, warnings = load_mesh(Path(task.path), config.max_faces, config.bad_texture,
                                                 root=root if root.is_dir() else root.parent,
                                                 outside_textures=config.outside_textures)
    try:
        to_canonical = to_canonical_transform(vertices, faces, config.normalize, config.up,
                                              resolve_front(config.front, task.path))
    except ValueError as e:
        raise MeshError(f"{task.path}: {e}") from e
    arrays = renderer.render(scene, to_canonical)
    if not np.asarray(arrays["masks"]).any():
        raise MeshError(f"{task.path}: the silhouette is empty in every view after normalisation (geometry "
                        "collapsed to under a pixel, e.g. by an outlier vertex far from the rest)")
    cams = renderer.cameras
    arrays.update({k: cams[k] for k in ("K", "R", "t", "azimuth", "elevation", "distance")})
    arrays["clipped"] = border_clipped(arrays["masks"])
    arrays["to_canonical"] = to_canonical
    if config.voxelize:
        from sc3d_data.voxel.voxelize import voxelize_triangles

        arrays["voxels"] = voxelize_triangles(apply_transform(vertices, to_canonical), faces,
                                              resolution=config.voxel_resolution)
    record = ObjectRecord(model_id=task.model_id, category=task.category, split=task.split,
                          source=task.path, arrays=arrays)
    return record, warnings


def _release_memory() -> None:
    """Give freed heap pages back to the OS (glibc ``malloc_trim``) so that one big mesh or
    texture does not keep a worker's RSS high for the rest of the run; no-op elsewhere."""
    import ctypes

    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _worker_main(conn, config: RenderConfig, backend: str) -> None:
    """Worker process: one renderer, then (task -> result) until ``None``."""
    for k, v in THREAD_ENV.items():
        os.environ.setdefault(k, v)
    from sc3d_data.render.renderer import MeshRenderer, RenderSettings

    try:
        renderer = MeshRenderer(config.view_settings(), RenderSettings(background=tuple(config.background),
                                                                       depth=config.depth), backend)
    except Exception as e:
        conn.send(("dead", None, f"{type(e).__name__}: {e}"))
        return
    try:
        conn.send(("ready", None, None))
        while True:
            task = conn.recv()
            if task is None:
                break
            try:
                record, warnings = render_one(renderer, task, config)
                reply = ("ok", task.pos, (record, warnings))
                del record
            except KeyboardInterrupt:
                break
            except Exception as e:
                msg = str(e) if type(e).__name__ == "MeshError" else f"{task.path}: {type(e).__name__}: {e}"
                reply = ("fail", task.pos, msg)
            conn.send(reply)
            del reply
            _release_memory()
    except (EOFError, OSError, KeyboardInterrupt):
        pass  # the main process is gone or stopping: nothing to report to
    renderer.close()


def _signal_name(signum: int) -> str:
    import signal

    try:
        name = signal.Signals(signum).name
    except ValueError:
        return "unknown signal"
    return name + (": out of memory or killed from outside" if name == "SIGKILL" else "")


class _Worker:
    def __init__(self, ctx, config: RenderConfig, backend: str):
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_worker_main, args=(child, config, backend), daemon=True)
        self.proc.start()
        child.close()
        self.ready = False
        self.task: Task | None = None
        self.started = 0.0

    def kill(self) -> None:
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join(5)
        self.conn.close()


class WorkerPool:
    """``n`` spawned render workers fed one task at a time; ``run(tasks)`` yields
    ``(pos, status, payload)`` with status ``ok`` (payload: (record, warnings)) or ``fail``
    (payload: reason), enforcing the per-object time limit."""

    def __init__(self, n: int, config: RenderConfig, backend: str):
        for k, v in THREAD_ENV.items():
            os.environ.setdefault(k, v)
        self.ctx = mp.get_context("spawn")
        self.config, self.backend = config, backend
        self.workers = [_Worker(self.ctx, config, backend) for _ in range(n)]

    def wait_ready(self) -> str | None:
        """Block until every worker has a renderer; return None, or the first start-up error
        (the pool is then closed)."""
        while not all(w.ready for w in self.workers):
            ready = wait([w.conn for w in self.workers if not w.ready], timeout=120)
            if not ready:
                self.close()
                return "render workers did not start within 120 s"
            for w in self.workers:
                if w.conn in ready:
                    try:
                        status, _, payload = w.conn.recv()
                    except (EOFError, OSError):
                        w.proc.join(5)
                        status, payload = "dead", f"worker exited with code {w.proc.exitcode}"
                    if status == "dead":
                        self.close()
                        return payload
                    w.ready = True
        return None

    def _replace(self, w: _Worker) -> _Worker:
        w.kill()
        new = _Worker(self.ctx, self.config, self.backend)
        self.workers[self.workers.index(w)] = new
        return new

    def run(self, tasks, may_dispatch=lambda pos: True):
        todo = list(tasks)[::-1]  # pop() from the end = plan order
        timeout = self.config.timeout_s
        while todo or any(w.task for w in self.workers):
            for w in self.workers:
                if w.ready and w.task is None and todo and may_dispatch(todo[-1].pos):
                    w.task, w.started = todo.pop(), time.monotonic()
                    try:
                        w.conn.send(w.task)
                    except OSError:
                        pass  # the worker died: its pipe reads EOF below and the task is failed

            busy = [w for w in self.workers if w.task is not None]
            now = time.monotonic()
            wait_s = min([w.started + timeout - now for w in busy], default=1.0)
            ready = wait([w.conn for w in self.workers], timeout=max(0.0, min(wait_s, 1.0)))
            for w in list(self.workers):
                if w.conn in ready:
                    try:
                        status, pos, payload = w.conn.recv()
                    except (EOFError, OSError):
                        status, pos, payload = "crash", None, None
                    if status == "ready":
                        w.ready = True
                    elif status == "dead":
                        self.close()
                        from sc3d_data.render.gl_backend import BackendError

                        raise BackendError(f"render worker could not start a renderer: {payload}")
                    elif status in ("ok", "fail"):
                        w.task = None
                        yield pos, status, payload
                    else:  # crashed
                        task = w.task
                        w.proc.join(5)
                        code = w.proc.exitcode
                        if not w.ready:
                            self.close()
                            raise RuntimeError(f"a render worker died while starting (exit code {code})")
                        self._replace(w)
                        if task is not None:
                            how = (f"killed by signal {-code} ({_signal_name(-code)})" if code and code < 0
                                   else f"exited with code {code}")
                            yield task.pos, "fail", f"{task.path}: render worker {how} while rendering it"
                elif w.task is not None and time.monotonic() - w.started > timeout:
                    task = w.task
                    self._replace(w)
                    yield task.pos, "fail", f"{task.path}: timed out after {timeout:g} s (--timeout)"

    def close(self) -> None:
        for w in self.workers:
            try:
                if w.proc.is_alive() and w.task is None:
                    w.conn.send(None)
            except OSError:
                pass
        for w in self.workers:
            w.proc.join(2)
            w.kill()


def start_pool(n: int, config: RenderConfig) -> WorkerPool:
    """Start ``n`` workers with ``config.backend``; ``auto`` tries EGL, then OSMesa (the
    workers themselves are the probe: the main process never creates a GL context). Raises
    ``BackendError`` naming the Debian packages when no backend works."""
    from sc3d_data.render.gl_backend import BACKENDS, BackendError, install_hint

    errors = []
    for backend in (BACKENDS if config.backend == "auto" else (config.backend,)):
        pool = WorkerPool(n, config, backend)
        err = pool.wait_ready()
        if err is None:
            pool.backend = backend
            return pool
        errors.append(f"{backend}: {err}")
    raise BackendError("no headless OpenGL backend works:\n  " + "\n  ".join(errors) + "\n" + install_hint())


# ----------------------------------------------------------------------------- main side
def _clean_tmp(out: Path) -> None:
    for p in out.glob("*.tmp"):
        try:
            p.unlink()
        except OSError:
            pass


def _plan(config: RenderConfig):
    from sc3d_data.formats.discover import discover_meshes
    from sc3d_data.formats.splits import assign_splits

    entries, problems = discover_meshes(Path(config.meshes), categories=config.categories,
                                        category_override=config.category)
    splits, split_desc, split_problems = assign_splits(entries, spec=config.split, seed=config.seed,
                                                       split_file=config.split_file)
    skipped = list(split_problems) + [p for p in problems if p.get("skipped")]
    problems = [p for p in problems if not p.get("skipped")]
    tasks = []
    for e in entries:
        key = (e.category, e.model_id)
        if key in splits:
            tasks.append(Task(len(tasks), str(e.path), e.category, e.model_id, splits[key]))
        else:
            skipped.append({"source": str(e.path), "reason": "not in any split (--split-file)"})
    return tasks, problems, skipped, split_desc


def _check_out(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ValueError(f"--out {out}: cannot create the folder ({e.strerror or e})") from e


def _same_settings(old: dict, new: dict) -> list[str]:
    """Settings that differ between an existing index and this run (keys an older index lacks
    count as their default value)."""
    defaults = {k: getattr(RenderConfig, k) for k in RenderConfig.__dataclass_fields__
                if hasattr(RenderConfig, k)}
    skip = ("backend", "requested_backend")
    keys = (set(old) | set(new)) - set(skip)
    return sorted(k for k in keys if old.get(k, defaults.get(k)) != new.get(k, defaults.get(k)))


def _resume_state(out: Path, old: dict, retry_failed: bool, K: int, tasks: list[Task]) -> dict:
    """What an existing index lets this run keep: chunks whose shard is intact (or that were
    empty), their index entries, and the failures to render again (``retry_failed``)."""
    from sc3d_data.io.shard_reader import verify_shard

    by_key = {(t.category, t.model_id): t for t in tasks}
    done_chunks, broken = set(old.get("empty_chunks", [])), []
    for s in old.get("shards", []):
        problem = verify_shard(out, s)
        if problem is None:
            done_chunks.add(s["chunk"])
        else:
            broken.append(problem + "; rendering its objects again")
    shards = [s for s in old.get("shards", []) if s["chunk"] in done_chunks]
    objects = [o for o in old.get("objects", []) if o.get("chunk") in done_chunks]
    failures = [f for f in old.get("failures", []) if f.get("chunk") in done_chunks]
    warnings = [w for w in old.get("warnings", []) if w.get("chunk") in done_chunks]
    retry, attempts = set(), {}
    if retry_failed:
        for f in failures:
            t = by_key.get((f.get("category"), f.get("model_id")))
            if t is not None and t.pos // K == f.get("chunk"):
                retry.add(t.pos)
                attempts[t.pos] = int(f.get("attempts", 1))
        failures = [f for f in failures if f.get("pos") not in retry]
        warnings = [w for w in warnings if w.get("source") not in {tasks[p].path for p in retry}]
    return {"done_chunks": done_chunks, "shards": shards, "objects": objects, "failures": failures,
            "warnings": warnings, "retry": retry, "attempts": attempts, "broken": broken,
            "empty_chunks": [c for c in old.get("empty_chunks", []) if c in done_chunks]}


def render_dataset(config: RenderConfig) -> dict:
    """Render ``config.meshes`` into shards under ``config.out`` (see module doc).

    Returns the summary ``{"done", "skipped", "failed", "resumed", "retried", "repaired",
    "seconds", "views", "views_per_s", "out", "notes"}``; ``index.json`` holds the details.
    Raises ``ValueError`` (bad option or folder), ``LockError`` (another writer),
    ``ShardError`` / ``OSError`` (a shard or the index cannot be written: disk full...) with
    one-line messages naming the option or file."""
    from sc3d_data.io.outlock import exclusive_lock

    config.validate(config.workers or os.cpu_count() or 1)
    out = Path(config.out)
    _check_out(out)
    with exclusive_lock(out, "sc3d-data render"):
        return _render_locked(config, out)


def _render_locked(config: RenderConfig, out: Path) -> dict:
    from sc3d_data.io.shards import ShardError, shard_path
    from sc3d_data.io.shard_reader import read_records

    t0 = time.monotonic()
    index_file = out / INDEX_NAME
    if config.overwrite:
        for p in list(out.glob("shard-*.h5")) + [index_file]:
            if p.exists():
                p.unlink()
    _clean_tmp(out)
    settings = config.settings(None)
    tasks, problems, skipped, split_desc = _plan(config)
    if not tasks and not problems and not skipped:
        raise ValueError(f"--meshes {config.meshes}: no mesh files found (looked for "
                         f"{', '.join(MESH_SUFFIXES)})")
    K = config.objects_per_shard

    # ---- resume
    old = None
    if index_file.is_file():
        from sc3d_data.io.shards import load_index

        old = load_index(out)
    state = {"done_chunks": set(), "shards": [], "objects": [], "failures": [], "warnings": [],
             "retry": set(), "attempts": {}, "broken": [], "empty_chunks": []}
    if old is not None:
        diff = _same_settings(old.get("settings", {}), settings)
        if diff:
            raise ValueError(f"{out}: existing shards were made with other settings ({', '.join(diff)} differ); "
                             "use another --out or --overwrite")
        state = _resume_state(out, old, config.retry_failed, K, tasks)
    done_chunks, retry = state["done_chunks"], state["retry"]
    shards, objects, failures = state["shards"], state["objects"], state["failures"]
    warnings, empty_chunks, attempts = state["warnings"], state["empty_chunks"], state["attempts"]
    todo = [t for t in tasks if t.pos // K not in done_chunks or t.pos in retry]
    kept_failed = {(f.get("category"), f.get("model_id")) for f in failures}
    resumed = sum(1 for t in tasks if t.pos // K in done_chunks and t.pos not in retry
                  and (t.category, t.model_id) not in kept_failed)
    n_workers = max(1, min(config.workers or os.cpu_count() or 1, max(1, len(todo))))
    pool = start_pool(n_workers, config) if todo else None
    settings["backend"] = pool.backend if pool else (old or {}).get("settings", {}).get("backend")

    def write_index(complete: bool) -> None:
        write_index_file(out, complete=complete, settings=settings, split=split_desc, shards=shards,
                         objects=objects, failures=problems + sorted(failures, key=lambda f: f["pos"]),
                         skipped=skipped, warnings=warnings, empty_chunks=empty_chunks)

    # ---- render
    chunk_tasks = defaultdict(list)
    for t in todo:
        chunk_tasks[t.pos // K].append(t)
    pending_chunks = sorted(chunk_tasks)
    results: dict[int, tuple] = {}
    n_done = 0
    bar = None

    def flush_ready_chunks() -> None:
        nonlocal n_done
        while pending_chunks and all(t.pos in results for t in chunk_tasks[pending_chunks[0]]):
            c = pending_chunks.pop(0)
            records, n_new = [], 0
            for t in chunk_tasks[c]:
                status, payload = results.pop(t.pos)
                if status == "ok":
                    record, warns = payload
                    records.append((t.pos, record))
                    n_new += 1
                    warnings.extend({"source": t.path, "warning": w, "chunk": c} for w in warns)
                else:
                    failures.append({"source": t.path, "category": t.category, "model_id": t.model_id,
                                     "reason": payload, "chunk": c, "pos": t.pos,
                                     "attempts": attempts.get(t.pos, 0) + 1})
            n_done += n_new
            kept = [sh for sh in shards if sh["chunk"] == c]
            if kept and not n_new:  # re-tried objects failed again: the shard stays as it is
                write_index(complete=not pending_chunks)
                continue
            if kept:  # a re-tried chunk: its shard's objects plus the new ones, in plan order
                pos_of = {(t.category, t.model_id): t.pos for t in tasks}
                records += [(pos_of[(r.category, r.model_id)], r)
                            for r in read_records(shard_path(out, kept[0]["file"]))]
                shards.remove(kept[0])
                objects[:] = [o for o in objects if o.get("chunk") != c]
            if c in empty_chunks:
                empty_chunks.remove(c)
            records = [r for _, r in sorted(records, key=lambda pr: pr[0])]
            if records:
                name = SHARD_PATTERN.format(c)
                digest = write_shard(out / name, records, settings)
                add_shard_to_index(shards, objects, name, c, records, sha256=digest)
            else:
                empty_chunks.append(c)
            write_index(complete=not pending_chunks)

    try:
        write_index(not todo)
        if pool is not None:
            if config.progress:
                from sc3d_data.pipeline.progress import progress_bar

                bar = progress_bar(total=len(todo), unit="obj", desc="render")
            first_open = lambda: pending_chunks[0] * K if pending_chunks else 0  # noqa: E731
            for pos, status, payload in pool.run(todo, may_dispatch=lambda p: p < first_open() + 2 * K + n_workers):
                results[pos] = (status, payload)
                if bar is not None:
                    bar.update(1)
                flush_ready_chunks()
    except OSError as e:  # the index could not be written (disk full, ...): one line naming it
        from sc3d_data.io.shards import io_reason

        raise ShardError(f"{e.filename or out / INDEX_NAME}: {io_reason(e)}") from e
    finally:
        if pool is not None:
            pool.close()
        if bar is not None:
            bar.close()
        _clean_tmp(out)
    seconds = time.monotonic() - t0
    views = n_done * len(config.elevations) * config.num_views
    return {"done": n_done, "resumed": resumed, "skipped": len(skipped), "failed": len(failures) + len(problems),
            "retried": len(retry), "repaired": len(state["broken"]), "notes": state["broken"],
            "seconds": seconds, "views": views, "views_per_s": views / seconds if seconds > 0 else 0.0,
            "out": str(out), "backend": settings["backend"], "workers": n_workers if todo else 0}
