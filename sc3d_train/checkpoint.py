"""Checkpoints of ``sc3d-train fit``: what they hold, how they are written, and how a model
is rebuilt from one (for ``--resume``, ``eval`` and ``predict``).

A checkpoint (``torch.save`` dict) holds ``model`` (state dict of the unwrapped network),
``optimizer``, ``scaler`` (AMP GradScaler or None), ``rng`` (one entry per DDP rank: torch CPU,
CUDA, numpy and python states), ``step`` (optimiser steps done), ``config`` (the
:class:`~sc3d_train.config.RunConfig` dict, with the model config inside), ``data_position``
(phase, phase start and samples consumed by each rank in that phase) and ``format_version``.
Files are written under a temporary name and renamed, so ``step_XXXXXX.pt`` and ``last.pt``
are always complete.
"""
from __future__ import annotations

import os
import random
import shutil
from pathlib import Path

import numpy as np
import torch

from sc3d_train.config import RunConfig

FORMAT_VERSION = 1


class CheckpointError(ValueError):
    """A checkpoint that cannot be used (missing, corrupt, or from another configuration)."""


def checkpoint_dir(run_dir: Path) -> Path:
    return Path(run_dir) / "checkpoints"


def step_path(run_dir: Path, step: int) -> Path:
    return checkpoint_dir(run_dir) / f"step_{step:06d}.pt"


def last_path(run_dir: Path) -> Path:
    return checkpoint_dir(run_dir) / "last.pt"


def rng_state() -> dict:
    """This process's RNG states (torch CPU, CUDA when present, numpy, python)."""
    return {"torch": torch.get_rng_state(),
            "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None,
            "numpy": np.random.get_state(), "python": random.getstate()}


def set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    if state.get("cuda") is not None and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])


def save_checkpoint(run_dir: Path, payload: dict) -> Path:
    """Write ``payload`` as ``checkpoints/step_XXXXXX.pt`` and copy it to ``last.pt``
    (both atomically). Returns the step file."""
    path = step_path(run_dir, payload["step"])
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"format_version": FORMAT_VERSION, **payload}
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    os.replace(tmp, path)
    last = last_path(run_dir)
    tmp_last = last.with_name(last.name + ".tmp")
    shutil.copyfile(path, tmp_last)
    os.replace(tmp_last, last)
    return path


def load_checkpoint(path: Path, map_location="cpu") -> dict:
    """Read a checkpoint with a clear error for a missing or foreign file."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: checkpoint not found")
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=False)
    except Exception as e:  # noqa: BLE001 - any unpickling failure means "not ours"
        raise CheckpointError(f"{path}: not a readable checkpoint ({type(e).__name__}: {e})") from e
    if not isinstance(ckpt, dict) or "model" not in ckpt or "config" not in ckpt:
        raise CheckpointError(f"{path}: not an sc3d-train checkpoint (no model/config)")
    return ckpt


def build_model(run_config: RunConfig):
    """The network described by ``run_config.model`` (a ModelConfig dict)."""
    from sc3d_train.model import ModelConfig, SelfConsistencyNet

    return SelfConsistencyNet(ModelConfig.from_dict(run_config.model))


def state_dict_mismatch(expected: dict, found: dict) -> str:
    """A short description of how ``found`` differs from ``expected`` (empty when they match)."""
    missing = [k for k in expected if k not in found]
    unexpected = [k for k in found if k not in expected]
    shapes = [k for k in expected if k in found and tuple(expected[k].shape) != tuple(found[k].shape)]
    parts = []
    for label, keys in (("missing", missing), ("unexpected", unexpected), ("shape differs", shapes)):
        if keys:
            parts.append(f"{len(keys)} {label}, e.g. {keys[0]}")
    return "; ".join(parts)


def load_model(path: Path, device="cpu"):
    """``(model in eval mode on device, RunConfig, checkpoint dict)`` from a checkpoint file;
    a clear error when the weights do not fit the stored configuration."""
    ckpt = load_checkpoint(path)
    cfg = RunConfig.from_dict(ckpt["config"])
    model = build_model(cfg)
    problems = state_dict_mismatch(model.state_dict(), ckpt["model"])
    if problems:
        raise CheckpointError(f"{path}: weights do not match the model config stored in it "
                              f"({problems}; a different config or version of sc3d_train.model?)")
    model.load_state_dict(ckpt["model"])
    return model.to(device).eval(), cfg, ckpt
