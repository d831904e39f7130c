"""numba kernel of rule 3 of ``sc3d_data.voxel.voxelize``: enclosed voxels by flood fill from
the grid's border (what ``scipy.ndimage.binary_fill_holes`` computes, without its overhead).
Compiled once and cached in ``__pycache__`` (``cache=True``).
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def fill_holes_kernel(occ):
    """``occ`` plus every empty voxel that no 6-connected path of empty voxels links to the
    grid's border (``scipy.ndimage.binary_fill_holes`` with its default structure). Flood fill
    from the border's empty voxels over a copy of the grid padded by one "outside" voxel per
    side, so that neighbours are plain offsets of a flat index with no bounds checks."""
    X, Y, Z = occ.shape
    Yp, Zp = Y + 2, Z + 2
    sy, sx = Zp, Yp * Zp
    state = np.full((X + 2) * sx, 2, dtype=np.uint8)  # 0 empty, 1 occupied, 2 outside
    stack = np.empty(X * Y * Z, dtype=np.int64)
    top = 0
    for i in range(X):
        for j in range(Y):
            for k in range(Z):
                f = (i + 1) * sx + (j + 1) * sy + k + 1
                if occ[i, j, k]:
                    state[f] = 1
                elif i == 0 or j == 0 or k == 0 or i == X - 1 or j == Y - 1 or k == Z - 1:
                    stack[top] = f  # border voxel: outside (state stays 2)
                    top += 1
                else:
                    state[f] = 0
    while top > 0:
        top -= 1
        f = stack[top]
        for n in (f - 1, f + 1, f - sy, f + sy, f - sx, f + sx):
            if state[n] == 0:
                state[n] = 2
                stack[top] = n
                top += 1
    out = np.empty(occ.shape, dtype=np.bool_)
    for i in range(X):
        for j in range(Y):
            for k in range(Z):
                out[i, j, k] = state[(i + 1) * sx + (j + 1) * sy + k + 1] != 2
    return out
