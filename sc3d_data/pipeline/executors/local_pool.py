"""The default executor of ``render``, ``voxelize --meshes`` and ``import-r2n2``: a pool of
worker processes on this machine (no extra dependency).

Workers are forked from multiprocessing's ``forkserver``, a clean process that imported
``worker_preload`` (trimesh, the voxelizer's compiled kernels) once, so a worker starts in ~0.3
CPU-s instead of ~1.2 (``spawn``, the fallback where there is no forkserver). Neither the server nor
the main process ever creates a GL context, so none is inherited through a fork; a worker gets the
main process's environment as it is when the worker starts (``pool_worker.worker_main``), as a spawned one
would. Each makes its per-worker state once (``Job.start``: for rendering ONE ``MeshRenderer``) and
handles one object at a time; ``start_pool`` returns when the first worker is up (all of them with
``--gpus``, so that a failing device is named before any work) and the others take tasks as they
come up; one that fails to start while another is up or starting is left out, its reason in
``start_failures`` (``render`` warns of them). ``render_dataset`` starts the server
(``start_server_early``) before it plans, so its imports overlap the planning. To each worker the
main process sends tasks down a pipe, keeping the next one queued behind the current (``QUEUED``),
and gets the result of ``job.run`` back (``job.Job``, e.g. ``jobs.render_job.RENDER``). Per-object
time limit (``config.timeout_s``, counted from when the worker starts the object): a worker that
takes longer (a loader that hangs, a huge mesh) is killed and replaced and the object is recorded as
a failure (the next run retries it, ``retry_failed``); one that crashes (segfault, OOM killer) is
replaced and its object run again in the new worker up to ``config.retries`` times (``--retries``,
as Ray's), then recorded; the tasks queued behind either are sent again. With ``config.gpus``,
worker slot ``i`` renders on EGL device ``gpus[i % len(gpus)]`` (``devices.py``).

Implements ``sc3d_data.pipeline.executors.executor.Executor`` (as ``ray_executor.RayExecutor`` does).
"""
from __future__ import annotations

import multiprocessing as mp
import os
import time
from multiprocessing.connection import wait

from sc3d_data.render.gl_backend import BackendError, install_hint
from sc3d_data.render.probe import exit_status
from sc3d_data.pipeline.executors.forkserver_start import ensure_server
from sc3d_data.pipeline.executors.job import THREAD_ENV, Job
from sc3d_data.pipeline.executors.pool_worker import WorkerProcess
from sc3d_data.pipeline.run.plan import Task
from sc3d_data.io.shards import write_shard


#: tasks a worker holds at a time: the one it works on and the next, already in its pipe
QUEUED = 2
#: imported once by the forkserver (see module doc); ``PRELOAD_EGL`` when EGL workers come first
PRELOAD = "sc3d_data.pipeline.executors.worker_preload"
PRELOAD_EGL = "sc3d_data.pipeline.executors.worker_preload_egl"
#: more modules for the forkserver to import after the preload (before the first pool starts;
#: ``benchmarks/stage_profile.py`` adds its timing hooks so that the workers inherit them)
PRELOAD_EXTRA: list[str] = []
#: what this process asked its forkserver to preload: None until the first pool, then the GL
#: backend it imported ("egl") or "" (none). The server is started once per process.
_server_gl: list[str | None] = [None]


def worker_context(gl_backend: str | None):
    """The multiprocessing context of a pool whose workers use ``gl_backend`` (None: no GL):
    ``forkserver`` where the platform has one, preloaded by the first pool of this process
    (with EGL when that pool renders with EGL); ``spawn`` where there is no forkserver or the
    server imported PyOpenGL for another backend (``PYOPENGL_PLATFORM`` cannot change)."""
    if "forkserver" not in mp.get_all_start_methods():
        return mp.get_context("spawn")
    ctx = mp.get_context("forkserver")
    if _server_gl[0] is None:
        _server_gl[0] = "egl" if gl_backend == "egl" else ""
        # "__main__" first, as multiprocessing's default does: the server imports the main
        # module once (e.g. the sc3d-data script) and the workers it forks skip re-importing it
        ctx.set_forkserver_preload(["__main__", PRELOAD_EGL if _server_gl[0] else PRELOAD, *PRELOAD_EXTRA])
    if gl_backend is not None and _server_gl[0] not in ("", gl_backend):
        return mp.get_context("spawn")
    return ctx


