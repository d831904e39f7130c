"""What an executor runs on each object (:class:`Job`), the run options every job shares
(:class:`ExecOptions`), and the render job (:data:`RENDER`).

Jobs: :data:`RENDER` (``render_job.render_task``, one renderer per worker), ``r2n2_job.IMPORT``
(one 3D-R2N2 model into an ``ObjectRecord``) and ``voxel_meshes.VOXELIZE_MESH`` (one mesh into
a ``.binvox`` file the worker writes). A task is any object with ``pos`` (its plan position)
and ``path`` (the file named in failure reasons). Executors: ``executor.py``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from sc3d_data.pipeline.render_job import RenderConfig, cached_renderer, render_task


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
    for the run), ``retries`` of an object whose Ray worker died. ``backend`` is the GL backend
    of render jobs (unused by the others)."""

    executor: str = "local"
    workers: int = 0
    timeout_s: float = 120.0
    address: str | None = None
    retries: int = 3
    backend: str = "auto"


def render_setup(config: RenderConfig, backend: str) -> str:
    """Make this worker's renderer (``render_job.cached_renderer``); the GL backend it got."""
    return cached_renderer(config, backend)[1]


def drop_renderers() -> None:
    """Close and forget this process's cached renderers."""
    from sc3d_data.pipeline import render_job

    for renderer, _ in render_job._RENDERERS.values():
        try:
            renderer.close()
        except Exception:  # noqa: BLE001 - it is being dropped
            pass
    render_job._RENDERERS.clear()


RENDER = Job("render", render_task, setup=render_setup, drop=drop_renderers, gl=True)
