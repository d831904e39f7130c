"""The paper's metrics of a network on a dataset (SPEC "Metrics"), shared by ``eval``
(:mod:`sc3d_train.evaluation.evaluate`) and the validation during ``fit``
(:mod:`sc3d_train.loop.validation`).

Per image: voxel IoU at :data:`VOXEL_THRESHOLDS` (0.4 as 3D-R2N2, 0.5 as PTN), mask IoU at
:data:`MASK_THRESHOLD`, the predicted and true azimuth/elevation and the rotation error
(:func:`sc3d_train.paper.pose.rotation_error_deg`, degrees); :func:`summarize` makes the
per-category, category-mean and pooled figures.

Why here and not in ``evaluation/``: validation runs inside the training loop, and the loop sits
below evaluation (``docs/ARCHITECTURE.md``), so what both measure lives in the lowest folder it
can: it needs only the network's output and the pose conventions of ``paper/``. The dataset is
taken as given (``num_views``, ``get_batch``, items): this module imports nothing of ``data/``.
"""
from __future__ import annotations

from collections import defaultdict

import numpy as np
import torch

from sc3d_train.paper.pose import pose_errors
from sc3d_train.settings.command_config import DEFAULT_POSE_SOURCE, check_pose_source
from sc3d_train.settings.config import LossWeights

VOXEL_THRESHOLDS = (0.4, 0.5)
MASK_THRESHOLD = 0.5


