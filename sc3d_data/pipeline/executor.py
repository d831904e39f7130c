"""The interface every render executor has, and the choice between them (``--executor``).

An executor runs :func:`sc3d_data.pipeline.render_job.render_task` once per
:class:`~sc3d_data.pipeline.render_job.Task` somewhere (worker processes on this machine, Ray
tasks on a cluster) and hands each result back to the driver (``render_run``), which writes
the shards in plan order. It owns everything about *where* and *how long*: worker start-up,
the per-object time limit, replacing or retrying a worker that died, and where a finished
chunk's shard file is written from (``write_shard``). It never decides what an
object's result is: that is ``render_task``'s (same arrays whatever the executor).

SLURM is not an executor of this kind: a job array runs whole parts (``slurm_executor``), each
part with the local pool, and ``merge`` joins them.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterable, Iterator, Protocol

from sc3d_data.pipeline.render_job import RenderConfig, Task

#: ``(pos, "ok", (record, warnings))`` or ``(pos, "fail", reason)``; ``pos`` = the task's plan position
Result = tuple[int, str, object]


class Executor(Protocol):
    """What ``render_run`` needs from an executor."""

    config: RenderConfig  # the settings its workers render with
    backend: str  # the GL backend its workers use ("egl" / "osmesa")

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


def start_executor(config: RenderConfig, n_workers: int) -> Executor:
    """The executor of ``config.executor`` (``local`` or ``ray``) with ``n_workers`` workers."""
    if config.executor == "ray":
        from sc3d_data.pipeline.ray_executor import RayExecutor

        return RayExecutor.start(config, n_workers)
    if config.executor != "local":
        raise ValueError(f"--executor {config.executor}: expected local or ray here (slurm submits parts)")
    from sc3d_data.pipeline.local_pool import start_pool

    return start_pool(n_workers, config)
