"""SLURM executor of ``render``, ``import-r2n2`` and ``voxelize --meshes`` with ``--executor
slurm``: a job array through submitit. Each job holds its own entry points, the function one
array task runs and the whole run (``jobs.render_run.render_part`` / ``render_on_slurm``,
``jobs.r2n2_job.import_part`` / ``import_on_slurm``, ``jobs.voxel_meshes.voxelize_part`` /
``voxelize_on_slurm``), built on :func:`run_array` and :func:`summed_parts` here, so this module
imports no job.

Array task ``i`` of ``N = --slurm-parts`` runs part ``i/N`` (``run/partition.py``) with the local
pool (``--slurm-cpus-per-task`` workers) into ``OUT/parts/part-00i-of-00N/``; the submitting
process waits for the array (printing a line per finished part), then merges the parts into
``OUT`` (``run/merge.py``). ``voxelize --meshes`` writes one file per mesh, so its parts share
``OUT`` and nothing is merged. Every part is an ordinary resumable output folder, so a rerun of the
same command resubmits the array and finished parts return at once; a part that failed is
named with its error and the merge is not attempted until every part is complete.

``cluster="local"`` runs the same array on this machine with submitit's ``LocalExecutor``
(how the tests run it). submitit writes its logs and pickles to ``OUT/parts/slurm-logs``.
"""
from __future__ import annotations

import dataclasses
import re
import time
from dataclasses import dataclass
from pathlib import Path

from sc3d_data.pipeline.run.partition import Part

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


def part_configs(config, parts: int, cpus: int, paths: tuple[str, ...] = ("meshes",),
                 shared_out: bool = False) -> list:
    """One config per array task: part ``i/parts`` into ``OUT/parts/<part dir>`` (``OUT`` itself
    with ``shared_out``), run by the local pool of ``cpus`` workers, input folders ``paths``
    (fields of ``config``) made absolute. With ``--gpus``, each task asks for ``len(gpus)`` GPUs
    and spreads its workers over the EGL devices of its allocation, ``0 .. len(gpus) - 1``."""
    root = Path(config.out).resolve()
    gpus = {"gpus": tuple(range(len(config.gpus)))} if getattr(config, "gpus", ()) else {}  # its own GPUs
    return [dataclasses.replace(config, part=Part(i, parts), workers=cpus, executor="local", progress=False, **gpus,
                                out=root if shared_out else root / "parts" / Part(i, parts).dirname(),
                                **{k: Path(getattr(config, k)).resolve() for k in paths}) for i in range(parts)]


def submit(fn, configs: list, options: SlurmOptions, log_dir: Path, name: str):
    """Submit the array of ``fn(config)``; the submitit jobs, in part order."""
    try:
        import submitit
    except ImportError:
        raise ImportError(MISSING) from None
    try:
        executor = submitit.AutoExecutor(folder=str(log_dir), cluster=options.cluster)
    except RuntimeError as e:  # no srun/sbatch here; never fall back to running locally unasked
        raise RuntimeError(f"--executor slurm: {e} (--slurm-cluster local runs the array on this machine)") from None
    params = {"timeout_min": options.time_min, "cpus_per_task": options.cpus_per_task, "nodes": 1,
              "tasks_per_node": 1, "name": f"sc3d-{name}"}
    gpus = len(getattr(configs[0], "gpus", ())) if configs else 0
    if gpus and options.cluster == "slurm":  # each array task gets its own GPUs (devices.py)
        params["gpus_per_node"] = gpus
    if options.partition and options.cluster == "slurm":
        params["slurm_partition"] = options.partition
    if options.cluster == "slurm":
        params["slurm_array_parallelism"] = len(configs)
    executor.update_parameters(**params)
    return executor.map_array(fn, configs)


def run_array(fn, config, options: SlurmOptions, paths: tuple[str, ...] = ("meshes",),
              shared_out: bool = False) -> tuple[list, list[dict]]:
    """Run ``fn`` on every part of ``config`` as a job array (module doc) and wait for it,
    printing a line per finished part. Returns the part configs and their summaries (dicts with
    ``done``, ``resumed``, ``failed``); ``RuntimeError`` naming every part that failed."""
    if not config.part.whole:
        raise ValueError(f"--part {config.part} with --executor slurm: the array makes the parts "
                         "(--slurm-parts); give one or the other")
    if hasattr(config, "validate"):
        config.validate(options.cpus_per_task)
    from sc3d_data.io.outlock import missing_folders, remove_made_folders

    configs = part_configs(config, options.parts, options.cpus_per_task, paths, shared_out)
    logs = Path(config.out) / "parts" / "slurm-logs"
    made = sorted({f for c in configs for f in missing_folders(Path(c.out))} | set(missing_folders(logs)),
                  key=lambda f: len(f.parts), reverse=True)  # deepest first
    for c in configs:
        Path(c.out).mkdir(parents=True, exist_ok=True)
    try:
        jobs = submit(fn, configs, options, logs, fn.__name__.split("_")[0])
    except BaseException:  # no job submitted (no sbatch here, a bad partition): no folder of it is left
        remove_made_folders(made)
        raise
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
                    errors.append(f"part {i}/{len(jobs)} (job {jobs[i].job_id}): {failure_reason(e, jobs[i])}")
        time.sleep(0.5 if pending else 0)
    if errors:
        raise RuntimeError("; ".join(errors) + " -- rerun the same command (finished parts are kept)")
    return configs, summaries


def failure_reason(error: Exception, job) -> str:
    """One line for a failed array task: submitit's ``FailedJobError`` holds the task's traceback
    between dashed lines, then log paths (its last line, once reported, named the ``.out`` log,
    which does not hold the error): the traceback's last line, the exception's class name left
    out, and the ``.err`` log that holds the trace. Other errors (a task that never finished:
    time limit, lost node) by their first line, which says so."""
    text = str(error).strip()
    parts = text.split("----------------------")
    if len(parts) >= 3 and parts[1].strip():
        reason = re.sub(r"^[\w.]*(Error|Exception|Exit|Interrupt): ", "", parts[1].strip().splitlines()[-1])
        return f"{reason} (log: {job.paths.stderr})"
    return text.splitlines()[0] if text else type(error).__name__


def summed_parts(summaries: list[dict], keys: tuple[str, ...], t0: float, config) -> dict:
    """The whole run's summary from the parts' ``summaries``: ``keys`` summed, with the
    ``seconds`` since ``t0``, ``out``, ``part`` 0/1 and ``executor`` slurm."""
    out = {k: sum(s[k] for s in summaries) for k in keys}
    out.update(seconds=time.monotonic() - t0, out=str(config.out), part="0/1", executor="slurm")
    return out
