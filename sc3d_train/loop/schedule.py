"""What a run does at a given optimiser step: its phase, learning rate, batch split and data
position (pure functions of the :class:`~sc3d_train.settings.config.RunConfig` and the step).

Phases: ``"supervised"`` (every step of ``supervised`` / ``labeled-only`` / ``true-pose-masks``
runs, the first ``pretrain_steps`` of ``semi``) and ``"unsupervised"`` (the mixed phase of
``semi``)."""
from __future__ import annotations

import math

from sc3d_train.settings.config import RunConfig


def phase_at(cfg: RunConfig, step: int) -> str:
    """``"supervised"`` or ``"unsupervised"``: the loss used at optimiser step ``step``."""
    if cfg.mode == "semi" and step >= cfg.pretrain_steps:
        return "unsupervised"
    return "supervised"


def phase_start(cfg: RunConfig, step: int) -> int:
    """The first step of the phase that ``step`` belongs to."""
    return cfg.pretrain_steps if phase_at(cfg, step) == "unsupervised" else 0


def lr_at(cfg: RunConfig, step: int) -> float:
    """The learning rate at ``step``: ``lr`` (``semi_lr`` in the unsupervised phase when set),
    constant or, with ``lr_schedule="cosine"``, annealed over the phase from that value to
    ``lr_min_ratio`` times it, at the end the run planned at that step (``steps``, or for steps
    before a ``--resume`` that changed it, the ``steps`` recorded in ``steps_before``)."""
    base = cfg.lr
    if phase_at(cfg, step) == "unsupervised" and cfg.semi_lr is not None:
        base = cfg.semi_lr
    if cfg.lr_schedule != "cosine":
        return base
    start = phase_start(cfg, step)
    planned = next((steps for until, steps in cfg.steps_before or [] if step < until), cfg.steps)
    end = cfg.pretrain_steps if cfg.mode == "semi" and step < cfg.pretrain_steps else planned
    t = (step - start) / max(end - start, 1)
    return base * (cfg.lr_min_ratio + (1 - cfg.lr_min_ratio) * 0.5 * (1 + math.cos(math.pi * t)))


def batch_split(cfg: RunConfig, local_batch: int) -> tuple[int, int]:
    """``(labelled, unlabelled)`` samples per rank of an unsupervised-phase batch."""
    labeled = int(round(local_batch * cfg.semi_labeled_share))
    if cfg.semi_labeled_share > 0:
        labeled = min(max(labeled, 1), local_batch - 1)
    return labeled, local_batch - labeled


def mixed_batch(cfg: RunConfig, local_batch: int) -> int:
    """Samples per rank of a mixed-phase step (labelled and unlabelled): ``local_batch`` (the
    rank's share of ``batch_size``) scaled to ``semi_batch_size`` when that is set. Raises
    ``ValueError`` when ``semi_batch_size`` does not split evenly over the ranks."""
    if cfg.semi_batch_size is None:
        return local_batch
    per_rank, rest = divmod(cfg.semi_batch_size * local_batch, cfg.batch_size)
    if rest:
        raise ValueError(f"semi batch size {cfg.semi_batch_size} is not divisible by "
                         f"{cfg.batch_size // local_batch} ranks")
    return per_rank


def step_samples(cfg: RunConfig, step: int) -> int:
    """Images of optimiser step ``step`` over all ranks: ``batch_size``, or in the mixed phase
    ``semi_batch_size`` when that is set (what ``fit`` counts in its samples/s)."""
    if phase_at(cfg, step) == "unsupervised" and cfg.semi_batch_size is not None:
        return cfg.semi_batch_size
    return cfg.batch_size


def data_position(cfg: RunConfig, step: int, local_batch: int) -> dict:
    """Samples of this phase's streams consumed by each rank before ``step`` (saved in every
    checkpoint and checked at resume)."""
    phase = phase_at(cfg, step)
    start = phase_start(cfg, step)
    if phase == "unsupervised":
        labeled, unlabeled = batch_split(cfg, mixed_batch(cfg, local_batch))
        return {"phase": phase, "phase_start": start, "samples_per_rank": (step - start) * unlabeled,
                "labeled_samples_per_rank": (step - start) * labeled}
    return {"phase": phase, "phase_start": start, "samples_per_rank": (step - start) * local_batch}


def no_semi_phase_warning(cfg: RunConfig) -> str | None:
    """The warning ``fit`` prints for a ``semi`` run whose ``pretrain_steps`` reach ``steps``: it
    never reaches its unlabelled phase, so it trains as ``labeled-only`` (its pretraining) from
    start to end; None for any other run."""
    if cfg.mode != "semi" or cfg.pretrain_steps < cfg.steps:
        return None
    return (f"--pretrain-steps {cfg.pretrain_steps} >= --steps {cfg.steps}: this semi run never reaches its phase "
            f"on unlabelled images and trains on the labelled objects only (as --labeled-only); give --steps above "
            f"{cfg.pretrain_steps}")


def no_label_warning(cfg: RunConfig) -> str | None:
    """The warning ``fit`` prints for a ``semi`` run that never reads a label: no pretraining
    (``pretrain_steps`` 0) and no labelled share in its mixed batches (``semi_labeled_share`` 0).
    Its labelled objects (``labeled_objects.txt``) are then left out of training altogether and the
    pose head gets no target that pins the canonical frame; None for any other run."""
    if cfg.mode != "semi" or cfg.pretrain_steps or cfg.semi_labeled_share:
        return None
    return ("--pretrain-steps 0 with --semi-labeled-share 0: this semi run reads no label and never trains on its "
            "labelled objects (labeled_objects.txt), only on the unlabelled rest; give --pretrain-steps above 0 "
            "(the paper's fine-tuning on unlabelled images follows a supervised pretraining) or a labelled share")
