"""A plain second implementation of the differentiable ray consistency projection, for tests and
benchmarks: ``project_occupancy_reference`` follows the same rays and samples as
``sc3d_train.paper.self_consistency.project_occupancy`` but gathers the 8 corner voxels by hand and
accumulates the escape product in a Python loop, so a test comparing the two fails if either
the module's grid_sample coordinates or its log-space escape are wrong. Not part of the library.
"""
from __future__ import annotations

import torch
from torch import Tensor

from sc3d_data.geometry.voxel_grid import CUBE_HALF
from sc3d_train.paper.self_consistency import DEFAULT_NUM_SAMPLES, camera_rays, sample_points


def project_occupancy_reference(occupancy: Tensor, azimuth: Tensor, elevation: Tensor, distance: Tensor,
                                K: Tensor, mask_size: int, num_samples: int = DEFAULT_NUM_SAMPLES) -> Tensor:
    """Straightforward baseline of :func:`project_occupancy` (same rays and samples), for tests and
    the benchmark: trilinear interpolation by gathering the 8 corner voxels by hand and the escape
    product accumulated in a Python loop over the samples. Returns ``projection [B, S, S]``."""
    origins, dirs = camera_rays(azimuth.float(), elevation.float(), distance.float(), K.float(), mask_size)
    pts = sample_points(origins, dirs, num_samples)  # [B, R, N, 3]
    b, g = occupancy.shape[0], occupancy.shape[1]
    occ = occupancy.float().reshape(b, -1)
    f = (pts + CUBE_HALF) * g - 0.5  # continuous index, voxel centres at integers
    i0 = torch.floor(f)
    w1 = f - i0
    i0 = i0.long()
    y = torch.zeros(pts.shape[:-1], dtype=occ.dtype, device=occ.device)
    for corner in range(8):
        offs = [(corner >> a) & 1 for a in range(3)]
        idx = [i0[..., a] + offs[a] for a in range(3)]
        w = torch.ones_like(y)
        valid = torch.ones_like(y, dtype=torch.bool)
        for a in range(3):
            w = w * (w1[..., a] if offs[a] else 1.0 - w1[..., a])
            valid &= (idx[a] >= 0) & (idx[a] < g)
        flat = ((idx[0].clamp(0, g - 1) * g + idx[1].clamp(0, g - 1)) * g + idx[2].clamp(0, g - 1))
        vals = torch.gather(occ, 1, flat.reshape(b, -1)).reshape(y.shape)
        y = y + torch.where(valid, w * vals, torch.zeros_like(vals))
    escape = torch.ones_like(y[..., 0])
    for i in range(num_samples):
        escape = escape * (1.0 - y[..., i])
    return (1.0 - escape).reshape(b, mask_size, mask_size)
