"""Silhouette of an occupancy grid seen through a stored camera.

The voxels are treated as closed cubes (not points): voxel (i, j, k) of a ``G^3`` grid is the
cube ``[-0.5 + i/G, -0.5 + (i+1)/G] x ...`` of the canonical frame (SPEC.md). A pixel is set
when its centre ``(u + 0.5, v + 0.5)`` lies in the projection of some occupied cube, which
is the same sampling rule as the rendered masks (a pixel is covered when the ray through its
centre hits the object). Cameras follow ``sc3d_data.geometry.camera`` (OpenCV K, R, t world->camera).

The union of the cubes' projections equals the union of the projections of their exposed
faces (faces whose neighbour is empty or outside the grid), so only those quads are
rasterised: each projects to a convex quadrilateral covering about one pixel at 64x64.
"""
from __future__ import annotations

import numpy as np

from sc3d_data.geometry.camera import project_points
from sc3d_data.geometry.voxel_grid import index_to_world


class BehindCamera(ValueError):
    """Occupied voxels lie behind the camera (or in its plane): their silhouette is not defined.
    Only a camera nearer than ``camera.MIN_DISTANCE`` to the origin can see this."""

# corner offsets (in voxel units) of the face of a unit cube on each side, in cyclic order
_FACES = {
    (-1, 0, 0): [(0, 0, 0), (0, 1, 0), (0, 1, 1), (0, 0, 1)],
    (1, 0, 0): [(1, 0, 0), (1, 1, 0), (1, 1, 1), (1, 0, 1)],
    (0, -1, 0): [(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)],
    (0, 1, 0): [(0, 1, 0), (1, 1, 0), (1, 1, 1), (0, 1, 1)],
    (0, 0, -1): [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)],
    (0, 0, 1): [(0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)],
}


def exposed_faces(voxels: np.ndarray) -> np.ndarray:
    """Corners of the exposed faces of the occupied voxels, float64 ``[F, 4, 3]`` in the
    canonical frame (each quad's corners in cyclic order)."""
    occ = np.asarray(voxels).astype(bool)
    if occ.ndim != 3 or len(set(occ.shape)) != 1:
        raise ValueError(f"voxels must be a cubic [G, G, G] grid, got shape {occ.shape}")
    G = occ.shape[0]
    padded = np.pad(occ, 1)
    quads = []
    for (dx, dy, dz), corners in _FACES.items():
        neighbour = padded[1 + dx:1 + dx + G, 1 + dy:1 + dy + G, 1 + dz:1 + dz + G]
        ijk = np.argwhere(occ & ~neighbour)
        if len(ijk):
            quads.append(ijk[:, None, :] + np.asarray(corners)[None])
    if not quads:
        return np.zeros((0, 4, 3))
    return index_to_world(np.concatenate(quads).astype(np.float64), G)


def project_voxels(voxels: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                   image_size: int) -> np.ndarray:
    """Silhouette of the occupied voxels (as cubes) through one camera.

    ``voxels`` bool/uint8 ``[G, G, G]`` index ``[x, y, z]`` over [-0.5, 0.5]^3; ``K [3, 3]``
    (pixels), ``R [3, 3]``, ``t [3]`` world->camera as stored in the shards; ``image_size``
    ``S`` (square). Returns bool ``[S, S]`` indexed ``[v, u]`` (row = image y, like the masks).
    All of the occupied voxels must be in front of the camera (else :class:`BehindCamera`).
    """
    S = int(image_size)
    out = np.zeros((S, S), dtype=bool)
    quads = exposed_faces(voxels)
    if len(quads) == 0:
        return out
    K, R, t = (np.asarray(a, dtype=np.float64) for a in (K, R, t))
    uv, depth = project_points(quads.reshape(-1, 3), K, R, t)
    if (depth <= 1e-9).any():
        raise BehindCamera("project_voxels: part of the voxel grid is behind the camera")
    uv = uv.reshape(-1, 4, 2) - 0.5  # continuous coordinates in which pixel centres are integers
    lo = np.clip(np.ceil(uv.min(1) - 1e-9).astype(np.int64), 0, S)
    hi = np.clip(np.floor(uv.max(1) + 1e-9).astype(np.int64), -1, S - 1)
    ext = np.maximum(hi - lo + 1, 0)
    counts = ext[:, 0] * ext[:, 1]
    keep = counts > 0
    uv, lo, ext, counts = uv[keep], lo[keep], ext[keep], counts[keep]
    if len(uv) == 0:
        return out
    q = np.repeat(np.arange(len(uv)), counts)
    local = np.arange(len(q)) - np.repeat(np.cumsum(counts) - counts, counts)
    pu = lo[q, 0] + local % ext[q, 0]
    pv = lo[q, 1] + local // ext[q, 0]
    corners = uv[q]  # [P, 4, 2]
    a = corners
    b = np.roll(corners, -1, axis=1)
    # edge functions of the pixel centre against the four edges; inside a convex quad (either
    # orientation) when they all have the same sign (zero counts: closed cubes)
    cross = (b[..., 0] - a[..., 0]) * (pv[:, None] - a[..., 1]) - \
            (b[..., 1] - a[..., 1]) * (pu[:, None] - a[..., 0])
    tol = 1e-9
    inside = (cross >= -tol).all(1) | (cross <= tol).all(1)
    out[pv[inside], pu[inside]] = True
    return out


def project_voxels_views(voxels: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                         image_size: int, views=None, behind: list[int] | None = None) -> np.ndarray:
    """Silhouettes of one object's voxels through several stored cameras (for ``preview`` and
    ``check``): ``K [V,3,3]``, ``R [V,3,3]``, ``t [V,3]``; ``views`` indices (default all).
    Returns bool ``[len(views), S, S]``. With ``behind`` (a list), a view whose camera has
    occupied voxels behind it is left empty and its index appended there; without it,
    :class:`BehindCamera` is raised."""
    views = range(len(K)) if views is None else views
    S = int(image_size)
    out = np.zeros((len(views), S, S), dtype=bool)
    for i, v in enumerate(views):
        try:
            out[i] = project_voxels(voxels, K[v], R[v], t[v], S)
        except BehindCamera:
            if behind is None:
                raise
            behind.append(int(v))
    return out
