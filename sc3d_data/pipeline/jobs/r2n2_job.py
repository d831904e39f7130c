"""``sc3d-data import-r2n2`` as a library: 3D-R2N2's released renderings and voxels into sc3d
shards without re-rendering, optionally one part ``I/N`` of the models (``--part``).

The conventions (cameras, voxel placement, front axis, images) are ``sc3d_data.formats.r2n2``;
this module plans the models (in (synset, model id) order, numbered 0..), assigns splits,
converts each model into an ``sc3d_data.io.shards.ObjectRecord`` (job :data:`IMPORT`, run by
an executor: the local pool or Ray, ``executor.py``; ``--executor slurm``: a job array of
parts, ``slurm_executor``) and writes shards and the index as ``render`` does: chunk ``c`` of
``objects_per_shard`` plan positions becomes ``shard-{c:05d}.h5`` (its failed models left
out), in plan order whatever order the results come in. A model that fails (bad files, the
per-model time limit ``--timeout``, a worker killed) is recorded in the index's ``failures``
with the reason and the others are imported.

Resume: the index is rewritten atomically after every shard (lazily past 10,000 objects; the chunk loop and index writer
``render`` uses: ``shard_output.py``). A rerun with the same settings and ``--part`` keeps the
chunks whose shard is intact (size and SHA-256 as in the index: ``resume.resume_state``) and
imports the rest, so a crash or Ctrl-C loses no finished shard; the models that failed are tried
again, as ``render`` retries its failures (a PNG restored after an incomplete extraction is then
imported, not reported missing again); other settings are refused (``--overwrite`` starts afresh).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from sc3d_data.formats.r2n2 import (BLENDER_LENS_MM, BLENDER_SENSOR_MM, MASK_THRESHOLD, R2N2_FOV_DEG, R2N2_FRONT,
                                    R2N2_NUM_VIEWS, R2N2_VOXEL_RESOLUTION, R2N2Model, find_r2n2_models,
                                    load_r2n2_object)
from sc3d_data.pipeline.executors.job import ExecOptions, Job
from sc3d_data.pipeline.executors.slurm_executor import SlurmOptions, run_array, summed_parts
from sc3d_data.pipeline.run.setting_meaning import config_defaults
from sc3d_data.io.shards import CHUNK_LAYOUTS, encode_arrays
from sc3d_data.pipeline.run.partition import Part
from sc3d_data.pipeline.run.plan import Task


@dataclass
class ImportConfig(ExecOptions):
    """Every option of ``sc3d-data import-r2n2`` (see ``cli/data_import_r2n2.py``); where and how
    long each model runs are the ``ExecOptions`` fields (not part of ``settings``)."""

    renderings: Path
    voxels: Path
    out: Path
    image_size: int = 64
    background: tuple[int, int, int] = (255, 255, 255)
    categories: str | None = None
    split: str = "r2n2"
    split_file: str | None = None
    seed: int = 0
    voxel_frame: str = "cube"
    front: str = R2N2_FRONT
    objects_per_shard: int = 256
    overwrite: bool = False
    part: Part = Part(0, 1)  # --part I/N (sc3d_data.pipeline.run.partition); 0/1 = all models
    progress: bool = True  # a progress bar / log lines on stderr

    def settings(self) -> dict:
        """JSON-able record of every setting (stored in the shards and the index)."""
        from sc3d_data.formats.splits import absolute_split_file

        return {
            "source": "3D-R2N2", "renderings": str(Path(self.renderings).resolve()),
            "voxels": str(Path(self.voxels).resolve()), "image_size": int(self.image_size),
            "background": [int(c) for c in self.background], "categories": self.categories,
            "split": self.split, "split_file": absolute_split_file(self.split_file), "seed": int(self.seed),
            "voxel_frame": self.voxel_frame, "front": self.front, "objects_per_shard": int(self.objects_per_shard),
            "num_views": R2N2_NUM_VIEWS, "voxel_resolution": R2N2_VOXEL_RESOLUTION,
            "r2n2_camera": {"distance": "distance_ratio * 1.75", "lens_mm": BLENDER_LENS_MM,
                            "sensor_mm": BLENDER_SENSOR_MM, "fov_deg": R2N2_FOV_DEG,
                            "azimuth": "read from the canonical camera centre (front -> +Z)",
                            "roll": "-in_plane"},
            "mask": f"box-filtered alpha >= {MASK_THRESHOLD}",
            "chunks": CHUNK_LAYOUTS[0],  # the shard writer's default layout, recorded as render does
        }


def _take_part(plan: list, part, problems: list, skipped: list):
    """This run's share of ``plan`` (``[(model, split)]``) for ``--part`` (all when None), the
    index's ``part`` record, and the problems/skipped files (reported by part 0 only)."""
    from sc3d_data.pipeline.run.partition import part_of, part_record, plan_digest

    part = part or Part(0, 1)
    digest = plan_digest((m.category, m.model_id, s) for m, s in plan)
    mine = [(m, s) for m, s in plan if part.whole or part_of(m.category, m.model_id, part.count) == part.index]
    if part.index != 0:
        problems, skipped = [], []
    return mine, part_record(part, len(mine), len(plan), digest), problems, skipped


@dataclass(frozen=True)
class R2N2Task(Task):
    """One model of the plan (``path``: its ``ShapeNetRendering`` folder, named in failures)."""

    model: R2N2Model | None = None


