"""A network rebuilt from a checkpoint of ``sc3d-train fit`` (``eval``, ``predict``, ``--resume``):
the model its config describes, compared with the weights the file holds before any memory is
spent on it (a crafted config could name a network of any size)."""
from __future__ import annotations

from pathlib import Path

import torch

from sc3d_train.loop.checkpoint import CheckpointError, checkpoint_config, load_checkpoint
from sc3d_train.settings.config import RunConfig


def network(run_config: RunConfig):
    """The network described by ``run_config.model`` (a :class:`~sc3d_train.settings.config.ModelConfig`),
    on the current default device (``torch.device("meta")``: shapes alone), unchecked."""
    from sc3d_train.paper.model import SelfConsistencyNet

    return SelfConsistencyNet(run_config.model)


def build_model(run_config: RunConfig):
    """:func:`network` of ``run_config``, measured first on the meta device: a width no memory holds
    (``model: {shape_dim: 100000000000}``, a typo's zeros) is refused in one line (``ValueError``)
    instead of torch's allocation error, a traceback."""
    from sc3d_train.loop.memory_check import available_bytes

    with torch.device("meta"):
        need = sum(p.numel() * p.element_size() for p in network(run_config).parameters())
    free = available_bytes()
    if free is not None and need > free:
        m = run_config.model
        raise ValueError(f"the model's weights alone need {need / 2**30:.1f} GiB, more than the {free / 2**30:.1f} "
                         f"GiB of memory available (model: base_channels {m.base_channels}, shape_dim {m.shape_dim}, "
                         f"pose_dim {m.pose_dim}, mask_size {m.mask_size}): use a smaller network")
    return network(run_config)


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
        problems = state_dict_mismatch(network(cfg).state_dict(), ckpt["model"])
    if problems:
        raise CheckpointError(f"{path}: weights do not match the model config stored in it "
                              f"({problems}; a different config or version of sc3d_train.paper.model?)")
    model = build_model(cfg)  # of the size of the weights the file holds
    model.load_state_dict(ckpt["model"])
    return model.to(device).eval(), cfg, ckpt
