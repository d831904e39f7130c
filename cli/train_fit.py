"""``sc3d-train fit``: option parsing only; the work is ``sc3d_train.loop.trainer.fit``.

The settings' options are generated from the dataclasses of ``sc3d_train.settings.config`` (their
defaults and help live there); the options written here are the paths, the mode flags, the
tiny preset and ``--config`` / ``--resume``."""
from __future__ import annotations

from pathlib import Path

import click

from sc3d_cli.folder_path import FolderPath
from sc3d_cli.config_options import config_options, given_on_command_line
from sc3d_train.settings.config import RESUMABLE_FIELDS, TINY_MODEL, ModelConfig, RunConfig

TINY_NOTES = {k: f"[--tiny: {v}]" for k, v in TINY_MODEL.items()}


@click.command()
@click.option("--config", "config_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="A run's config.yaml: train that run again (options given here override it; "
              "--shards and --out default to its values).")
@click.option("--shards", type=FolderPath(), default=None,
              help="Shard directory written by `sc3d-data render --voxelize` (optional with --resume; "
                   "there, a moved copy of the run's data).")
@click.option("--out", type=FolderPath(), default=None,
              help="Run directory: config.yaml, checkpoints/, metrics.csv, tb/, curves.png.")
@config_options(RunConfig)
@click.option("--semi", is_flag=True, help="Semi-supervised: pre-train on the labelled subset, then "
              "train on mixed batches: labelled images (supervised) and unlabelled images "
              "(self-consistency + KL + pose search on the predictions).")
@click.option("--labeled-only", is_flag=True, help="Train on the labelled subset alone (the paper's comparison).")
@config_options(ModelConfig, TINY_NOTES)
@click.option("--tiny", is_flag=True, help="The tiny network preset for CPU demos and tests "
              f"({', '.join(f'{k} {v}' for k, v in TINY_MODEL.items())}).")
@click.option("--resume", is_flag=True, help="Continue RUN_DIR from checkpoints/last.pt exactly; only "
              + ", ".join("--" + k.replace("_", "-") for k in RESUMABLE_FIELDS)
              + " may change (--shards: the same data, moved).")
@click.pass_context
def fit(ctx, config_file, shards, out, semi, labeled_only, tiny, resume, **_settings):
    """Train the self-consistency model on the shards' training split."""
    from sc3d_train.loop.checkpoint import CheckpointError
    from sc3d_train.data.dataset import DataError
    from sc3d_train.loop.config_file import file_settings
    from sc3d_train.loop.resolve import check_mode_options, pose_grid_warning, resolve_config
    from sc3d_train.loop.schedule import no_label_warning, no_semi_phase_warning
    from sc3d_train.loop.runtime import check_device_name
    from sc3d_train.loop.loss_window import TrainingDiverged
    from sc3d_train.loop.trainer import fit as run_fit

    if semi and labeled_only:
        raise click.UsageError("--semi and --labeled-only exclude each other")
    if resume and config_file is not None:
        raise click.UsageError("--resume reads the run's own config; it takes no --config")
    if out is None and config_file is None:
        raise click.UsageError("Missing option '--out'")
    if shards is None and not resume and config_file is None:
        raise click.UsageError("Missing option '--shards' (needed unless --resume or --config)")
    options = given_on_command_line(ctx, RunConfig)
    if shards is not None:
        options["shards"] = str(shards)  # made absolute with the config's: resolve_config
    if out is not None:
        options["out"] = str(out)
    if semi or labeled_only:
        options["mode"] = "semi" if semi else "labeled-only"
    model_options = {**given_on_command_line(ctx, ModelConfig), "tiny": tiny}
    import os

    main_rank = os.environ.get("RANK", "0") == "0"  # under torchrun only rank 0 reports
    from contextlib import nullcontext

    import torch

    from sc3d_data.io.outlock import LockError, exclusive_lock

    try:
        run_dir = out if out is not None else file_settings(config_file, options).get("out")
        # one writer per run folder (rank 0 writes for all ranks), from the "already holds a run"
        # check to the last checkpoint, so config.yaml and checkpoints belong to one run
        lock = exclusive_lock(run_dir, "sc3d-train fit", create=True) if main_rank and run_dir else nullcontext()
        with lock:
            cfg = resolve_config(options, model_options, resume, config_file)
            check_mode_options(cfg, options, config_file)
            check_device_name(cfg.device)  # before the run's first line
            warnings = (pose_grid_warning(cfg), no_semi_phase_warning(cfg), no_label_warning(cfg))
            for warning in warnings if main_rank else ():
                if warning:
                    click.echo(f"warning: {warning}", err=True)
            line = (f"training {cfg.mode} for {cfg.steps} steps, batch {cfg.batch_size}, model {cfg.model}, "
                    f"run dir {cfg.out}")
            # said once steps will run: a resumed run already at --steps says only 'nothing to train'
            summary = run_fit(cfg, resume=resume, announce=lambda: click.echo(line) if main_rank else None)
    except (DataError, CheckpointError, TrainingDiverged, LockError, ValueError, OSError) as e:  # OSError: disk full...
        from sc3d_data.io.shards import one_line

        raise click.ClickException(one_line(e)) from e
    except torch.cuda.OutOfMemoryError as e:  # CUDA; a CPU batch that does not fit is refused before training
        from sc3d_data.io.shards import one_line

        raise click.ClickException(f"out of GPU memory while training ({one_line(e)[:160]}); the memory of a "
                                   "step grows with --batch-size: use a smaller one") from e
    if not main_rank:
        return
    if summary.get("already_done"):
        click.echo(f"nothing to train: {summary['checkpoint']} is already at step {summary['step']} >= --steps "
                   f"{cfg.steps}; give a larger --steps to train further")
        return
    losses = ", ".join(f"{k} {v:.4f}" for k, v in summary["last_losses"].items())
    if losses:
        click.echo(f"done: step {summary['step']}, {summary['samples_per_s']:.1f} samples/s on {summary['device']}; "
                   f"{losses}")
    else:  # a finished run stopped while validating its last step: that validation alone was done
        click.echo(f"nothing to train: the run is at step {summary['step']}; validated that step, which the run had "
                   "stopped while validating")
    click.echo(f"checkpoint: {summary['checkpoint']}")
    best = summary.get("best")
    if best:
        click.echo(f"best on {best['split']!r} ({best['select_by']}): step {best['step']}, IoU@0.4 "
                   f"{best['val_iou']:.3f}, rotation within 30 deg {best['val_rot_acc30']:.2f} "
                   f"(checkpoints/best.pt; eval --checkpoint {summary['checkpoint'].rsplit('/checkpoints/', 1)[0]})")
