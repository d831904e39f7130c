"""Training losses of the paper (SPEC "Training defaults").

- ``L_3D = L_PCE + L_IoU``: binary cross-entropy with positive weight 3 (mean over voxels and
  batch) plus the IoU loss ``exp(1 - IoU_soft) - 1`` (per object, mean over the batch; the IoU form
  ``sum(p y) / sum(p + y - p y)`` — the paper's ``+ p y`` in the denominator is a typo).
- ``L_2D``: binary cross-entropy of the predicted mask logits ``[B, S, S]`` (image size) vs the
  ground-truth mask (mean over pixels and batch).
- ``L_KL = KL(N(mu, sigma^2) || N(0, 1))`` of the shape code, *averaged* over batch and code
  dimensions (the paper does not say; a per-dimension mean keeps the 0.02 weight on the same
  scale as the per-voxel/per-pixel means of the other terms, whatever ``shape_dim`` is).
- ``L_sc = 5 L_ray + 0.125 L_proj`` (:mod:`sc3d_train.paper.self_consistency`), always with the
  *predicted* pose; the ground-truth pose in the batch is never read here.

- ``L_pose``: cross-entropy of the pose head's azimuth and elevation logits against the candidate
  pose whose L_sc is lowest in a search over the pose grid (:mod:`sc3d_train.paper.pose_search`): the
  paper's objective minimised over the candidates instead of descended from the current guess.
  ``batch["pose_target"]`` holds that candidate (computed from the voxels and masks, never from a
  pose label).

Supervised: ``0.5 L_3D + 0.5 L_2D + 1 L_sc + 0.02 L_KL + 1 L_pose`` with L_sc on the ground-truth
voxels and 48x48 masks (``batch["voxels"]``, ``batch["masks_sc"]``): only the pose head and
encoder get gradients from it; the pose target is the search over the ground-truth voxels and
masks. Semi-supervised fine-tuning (unlabelled images): ``1 L_sc + 0.02 L_KL`` with L_sc
on the predicted occupancy ``sigmoid(voxel_logits)`` and the predicted mask ``sigmoid(mask_logits)``
area-downsampled to 48x48 and *detached*: as in the paper, L_sc updates the encoder and the voxel
decoder, not the mask decoder; plus ``wpose_unlabeled L_pose`` (azimuth term) with the target
searched between the (detached) predicted occupancy and mask over the azimuths at the elevation
the pose head predicts.
"""
from __future__ import annotations

from dataclasses import replace

import torch
import torch.nn.functional as F
from torch import Tensor

from sc3d_train.settings.config import MASK_SIZE, LossWeights
from .model import ModelOutput
from .pose import pose_classification_loss
from .self_consistency import area_downsample, iou_loss, self_consistency_losses

LOSS_KEYS = ("total", "l3d", "l2d", "lsc", "ray", "proj", "kl", "pose")


def voxel_loss(voxel_logits: Tensor, voxels: Tensor, pos_weight: float = 3.0) -> Tensor:
    """L_3D of ``voxel_logits [B, G, G, G]`` vs ``voxels [B, G, G, G]`` in {0, 1}."""
    logits = voxel_logits.float()
    target = voxels.float()
    pw = torch.full((), pos_weight, dtype=logits.dtype, device=logits.device)  # made on the device: no host copy
    pce = F.binary_cross_entropy_with_logits(logits, target, pos_weight=pw)
    return pce + iou_loss(torch.sigmoid(logits), target)


def mask_loss(mask_logits: Tensor, masks: Tensor) -> Tensor:
    """L_2D: BCE of ``mask_logits [B, S, S]`` vs ``masks [B, S, S]`` in [0, 1]."""
    if mask_logits.shape != masks.shape:
        raise ValueError(f"mask logits {tuple(mask_logits.shape)} and masks {tuple(masks.shape)} differ")
    return F.binary_cross_entropy_with_logits(mask_logits.float(), masks.float())


def kl_loss(z_mean: Tensor, z_logvar: Tensor) -> Tensor:
    """KL(N(mean, exp(logvar)) || N(0, 1)), mean over batch and dimensions."""
    m, lv = z_mean.float(), z_logvar.float()
    return (0.5 * (m.pow(2) + lv.exp() - 1.0 - lv)).mean()


def _sc(out: ModelOutput, occupancy: Tensor, masks_sc: Tensor, batch: dict, weights: LossWeights) -> dict[str, Tensor]:
    sc = self_consistency_losses(occupancy, masks_sc, out.azimuth, out.elevation, batch["distance"],
                                 batch["K_sc"], weights.num_samples)
    return {"lsc": weights.ray * sc["ray"] + weights.proj * sc["proj"], "ray": sc["ray"], "proj": sc["proj"]}


def search_target(occupancy: Tensor, masks: Tensor, batch: dict, grid, weights: LossWeights) -> Tensor:
    """The candidate pose (index ``[B]``, long) of ``grid`` with the lowest L_sc between
    ``occupancy [B, G, G, G]`` and ``masks [B, S, S]`` (camera ``batch["K_sc"]`` at S), over all
    candidates."""
    from .pose_search import search_losses

    losses = search_losses(occupancy, masks, batch["distance"], batch["K_sc"], grid, weights.ray,
                           weights.proj, weights.search_mask_size, weights.search_samples)
    return losses.argmin(1)


