"""Camera math shared by rendering, voxel checks and the self-consistency module.

This module is the single owner of the camera convention of sc3d (see SPEC.md). Both
``sc3d_data`` (rendering, ``check``) and ``sc3d_train`` (ray consistency) import it; nothing
else may re-derive these formulas.

Conventions
-----------
World (object) frame
    Canonical, right-handed, +Y up, the object's front facing +Z. Units: the object is
    normalised into the cube [-0.5, 0.5]^3.
Pose
    ``azimuth`` (degrees): 0 puts the camera on +Z looking at the front; it grows
    counter-clockwise seen from above (+Y), so azimuth 90 puts the camera on +X.
    ``elevation`` (degrees): > 0 puts the camera above the object.
    ``distance`` (world units): from the origin to the camera centre. No in-plane roll
    unless ``roll`` is given (degrees, rotation about the optical axis, counter-clockwise
    as seen in the image).
    Camera centre: ``C = distance * (cos(el) sin(az), sin(el), cos(el) cos(az))``.
Camera frame (OpenCV)
    x right, y down, z forward (towards the scene). ``X_cam = R @ X_world + t``
    with ``t = -R @ C``.
Intrinsics ``K`` (pixels)
    ``[[f, 0, cx], [0, f, cy], [0, 0, 1]]``; pixel (u, v) covers [u, u+1) x [v, v+1), so the
    image centre is ``(W/2, H/2)`` and the centre of pixel (u, v) is ``(u + 0.5, v + 0.5)``.
    ``f = (W / 2) / tan(fov / 2)`` with ``fov`` the horizontal field of view (the same as the
    vertical one for square images).

Functions accept NumPy arrays or torch tensors (one implementation serves both; the
array namespace follows the input) and broadcast over leading batch dimensions.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

DEFAULT_NUM_VIEWS = 24
DEFAULT_ELEVATION_DEG = 30.0
DEFAULT_FOV_DEG = 49.13
DEFAULT_DISTANCE = 2.0
#: the farthest point of the voxel grid's cube [-0.5, 0.5]^3 from the origin (sqrt(3)/2): a
#: camera nearer than this can be inside the cube, with part of the grid behind it
MIN_DISTANCE = 0.5 * 3 ** 0.5
DEFAULT_IMAGE_SIZE = 64


def _xp(x: Any):
    """Return the array namespace (``torch`` or ``numpy``) of ``x``."""
    if type(x).__module__.startswith("torch"):
        import torch

        return torch
    return np


def _mT(x):
    """Swap the last two axes (matrix transpose over batch dims), numpy or torch."""
    return x.swapaxes(-1, -2) if _xp(x) is np else x.transpose(-1, -2)


def _asarray(x: Any, like: Any = None):
    xp = _xp(like) if like is not None else _xp(x)
    if xp is np:
        return np.asarray(x, dtype=np.float64)
    if type(x).__module__.startswith("torch"):
        return x
    return xp.as_tensor(x, dtype=like.dtype if like is not None else xp.float32,
                        device=getattr(like, "device", None))


# ----------------------------------------------------------------------------- poses
def ptn_poses(num_views: int = DEFAULT_NUM_VIEWS,
              elevations_deg: tuple[float, ...] = (DEFAULT_ELEVATION_DEG,)) -> tuple[np.ndarray, np.ndarray]:
    """PTN view poses: ``num_views`` azimuths evenly spaced from 0, for each elevation.

    Returns ``(azimuth_deg, elevation_deg)``, both float64 ``[len(elevations) * num_views]``,
    elevation-major (all azimuths of the first elevation first). The default is PTN's
    24 views: azimuth 15 deg * k, elevation 30 deg.
    """
    az = np.arange(num_views, dtype=np.float64) * (360.0 / num_views)
    azs = np.concatenate([az for _ in elevations_deg])
    els = np.concatenate([np.full(num_views, e, dtype=np.float64) for e in elevations_deg])
    return azs, els


def camera_center(azimuth_deg, elevation_deg, distance):
    """Camera centre in the world frame, ``[..., 3]`` (see module conventions)."""
    xp = _xp(azimuth_deg)
    az = xp.deg2rad(_asarray(azimuth_deg))
    el = xp.deg2rad(_asarray(elevation_deg, az))
    d = _asarray(distance, az)
    return xp.stack([d * xp.cos(el) * xp.sin(az), d * xp.sin(el) + 0 * az,
                     d * xp.cos(el) * xp.cos(az)], -1)


def look_at_rotation(azimuth_deg, elevation_deg, roll_deg=None):
    """World->camera rotation ``R`` ``[..., 3, 3]`` (OpenCV axes) of a camera at the given pose
    looking at the origin with world +Y up in the image (before roll).

    Rows of ``R`` are the camera's right, down and forward axes expressed in world coordinates:
    ``right = (cos az, 0, -sin az)``, ``forward = -(cos el sin az, sin el, cos el cos az)``,
    ``down = forward x right``. Differentiable in the angles when given tensors.
    """
    xp = _xp(azimuth_deg)
    az = xp.deg2rad(_asarray(azimuth_deg))
    el = xp.deg2rad(_asarray(elevation_deg, az))
    zero = 0 * az
    ca, sa, ce, se = xp.cos(az), xp.sin(az), xp.cos(el) + zero, xp.sin(el) + zero
    right = xp.stack([ca, zero, -sa], -1)
    forward = xp.stack([-ce * sa, -se, -ce * ca], -1)
    # down = forward x right
    down = xp.stack([forward[..., 1] * right[..., 2] - forward[..., 2] * right[..., 1],
                     forward[..., 2] * right[..., 0] - forward[..., 0] * right[..., 2],
                     forward[..., 0] * right[..., 1] - forward[..., 1] * right[..., 0]], -1)
    if roll_deg is not None:
        r = xp.deg2rad(_asarray(roll_deg, az))
        cr, sr = xp.cos(r) + zero, xp.sin(r) + zero
        # rotate the image axes counter-clockwise (as seen in the image) by roll
        right, down = (cr[..., None] * right - sr[..., None] * down,
                       sr[..., None] * right + cr[..., None] * down)
    return xp.stack([right, down, forward], -2)


def extrinsics(azimuth_deg, elevation_deg, distance, roll_deg=None):
    """``(R [...,3,3], t [...,3])`` world->camera (OpenCV) for a look-at camera, ``t = -R C``."""
    R = look_at_rotation(azimuth_deg, elevation_deg, roll_deg)
    C = camera_center(azimuth_deg, elevation_deg, distance)
    t = -(R @ C[..., None])[..., 0]
    return R, t


def intrinsics(image_size: int = DEFAULT_IMAGE_SIZE, fov_deg: float = DEFAULT_FOV_DEG) -> np.ndarray:
    """Pinhole ``K`` [3, 3] float64 in pixels for a square ``image_size`` image and the
    horizontal field of view ``fov_deg`` (degrees); principal point at the image centre."""
    f = (image_size / 2.0) / np.tan(np.deg2rad(fov_deg) / 2.0)
    c = image_size / 2.0
    return np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])


def scale_intrinsics(K, new_size: int, old_size: int):
    """``K`` for the same camera at another (square) image size: focal length and principal
    point scale by ``new_size / old_size`` (pixel-edge convention keeps the centre at W/2)."""
    s = new_size / old_size
    xp = _xp(K)
    if xp is np:
        return np.diag([s, s, 1.0]) @ K
    S = K.new_ones(3, 1)  # diag(s, s, 1) @ K as a row scaling, built on K's device (no host copy)
    S[:2] = s
    return S * K


def fov_from_focal(focal_px: float, image_size: int) -> float:
    """Field of view (degrees) of a square image of ``image_size`` pixels with focal ``focal_px``."""
    return float(np.rad2deg(2.0 * np.arctan((image_size / 2.0) / focal_px)))


# ----------------------------------------------------------------------------- projection
def world_to_camera(points, R, t):
    """``points [..., P, 3]`` world -> camera frame ``[..., P, 3]`` with ``R [...,3,3]``, ``t [...,3]``."""
    return points @ _mT(R) + t[..., None, :]


def project_points(points, K, R, t):
    """Project world points ``[..., P, 3]`` to pixel coordinates ``[..., P, 2]`` (u right, v down,
    continuous: the centre of pixel (u, v) is (u + 0.5, v + 0.5)) and return ``(uv, depth)``
    with ``depth [..., P]`` the camera-frame z (positive in front of the camera)."""
    cam = world_to_camera(points, R, t)
    z = cam[..., 2]
    proj = cam @ _mT(K)
    uv = proj[..., :2] / proj[..., 2:3]
    return uv, z


def _upper_triangular_inverse(K):
    """The inverse of pinhole intrinsics ``K [..., 3, 3]`` (torch; upper triangular: focal
    lengths, skew, principal point, last row ``0 0 1`` as every K here), in closed form:
    elementwise ops only, so on CUDA no host sync (``torch.linalg.inv`` checks its result on the
    host) and one fused kernel under ``torch.compile``."""
    import torch

    a, b, c = K[..., 0, 0], K[..., 0, 1], K[..., 0, 2]
    d, e, g = K[..., 1, 1], K[..., 1, 2], K[..., 2, 2]
    zero = torch.zeros_like(a)
    rows = [torch.stack([1 / a, -b / (a * d), (b * e - c * d) / (a * d * g)], -1),
            torch.stack([zero, 1 / d, -e / (d * g)], -1),
            torch.stack([zero, zero, 1 / g], -1)]
    return torch.stack(rows, -2)


def pixel_rays(K, R, t, image_size: int):
    """Rays through the centres of all pixels of a square ``image_size`` image.

    Returns ``(origins [..., 3], directions [..., H*W, 3])`` in the world frame; directions are
    unit vectors, pixels in row-major order (v then u). ``K``, ``R``, ``t`` as in the shards
    (numpy or torch; batch dims broadcast)."""
    xp = _xp(R)
    n = image_size
    if xp is np:
        grid = np.arange(n, dtype=np.float64) + 0.5
        v, u = np.meshgrid(grid, grid, indexing="ij")
        pix = np.stack([u.ravel(), v.ravel(), np.ones(n * n)], -1)
        Kinv = np.linalg.inv(K)
    else:
        grid = xp.arange(n, dtype=R.dtype, device=R.device) + 0.5
        v, u = xp.meshgrid(grid, grid, indexing="ij")
        pix = xp.stack([u.reshape(-1), v.reshape(-1), xp.ones_like(u.reshape(-1))], -1)
        Kinv = _upper_triangular_inverse(K.to(R.dtype))
    d_cam = pix @ _mT(Kinv)
    d_world = d_cam @ R  # (R^T d)^T for row vectors: camera -> world directions
    d_world = d_world / ((d_world ** 2).sum(-1, keepdims=True) ** 0.5)
    origins = -(_mT(R) @ t[..., None])[..., 0]
    return origins, d_world


@dataclass(frozen=True)
class ViewSettings:
    """The camera settings of a dataset (all views of all objects share them).

    ``num_views`` azimuths per elevation, ``elevations_deg``, ``distance`` (world units),
    ``fov_deg`` (degrees), ``image_size`` (pixels, square)."""

    num_views: int = DEFAULT_NUM_VIEWS
    elevations_deg: tuple[float, ...] = (DEFAULT_ELEVATION_DEG,)
    distance: float = DEFAULT_DISTANCE
    fov_deg: float = DEFAULT_FOV_DEG
    image_size: int = DEFAULT_IMAGE_SIZE

    def cameras(self) -> dict[str, np.ndarray]:
        """All views' cameras: ``K [V,3,3]``, ``R [V,3,3]``, ``t [V,3]``, ``azimuth``,
        ``elevation``, ``distance`` ``[V]`` (float64; degrees and world units)."""
        az, el = ptn_poses(self.num_views, self.elevations_deg)
        dist = np.full_like(az, self.distance)
        R, t = extrinsics(az, el, dist)
        K = np.broadcast_to(intrinsics(self.image_size, self.fov_deg), (len(az), 3, 3)).copy()
        return {"K": K, "R": R, "t": t, "azimuth": az, "elevation": el, "distance": dist}
