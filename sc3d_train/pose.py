"""Camera-pose parameterisation of the pose head and wrapped angle errors.

The pose head (one FC layer on the pose code z_p) outputs ``pose_raw [B, 3]``:

- ``pose_raw[:, 0:2]`` = an unnormalised ``(cos az, sin az)`` vector; the azimuth is its angle,
  ``atan2(sin, cos)`` in degrees mapped to [0, 360). The 0/360 wrap is therefore no boundary at
  all: 359 deg and 1 deg are neighbouring directions of the 2-vector.
- ``pose_raw[:, 2]`` = ``e``; the elevation is ``90 * tanh(e)`` degrees, bounded to (-90, 90)
  (elevation does not wrap; the bound keeps the camera off the poles where azimuth is undefined).

Angles are degrees and follow ``sc3d_data.camera`` (azimuth 0 = camera on +Z, counter-clockwise
seen from +Y; elevation > 0 above the object).
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

POSE_RAW_DIM = 3
ELEVATION_SCALE_DEG = 90.0


def pose_from_raw(pose_raw: Tensor) -> tuple[Tensor, Tensor]:
    """``pose_raw [B, 3]`` -> ``(azimuth [B] deg in [0, 360), elevation [B] deg in (-90, 90))``.
    Differentiable (the azimuth through ``atan2``)."""
    if pose_raw.shape[-1] != POSE_RAW_DIM:
        raise ValueError(f"pose_raw must end with {POSE_RAW_DIM} values, got shape {tuple(pose_raw.shape)}")
    az = torch.rad2deg(torch.atan2(pose_raw[..., 1], pose_raw[..., 0]))
    az = torch.remainder(az, 360.0)
    el = ELEVATION_SCALE_DEG * torch.tanh(pose_raw[..., 2])
    return az, el


def raw_from_pose(azimuth_deg: Tensor, elevation_deg: Tensor) -> Tensor:
    """Inverse of :func:`pose_from_raw` (unit-length azimuth vector): ``[B, 3]``."""
    az = torch.deg2rad(azimuth_deg)
    e = torch.atanh(torch.clamp(elevation_deg / ELEVATION_SCALE_DEG, -1 + 1e-6, 1 - 1e-6))
    return torch.stack([torch.cos(az), torch.sin(az), e], -1)


def wrap_degrees(angle_deg):
    """Wrap angles (tensor, numpy array or float) to [-180, 180)."""
    return (angle_deg + 180.0) % 360.0 - 180.0


def angular_error_deg(pred_deg, true_deg):
    """Absolute wrapped difference in degrees, in [0, 180]: 359 vs 1 -> 2."""
    return abs(wrap_degrees(pred_deg - true_deg))


def pose_errors(pred_azimuth, pred_elevation, true_azimuth, true_elevation,
                threshold_deg: float = 30.0) -> dict[str, float]:
    """Pose-error summary (SPEC "Metrics") over 1-D arrays/tensors of degrees.

    Returns ``azimuth_mean``, ``azimuth_median``, ``azimuth_acc30`` (fraction within
    ``threshold_deg``), the same for ``elevation_*``, ``azimuth_flip_acc30`` (a diagnostic: the
    fraction within ``threshold_deg`` of the true azimuth *or* of the true azimuth + 180, i.e.
    right up to the front/back ambiguity of many silhouettes at 30 deg elevation) and ``count``."""
    out: dict[str, float] = {}
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
