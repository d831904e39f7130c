"""``sc3d-train fit``: option parsing only; the work is ``sc3d_train.trainer.fit``."""
from __future__ import annotations

from pathlib import Path

import click


@click.command()
@click.option("--shards", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Shard directory written by `sc3d-data render --voxelize` (optional with --resume).")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Run directory: config.json, checkpoints/, metrics.csv, tb/, curves.png.")
@click.option("--steps", type=int, default=2000, show_default=True, help="Optimiser steps (all phases).")
@click.option("--batch-size", type=int, default=48, show_default=True, help="Global batch size.")
@click.option("--lr", type=float, default=1e-3, show_default=True,
              help="Adam lr at the start of each phase (the paper: 2e-4 constant).")
@click.option("--lr-schedule", type=click.Choice(["cosine", "constant"]), default="cosine", show_default=True,
              help="cosine: annealed over each phase down to 0.1 x lr; constant: the paper's.")
@click.option("--semi-lr", type=float, default=None, help="Adam lr of the mixed/unlabelled phase [--lr].")
@click.option("--semi-labeled-share", type=float, default=0.5, show_default=True,
              help="--semi: share of each batch of the second phase that are labelled images "
              "(0 = the paper's fine-tuning on unlabelled images alone).")
@click.option("--semi", is_flag=True, help="Semi-supervised: pre-train on the labelled subset, then "
              "train on mixed batches: labelled images (supervised) and unlabelled images "
              "(self-consistency + KL + pose search on the predictions).")
@click.option("--labeled-only", is_flag=True, help="Train on the labelled subset alone (the paper's comparison).")
@click.option("--labeled-fraction", type=float, default=0.15, show_default=True,
              help="Fraction of training objects with labels (--semi / --labeled-only); chosen by object, seeded.")
@click.option("--pretrain-steps", type=int, default=None, help="--semi: supervised steps first [steps // 2].")
@click.option("--voxel-decoder", type=click.Choice(["3tube", "1tube"]), default="3tube", show_default=True)
@click.option("--base-channels", type=int, default=None, help="Network width C [32; 8 with --tiny].")
@click.option("--tiny", is_flag=True, help="Small network (C=8, z_s 32, z_p 8) for CPU demos and tests.")
@click.option("--split", default="train", show_default=True, help="Split to train on (train or val; "
              "test is refused).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--checkpoint-every", type=int, default=500, show_default=True)
@click.option("--log-every", type=int, default=10, show_default=True)
@click.option("--workers", type=int, default=0, show_default=True, help="DataLoader worker processes per rank.")
@click.option("--device", default="auto", show_default=True, help="auto (CUDA if present) | cpu | cuda | cuda:N")
@click.option("--amp", type=click.Choice(["auto", "off", "bf16", "fp16"]), default="auto", show_default=True,
              help="Mixed precision; auto = bf16/fp16 on CUDA, off on CPU.")
@click.option("--channels-last", type=click.Choice(["auto", "on", "off"]), default="auto", show_default=True)
@click.option("--resume", is_flag=True, help="Continue RUN_DIR from checkpoints/last.pt exactly; only "
              "--steps/--checkpoint-every/--log-every/--workers/--device may change.")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
@click.pass_context
def fit(ctx, shards, out, steps, batch_size, lr, lr_schedule, semi_lr, semi_labeled_share, semi, labeled_only, labeled_fraction,
        pretrain_steps, voxel_decoder, base_channels, tiny, split, seed, checkpoint_every, log_every,
        workers, device, amp, channels_last, resume, no_progress):
    """Train the self-consistency model on the shards' training split."""
    from sc3d_train.checkpoint import CheckpointError
    from sc3d_train.data import DataError
    from sc3d_train.trainer import TrainingDiverged, fit as run_fit, resolve_config

    if semi and labeled_only:
        raise click.UsageError("--semi and --labeled-only exclude each other")
    if shards is None and not resume:
        raise click.UsageError("Missing option '--shards' (needed unless --resume)")
    renamed = {"no_progress": "progress", "semi": "mode", "labeled_only": "mode"}
    given = {renamed.get(name, name) for name in ctx.params
             if ctx.get_parameter_source(name) == click.core.ParameterSource.COMMANDLINE}
    options = dict(shards=str(shards.resolve()) if shards else None,  # absolute: resume from anywhere
                   out=str(out), steps=steps, batch_size=batch_size, lr=lr, lr_schedule=lr_schedule,
                   semi_lr=semi_lr, semi_labeled_share=semi_labeled_share, mode="semi" if semi else "labeled-only" if labeled_only else "supervised",
                   labeled_fraction=labeled_fraction, pretrain_steps=pretrain_steps, split=split,
                   seed=seed, checkpoint_every=checkpoint_every, log_every=log_every, workers=workers,
                   device=device, amp=amp, channels_last=channels_last, progress=not no_progress)
    model_options = {"voxel_decoder": voxel_decoder, "base_channels": base_channels, "tiny": tiny}
    import os

    main_rank = os.environ.get("RANK", "0") == "0"  # under torchrun only rank 0 reports
    try:
        cfg = resolve_config(options, model_options, given, resume)
        if main_rank:
                click.echo(f"training {cfg.mode} for {cfg.steps} steps, batch {cfg.batch_size}, "
                       f"model {cfg.model}, run dir {cfg.out}")
        summary = run_fit(cfg, resume=resume)
    except (DataError, CheckpointError, TrainingDiverged, ValueError, OSError) as e:  # OSError: disk full...
        from sc3d_data.io.shards import one_line

        raise click.ClickException(one_line(e)) from e
    if not main_rank:
        return
    losses = ", ".join(f"{k} {v:.4f}" for k, v in summary["last_losses"].items())
    click.echo(f"done: step {summary['step']}, {summary['samples_per_s']:.1f} samples/s; {losses}")
    click.echo(f"checkpoint: {summary['checkpoint']}")
