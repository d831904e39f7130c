"""``sc3d-data render`` as a library: plan the objects, hand them to an executor, write HDF5
shards and ``index.json`` in plan order.

Design
------
- Plan (``run/plan.py``): discovered meshes with a split, ordered by ``(category, model_id)``,
  optionally one part of a deterministic partition (``--part I/N``). The plan is cut into
  chunks of ``objects_per_shard`` objects; chunk ``c`` becomes ``shard-{c:05d}.h5`` (objects
  that fail are left out of it).
- Executor (``executor.Executor``: ``local_pool.WorkerPool`` by default,
  ``ray_executor.RayExecutor`` with ``executor="ray"``): runs :func:`render_job.render_task`
  per object with a per-object time limit and yields results in any order; this module
  collects them by position and writes chunk after chunk in order, so the output depends
  neither on the number of workers nor on the executor. ``may_dispatch`` keeps at most ~2
  chunks of results in memory. The shard file itself is written by the executor
  (``Executor.write_shard``: here for the local pool, on a Ray worker for Ray, from the arrays
  in the object store: they never pass through this process).
- Resume and retry (``run/resume.py``): the index is rewritten atomically after every shard; a
  rerun keeps intact chunks and renders the rest (and the recorded failures). Ctrl-C or a kill
  loses at most the chunks in progress.
- One writer: the run holds ``sc3d_data.io.outlock.exclusive_lock(out)``.
- Validation: ``RenderConfig.validate`` bounds the options; an object whose silhouettes are
  empty in every view is a failure, not a success.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

from sc3d_data.io.meshes import MESH_SUFFIXES
from sc3d_data.pipeline.executors.executor import finished_chunks, start_executor
from sc3d_data.pipeline.executors.slurm_executor import SlurmOptions, run_array, summed_parts
from sc3d_data.pipeline.jobs.render_job import RENDER, RenderConfig
from sc3d_data.pipeline.run.resume import (check_out, check_resume, clean_tmp, empty_state, remaining,
                                           remove_listed_outputs, resume_state)
from sc3d_data.io.shards import INDEX_NAME, SHARD_PATTERN, add_shard_to_index
from sc3d_data.io.shards import write_index as write_index_file


def render_dataset(config: RenderConfig, executor=None) -> dict:
    """Render ``config.meshes`` into shards under ``config.out`` (see module doc).

    Returns the summary ``{"done", "skipped", "failed", "resumed", "retried", "repaired",
    "seconds", "views", "views_per_s", "out", "notes"}``; ``index.json`` holds the details.
    Raises ``ValueError`` (bad option or folder), ``LockError`` (another writer),
    ``ShardError`` / ``OSError`` (a shard or the index cannot be written: disk full...) with
    one-line messages naming the option or file.

    ``executor``: an executor already started (``local_pool.start_pool`` /
    ``RayExecutor.start``) with the same output settings, used instead of starting one and
    left open (a library caller rendering several parts in one process); else one is started
    for the run and closed at its end."""
    from sc3d_data.io.outlock import exclusive_lock

    config.validate(config.workers or os.cpu_count() or 1)
    out = Path(config.out)
    check_out(out)
    with exclusive_lock(out, "sc3d-data render"):
        return _render_locked(config, out, executor)


def _render_locked(config: RenderConfig, out: Path, executor=None) -> dict:
    from sc3d_data.io.shards import ShardError, shard_path
    from sc3d_data.io.shard_reader import read_records

    t0 = time.monotonic()
    index_file = out / INDEX_NAME
    if config.overwrite:
        remove_listed_outputs(out)
    clean_tmp(out)
    settings = config.settings(None)
    from sc3d_data.pipeline.run.plan import make_plan

    plan = make_plan(config)
    tasks, problems, skipped, split_desc = plan.tasks, plan.problems, plan.skipped, plan.split_desc
    if not plan.found_any:
        raise ValueError(f"--meshes {config.meshes}: no mesh files found (looked for "
                         f"{', '.join(MESH_SUFFIXES)})")
    K = config.objects_per_shard

    # ---- resume
    old = None
    if index_file.is_file():
        from sc3d_data.io.shards import load_index

        old = load_index(out)
    state = empty_state()
    if old is not None:
        defaults = {k: getattr(RenderConfig, k) for k in RenderConfig.__dataclass_fields__ if hasattr(RenderConfig, k)}
        check_resume(out, old, settings, defaults, plan.part)
        state = resume_state(out, old, config.retry_failed, K, tasks)
    retry = state["retry"]
    shards, objects, failures = state["shards"], state["objects"], state["failures"]
    warnings, empty_chunks, attempts = state["warnings"], state["empty_chunks"], state["attempts"]
    todo, resumed = remaining(tasks, state, K)
    n_workers = max(1, min(config.workers or os.cpu_count() or 1, max(1, len(todo))))
    if executor is not None and executor.config.settings(None) != settings:
        raise ValueError("the executor given was started with other render settings than this run")
    pool = executor if executor is not None else start_executor(config, n_workers, RENDER) if todo else None
    settings["backend"] = pool.backend if pool else (old or {}).get("settings", {}).get("backend")

    def write_index(complete: bool) -> None:
        write_index_file(out, complete=complete, settings=settings, split=split_desc, shards=shards,
                         objects=objects, failures=problems + sorted(failures, key=lambda f: f["pos"]),
                         skipped=skipped, warnings=warnings, empty_chunks=empty_chunks,
                         extra={"part": plan.part})

    # ---- render
    n_done = 0
    bar = None

    def write_chunk(c: int, results: list, last: bool) -> None:
        nonlocal n_done
        records, n_new = [], 0
        for t, status, payload in results:
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
            write_index(complete=last)
            return
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
            digest = pool.write_shard(out / name, records, settings)
            add_shard_to_index(shards, objects, name, c, records, sha256=digest)
        else:
            empty_chunks.append(c)
        write_index(complete=last)

    try:
        write_index(not todo)
        if pool is not None:
            if config.progress:
                from sc3d_data.pipeline.run.progress import progress_bar

                bar = progress_bar(total=len(todo), unit="obj", desc="render")
            for chunk in finished_chunks(pool, todo, K, n_workers, bar.update if bar is not None else None):
                write_chunk(*chunk)
    except OSError as e:  # the index could not be written (disk full, ...): one line naming it
        from sc3d_data.io.shards import io_reason

        raise ShardError(f"{e.filename or out / INDEX_NAME}: {io_reason(e)}") from e
    finally:
        if pool is not None and executor is None:
            pool.close()
        if bar is not None:
            bar.close()
        clean_tmp(out)
    seconds = time.monotonic() - t0
    views = n_done * len(config.elevations) * config.num_views
    return {"done": n_done, "resumed": resumed, "skipped": len(skipped), "failed": len(failures) + len(problems),
            "retried": len(retry), "repaired": len(state["broken"]), "notes": state["broken"],
            "seconds": seconds, "views": views, "views_per_s": views / seconds if seconds > 0 else 0.0,
            "out": str(out), "backend": settings["backend"], "workers": n_workers if todo else 0,
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
    merged = merge_parts(Path(config.out), [c.out for c in configs])
    out = summed_parts(summaries, ("done", "resumed", "skipped", "failed", "retried", "repaired", "views"), t0, config)
    out.update(notes=[n for s in summaries for n in s["notes"]],
               views_per_s=out["views"] / out["seconds"] if out["seconds"] > 0 else 0.0,
               backend=",".join(sorted({str(s["backend"]) for s in summaries})),
               workers=options.parts * options.cpus_per_task, merged_objects=merged.objects)
    return out
