"""Options shared by the commands that scale out (``render``, ``voxelize``, ``import-r2n2``):
``--part I/N``, the executor choice (``--executor local|ray|slurm`` and its settings) and the
spelling of the ``--up`` / ``--front`` axes."""
from __future__ import annotations

import click

from sc3d_data.pipeline.run.partition import Part, parse_part, part_from_env


def _part(ctx, param, value) -> Part:
    try:
        if value is not None:
            return parse_part(value)
    except ValueError as e:
        raise click.BadParameter(str(e)) from None
    try:
        return part_from_env() or Part(0, 1)
    except ValueError as e:  # the job array's, not an option the user gave
        raise click.UsageError(str(e)) from None


def axis_value(ctx, param, value):
    """``--up`` / ``--front`` as ``AXES`` spells them (``+z`` -> ``+Z``), so that a dataset records
    one spelling per axis; ``auto`` and anything invalid unchanged (checked with the run)."""
    from sc3d_data.geometry.normalize import axis_name

    return axis_name(value)


def part_option(f):
    """``--part I/N`` (default: the SLURM array task's, else the whole plan)."""
    return click.option("--part", callback=_part, default=None, metavar="I/N",
                        help="Only part I of N (0 <= I < N) of the objects, chosen by a hash of the object id; "
                             "default inside a SLURM job array: part (SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN) / "
                             "SLURM_ARRAY_TASK_STEP of SLURM_ARRAY_TASK_COUNT, so --array=1-16 gives 0/16 to 15/16; "
                             "else all. "
                             "render, import-r2n2: combine the part folders with `sc3d-data merge`; voxelize "
                             "--meshes: the parts share one --out.")(f)


def part_from_slurm_note(part: Part) -> str | None:
    """A line for the user when ``--part`` was not given and the part came from SLURM's
    environment (``part_from_env``), so a job-array user who meant every object notices; None
    otherwise. Call inside the command."""
    from click.core import ParameterSource

    if part.whole or click.get_current_context().get_parameter_source("part") != ParameterSource.DEFAULT:
        return None
    return (f"part {part} taken from SLURM_ARRAY_TASK_ID/SLURM_ARRAY_TASK_COUNT (this is a job array task): only "
            "this part's objects were done; merge the part folders with `sc3d-data merge`, or give --part 0/1 "
            "for all")


def _slurm(ctx, param, value):
    from sc3d_data.pipeline.executors.slurm_executor import SlurmOptions

    p = ctx.params
    return SlurmOptions(parts=value, cpus_per_task=p.pop("slurm_cpus_per_task"), partition=p.pop("slurm_partition"),
                        time_min=p.pop("slurm_time"), cluster=p.pop("slurm_cluster"))


def executor_options(f):
    """``--executor``, ``--address``, ``--retries`` and the ``--slurm-*`` settings (the latter
    arrive as one ``slurm`` argument, a ``SlurmOptions``)."""
    opts = [
        click.option("--executor", type=click.Choice(["local", "ray", "slurm"]), default="local", show_default=True,
                     help="local: a process pool on this machine; ray: one Ray task per object "
                          "(pip install 'sc3d[ray]'); slurm: a job array of --slurm-parts parts through "
                          "submitit, merged into --out at the end (pip install 'sc3d[slurm]')."),
        click.option("--address", default=None,
                     help="ray: address of a running cluster (auto, HOST:PORT); default: start a local one."),
        click.option("--retries", type=click.IntRange(0), default=3, show_default=True,
                     help="Times an object is run again when its worker process dies (segfault, OOM "
                          "killer, lost node); a timeout or an error of the mesh is not retried."),
        click.option("--slurm-cpus-per-task", type=click.IntRange(1), default=4, show_default=True, is_eager=True,
                     expose_value=True, help="slurm: CPUs (render workers) per array task."),
        click.option("--slurm-partition", default=None, is_eager=True, help="slurm: partition to submit to."),
        click.option("--slurm-time", type=click.IntRange(1), default=240, show_default=True, is_eager=True,
                     help="slurm: time limit of one array task, minutes."),
        click.option("--slurm-cluster", type=click.Choice(["slurm", "local"]), default="slurm", show_default=True,
                     is_eager=True, help="slurm: 'local' runs the array on this machine with submitit's "
                                         "LocalExecutor (to try a setup)."),
        click.option("--slurm-parts", "slurm", type=click.IntRange(1), default=8, show_default=True, callback=_slurm,
                     help="slurm: number of parts (array tasks)."),
    ]
    for o in reversed(opts):
        f = o(f)
    return f


def timeout_option(f):
    """``--timeout`` (per-object time limit, seconds) as ``timeout_s``."""
    return click.option("--timeout", "timeout_s", type=click.FloatRange(0, min_open=True), default=120.0,
                        show_default=True, help="Per-object time limit, seconds (a hung object is recorded as "
                                                "failed).")(f)


#: the options of one executor (``--executor``), refused on the command line with another
EXECUTOR_ONLY = {"address": "ray", "slurm_cpus_per_task": "slurm", "slurm_partition": "slurm",
                 "slurm_time": "slurm", "slurm_cluster": "slurm", "slurm": "slurm"}


def check_executor_options(executor: str, advice: str = "give that executor or leave them out") -> None:
    """``click.UsageError`` naming the options given on the command line that ``executor`` does
    not read (``--slurm-parts 16`` without ``--executor slurm`` rendered everything here, silently)."""
    from click.core import ParameterSource

    ctx = click.get_current_context()
    given = [p for p in ctx.command.params if EXECUTOR_ONLY.get(p.name, executor) != executor
             and ctx.get_parameter_source(p.name) == ParameterSource.COMMANDLINE]
    if given:
        names = ", ".join(p.opts[0] for p in given)
        raise click.UsageError(f"{names}: not read by --executor {executor} (only by --executor "
                               f"{' / '.join(sorted({EXECUTOR_ONLY[p.name] for p in given}))}); {advice}")


def run_scaled(config, slurm, run_local, run_slurm):
    """``run_slurm(config, slurm)`` with ``--executor slurm``, else ``run_local(config)``
    (local pool or Ray); errors become one line. Options of another executor are refused first."""
    from sc3d_data.io.shards import one_line

    check_executor_options(config.executor)
    try:
        return run_slurm(config, slurm) if config.executor == "slurm" else run_local(config)
    except (ValueError, RuntimeError, OSError, ImportError) as e:  # option, folder, lock, disk, missing extra
        raise click.ClickException(one_line(e))


def run_render(config, slurm):
    """Run ``render`` with ``config.executor``; errors become one line."""
    from sc3d_data.pipeline.jobs.render_run import render_dataset
    from sc3d_data.pipeline.jobs.render_run import render_on_slurm

    return run_scaled(config, slurm, render_dataset, render_on_slurm)