def import_task(config: ImportConfig, backend: str, task: R2N2Task):
    """The job of one model (``executor.Job``, run by a worker): ``(pos, "ok", (ObjectRecord,
    []))`` or ``(pos, "fail", reason)`` naming the file and the problem."""
    try:
        record = load_r2n2_object(task.model, task.split, config.image_size, config.background,
                                  config.voxel_frame, config.front)
        return task.pos, "ok", (encode_arrays(record, CHUNK_LAYOUTS[0]), [])
    except (ValueError, OSError) as e:  # the messages name the file
        return task.pos, "fail", str(e)
    except Exception as e:  # noqa: BLE001 - recorded per model, never aborts the run
        return task.pos, "fail", f"{task.path}: {type(e).__name__}: {e}"


IMPORT = Job("import", import_task)


def plan_models(config: ImportConfig):
    """``(tasks, split description, part record, problems, skipped)`` of ``config``: the models
    with a split, in (synset, model id) order, this run's part of them numbered from 0. A model
    folder whose name is not valid UTF-8 is a problem (``io.names.split_not_utf8``)."""
    from sc3d_data.formats.splits import assign_splits

    from sc3d_data.io.names import split_not_utf8

    models, problems = find_r2n2_models(config.renderings, config.voxels, config.categories)
    models, name_problems = split_not_utf8(models, lambda m: m.rendering_dir.parent, config.renderings,
                                           "not imported")
    problems += name_problems
    splits, split_desc, split_problems = assign_splits(models, spec=config.split, seed=config.seed,
                                                       split_file=config.split_file)
    skipped = list(split_problems)
    plan = []
    for m in models:
        if (m.category, m.model_id) in splits:
            plan.append((m, splits[(m.category, m.model_id)]))
        else:
            skipped.append({"source": str(m.rendering_dir.parent), "reason": "not in any split (--split-file)"})
    plan, part, problems, skipped = _take_part(plan, config.part, problems, skipped)
    tasks = [R2N2Task(i, str(m.rendering_dir.parent), m.category, m.model_id, s, m) for i, (m, s) in enumerate(plan)]
    return tasks, split_desc, part, problems, skipped


def import_r2n2(config: ImportConfig, progress: Callable[[int], None] | None = None) -> dict:
    """Import ``config.renderings`` + ``config.voxels`` into shards under ``config.out`` (module
    doc), holding the folder's write lock.

    ``progress``: called with 1 per finished model instead of the bar of ``config.progress``.
    Returns the summary ``{"done", "resumed", "failed", "skipped", "planned", "seconds", "out",
    "failures"}`` (``done``: imported by this run; ``failures``: those of this run and of
    discovery). ``ValueError`` / ``FileNotFoundError`` / ``ShardError`` with one line naming
    the folder or file (another ``--part`` or other settings in ``out``, missing input, ...)."""
    from sc3d_data.pipeline.jobs.shard_output import locked_output

    with locked_output(Path(config.out), "sc3d-data import-r2n2") as out:
        return _import_locked(config, out, progress)


def _import_locked(config: ImportConfig, out: Path, progress) -> dict:
    import os

    from sc3d_data.pipeline.executors.executor import start_executor
    from sc3d_data.pipeline.jobs.shard_output import NewShards, ShardIndex

    t0 = time.monotonic()
    tasks, split_desc, part, problems, skipped = plan_models(config)
    index = ShardIndex(out, config.settings(), split_desc, extra={"part": part},
                       problems=[dict(p, category="", model_id="") for p in problems], skipped=skipped)
    run = NewShards.resume(index, tasks, max(1, int(config.objects_per_shard)), config_defaults(ImportConfig),
                           retry_failed=True, overwrite=config.overwrite)
    pool, n_workers = None, 1
    try:
        if run.todo:
            n_workers = max(1, min(config.workers or os.cpu_count() or 1, len(run.todo)))
            pool = start_executor(config, n_workers, IMPORT)
        run.run(pool, n_workers, progress, bar="import-r2n2" if config.progress else None)
    finally:
        if pool is not None:
            pool.close()
    return {"done": run.done, "resumed": run.resumed, "failed": len(index.failures) + len(index.problems),
            "skipped": len(skipped), "planned": len(tasks), "seconds": time.monotonic() - t0, "out": str(out),
            "failures": index.problems + run.new_failures}


def import_part(config) -> dict:
    """What one array task of ``import-r2n2`` runs."""
    return import_r2n2(config)


def import_on_slurm(config, options: SlurmOptions) -> dict:
    """``import-r2n2`` of ``config`` (``r2n2_job.ImportConfig``) as a job array, then merged into
    ``config.out``; the summary keys of ``r2n2_job.import_r2n2`` (summed over the parts)."""
    from sc3d_data.pipeline.run.merge import merge_parts

    t0 = time.monotonic()
    configs, summaries = run_array(import_part, config, options, paths=("renderings", "voxels"))
    merge_parts(Path(config.out), [c.out for c in configs], defaults_of=lambda _: config_defaults(ImportConfig))
    out = summed_parts(summaries, ("done", "resumed", "failed", "skipped", "planned"), t0, config)
    out["failures"] = [f for s in summaries for f in s["failures"]]
    return out
