"""One training step's batches and losses, per phase (see :mod:`sc3d_train.loop.trainer`).

The ground-truth pose (``azimuth``, ``elevation``, ``R``, ``t``) is removed from every training
batch before the model and the losses see it; in the unsupervised phase the voxels and masks
are removed too. The camera's intrinsics and distance (fixed by the dataset) stay."""
from __future__ import annotations

from contextlib import contextmanager

import torch

from sc3d_train.data.augment import augment_generator, augment_images, key_foreground
from sc3d_train.settings.config import LossWeights, RunConfig
from sc3d_train.data.batch_format import expand_batch
from sc3d_train.paper.losses import supervised_loss, true_pose_mask_loss, unsupervised_loss

#: batch keys that carry the ground-truth pose: never given to the model or a loss
POSE_KEYS = ("azimuth", "elevation", "R", "t")
#: batch keys that carry 3D/2D labels: removed in the unsupervised phase
LABEL_KEYS = ("voxels", "masks", "masks_sc")


def training_batch(batch: dict, phase: str, device: torch.device, channels_last: bool,
                   pose_targets: torch.Tensor | None = None) -> dict:
    """Move a loader batch (compact: ``sc3d_train.data.loader.make_loader``) to ``device`` and
    expand it there to the float training batch (``sc3d_train.data.batch_format.expand_batch``), dropping
    the ground-truth pose (and, unsupervised, the labels). ``pose_targets [num_objects * V]``
    (searched from voxels and masks; best kept on ``device``: then no host copy) adds
    ``pose_target [B]`` for labelled batches."""
    drop = POSE_KEYS + (LABEL_KEYS if phase == "unsupervised" else ())
    if phase == "true-pose-masks":  # the ablation: masks and the true pose, no 3D labels
        drop = ("R", "t", "voxels")
    out = expand_batch({k: v for k, v in batch.items() if k not in drop}, device, non_blocking=True)
    if pose_targets is not None and phase == "supervised" and "index" in batch:
        out["pose_target"] = pose_targets[out["index"].to(pose_targets.device)]
    if channels_last:
        out["images"] = out["images"].contiguous(memory_format=torch.channels_last)
    return out


def augment_step(batches: dict, cfg: RunConfig, step: int, rank: int = 0) -> dict:
    """The device batches of optimiser step ``step`` (``{"supervised": ..., "unsupervised": ...}``,
    one or both) with their ``images`` augmented (``sc3d_train.data.augment``) when ``cfg.augment``;
    nothing else of a batch changes. The object's pixels are the stored ``masks`` where the batch
    holds them (labelled images) and, in an unlabelled batch (its masks are labels it may not
    read), the pixels whose colour differs from the shards' background ``cfg.background``. The
    draws depend on (seed, step, rank, phase) only. Without ``cfg.augment``: ``batches``."""
    if not cfg.augment:
        return batches
    out = {}
    for slot, (phase, batch) in enumerate(sorted(batches.items())):
        images = batch["images"]
        fg = batch["masks"] if "masks" in batch else key_foreground(images, cfg.background)
        g = augment_generator(cfg.seed, step, rank, slot, images.device)
        out[phase] = {**batch, "images": augment_images(images, fg, g)}
    return out


@contextmanager
def frozen_batchnorm_statistics(model: torch.nn.Module):
    """Inside: BatchNorm layers still normalise with the batch's statistics (train mode) but do
    not update their running statistics (momentum 0)."""
    layers = [m for m in model.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
    saved = [(m.momentum, m.num_batches_tracked.clone()) for m in layers]
    for m in layers:
        m.momentum = 0.0
    try:
        yield
    finally:
        for m, (momentum, tracked) in zip(layers, saved):
            m.momentum = momentum
            m.num_batches_tracked.copy_(tracked)


def step_losses(batches: dict, model: torch.nn.Module, train_model: torch.nn.Module, mode: str,
                weights: LossWeights, grid) -> dict:
    """The losses of one step (scalar tensors; ``total`` is optimised). ``batches``: the phase's
    device batches, ``{"supervised": ...}``, ``{"unsupervised": ...}`` or both (the mixed phase
    of ``semi``); ``train_model`` is ``model`` or its DDP wrapper. Unlabelled terms are logged
    with the prefix ``u_``. A batch's ``noise [B, shape_dim]``, when present, is the network's
    reparameterisation draw (``sc3d_train.loop.train_step.draw_noise``).

    Under DDP the mixed phase's unlabelled pass runs on ``model``, not on its wrapper, and its
    gradient is still averaged over the ranks: both passes use the same parameters, and the one
    ``backward`` of their summed ``total`` sums both passes' contributions into each parameter's
    gradient accumulator, which runs once; DDP all-reduces the gradient in a hook after that
    accumulator, i.e. the whole gradient. This needs every parameter the unlabelled pass trains
    to be used by the labelled pass too (it is: that pass runs the whole network). Every
    checkpoint checks that the ranks hold the same weights
    (:func:`~sc3d_train.loop.runtime.check_same_weights`; measured, 2 gloo ranks: equal as is, and
    both passes on ``model`` diverge at the first checkpoint)."""
    if len(batches) == 2:
        # two passes, so that BatchNorm never normalises labelled images with statistics of
        # unlabelled ones; the unlabelled pass leaves the running statistics alone (eval
        # normalises as the labelled training did). Measured: one pass over the concatenated
        # batch let held-out mask IoU fall from 0.85 to 0.20 even with every unlabelled loss
        # weight at 0 (docs/training.md).
        sup, uns = batches["supervised"], batches["unsupervised"]
        ls = supervised_loss(train_model(sup["images"], sup.get("noise")), sup, weights, grid)
        with frozen_batchnorm_statistics(model):
            lu = unsupervised_loss(model(uns["images"], uns.get("noise")), uns, weights, grid)
        losses = {**ls, **{f"u_{k}": v for k, v in lu.items()}}
        losses["total"] = ls["total"] + lu["total"]
        return losses
    if "unsupervised" in batches:  # the mask is no target here: outside the graph, or DDP waits for its gradients
        out = train_model(batches["unsupervised"]["images"], batches["unsupervised"].get("noise"), mask_grad=False)
        losses = {f"u_{k}": v for k, v in
                  unsupervised_loss(out, batches["unsupervised"], weights, grid).items()}
        losses["total"] = losses.pop("u_total")
        return losses
    out = train_model(batches["supervised"]["images"], batches["supervised"].get("noise"))
    loss_fn = true_pose_mask_loss if mode == "true-pose-masks" else supervised_loss
    return loss_fn(out, batches["supervised"], weights, grid)


def backward(loss: torch.Tensor, scaler) -> None:
    """Gradients of ``loss`` (scaled by the AMP GradScaler when there is one)."""
    (loss if scaler is None else scaler.scale(loss)).backward()


def optimizer_step(optimizer: torch.optim.Optimizer, scaler) -> None:
    """The Adam step (through the AMP GradScaler when there is one)."""
    if scaler is not None:
        scaler.step(optimizer)
        scaler.update()
    else:
        optimizer.step()
