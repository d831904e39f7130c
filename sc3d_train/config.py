"""The run configuration of ``sc3d-train fit``: one dataclass, fully resolved, saved as
``RUN_DIR/config.json`` and inside every checkpoint.

Everything a run depends on is a field here (the model's own config is the nested
``model`` dict of :class:`sc3d_train.model.ModelConfig`, the loss weights the nested
``loss_weights`` dict of :class:`sc3d_train.losses.LossWeights`), so a run can be reproduced
or resumed from this file alone.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path


def dataclass_from_dict(cls, d: dict):
    """``cls(**d)`` for a config dataclass, refusing keys it does not have (a checkpoint or
    config.json from another version) with the unknown and known names in the message."""
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(d) - known)
    if unknown:
        raise ValueError(f"unknown {cls.__name__} keys {unknown}; known: {sorted(known)}")
    return cls(**d)

#: fields that ``--resume`` may change (they do not alter the optimisation trajectory up to the
#: checkpoint); every other field must match the checkpoint's config.
RESUMABLE_FIELDS = ("steps", "checkpoint_every", "workers", "log_every", "device", "progress", "out")

#: ModelConfig overrides of ``--tiny``: a small network for demos and tests on a CPU.
TINY_MODEL = {"base_channels": 8, "shape_dim": 32, "pose_dim": 8}


#: training modes: the paper's three, and ``true-pose-masks``, the self-consistency ablation
#: (voxels from masks at the true pose; the only mode that reads pose labels; used by ``claims``)
MODES = ("supervised", "semi", "labeled-only", "true-pose-masks")


@dataclass
class RunConfig:
    """Resolved settings of one training run.

    ``steps`` counts optimiser steps over all phases. In semi-supervised mode the first
    ``pretrain_steps`` steps train on the labelled subset (supervised loss, ``lr``); the rest
    train on mixed batches at ``semi_lr`` (``None``: ``lr``): a share ``semi_labeled_share`` of
    each batch are labelled images (supervised loss: keeps the canonical frame and what the
    labelled phase learnt), the others unlabelled images (self-consistency + KL + pose search on
    the predictions). ``semi_labeled_share = 0`` is the paper's pure unlabelled fine-tuning.
    ``batch_size`` is the global batch (split evenly over DDP ranks).
    """

    shards: str
    out: str
    steps: int = 2000
    batch_size: int = 48
    lr: float = 1e-3
    semi_lr: float | None = None
    semi_labeled_share: float = 0.5
    lr_schedule: str = "cosine"        # cosine (per phase, down to lr_min_ratio * lr) | constant
    lr_min_ratio: float = 0.1
    mode: str = "supervised"           # see MODES
    labeled_fraction: float = 0.15
    pretrain_steps: int | None = None  # semi mode only; default steps // 2
    split: str = "train"
    seed: int = 0
    checkpoint_every: int = 500
    log_every: int = 10
    workers: int = 0
    device: str = "auto"               # auto | cpu | cuda | cuda:N
    amp: str = "auto"                  # auto (bf16/fp16 on CUDA, off on CPU) | off | bf16 | fp16
    channels_last: str = "auto"        # auto (on for CUDA) | on | off
    progress: bool = True
    model: dict = field(default_factory=dict)
    loss_weights: dict = field(default_factory=dict)
    # dataset facts copied from the shards (checked against the data at resume / eval time)
    image_size: int = 64
    num_views: int = 24
    background: list = field(default_factory=lambda: [255, 255, 255])
    intrinsics: list | None = None     # K [3][3] in pixels at image_size
    camera_distance: float = 2.0       # world units

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if self.steps < 1 or self.batch_size < 1:
            raise ValueError("steps and batch size must be positive")
        if not 0.0 < self.labeled_fraction <= 1.0:
            raise ValueError(f"labeled fraction must be in (0, 1], got {self.labeled_fraction}")
        if self.lr_schedule not in ("cosine", "constant"):
            raise ValueError(f"lr schedule must be cosine or constant, got {self.lr_schedule!r}")
        if not 0.0 <= self.semi_labeled_share < 1.0:
            raise ValueError(f"semi labelled share must be in [0, 1), got {self.semi_labeled_share}")
        if self.mode == "semi":
            if self.pretrain_steps is None:
                self.pretrain_steps = self.steps // 2
            if not 0 <= self.pretrain_steps <= self.steps:
                raise ValueError(f"pretrain steps {self.pretrain_steps} not in [0, steps={self.steps}]")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "RunConfig":
        return dataclass_from_dict(cls, d)

    def save(self, path: Path) -> None:
        from sc3d_data.io.shards import write_json_atomic

        write_json_atomic(Path(path), self.to_dict())

    @classmethod
    def load(cls, path: Path) -> "RunConfig":
        return cls.from_dict(json.loads(Path(path).read_text()))

    def phase_at(self, step: int) -> str:
        """``"supervised"`` or ``"unsupervised"``: the loss used at optimiser step ``step``."""
        if self.mode == "semi" and step >= self.pretrain_steps:
            return "unsupervised"
        return "supervised"

    def phase_start(self, step: int) -> int:
        """The first step of the phase that ``step`` belongs to."""
        return self.pretrain_steps if self.phase_at(step) == "unsupervised" else 0

    def lr_at(self, step: int) -> float:
        """The learning rate at ``step``: ``lr`` (``semi_lr`` in the unsupervised phase when set),
        constant or, with ``lr_schedule="cosine"``, annealed over the phase from that value to
        ``lr_min_ratio`` times it."""
        base = self.lr
        if self.phase_at(step) == "unsupervised" and self.semi_lr is not None:
            base = self.semi_lr
        if self.lr_schedule != "cosine":
            return base
        import math

        start = self.phase_start(step)
        end = self.pretrain_steps if self.mode == "semi" and step < self.pretrain_steps else self.steps
        t = (step - start) / max(end - start, 1)
        return base * (self.lr_min_ratio + (1 - self.lr_min_ratio) * 0.5 * (1 + math.cos(math.pi * t)))

    def batch_split(self, local_batch: int) -> tuple[int, int]:
        """``(labelled, unlabelled)`` samples per rank of an unsupervised-phase batch."""
        labeled = int(round(local_batch * self.semi_labeled_share))
        if self.semi_labeled_share > 0:
            labeled = min(max(labeled, 1), local_batch - 1)
        return labeled, local_batch - labeled

    def differences(self, other: "RunConfig", ignore=RESUMABLE_FIELDS) -> list[str]:
        """Names and values of the fields that differ, other than ``ignore``."""
        a, b = self.to_dict(), other.to_dict()
        return [f"{k}: {a[k]!r} != {b[k]!r}" for k in a if k not in ignore and a[k] != b[k]]
