"""A network rebuilt from a checkpoint of ``sc3d-train fit`` (``eval``, ``predict``, ``--resume``):
the model its config describes, compared with the weights the file holds before any memory is
spent on it (a crafted config could name a network of any size)."""
from __future__ import annotations

from pathlib import Path

import torch

from sc3d_train.loop.checkpoint import CheckpointError, checkpoint_config, load_checkpoint
from sc3d_train.settings.config import RunConfig


def build_model(run_config: RunConfig):
    """The network described by ``run_config.model`` (a :class:`~sc3d_train.settings.config.ModelConfig`)."""
    from sc3d_train.paper.model import SelfConsistencyNet

    return SelfConsistencyNet(run_config.model)


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
    cfg = checkpoint_config(path, ckpt)
    with torch.device("meta"):  # shapes alone: a config naming a huge network allocates nothing
        problems = state_dict_mismatch(build_model(cfg).state_dict(), ckpt["model"])
    if problems:
        raise CheckpointError(f"{path}: weights do not match the model config stored in it "
                              f"({problems}; a different config or version of sc3d_train.paper.model?)")
    model = build_model(cfg)  # of the size of the weights the file holds
    model.load_state_dict(ckpt["model"])
    return model.to(device).eval(), cfg, ckpt
