"""Camera-pose parameterisation of the pose head and wrapped angle errors.

The pose head classifies the camera over a fixed grid of candidate poses (:class:`PoseGrid`):
``azimuth_bins`` A azimuths every ``360 / A`` degrees from 0, and ``elevation_bins`` E elevations
evenly spaced over ``[elevation_min, elevation_max]``. It outputs ``pose_logits [B, A + E]``: the
first A are azimuth logits, the last E elevation logits (two factorised distributions). Why a
classifier and not one regressed angle: the self-consistency loss over azimuth has a narrow basin
and near-symmetric secondary minima, so the pose is learnt from the best candidate of a search of
that loss over the grid (:mod:`sc3d_train.paper.pose_search`, docs/training.md), which a
classifier can represent (including its ambiguity between candidates) and a single angle cannot.

The continuous pose (:func:`pose_from_logits`) is differentiable:

- azimuth: the argmax bin ``k`` refined by a soft-argmax over bins ``k - 1, k, k + 1`` (circular,
  so 345 deg and 0 deg are neighbours; no wrap boundary), in [0, 360);
- elevation: the expectation of the elevation softmax, within ``[elevation_min, elevation_max]``
  (bounded: the camera never reaches the poles).

Angles are degrees and follow ``sc3d_data.geometry.camera`` (azimuth 0 = camera on +Z, counter-clockwise
seen from +Y; elevation > 0 above the object).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from sc3d_train.settings.config import ModelConfig, check_pose_grid


@dataclass(frozen=True)
class PoseGrid:
    """The candidate poses of the pose head and of the pose search (degrees):
    ``azimuth_bins`` A from 0 deg, ``elevation_bins`` E over ``[elevation_min, elevation_max]``.
    Candidate ``p = a * E + e`` (azimuth-major)."""

    azimuth_bins: int = 24
    elevation_bins: int = 5
    elevation_min: float = 10.0
    elevation_max: float = 50.0

    def __post_init__(self):
        check_pose_grid(self.azimuth_bins, self.elevation_bins, self.elevation_min, self.elevation_max)

    @classmethod
    def of(cls, model: ModelConfig) -> "PoseGrid":
        """The grid of a network's settings (``azimuth_bins``, ``elevation_bins``,
        ``elevation_min``, ``elevation_max`` of :class:`~sc3d_train.settings.config.ModelConfig`)."""
        return cls(model.azimuth_bins, model.elevation_bins, model.elevation_min, model.elevation_max)

    def to_dict(self) -> dict:
        return asdict(self)

    def outside(self, elevations) -> list[float]:
        """The distinct ``elevations`` (degrees, e.g. a dataset's ``settings.elevations``) outside
        ``[elevation_min, elevation_max]``, sorted: views the pose head cannot predict (its
        elevation is a softmax expectation over the grid) and whose pose targets are the best-fitting
        grid poses."""
        return sorted({float(e) for e in elevations or [] if not self.elevation_min <= e <= self.elevation_max})

    def azimuth_floor(self, azimuths) -> float:
        """The mean angle (degrees) from ``azimuths`` (the true azimuths of evaluated views) to the
        nearest grid azimuth: 0 where every view lies on the grid (``render``'s default 24 views);
        else the least mean azimuth error of poses on the grid, which the self-consistent pose is and
        the head's targets are (``render --views 7``: 3.7 deg)."""
        off = [abs(a / self.azimuth_step - round(a / self.azimuth_step)) * self.azimuth_step for a in azimuths]
        return float(sum(off) / len(off)) if off else 0.0

    @property
    def size(self) -> int:
        """P = A * E candidates."""
        return self.azimuth_bins * self.elevation_bins

    @property
    def num_logits(self) -> int:
        """A + E outputs of the pose head."""
        return self.azimuth_bins + self.elevation_bins

    @property
    def azimuth_step(self) -> float:
        return 360.0 / self.azimuth_bins

    # ``device``: where to build the tensor (default CPU); made there, not copied from the host,
    # so a training step on CUDA neither waits for a copy nor puts a CPU op in its graph

    def azimuths(self, device=None) -> Tensor:
        """``[A]`` degrees: ``0, 360/A, ...`` (float64)."""
        return torch.arange(self.azimuth_bins, dtype=torch.float64, device=device) * self.azimuth_step

    def elevations(self, device=None) -> Tensor:
        """``[E]`` degrees, evenly spaced over ``[elevation_min, elevation_max]`` (float64)."""
        if self.elevation_bins == 1:
            return torch.full((1,), (self.elevation_min + self.elevation_max) / 2, dtype=torch.float64,
                              device=device)
        return torch.linspace(self.elevation_min, self.elevation_max, self.elevation_bins, dtype=torch.float64,
                              device=device)

    def candidates(self, device=None) -> tuple[Tensor, Tensor]:
        """``(azimuth [P], elevation [P])`` degrees of every candidate, azimuth-major."""
        az, el = torch.meshgrid(self.azimuths(device), self.elevations(device), indexing="ij")
        return az.reshape(-1), el.reshape(-1)

    def split(self, index: Tensor) -> tuple[Tensor, Tensor]:
        """Candidate index ``[...]`` -> ``(azimuth bin, elevation bin)``."""
        return torch.div(index, self.elevation_bins, rounding_mode="floor"), index % self.elevation_bins


def pose_from_logits(pose_logits: Tensor, grid: PoseGrid) -> tuple[Tensor, Tensor]:
    """``pose_logits [B, A + E]`` -> ``(azimuth [B] deg in [0, 360), elevation [B] deg)`` (see the
    module doc). Differentiable in the logits (the argmax bin itself is not)."""
    a = grid.azimuth_bins
    if pose_logits.shape[-1] != grid.num_logits:
        raise ValueError(f"pose_logits must end with {grid.num_logits} values (grid {grid}), "
                         f"got shape {tuple(pose_logits.shape)}")
    az_logits, el_logits = pose_logits[..., :a].float(), pose_logits[..., a:].float()
    k = az_logits.argmax(-1, keepdim=True)
    window = torch.cat([(k - 1) % a, k, (k + 1) % a], -1)  # [B, 3]
    w = torch.softmax(torch.gather(az_logits, -1, window), -1)
    offset = (w[..., 2] - w[..., 0]) * grid.azimuth_step
    azimuth = torch.remainder(k[..., 0].to(offset.dtype) * grid.azimuth_step + offset, 360.0)
    elevation = (torch.softmax(el_logits, -1) * grid.elevations(el_logits.device).to(el_logits.dtype)).sum(-1)
    return azimuth, elevation


def pose_classification_loss(pose_logits: Tensor, target: Tensor, grid: PoseGrid,
                             elevation: bool = True) -> Tensor:
    """Cross-entropy of the azimuth and elevation logits against candidate indices ``target [B]``
    (long, ``a * E + e``), summed over the two factors (``elevation=False``: the azimuth term only)
    and averaged over the batch. Samples with a negative target are ignored (no candidate); with
    none left the loss is 0 (gradient 0). Branch-free: no host sync, one graph under
    ``torch.compile`` (a ``mean`` over the kept samples, not ``ignore_index``, whose mean over
    zero samples is NaN)."""
    keep = target >= 0
    ta, te = grid.split(target.long().clamp_min(0))
    a = grid.azimuth_bins
    per_sample = F.cross_entropy(pose_logits[..., :a].float(), ta, reduction="none")
    if elevation:
        per_sample = per_sample + F.cross_entropy(pose_logits[..., a:].float(), te, reduction="none")
    kept = keep.to(per_sample.dtype)
    return (per_sample * kept).sum() / kept.sum().clamp_min(1.0)


def wrap_degrees(angle_deg):
    """Wrap angles (tensor, numpy array or float) to [-180, 180)."""
    return (angle_deg + 180.0) % 360.0 - 180.0


def angular_error_deg(pred_deg, true_deg):
    """Absolute wrapped difference in degrees, in [0, 180]: 359 vs 1 -> 2."""
    return abs(wrap_degrees(pred_deg - true_deg))


def rotation_error_deg(R_pred, R_true):
    """Geodesic angle (degrees, in [0, 180]) between camera rotations ``[..., 3, 3]``:
    ``arccos((trace(R_pred^T R_true) - 1) / 2)``, the angle of the rotation that takes one camera
    to the other (MVC's metric). Numpy or torch in, numpy float64 out."""
    import numpy as np

    a, b = np.asarray(R_pred, dtype=np.float64), np.asarray(R_true, dtype=np.float64)
    cos = (np.einsum("...ij,...ij->...", a, b) - 1.0) / 2.0  # trace(a^T b) = sum a*b
    return np.rad2deg(np.arccos(np.clip(cos, -1.0, 1.0)))


def pose_errors(pred_azimuth, pred_elevation, true_azimuth, true_elevation,
                threshold_deg: float = 30.0, rotation_error=None) -> dict[str, float]:
    """Pose-error summary (SPEC "Metrics") over 1-D arrays/tensors of degrees.

    Returns ``azimuth_mean``, ``azimuth_median``, ``azimuth_acc30`` (fraction within
    ``threshold_deg``), the same for ``elevation_*``, ``azimuth_flip_acc30`` (a diagnostic: the
    fraction within ``threshold_deg`` of the true azimuth *or* of the true azimuth + 180, i.e.
    right up to the front/back ambiguity of many silhouettes at 30 deg elevation) and ``count``;
    with ``rotation_error`` (degrees, :func:`rotation_error_deg`) also ``rotation_median``,
    ``rotation_mean``, ``rotation_acc15`` and ``rotation_acc30``."""
    out: dict[str, float] = {}
    if rotation_error is not None:
        err = torch.as_tensor(rotation_error, dtype=torch.float64).reshape(-1)
        empty = err.numel() == 0
        out["rotation_median"] = math.nan if empty else float(err.quantile(0.5))
        out["rotation_mean"] = math.nan if empty else float(err.mean())
        out["rotation_acc15"] = math.nan if empty else float((err <= 15.0).double().mean())
        out["rotation_acc30"] = math.nan if empty else float((err <= 30.0).double().mean())
    for name, p, t in (("azimuth", pred_azimuth, true_azimuth), ("elevation", pred_elevation, true_elevation)):
        err = torch.as_tensor(angular_error_deg(torch.as_tensor(p, dtype=torch.float64),
                                                torch.as_tensor(t, dtype=torch.float64)))
        if err.numel() == 0:
            out.update({f"{name}_mean": math.nan, f"{name}_median": math.nan, f"{name}_acc30": math.nan})
            if name == "azimuth":
                out["azimuth_flip_acc30"] = math.nan
            continue
        out[f"{name}_mean"] = float(err.mean())
        out[f"{name}_median"] = float(err.quantile(0.5))
        out[f"{name}_acc30"] = float((err <= threshold_deg).double().mean())
        if name == "azimuth":
            flip_ok = (err <= threshold_deg) | (err >= 180.0 - threshold_deg)
            out["azimuth_flip_acc30"] = float(flip_ok.double().mean())
    out["count"] = int(torch.as_tensor(pred_azimuth).numel())
    return out