def supervised_loss(out: ModelOutput, batch: dict, weights: LossWeights | None = None,
                    grid=None) -> dict[str, Tensor]:
    """Supervised objective; ``batch`` needs ``voxels [B,G,G,G]``, ``masks [B,S,S]`` (image size),
    ``masks_sc [B,48,48]``, ``K_sc [B,3,3]``, ``distance [B]`` and, with a pose ``grid``
    (:class:`~sc3d_train.paper.pose.PoseGrid`), ``pose_target [B]`` (searched when absent). Returns
    scalars ``LOSS_KEYS``."""
    w = weights or LossWeights()
    l3d = voxel_loss(out.voxel_logits, batch["voxels"], w.pos_weight)
    l2d = mask_loss(out.mask_logits, batch["masks"])
    kl = kl_loss(out.z_mean, out.z_logvar)
    sc = _sc(out, batch["voxels"].float(), batch["masks_sc"], batch, w)
    pose = torch.zeros((), device=kl.device)
    if grid is not None and w.wpose:
        target = batch.get("pose_target")
        if target is None:
            target = search_target(batch["voxels"].float(), batch["masks_sc"], batch, grid, w)
        pose = pose_classification_loss(out.pose_logits, target, grid)
    total = w.w3d * l3d + w.w2d * l2d + w.wsc * sc["lsc"] + w.wkl * kl + w.wpose * pose
    return {"total": total, "l3d": l3d, "l2d": l2d, "kl": kl, "pose": pose, **sc}


def unsupervised_loss(out: ModelOutput, batch: dict, weights: LossWeights | None = None,
                      grid=None) -> dict[str, Tensor]:
    """Objective on unlabelled images: ``wsc_unlabeled L_sc + wkl_unlabeled L_KL +
    wpose_unlabeled L_pose`` with the predicted occupancy and the (detached) predicted mask at the
    size of ``batch["masks_sc"]`` or, without it, of ``K_sc`` for 48-pixel masks. With a pose
    ``grid``, the azimuth is searched first (the lowest L_sc between the detached predicted
    occupancy and mask, at the elevation bin the head predicts); L_pose pulls the head's azimuth
    towards it and, when ``unlabeled_sc_at_search`` is set, L_sc is taken at that searched pose
    (detached) rather than at the head's pose, so the voxels are fitted to the mask from the
    viewpoint that explains it best. With ``unlabeled_pose_gate`` N >= 0 the searched azimuth counts
    only where it is within N azimuth bins of the head's top one (a confidence gate: a head that
    learnt pose from labels is not pulled to a worse search); elsewhere no L_pose and L_sc at the
    head's pose. ``batch`` needs ``K_sc``, ``distance``. Returns
    ``LOSS_KEYS`` without ``l3d`` and ``l2d`` (no labels)."""
    w = weights or LossWeights()
    size = batch["masks_sc"].shape[-1] if "masks_sc" in batch else MASK_SIZE
    occupancy = torch.sigmoid(out.voxel_logits.float())
    masks_pred = area_downsample(torch.sigmoid(out.mask_logits.float()).detach(), size)
    kl = kl_loss(out.z_mean, out.z_logvar)
    pose = torch.zeros((), device=kl.device)
    at = out
    if grid is not None and (w.wpose_unlabeled or w.unlabeled_sc_at_search):
        from .pose_search import search_at_head_elevation

        target = search_at_head_elevation(occupancy, masks_pred, batch["distance"], batch["K_sc"],
                                          out.pose_logits, grid, w)
        trusted = torch.ones_like(target, dtype=torch.bool)
        if w.unlabeled_pose_gate >= 0:  # pseudo-label only where the search agrees with the head
            a = grid.azimuth_bins
            gap = (grid.split(target)[0] - out.pose_logits[:, :a].detach().argmax(1)) % a
            trusted = torch.minimum(gap, a - gap) <= w.unlabeled_pose_gate
        pose = pose_classification_loss(out.pose_logits, target.masked_fill(~trusted, -1), grid, elevation=False)
        if w.unlabeled_sc_at_search:
            cand_az, _ = grid.candidates(target.device)
            searched = cand_az.to(torch.float32)[target]
            at = replace(out, azimuth=torch.where(trusted, searched, out.azimuth.detach().float()),
                         elevation=out.elevation.detach())
    sc = _sc(at, occupancy, masks_pred, batch, w)
    total = w.wsc_unlabeled * sc["lsc"] + w.wkl_unlabeled * kl + w.wpose_unlabeled * pose
    return {"total": total, "kl": kl, "pose": pose, **sc}


def true_pose_mask_loss(out: ModelOutput, batch: dict, weights: LossWeights | None = None,
                        grid=None) -> dict[str, Tensor]:
    """The paper's self-consistency ablation (DRC's setting): voxels learnt from masks alone, with
    the TRUE camera pose (``batch["azimuth"]``, ``batch["elevation"]``; the only loss that reads
    a pose label, used by ``sc3d-train claims`` only): ``wsc (ray L_ray + proj L_proj) + wkl L_KL``
    on ``sigmoid(voxel_logits)`` against ``batch["masks_sc"]``. Set ``proj = 0`` for "Ray"."""
    w = weights or LossWeights()
    at_true_pose = replace(out, azimuth=batch["azimuth"].float(), elevation=batch["elevation"].float())
    sc = _sc(at_true_pose, torch.sigmoid(out.voxel_logits.float()), batch["masks_sc"], batch, w)
    kl = kl_loss(out.z_mean, out.z_logvar)
    return {"total": w.wsc * sc["lsc"] + w.wkl * kl, "kl": kl, **sc}