class WorkerPool:
    """``n`` workers of ``job``, each holding up to ``QUEUED`` tasks; ``run(tasks)`` yields
    ``(pos, status, payload)`` with status ``ok`` (payload: (record, warnings)) or ``fail``
    (payload: reason), enforcing the per-object time limit."""

    def __init__(self, n: int, config, backend: str, job: Job):
        for k, v in THREAD_ENV.items():
            os.environ.setdefault(k, v)
        self.ctx = worker_context(backend if job.gl else None)
        ensure_server(self.ctx)
        self.config, self.backend, self.job = config, backend, job
        self.workers = [WorkerProcess(self.ctx, job, config, backend, slot) for slot in range(n)]
        self.start_failures: list[str] = []  # why the workers left out did not start (``run``)

    def wait_ready(self, every: bool = True) -> str | None:
        """Block until every worker is set up (has a renderer), or with ``every=False`` until the
        first one is (the backend works; ``run`` hands tasks to the others as they come up);
        return None, or the first start-up error once none can come up (the pool is then closed;
        with ``every=False`` one that fails while others may still start is left out)."""
        while not (all if every else any)(w.ready for w in self.workers):
            ready = wait([w.conn for w in self.workers if not w.ready], timeout=120)
            if not ready:
                self.close()
                return f"{self.job.name} workers did not start within 120 s"
            for w in [w for w in self.workers if w.conn in ready]:
                status, _, payload = w.receive()  # "ready", "dead" (its reason) or "crash"
                if status == "ready":
                    w.ready = True
                elif every or len(self.workers) == 1:  # no other worker left to come up
                    w.proc.join(5)
                    self.close()
                    return (self.start_failures or [payload or f"worker exited with code {w.proc.exitcode}"])[0]
                else:
                    self._drop_unstarted(w, payload if status == "dead" else None)
        return None

    def _drop_unstarted(self, w: WorkerProcess, reason: str | None) -> None:
        """``w`` could not start (``reason``; None: it crashed). With another worker up or still
        starting the run goes on without it and ``start_failures`` says why; else the pool is
        closed and the error raised (``BackendError`` with a reason, ``RuntimeError`` for a crash)."""
        w.proc.join(5)
        why = reason or f"exited with code {w.proc.exitcode} while starting"
        if len(self.workers) > 1:
            w.kill()
            self.workers.remove(w)
            self.start_failures.append(why)
            return
        self.close()
        if reason is None:
            raise RuntimeError(f"a {self.job.name} worker died while starting (exit code {w.proc.exitcode})")
        raise BackendError(f"{self.job.name} worker could not start: {reason}")

    def _replace(self, w: WorkerProcess) -> list[Task]:
        """Kill ``w`` and start a worker in its place; the tasks it had queued behind the one it
        was working on (to be sent again)."""
        w.kill()
        new = WorkerProcess(self.ctx, self.job, self.config, self.backend, w.slot)
        self.workers[self.workers.index(w)] = new
        return w.tasks[1:]

    def run(self, tasks, may_dispatch=lambda pos: True):
        """Yield ``(pos, status, payload)`` per task. Each worker has up to ``QUEUED`` tasks
        sent ahead, so it starts the next object the moment it sends a result (no round trip
        through this process in between); the time limit of a task runs from then."""
        todo = list(tasks)[::-1]  # pop() from the end = plan order
        timeout, crashes = self.config.timeout_s, {}  # crashes: {pos: times its worker died on it}
        while todo or any(w.tasks for w in self.workers):
            for w in self.workers:
                while w.ready and len(w.tasks) < QUEUED and todo and may_dispatch(todo[-1].pos):
                    task = todo.pop()
                    if not w.tasks:
                        w.started = time.monotonic()
                    w.tasks.append(task)
                    try:
                        w.conn.send(task)
                    except OSError:
                        break  # the worker died: its pipe reads EOF below and the task is failed

            busy = [w for w in self.workers if w.tasks]
            now = time.monotonic()
            wait_s = min([w.started + timeout - now for w in busy], default=1.0)
            ready = wait([w.conn for w in self.workers], timeout=max(0.0, min(wait_s, 1.0)))
            for w in list(self.workers):
                if w.conn in ready:
                    status, pos, payload = w.receive()
                    if status == "ready":
                        w.ready = True
                    elif not w.ready:  # could not start ("dead": its reason; else it crashed)
                        self._drop_unstarted(w, payload if status == "dead" else None)
                    elif status in ("ok", "fail"):
                        w.tasks.pop(0)
                        w.started = time.monotonic()
                        yield pos, status, payload
                    else:  # crashed
                        task = w.tasks[0] if w.tasks else None
                        w.proc.join(5)
                        code = w.proc.exitcode
                        if code == 0 and task is not None:  # it stopped on Ctrl-C (pool_worker.worker_main), whose
                            raise KeyboardInterrupt  # KeyboardInterrupt here was lost (a weakref callback's)
                        todo.extend(self._replace(w)[::-1])
                        if task is None:
                            continue
                        crashes[task.pos] = n = crashes.get(task.pos, 0) + 1
                        if n <= self.config.retries:  # a driver's rare crash is not the mesh's fault
                            todo.append(task)  # next, in the new worker
                            continue
                        how = exit_status(code) if code and code < 0 else f"exited with code {code}"
                        yield task.pos, "fail", (f"{task.path}: {self.job.name} worker {how} while working on it"
                                                 + (f", on all {n} attempts (--retries)" if n > 1 else ""))
                elif w.tasks and time.monotonic() - w.started > timeout:
                    task = w.tasks[0]
                    todo.extend(self._replace(w)[::-1])
                    yield task.pos, "fail", f"{task.path}: timed out after {timeout:g} s (--timeout)"
        for w in [w for w in self.workers if not w.ready and w.conn.poll(0)]:  # failed starts not read yet
            status, _, payload = w.receive()
            if status != "ready":
                self._drop_unstarted(w, payload if status == "dead" else None)

    def write_shard(self, path, records, settings: dict, attrs: dict[str, str] | None = None) -> str:
        """Write the shard in this (the main) process (``Executor.write_shard``)."""
        return write_shard(path, records, settings, attrs)

    def close(self) -> None:
        for w in self.workers:
            try:
                if w.proc.is_alive() and not w.tasks:
                    w.conn.send(None)
            except OSError:
                pass
        for w in self.workers:
            w.proc.join(2)
            w.kill()


