"""The voxel grid convention (SPEC.md, "Voxels"), stated once.

A grid of resolution ``G`` covers the canonical cube ``[-CUBE_HALF, CUBE_HALF]^3`` (world units,
canonical object frame: +Y up, front +Z), ``CUBE_HALF = 0.5``. Arrays are indexed ``[x, y, z]``.
Voxel ``(i, j, k)`` is the cube from ``index_to_world((i, j, k))`` to
``index_to_world((i + 1, j + 1, k + 1))``; its centre is ``index_to_world((i, j, k) + 0.5)``,
i.e. ``-0.5 + (i + 0.5) / G``.

*Continuous index* coordinates put voxel ``i`` on ``[i, i + 1)``. The functions are plain
arithmetic, so they work on numpy arrays, torch tensors and floats alike.
"""
from __future__ import annotations

import numpy as np

#: half the side of the cube the grid covers (world units)
CUBE_HALF = 0.5


def voxel_size(resolution: int) -> float:
    """Side of one voxel in world units: ``2 * CUBE_HALF / G``."""
    return 2.0 * CUBE_HALF / resolution


def index_to_world(index, resolution: int):
    """Continuous index ``[..., 3]`` (voxel ``i`` spans ``[i, i + 1)``) -> world ``[..., 3]``."""
    return index * voxel_size(resolution) - CUBE_HALF


def world_to_index(points, resolution: int):
    """World ``[..., 3]`` -> continuous index ``[..., 3]`` (inverse of :func:`index_to_world`)."""
    return (points + CUBE_HALF) / voxel_size(resolution)


def voxel_centres(indices, resolution: int):
    """World centres ``[..., 3]`` of integer voxel indices ``[..., 3]``."""
    return index_to_world(indices + 0.5, resolution)


def centre_grid(resolution: int) -> np.ndarray:
    """Centres of all voxels, float64 ``[G, G, G, 3]`` (x, y, z), world units."""
    c = voxel_centres(np.arange(resolution, dtype=np.float64), resolution)
    return np.stack(np.meshgrid(c, c, c, indexing="ij"), -1)