def iou(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-sample IoU of boolean tensors ``[B, ...]``; 1 where both are empty."""
    p, t = pred.flatten(1), target.flatten(1)
    inter = (p & t).sum(1).double()
    union = (p | t).sum(1).double()
    return torch.where(union > 0, inter / union.clamp(min=1), torch.ones_like(union))


@torch.no_grad()
def predict_dataset(model, dataset, device, batch_size: int = 64,
                    keep: int = 2, keep_views: tuple[int, ...] = (3, 15),
                    pose_from: str = DEFAULT_POSE_SOURCE, loss_weights=None, indices=None):
    """Run ``model`` over every view of ``dataset`` (a :class:`~sc3d_train.data.dataset.ShardDataset`)
    (or its items ``indices``, object * V + view, when given). Returns ``(rows, examples)``: one dict per
    image (category, model_id, view, iou_0.4, iou_0.5, mask_iou, azimuth/elevation predicted and
    true, rotation_error) and, for the first ``keep`` objects of every category, views
    ``keep_views`` (default 3 and 15: opposite sides) with input, masks, voxels and poses (numpy)
    for the figure. A row's ``finite`` is False where the image's predicted occupancy, mask or
    pose holds NaN or inf (a network that overflows on it; its IoU then counts as 0).

    ``pose_from`` (one of :data:`~sc3d_train.settings.command_config.POSE_SOURCES`): ``"search"``
    (the default of every entry point,
    :data:`~sc3d_train.settings.command_config.DEFAULT_POSE_SOURCE`) the test-time self-consistent
    pose, searched with ``loss_weights`` (None: the defaults of
    :class:`~sc3d_train.settings.config.LossWeights`); ``"head"`` the pose head alone (cheaper;
    voxel and mask IoU do not depend on it)."""
    from sc3d_data.geometry.camera import look_at_rotation
    from sc3d_train.paper.pose import rotation_error_deg
    from sc3d_train.paper.self_consistency import area_downsample

    check_pose_source(pose_from)
    kept_objects: dict[str, list[str]] = defaultdict(list)

    if indices is None:  # read in this process (no workers): a broken shard raises its one-line DataError
        loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, shuffle=False)
    else:
        loader = (dataset.get_batch(indices[i:i + batch_size]) for i in range(0, len(indices), batch_size))
    rows, examples = [], []
    for batch in loader:
        out = model(batch["images"].to(device))
        if pose_from == "search":  # test-time self-consistency (no label): pose_search.self_consistent_pose
            from sc3d_train.paper.pose_search import self_consistent_pose

            out.azimuth, out.elevation = self_consistent_pose(out, batch["K"].to(device).float(),
                                                              batch["distance"].to(device).float(),
                                                              model.pose_grid, loss_weights or LossWeights())
        probs = torch.sigmoid(out.voxel_logits.float()).cpu()
        gt = batch["voxels"] > 0.5
        mask_prob = torch.sigmoid(out.mask_logits.float()).cpu()
        gt_mask = batch["masks"]
        if gt_mask.shape[-1] != mask_prob.shape[-1]:
            gt_mask = area_downsample(gt_mask, mask_prob.shape[-1]) >= 0.5
        ious = {thr: iou(probs >= thr, gt) for thr in VOXEL_THRESHOLDS}
        mask_iou = iou(mask_prob >= MASK_THRESHOLD, gt_mask > 0.5)
        az, el = out.azimuth.float().cpu(), out.elevation.float().cpu()
        finite = (probs.flatten(1).isfinite().all(1) & mask_prob.flatten(1).isfinite().all(1)
                  & az.isfinite() & el.isfinite())
        rot_err = rotation_error_deg(look_at_rotation(az.double(), el.double()), batch["R"].double())
        for i in range(len(probs)):
            obj, view = divmod(int(batch["index"][i]), dataset.num_views)
            rows.append({"category": batch["category"][i], "model_id": batch["model_id"][i],
                         "view": view, **{f"iou_{thr}": float(ious[thr][i]) for thr in VOXEL_THRESHOLDS},
                         "mask_iou": float(mask_iou[i]),
                         "azimuth_pred": float(az[i]), "elevation_pred": float(el[i]),
                         "azimuth_true": float(batch["azimuth"][i]),
                         "elevation_true": float(batch["elevation"][i]),
                         "rotation_error": float(rot_err[i]), "finite": bool(finite[i])})
            category, model_id = batch["category"][i], batch["model_id"][i]
            chosen = kept_objects[category]
            if model_id not in chosen and len(chosen) < keep:
                chosen.append(model_id)
            if model_id in chosen and view in {v % dataset.num_views for v in keep_views}:
                examples.append({
                    "category": category, "model_id": model_id, "view": int(view),
                    "image": batch["images"][i].permute(1, 2, 0).numpy(),
                    "mask_true": gt_mask[i].numpy() > 0.5, "mask_pred": mask_prob[i].numpy(),
                    "voxels_true": gt[i].numpy(), "voxels_pred": probs[i].numpy(),
                    "K": batch["K"][i].numpy(), "distance": float(batch["distance"][i]),
                    "azimuth_true": float(batch["azimuth"][i]), "elevation_true": float(batch["elevation"][i]),
                    "azimuth_pred": float(az[i]), "elevation_pred": float(el[i]),
                    "rotation_error": float(rot_err[i]), "iou": float(ious[0.5][i])})
    return rows, examples


def summarize(rows: list[dict]) -> dict:
    """Per-category, category-mean and pooled metrics from :func:`predict_dataset` rows."""
    def block(rs: list[dict]) -> dict:
        out = {"images": len(rs), "objects": len({(r["category"], r["model_id"]) for r in rs})}
        for thr in VOXEL_THRESHOLDS:
            out[f"voxel_iou_{thr}"] = float(np.mean([r[f"iou_{thr}"] for r in rs]))
        out["mask_iou"] = float(np.mean([r["mask_iou"] for r in rs]))
        pe = pose_errors(torch.tensor([r["azimuth_pred"] for r in rs]), torch.tensor([r["elevation_pred"] for r in rs]),
                         torch.tensor([r["azimuth_true"] for r in rs]), torch.tensor([r["elevation_true"] for r in rs]),
                         rotation_error=[r["rotation_error"] for r in rs])
        pe.pop("count", None)
        out.update({f"pose_{k}": v for k, v in pe.items()})
        return out

    by_cat = defaultdict(list)
    for r in rows:
        by_cat[r["category"]].append(r)
    per_category = {c: block(rs) for c, rs in sorted(by_cat.items())}
    keys = [k for k in next(iter(per_category.values())) if k not in ("images", "objects")]
    mean = {k: float(np.mean([v[k] for v in per_category.values()])) for k in keys}
    return {"per_category": per_category, "mean": mean, "overall": block(rows)}
