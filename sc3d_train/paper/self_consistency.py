"""2D-3D self-consistency module: differentiable ray consistency (L_ray) and projection (L_proj).

For every pixel of a ``S x S`` mask (S = 48 in the paper) a ray is cast through the camera of the
shards: ``R, t`` from the (predicted) pose via ``sc3d_data.geometry.camera.extrinsics`` and the rays from
``sc3d_data.geometry.camera.pixel_rays`` (pixel centres, OpenCV axes; K in pixels *at mask size*, e.g.
``scale_intrinsics(K_64, 48, 64)``). No camera math lives here.

Sampling
    Each ray is clipped to the voxel grid's cube [-0.5, 0.5]^3 (slab intersection; rays that miss
    it see no occupancy and escape). ``N`` samples (default 64) sit at the midpoints of N equal
    segments between the near and far intersection. The paper's samples ``l_i = d * i / N`` span a
    fixed depth range instead; clipping to the cube puts all N samples where the grid is (spacing
    <= sqrt(3)/64 ~ 0.027 < the 1/32 voxel), and near/far stay differentiable in the pose.
Trilinear sampling
    ``torch.nn.functional.grid_sample`` on the occupancy ``[B, G, G, G]`` in ``[x, y, z]`` index
    order, viewed as a volume ``[B, 1, D=x, H=y, W=z]``; grid_sample's coordinate triple is
    ``(W, H, D)`` so a world point ``(x, y, z)`` is passed as ``(2z, 2y, 2x)``. With
    ``align_corners=False`` the normalised coordinates -1 and +1 are the outer faces of the corner
    voxels, so voxel i has its centre at ``-0.5 + (i + 0.5)/G`` as in SPEC; outside the cube the
    occupancy is 0 (``padding_mode="zeros"``).
Probabilities (the paper's equations, per ray, ``y_i`` = sampled occupancy)
    termination ``q(i) = y_i prod_{j<i} (1 - y_j)``, escape ``q_esc = prod_i (1 - y_i)``,
    ``L_ray(u, v) = m q_esc + (1 - m) sum_i q(i)`` averaged over pixels and batch (``sum_i q(i)
    = 1 - q_esc``, so the loss computes only ``q_esc``, as ``exp(sum log(1 - y_i))``);
    projection ``P = 1 - q_esc``;
    ``L_proj = exp(1 - sum(P m) / sum(P + m - P m)) - 1`` per image, averaged over the batch. The
    paper prints the denominator as ``P + m + P m``, a sign typo: the IoU form (``- P m``) is used.
Precision
    The module always computes in float32 (autocast is disabled inside), because products of 64
    factors and grid_sample are fragile in float16.
"""
from __future__ import annotations

from contextlib import nullcontext

import torch
import torch.nn.functional as F
from torch import Tensor

from sc3d_data.geometry.camera import extrinsics, pixel_rays
from sc3d_data.geometry.voxel_grid import CUBE_HALF

from sc3d_train.settings.config import RAY_SAMPLES as DEFAULT_NUM_SAMPLES


