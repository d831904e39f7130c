"""The interface every executor has, what it runs per object (:class:`Job`), and the choice
between executors (``--executor``).

An executor runs a :class:`Job` once per task somewhere (worker processes on this machine, Ray
tasks on a cluster) and hands each result back to the driver (``render_run``, ``r2n2_job``,
``voxel_meshes``), which writes the outputs in plan order. It owns everything about *where* and
*how long*: worker start-up, the per-object time limit, replacing or retrying a worker that
died, and where a finished chunk's shard file is written from (``write_shard``). It never
decides what an object's result is: that is the job's (same result whatever the executor).

What a worker runs is a ``job.Job``: ``jobs.render_job.RENDER``, ``jobs.r2n2_job.IMPORT`` or
``jobs.voxel_meshes.VOXELIZE_MESH``.

SLURM is not an executor of this kind: a job array runs whole parts (``slurm_executor``), each
part with the local pool, and ``merge`` joins them.
"""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Callable, Iterable, Iterator, Protocol

from sc3d_data.pipeline.executors.job import Job
from sc3d_data.pipeline.run.plan import Task

#: ``(pos, "ok", (record, warnings))`` or ``(pos, "fail", reason)``; ``pos`` = the task's plan position
Result = tuple[int, str, object]


class Executor(Protocol):
    """What the drivers need from an executor."""

    config: object  # the settings its workers run with (RenderConfig, ImportConfig, ...)
    backend: str  # the GL backend its workers use ("egl" / "osmesa"; "cpu" for jobs without one)

    def run(self, tasks: Iterable[Task], may_dispatch: Callable[[int], bool] = ...) -> Iterator[Result]:
        """Yield one :data:`Result` per task, in any order. A task is started only when
        ``may_dispatch(task.pos)`` (the driver bounds the results it holds); tasks are started
        in the given order. A task that hangs past ``config.timeout_s`` or whose worker dies
        yields ``"fail"`` with the reason; nothing raises for one object."""

    def write_shard(self, path: Path, records: list, settings: dict, attrs: dict[str, str] | None = None) -> str:
        """Write the shard ``path`` from the records of one chunk in plan order (``ObjectRecord``
        s, or what this executor yielded in their place) as ``sc3d_data.io.shards.write_shard``
        does (file attributes ``settings`` and ``attrs``), and return its SHA-256."""

    def close(self) -> None:
        """Stop the workers (and a cluster started for the run)."""


def start_executor(config, n_workers: int, job: Job) -> Executor:
    """The executor of ``config.executor`` (``local`` or ``ray``) running ``job`` with
    ``n_workers`` workers."""
    if config.executor == "ray":
        from sc3d_data.pipeline.executors.ray_executor import RayExecutor

        return RayExecutor.start(config, n_workers, job)
    if config.executor != "local":
        raise ValueError(f"--executor {config.executor}: expected local or ray here (slurm submits parts)")
    from sc3d_data.pipeline.executors.local_pool import start_pool

    return start_pool(n_workers, config, job)


def finished_chunks(pool: Executor, todo: list, chunk_size: int, n_workers: int,
                    progress: Callable[[int], None] | None = None) -> Iterator[tuple[int, list, bool]]:
    """Run ``todo`` (tasks in plan order, each with its plan position ``pos``) on ``pool`` and
    yield ``(chunk, [(task, status, payload), ...], last)`` for each chunk ``pos // chunk_size``
    as soon as all of its tasks in ``todo`` have a result, in chunk order, so the drivers write
    shards in plan order whatever order results arrive in; ``last`` is True for the final chunk.
    A task is dispatched only below the first unfinished chunk's start + 2 chunks + ``n_workers``,
    which bounds the results held in memory. ``progress(1)`` is called per result."""
    chunk_tasks: dict[int, list] = defaultdict(list)
    for t in todo:
        chunk_tasks[t.pos // chunk_size].append(t)
    pending = sorted(chunk_tasks)
    results: dict[int, tuple] = {}

    def may_dispatch(pos: int) -> bool:
        return pos < (pending[0] * chunk_size if pending else 0) + 2 * chunk_size + n_workers

    for pos, status, payload in pool.run(todo, may_dispatch=may_dispatch):
        results[pos] = (status, payload)
        if progress is not None:
            progress(1)
        while pending and all(t.pos in results for t in chunk_tasks[pending[0]]):
            c = pending.pop(0)
            yield c, [(t, *results.pop(t.pos)) for t in chunk_tasks[c]], not pending
