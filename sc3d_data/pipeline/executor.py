"""The interface every executor has, what it runs per object (:class:`Job`), and the choice
between executors (``--executor``).

An executor runs a :class:`Job` once per task somewhere (worker processes on this machine, Ray
tasks on a cluster) and hands each result back to the driver (``render_run``, ``r2n2_job``,
``voxel_job``), which writes the outputs in plan order. It owns everything about *where* and
*how long*: worker start-up, the per-object time limit, replacing or retrying a worker that
died, and where a finished chunk's shard file is written from (``write_shard``). It never
decides what an object's result is: that is the job's (same result whatever the executor).

Jobs: :data:`RENDER` (``render_job.render_task``, one renderer per worker), ``r2n2_job.IMPORT``
(one 3D-R2N2 model into an ``ObjectRecord``) and ``voxel_job.VOXELIZE_MESH`` (one mesh into a
``.binvox`` file the worker writes). A task is any object with ``pos`` (its plan position)
and ``path`` (the file named in failure reasons).

SLURM is not an executor of this kind: a job array runs whole parts (``slurm_executor``), each
part with the local pool, and ``merge`` joins them.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Iterator, Protocol

from sc3d_data.pipeline.render_job import RenderConfig, Task, cached_renderer, render_task

#: ``(pos, "ok", (record, warnings))`` or ``(pos, "fail", reason)``; ``pos`` = the task's plan position
Result = tuple[int, str, object]


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


class Executor(Protocol):
    """What the drivers need from an executor."""

    config: object  # the settings its workers run with (RenderConfig, ImportConfig, ...)
    backend: str  # the GL backend its workers use ("egl" / "osmesa"; "cpu" for jobs without one)

    def run(self, tasks: Iterable[Task], may_dispatch: Callable[[int], bool] = ...) -> Iterator[Result]:
        """Yield one :data:`Result` per task, in any order. A task is started only when
        ``may_dispatch(task.pos)`` (the driver bounds the results it holds); tasks are started
        in the given order. A task that hangs past ``config.timeout_s`` or whose worker dies
        yields ``"fail"`` with the reason; nothing raises for one object."""

    def write_shard(self, path: Path, records: list, settings: dict) -> str:
        """Write the shard ``path`` from the records of one chunk in plan order (``ObjectRecord``
        s, or what this executor yielded in their place) as ``sc3d_data.io.shards.write_shard``
        does, and return its SHA-256."""

    def close(self) -> None:
        """Stop the workers (and a cluster started for the run)."""


def start_executor(config, n_workers: int, job: Job = RENDER) -> Executor:
    """The executor of ``config.executor`` (``local`` or ``ray``) running ``job`` with
    ``n_workers`` workers."""
    if config.executor == "ray":
        from sc3d_data.pipeline.ray_executor import RayExecutor

        return RayExecutor.start(config, n_workers, job)
    if config.executor != "local":
        raise ValueError(f"--executor {config.executor}: expected local or ray here (slurm submits parts)")
    from sc3d_data.pipeline.local_pool import start_pool

    return start_pool(n_workers, config, job)
