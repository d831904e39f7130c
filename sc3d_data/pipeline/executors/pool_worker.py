"""One worker process of ``local_pool``: its main loop (``worker_main``: the job's per-worker
state once, then task -> result down a pipe until ``None``) and the main process's handle on it
(``WorkerProcess``). ``benchmarks/stage_profile.py`` wraps ``worker_main`` to time a worker's life."""
from __future__ import annotations

import os
import signal
import sys

from sc3d_data.pipeline.executors.devices import worker_environ
from sc3d_data.pipeline.executors.job import THREAD_ENV, Job
from sc3d_data.pipeline.run.plan import Task


def worker_main(conn, job: Job, config, backend: str, environ: dict | None = None) -> None:
    """Worker process: take the main process's ``environ`` (the forkserver's dates from its own
    start), ``job.start`` (one renderer), then (task -> result) until ``None``."""
    signal.signal(signal.SIGINT, signal.default_int_handler)  # the server ignores it: ensure_server
    if environ is not None:
        fixed = {k: os.environ[k] for k in ("PYOPENGL_PLATFORM",) if k in os.environ and "OpenGL" in sys.modules}
        os.environ.clear()
        os.environ.update(environ)
        os.environ.update(fixed)  # PyOpenGL was imported by the forkserver with this platform
    for k, v in THREAD_ENV.items():
        os.environ.setdefault(k, v)
    try:
        job.start(config, backend)
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
                pos, status, payload = job.run(config, backend, task)
                reply = (status, pos, payload)
                del payload
            except KeyboardInterrupt:
                break
            conn.send(reply)
            del reply
    except (EOFError, OSError, KeyboardInterrupt):
        pass  # the main process is gone or stopping: nothing to report to
    if job.drop is not None:
        job.drop()


class WorkerProcess:
    """The main process's handle on one worker: its process (``worker_main``), pipe, the tasks
    sent to it and when its current one started."""

    def __init__(self, ctx, job: Job, config, backend: str, slot: int = 0):
        self.conn, child = ctx.Pipe()
        self.slot = slot  # its GPU: ``devices.device_of_slot(slot, config.gpus)`` (render jobs)
        gpus = tuple(getattr(config, "gpus", ())) if job.gl else ()
        self.proc = ctx.Process(target=worker_main, args=(child, job, config, backend,
                                                           worker_environ(os.environ, slot, gpus)),
                                daemon=True)
        self.proc.start()
        child.close()
        self.ready = False
        self.tasks: list[Task] = []  # sent, no result yet; the first is the one being worked on
        self.started = 0.0  # when the first of ``tasks`` started (its time limit runs from here)

    def receive(self) -> tuple:
        """The worker's next message ``(status, pos, payload)``; ``("crash", None, None)`` when
        its pipe is closed (the process died)."""
        try:
            return self.conn.recv()
        except (EOFError, OSError):
            return "crash", None, None

    def kill(self) -> None:
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join(5)
        self.conn.close()