def area_downsample(masks: Tensor, size: int) -> Tensor:
    """Exact area-average resampling of square masks ``[B, H, H]`` (float, any values) to
    ``[B, size, size]``: every output pixel is the mean of the input area it covers (a 64 -> 48
    pixel covers 4/3 input pixels). Implemented as nearest upsampling to the least common multiple
    followed by average pooling, so pixel edges stay aligned (same camera after
    ``scale_intrinsics``). Threshold the result at 0.5 for a binary mask."""
    import math

    h = masks.shape[-1]
    if masks.shape[-2] != h:
        raise ValueError(f"masks must be square, got {tuple(masks.shape)}")
    if h == size:
        return masks
    lcm = h * size // math.gcd(h, size)
    x = masks.reshape(-1, 1, h, h).float()
    up = lcm // h
    if up > 1:
        x = x.repeat_interleave(up, -1).repeat_interleave(up, -2)
    x = F.avg_pool2d(x, lcm // size)
    return x.reshape(*masks.shape[:-2], size, size)


def ray_cube_bounds(origins: Tensor, directions: Tensor, half: float = CUBE_HALF) -> tuple[Tensor, Tensor, Tensor]:
    """Slab intersection of rays ``origins [B, 3]`` + s * ``directions [B, R, 3]`` (unit) with the
    cube ``[-half, half]^3``. Returns ``(near [B, R], far [B, R], hit [B, R] bool)`` in world units
    along the ray (near >= 0); for rays that miss, near = far = 0."""
    o = origins[:, None, :]
    d = torch.where(directions.abs() < 1e-9, torch.full_like(directions, 1e-9), directions)
    t1 = (-half - o) / d
    t2 = (half - o) / d
    near = torch.minimum(t1, t2).amax(-1).clamp_min(0.0)
    far = torch.maximum(t1, t2).amin(-1)
    hit = far > near
    zero = torch.zeros_like(near)
    return torch.where(hit, near, zero), torch.where(hit, far, zero), hit


def _ray_depths(origins: Tensor, directions: Tensor, num_samples: int) -> Tensor:
    """Distances ``[B, R, N]`` along each ray of the sample midpoints (see module docstring)."""
    near, far, _ = ray_cube_bounds(origins, directions)
    frac = (torch.arange(num_samples, device=near.device, dtype=near.dtype) + 0.5) / num_samples
    return near[..., None] + (far - near)[..., None] * frac


def sample_points(origins: Tensor, directions: Tensor, num_samples: int) -> Tensor:
    """World points ``[B, R, N, 3]`` at the midpoints of ``num_samples`` equal segments of each
    ray's chord through the cube (see module docstring)."""
    s = _ray_depths(origins, directions, num_samples)
    return origins[:, None, None, :] + s[..., None] * directions[:, :, None, :]


def _grid_coords(points_or_rays) -> Tensor:
    """World (x, y, z) -> grid_sample's normalised (W=z, H=y, D=x) coordinates (x 1/CUBE_HALF)."""
    return points_or_rays.flip(-1) / CUBE_HALF


def sample_occupancy(occupancy: Tensor, points: Tensor, normalized: bool = False) -> Tensor:
    """Trilinear occupancy ``[B, R, N]`` at world points ``[B, R, N, 3]`` of the grid
    ``occupancy [B, G, G, G]`` (``[x, y, z]`` index order, cube [-0.5, 0.5]^3, zero outside).
    ``normalized=True``: the points are already grid_sample coordinates (``_grid_coords``)."""
    b, r, n, _ = points.shape
    grid = (points if normalized else _grid_coords(points)).reshape(b, 1, r, n, 3)
    vol = occupancy[:, None]  # [B, 1, D=x, H=y, W=z]
    out = F.grid_sample(vol, grid.to(vol.dtype), mode="bilinear", padding_mode="zeros", align_corners=False)
    return out.reshape(b, r, n)


def sample_rays(occupancy: Tensor, azimuth: Tensor, elevation: Tensor, distance: Tensor, K: Tensor,
                mask_size: int, num_samples: int = DEFAULT_NUM_SAMPLES) -> Tensor:
    """Occupancy ``y [B, S*S, N]`` at the N samples of every pixel ray (float32). The points are
    built directly in grid_sample coordinates (the flip and scale act on the small per-ray tensors,
    not on the ``[B, R, N, 3]`` one)."""
    origins, dirs = camera_rays(azimuth.float(), elevation.float(), distance.float(), K.float(), mask_size)
    s = _ray_depths(origins, dirs, num_samples)
    o_n, d_n = _grid_coords(origins), _grid_coords(dirs)
    pts = torch.addcmul(o_n[:, None, None, :], s[..., None], d_n[:, :, None, :])
    return sample_occupancy(occupancy.float(), pts, normalized=True)


def camera_rays(azimuth: Tensor, elevation: Tensor, distance: Tensor, K: Tensor, mask_size: int) -> tuple[Tensor, Tensor]:
    """Rays of all ``mask_size^2`` pixel centres (row-major, v then u) for look-at cameras at the
    given pose (degrees, world units; ``[B]`` each) with intrinsics ``K [B, 3, 3]`` in pixels at
    mask size: ``(origins [B, 3], directions [B, S*S, 3])``. Differentiable in the pose."""
    R, t = extrinsics(azimuth, elevation, distance)
    return pixel_rays(K.to(R.dtype), R, t, mask_size)


def _check_inputs(occupancy: Tensor, azimuth: Tensor, K: Tensor) -> None:
    if occupancy.ndim != 4 or not (occupancy.shape[1] == occupancy.shape[2] == occupancy.shape[3]):
        raise ValueError(f"occupancy must be [B, G, G, G], got {tuple(occupancy.shape)}")
    b = occupancy.shape[0]
    if azimuth.shape != (b,):
        raise ValueError(f"azimuth must be [B]={b}, got {tuple(azimuth.shape)}")
    if K.shape != (b, 3, 3):
        raise ValueError(f"K must be [B, 3, 3] with B={b}, got {tuple(K.shape)}")


def _fp32(device: torch.device):
    return torch.autocast(device.type, enabled=False) if device.type in ("cuda", "cpu") else nullcontext()


def project_occupancy(occupancy: Tensor, azimuth: Tensor, elevation: Tensor, distance: Tensor, K: Tensor,
                      mask_size: int, num_samples: int = DEFAULT_NUM_SAMPLES) -> tuple[Tensor, Tensor]:
    """Project an occupancy grid through the camera at a pose.

    ``occupancy [B, G, G, G]`` in [0, 1] (``[x, y, z]``); ``azimuth``, ``elevation`` ``[B]``
    degrees; ``distance [B]`` world units; ``K [B, 3, 3]`` pixels at ``mask_size``.
    Returns ``(projection [B, S, S] = 1 - escape, termination_probs [B, S*S, N+1])``; the last
    entry of ``termination_probs`` is the escape probability (rows sum to 1). Differentiable with
    respect to the occupancy and the pose."""
    _check_inputs(occupancy, azimuth, K)
    with _fp32(occupancy.device):
        y = sample_rays(occupancy, azimuth, elevation, distance, K, mask_size, num_samples)  # [B, R, N]
        transmit = torch.cumprod(1.0 - y, -1)  # prod_{j<=i} (1 - y_j)
        before = torch.cat([torch.ones_like(transmit[..., :1]), transmit[..., :-1]], -1)
        q = torch.cat([y * before, transmit[..., -1:]], -1)  # [B, R, N+1]
        projection = (1.0 - transmit[..., -1]).reshape(-1, mask_size, mask_size)
    return projection, q


def iou_loss_per_sample(pred: Tensor, target: Tensor, eps: float = 1e-6) -> Tensor:
    """``exp(1 - IoU_soft) - 1`` per sample ``[B]`` (all but the first axis reduced);
    ``IoU_soft = sum(p t) / sum(p + t - p t)``."""
    p, t = pred.flatten(1), target.flatten(1)
    inter = (p * t).sum(1)
    union = (p + t - p * t).sum(1)
    return torch.exp(1.0 - inter / (union + eps)) - 1.0


def iou_loss(pred: Tensor, target: Tensor, eps: float = 1e-6) -> Tensor:
    """:func:`iou_loss_per_sample` averaged over the batch. Used for L_proj and the IoU part of
    L_3D."""
    return iou_loss_per_sample(pred, target, eps).mean()


def escape_probability(y: Tensor) -> Tensor:
    """``prod_i (1 - y_i)`` over the last axis (samples along a ray), computed in log space (a
    cheaper backward than ``cumprod``); ``y`` is clamped below 1 so the log stays finite."""
    return torch.exp(torch.log1p(-y.clamp(max=1.0 - 1e-6)).sum(-1))


def self_consistency_losses(occupancy: Tensor, masks: Tensor, azimuth: Tensor, elevation: Tensor,
                            distance: Tensor, K: Tensor, num_samples: int = DEFAULT_NUM_SAMPLES) -> dict[str, Tensor]:
    """L_ray and L_proj of ``occupancy [B, G, G, G]`` seen at the pose against ``masks [B, S, S]``
    (float in [0, 1], S = mask size, ``K`` at that size). Returns ``ray`` and ``proj`` (scalars)
    and ``projection [B, S, S]``. Not weighted (see :class:`sc3d_train.paper.losses.LossWeights`)."""
    if masks.ndim != 3 or masks.shape[1] != masks.shape[2]:
        raise ValueError(f"masks must be [B, S, S], got {tuple(masks.shape)}")
    _check_inputs(occupancy, azimuth, K)
    s = masks.shape[-1]
    with _fp32(occupancy.device):
        y = sample_rays(occupancy, azimuth, elevation, distance, K, s, num_samples)
        # escape = prod_i (1 - y_i), in log space (cheaper backward than cumprod); the sum of the
        # termination probabilities is 1 - escape, so L_ray needs only the escape probability
        escape = escape_probability(y)  # [B, R]
        m = masks.float().reshape(masks.shape[0], -1)
        ray = (m * escape + (1.0 - m) * (1.0 - escape)).mean()
        projection = (1.0 - escape).reshape(-1, s, s)
        proj = iou_loss(projection, masks.float())
    return {"ray": ray, "proj": proj, "projection": projection}
