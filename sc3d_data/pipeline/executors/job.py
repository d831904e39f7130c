"""What an executor runs on each object (:class:`Job`), the run options every job shares
(:class:`ExecOptions`) and the environment of a worker (:data:`THREAD_ENV`; :data:`CRASH_ENV`,
a test hook): the contract between ``executors/`` and ``jobs/``, kept here so that executors
import no job.

Jobs (in ``sc3d_data.pipeline.jobs``): ``render_job.RENDER`` (``render_job.render_task``, one
renderer per worker), ``r2n2_job.IMPORT`` (one 3D-R2N2 model into an ``ObjectRecord``) and
``voxel_meshes.VOXELIZE_MESH`` (one mesh into a ``.binvox`` file the worker writes). A task is
any object with ``pos`` (its plan position) and ``path`` (the file named in failure reasons),
e.g. ``run.plan.Task``. Executors: ``executor.py``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable


#: one BLAS/OpenMP thread per worker process (the workers are the parallelism)
THREAD_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "LP_NUM_THREADS": "1"}
#: TEST-ONLY fault injection (tests/test_scale.py): comma-separated model ids whose worker
#: process kills itself with SIGKILL when it starts them, as a mesh that crashes the GL driver
#: would; ``ID@FILE``: only while FILE does not exist (the crash creates it: a crash of the first
#: attempt alone, as a driver's rare one). Unset in normal use; nothing else reads it.
CRASH_ENV = "SC3D_TEST_CRASH_MODEL_IDS"


def crash_if_asked(model_id: str) -> None:
    """Kill this process with SIGKILL where :data:`CRASH_ENV` names ``model_id`` (see there)."""
    import os
    import signal

    for entry in os.environ.get(CRASH_ENV, "").split(","):
        name, _, marker = entry.partition("@")
        if name == model_id and not (marker and os.path.exists(marker)):
            if marker:
                open(marker, "x").close()
            os.kill(os.getpid(), signal.SIGKILL)


@dataclass(frozen=True)
class Job:
    """What an executor runs on each object. The functions are module-level (pickled by
    reference to spawned workers and Ray tasks).

    ``run(config, backend, task) -> Result`` never raises for bad input. ``setup(config,
    backend) -> backend`` makes a worker's per-process state once, before its first task's
    time limit starts (the renderer; the voxelizer's compiled kernels), ``drop()`` forgets it
    after a task was interrupted or at the worker's end. ``gl``: the job renders (its workers
    need a GL backend, ``auto`` tries EGL, then OSMesa; else the backend is ``"cpu"``).
    ``name`` ("render", ...) names the worker in failure reasons."""

    name: str
    run: Callable
    setup: Callable | None = None
    drop: Callable | None = None
    gl: bool = False

    def backends(self, requested: str) -> tuple[str, ...]:
        """Backends to try in turn for ``requested``."""
        if not self.gl:
            return ("cpu",)
        from sc3d_data.render.gl_backend import BACKENDS

        return tuple(BACKENDS) if requested == "auto" else (requested,)

    def start(self, config, backend: str) -> str:
        """Make this process's per-worker state; the backend it got."""
        return backend if self.setup is None else self.setup(config, backend)


@dataclass(kw_only=True)
class ExecOptions:
    """Where and how long the objects of a job run (settings that never change the output):
    ``executor`` ``local`` | ``ray`` | ``slurm``, ``workers`` (0 = CPU cores; Ray: 0 = the
    cluster's CPUs), ``timeout_s`` per object, ``address`` of a Ray cluster (None: a local one
    for the run), ``retries`` of an object whose worker process died (``local_pool``, Ray). ``backend`` is the GL backend
    of render jobs (unused by the others)."""

    executor: str = "local"
    workers: int = 0
    timeout_s: float = 120.0
    address: str | None = None
    retries: int = 3
    backend: str = "auto"
