"""``sc3d-train claims``: option parsing only; the work is ``sc3d_train.evaluation.claims.run_all``."""
from __future__ import annotations

import click

from sc3d_cli.folder_path import FolderPath
from sc3d_cli.config_options import config_options
from sc3d_train.settings.command_config import ClaimsConfig


@click.command()
@click.option("--train-shards", type=FolderPath(), required=True,
              help="Shards to train on (their 'train' split).")
@click.option("--eval-shards", type=FolderPath(), required=True,
              help="Shards to evaluate on (objects never trained on; may be the same folder).")
@click.option("--out", type=FolderPath(), required=True,
              help="Study folder: runs/NAME/seed-S (each run; its evaluation in eval/, with --pick last "
              "eval-last/), claims.md, claims.json, claims.png (--pick last: claims-last.*).")
@click.option("--runs", default=None, help="Comma-separated subset of: sup-3tube, sup-1tube, "
              "labeled-only, semi, ray, ray-proj [all].")
@config_options(ClaimsConfig)
def claims(train_shards, eval_shards, eval_split, out, preset, runs, device, workers, pick, seeds):
    """Train the paper's comparisons (supervised 3/1 tubes, labelled-only vs semi at 15%, ray vs
    ray+projection at the true pose) with --seeds seeds and equal budgets, evaluate each on
    held-out objects and write the paper's tables (mean ± standard deviation over the seeds).
    Rerunning resumes."""
    from sc3d_data.io.outlock import LockError, exclusive_lock
    from sc3d_data.io.shards import one_line
    from sc3d_train.loop.checkpoint import CheckpointError
    from sc3d_train.loop.loss_window import TrainingDiverged
    from sc3d_train.evaluation.claims import PRESETS, RUNS, check_study_options, run_all
    from sc3d_train.data.dataset import DataError

    names = [r.strip() for r in runs.split(",")] if runs is not None else None
    if names is not None and not all(names):
        raise click.UsageError(f"--runs {runs!r} names no run (an empty name); choose from {', '.join(RUNS)}, "
                               "or leave --runs out for all of them")
    unknown = sorted(set(names or []) - set(RUNS))
    if unknown:
        raise click.UsageError(f"unknown runs {unknown}; choose from {', '.join(RUNS)}")
    try:  # options that cannot serve: refused before the study's folder is created
        check_study_options(PRESETS[preset], seeds, device)
    except ValueError as e:
        raise click.ClickException(one_line(e)) from e
    try:  # one study per folder: its runs, evaluations and reports are written by this process only
        with exclusive_lock(out, "sc3d-train claims", create=True):
            run_all(train_shards, eval_shards, out, preset, eval_split, device, workers, names, echo=click.echo,
                    seeds=seeds, pick=pick)
    except (DataError, CheckpointError, TrainingDiverged, LockError, ValueError, OSError) as e:  # OSError: disk full
        raise click.ClickException(one_line(e)) from e