def start_server_early(config, job: Job) -> None:
    """Start this process's forkserver now, for the workers ``start_pool(n, config, job)`` will
    fork: its imports (trimesh, the voxelizer's kernels, PyOpenGL: seconds, single-threaded)
    then run while the caller plans the run, instead of after. A no-op where workers are
    spawned, or when the server already runs."""
    first = job.backends(getattr(config, "backend", "auto"))[0] if job.gl else None
    ensure_server(worker_context(first))


def start_pool(n: int, config, job: Job) -> WorkerPool:
    """Start ``n`` workers of ``job`` with ``config.backend``; ``auto`` tries EGL, then OSMesa
    (the workers themselves are the probe: the main process never creates a GL context), EGL
    alone when ``config.gpus`` names devices. Raises ``BackendError`` naming the Debian packages
    when no backend works."""
    errors, gpus = [], bool(job.gl and getattr(config, "gpus", ()))
    backends = job.backends(getattr(config, "backend", "auto"))
    if gpus:  # EGL devices: one that fails is an error, not a fall back to OSMesa (refused: render_checks)
        backends = [b for b in backends if b == "egl"]
    for backend in backends:
        pool = WorkerPool(n, config, backend, job)
        # work starts with the first worker up; --gpus waits for all, so a device that fails is
        # named before any object is rendered
        err = pool.wait_ready(every=gpus)
        if err is None:
            pool.backend = backend
            return pool
        if not job.gl:  # no GL to blame: the workers themselves could not start
            raise RuntimeError(f"{job.name} workers could not start: {err}")
        if err.startswith("DeviceError: "):  # a --gpus device this machine lacks: that line alone
            raise BackendError(err.removeprefix("DeviceError: "))
        errors.append(f"{backend}: {err}")
    raise BackendError("no headless OpenGL backend works:\n  " + "\n  ".join(errors) + "\n" + install_hint())
