"""SLURM executor of ``sc3d-data render --executor slurm``: a job array through submitit.

Array task ``i`` of ``N = --slurm-parts`` renders part ``i/N`` (``partition.py``) with the local
pool (``--slurm-cpus-per-task`` workers) into ``OUT/parts/part-00i-of-00N/``; the submitting
process waits for the array (printing a line per finished part), then merges the parts into
``OUT`` (``merge.py``). Every part is an ordinary resumable render folder, so a rerun of the
same command resubmits the array and finished parts return at once; a part that failed is
named with its error and the merge is not attempted until every part is complete.

``cluster="local"`` runs the same array on this machine with submitit's ``LocalExecutor``
(how the tests run it). submitit writes its logs and pickles to ``OUT/parts/slurm-logs``.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

from sc3d_data.pipeline.partition import Part
from sc3d_data.pipeline.render_job import RenderConfig

MISSING = "the SLURM executor needs submitit: pip install 'sc3d[slurm]'"


@dataclass(frozen=True)
class SlurmOptions:
    """Job array settings: ``parts`` array tasks of ``cpus_per_task`` CPUs on ``partition``
    (None = the cluster's default) for at most ``time_min`` minutes each."""

    parts: int = 8
    cpus_per_task: int = 4
    partition: str | None = None
    time_min: int = 240
    cluster: str = "slurm"  # or "local": submitit's LocalExecutor


def part_configs(config: RenderConfig, parts: int, cpus: int) -> list[RenderConfig]:
    """One render config per array task: part ``i/parts`` into ``OUT/parts/<part dir>``."""
    root = Path(config.out).resolve() / "parts"
    return [dataclasses.replace(config, part=Part(i, parts), out=root / Part(i, parts).dirname(), workers=cpus,
                                meshes=Path(config.meshes).resolve(),
                                executor="local", progress=False) for i in range(parts)]


def render_part(config: RenderConfig) -> dict:
    """What one array task runs (a plain function: submitit pickles it by reference)."""
    from sc3d_data.pipeline.render_run import render_dataset

    return render_dataset(config)


def submit(configs: list[RenderConfig], options: SlurmOptions, log_dir: Path):
    """Submit the array; the submitit jobs, in part order."""
    try:
        import submitit
    except ImportError:
        raise ImportError(MISSING) from None
    try:
        executor = submitit.AutoExecutor(folder=str(log_dir), cluster=options.cluster)
    except RuntimeError as e:  # no srun/sbatch here; never fall back to running locally unasked
        raise RuntimeError(f"--executor slurm: {e} (--slurm-cluster local runs the array on this machine)") from None
    params = {"timeout_min": options.time_min, "cpus_per_task": options.cpus_per_task, "nodes": 1,
              "tasks_per_node": 1, "name": "sc3d-render"}
    if options.partition and options.cluster == "slurm":
        params["slurm_partition"] = options.partition
    if options.cluster == "slurm":
        params["slurm_array_parallelism"] = len(configs)
    executor.update_parameters(**params)
    return executor.map_array(render_part, configs)


def render_on_slurm(config: RenderConfig, options: SlurmOptions) -> dict:
    """Render ``config`` as a job array of ``options.parts`` parts, then merge into ``config.out``.
    Returns the summary keys of ``render_dataset`` (summed over the parts)."""
    from sc3d_data.pipeline.merge import merge_parts

    t0 = time.monotonic()
    if not config.part.whole:
        raise ValueError(f"--part {config.part} with --executor slurm: the array makes the parts "
                         "(--slurm-parts); give one or the other")
    config.validate(options.cpus_per_task)
    configs = part_configs(config, options.parts, options.cpus_per_task)
    for c in configs:
        Path(c.out).mkdir(parents=True, exist_ok=True)
    jobs = submit(configs, options, Path(config.out) / "parts" / "slurm-logs")
    summaries, errors = [None] * len(jobs), []
    pending = set(range(len(jobs)))
    while pending:
        for i in sorted(pending):
            if jobs[i].done():
                pending.discard(i)
                try:
                    summaries[i] = jobs[i].result()
                    s = summaries[i]
                    print(f"part {i}/{len(jobs)}: done {s['done']}, resumed {s['resumed']}, failed {s['failed']} "
                          f"({len(jobs) - len(pending)}/{len(jobs)} parts finished)", flush=True)
                except Exception as e:  # noqa: BLE001 - reported per part below
                    errors.append(f"part {i}/{len(jobs)} (job {jobs[i].job_id}): {str(e).strip().splitlines()[-1]}")
        time.sleep(0.5 if pending else 0)
    if errors:
        raise RuntimeError("; ".join(errors) + " -- rerun the same command (finished parts are kept)")
    merged = merge_parts(Path(config.out), [c.out for c in configs])
    seconds = time.monotonic() - t0
    views = sum(s["views"] for s in summaries)
    keys = ("done", "resumed", "skipped", "failed", "retried", "repaired")
    out = {k: sum(s[k] for s in summaries) for k in keys}
    out.update(notes=[n for s in summaries for n in s["notes"]], seconds=seconds, views=views,
               views_per_s=views / seconds if seconds > 0 else 0.0, out=str(config.out),
               backend=",".join(sorted({str(s["backend"]) for s in summaries})),
               workers=options.parts * options.cpus_per_task, part="0/1", executor="slurm",
               merged_objects=merged.objects)
    return out
