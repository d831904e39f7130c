"""``sc3d-data render`` as a library: plan the objects, hand them to an executor, write HDF5
shards and ``index.json`` in plan order.

Design
------
- Plan (``plan.py``): discovered meshes with a split, ordered by ``(category, model_id)``,
  optionally one part of a deterministic partition (``--part I/N``). The plan is cut into
  chunks of ``objects_per_shard`` objects; chunk ``c`` becomes ``shard-{c:05d}.h5`` (objects
  that fail are left out of it).
- Executor (``executor.Executor``: ``local_pool.WorkerPool`` by default,
  ``ray_executor.RayExecutor`` with ``executor="ray"``): runs :func:`render_job.render_task`
  per object with a per-object time limit and yields results in any order; the chunk loop
  (``shard_output.py``, shared with ``import-r2n2`` and ``voxelize``) collects them by
  position and writes chunk after chunk in order, so the output depends neither on the
  number of workers nor on the executor. ``may_dispatch`` keeps at most ~2
  chunks of results in memory. The shard file itself is written by the executor
  (``Executor.write_shard``: here for the local pool, on a Ray worker for Ray, from the arrays
  in the object store: they never pass through this process).
- Resume and retry (``resume.py``, ``shard_output.NewShards``): the index is rewritten
  atomically after every shard (less often once it is large: ``shard_output``); a rerun
  keeps intact chunks and renders the rest (and the recorded failures). Ctrl-C loses at most
  the chunks in progress, a kill also the listing of the last seconds' shards.
- One writer: the run holds ``sc3d_data.io.outlock.exclusive_lock(out)``
  (``shard_output.locked_output``).
- Validation: ``RenderConfig.validate`` bounds the options; an object whose silhouettes are
  empty in every view is a failure, not a success.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

from sc3d_data.formats.discover import no_meshes_found
from sc3d_data.pipeline.executors.executor import start_executor
from sc3d_data.pipeline.executors.slurm_executor import SlurmOptions, run_array, summed_parts
from sc3d_data.pipeline.run.setting_meaning import config_defaults
from sc3d_data.pipeline.jobs.render_job import RENDER, RenderConfig
from sc3d_data.pipeline.jobs.shard_output import NewShards, ShardIndex, locked_output
from sc3d_data.pipeline.run.resume_voxels import voxels_as_recorded


def render_dataset(config: RenderConfig, executor=None) -> dict:
    """Render ``config.meshes`` into shards under ``config.out`` (see module doc).

    Returns the summary ``{"done", "skipped", "failed", "warned" (objects of the index with
    warnings: a fallback texture, a missing .mtl...), "resumed", "retried" (recorded failures
    rendered again), "added" (objects of kept chunks the index did not list: new meshes),
    "repaired", "seconds", "views", "views_per_s", "out", "notes"}``; ``index.json`` holds the
    details.
    Raises ``ValueError`` (bad option or folder), ``LockError`` (another writer),
    ``ShardError`` / ``OSError`` (a shard or the index cannot be written: disk full...) with
    one-line messages naming the option or file.

    ``executor``: an executor already started (``local_pool.start_pool`` /
    ``RayExecutor.start``) with the same output settings, used instead of starting one and
    left open (a library caller rendering several parts in one process); else one is started
    for the run and closed at its end."""
    config.validate(config.workers or os.cpu_count() or 1)
    if executor is None and config.executor == "local":
        from sc3d_data.pipeline.executors.local_pool import start_server_early

        start_server_early(config, RENDER)
    with locked_output(Path(config.out), "sc3d-data render") as out:
        return _render_locked(config, out, executor)


def _render_locked(config: RenderConfig, out: Path, executor=None) -> dict:
    from sc3d_data.pipeline.run.plan import make_plan

    t0 = time.monotonic()
    settings = config.settings(None)
    plan = make_plan(config)
    if not plan.found_any:
        raise no_meshes_found(config.meshes)
    defaults = config_defaults(RenderConfig)
    index = ShardIndex(out, settings, plan.split_desc, extra={"part": plan.part}, problems=plan.problems,
                       skipped=plan.skipped)
    run = NewShards.resume(index, plan.tasks, config.objects_per_shard, defaults, config.retry_failed,
                           count_attempts=True, overwrite=config.overwrite)
    config = voxels_as_recorded(config, index.extra.get("voxels"))
    n_workers = max(1, min(config.workers or os.cpu_count() or 1, max(1, len(run.todo))))
    if executor is not None and executor.config.settings(None) != settings:
        raise ValueError("the executor given was started with other render settings than this run")
    pool = executor if executor is not None else start_executor(config, n_workers, RENDER) if run.todo else None
    settings["backend"] = pool.backend if pool else run.old_settings.get("backend")
    try:
        run.run(pool, n_workers, bar="render" if config.progress else None)
    finally:
        if pool is not None and executor is None:
            pool.close()
    if failed := getattr(pool, "start_failures", None):
        run.notes.append(f"{len(failed)} of {n_workers} render workers could not start ({failed[0]}); "
                         f"the run went on with the others")
    seconds = time.monotonic() - t0
    views = run.done * len(config.elevations) * config.num_views
    return {"done": run.done, "resumed": run.resumed, "skipped": len(plan.skipped),
            "failed": len(index.failures) + len(index.problems), "retried": len(run.retry - run.unlisted),
            "added": len(run.unlisted),
            "warned": len({w.get("source") for w in index.warnings}),
            "repaired": len(run.repaired), "notes": plan.split_notes + run.repaired + run.notes,
            "seconds": seconds, "views": views, "views_per_s": views / seconds if seconds > 0 else 0.0,
            "out": str(out), "backend": settings["backend"], "workers": n_workers if run.todo else 0,
            "part": str(config.part), "executor": config.executor}


def render_part(config) -> dict:
    """What one array task of ``render`` runs (a plain function: submitit pickles it by reference)."""
    return render_dataset(config)


def render_on_slurm(config: RenderConfig, options: SlurmOptions) -> dict:
    """Render ``config`` as a job array of ``options.parts`` parts, then merge into ``config.out``.
    Returns the summary keys of ``render_dataset`` (summed over the parts)."""
    from sc3d_data.pipeline.run.merge import merge_parts

    t0 = time.monotonic()
    configs, summaries = run_array(render_part, config, options)
    merged = merge_parts(Path(config.out), [c.out for c in configs], defaults_of=lambda _: config_defaults(RenderConfig))
    out = summed_parts(summaries, ("done", "resumed", "skipped", "failed", "warned", "retried", "added",
                                   "repaired", "views"), t0, config)
    out.update(notes=[n for s in summaries for n in s["notes"]],
               views_per_s=out["views"] / out["seconds"] if out["seconds"] > 0 else 0.0,
               backend=",".join(sorted({str(s["backend"]) for s in summaries})),
               workers=options.parts * options.cpus_per_task, merged_objects=merged.objects)
    return out
