"""Normalisation into the canonical frame of SPEC.md ("Object frame and normalisation").

Canonical frame: right-handed, +Y up, the object's front facing +Z. A source mesh is first
rotated so that its ``up`` axis becomes +Y and its ``front`` axis becomes +Z (the bundled GLB
meshes are already canonical: ``up="+Y", front="+Z"``; ShapeNetCore v1 faces +X and v2 -Z,
``sc3d_data.formats.shapenet.resolve_front``), then its axis-aligned
bounding box is centred at the origin and scaled:

- ``fit`` (default): longest bounding-box side = 1, so the object fills [-0.5, 0.5]^3 (3D-R2N2);
- ``diagonal``: bounding-box diagonal = 1 (ShapeNetCore v2).

Everything is returned as one 4x4 matrix ``to_canonical`` (source -> canonical, acting on
column vectors ``[x, y, z, 1]``), which is stored per object in the shards.
"""
from __future__ import annotations

import numpy as np

NORMALIZE_MODES = ("fit", "diagonal")
AXES = ("+X", "-X", "+Y", "-Y", "+Z", "-Z")


def axis_name(axis: str) -> str:
    """An axis as ``AXES`` spells it (case-insensitive, a missing sign means +: ``"z"``, ``"+z"``
    -> ``"+Z"``); anything that is not an axis (``"auto"``) unchanged."""
    a = axis.strip().upper() if isinstance(axis, str) else ""
    if a and a[0] not in "+-":
        a = "+" + a
    return a if a in AXES else axis


def axis_vector(axis: str) -> np.ndarray:
    """``"+X"``, ``"-Y"``, ... (spelt as :func:`axis_name` reads them) -> unit vector [3]."""
    a = axis_name(axis)
    if a not in AXES:
        raise ValueError(f"axis must be one of {', '.join(AXES)}, not {axis!r}")
    v = np.zeros(3)
    v["XYZ".index(a[1])] = 1.0 if a[0] == "+" else -1.0
    return v


def canonical_rotation(up: str = "+Y", front: str = "+Z") -> np.ndarray:
    """Rotation [3,3] taking the source ``up`` axis to +Y and the source ``front`` axis to +Z."""
    u, f = axis_vector(up), axis_vector(front)
    if abs(u @ f) > 0:
        raise ValueError(f"--up {up} and --front {front} must be perpendicular axes")
    # rows: where source coordinates go. canonical x = y_canon x z_canon = up x front
    return np.stack([np.cross(u, f), u, f])


def apply_transform(vertices: np.ndarray, transform: np.ndarray) -> np.ndarray:
    """Apply a 4x4 ``transform`` (e.g. ``to_canonical``) to points ``[n,3]`` -> ``[n,3]`` float64."""
    vertices = np.asarray(vertices, dtype=np.float64)
    T = np.asarray(transform, dtype=np.float64)
    return vertices @ T[:3, :3].T + T[:3, 3]


def used_vertices(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The rows of ``vertices [n,3]`` that some triangle of ``faces [m,3]`` names, in index order
    (``vertices[np.unique(faces)]``, by a boolean mark: ~10x cheaper than the sort/hash)."""
    is_used = np.zeros(len(vertices), dtype=bool)
    is_used[np.asarray(faces).ravel()] = True
    return vertices[is_used]


def to_canonical_transform(vertices: np.ndarray, faces: np.ndarray | None = None,
                           mode: str = "fit", up: str = "+Y", front: str = "+Z") -> np.ndarray:
    """4x4 source -> canonical matrix for a mesh (``vertices [n,3]`` in the source frame; only
    vertices used by ``faces [m,3]`` count when given): rotate (``up``/``front``), centre the
    bounding box at the origin, scale per ``mode`` (``fit`` or ``diagonal``)."""
    if mode not in NORMALIZE_MODES:
        raise ValueError(f"normalize must be one of {NORMALIZE_MODES}, not {mode!r}")
    v = np.asarray(vertices, dtype=np.float64)
    if faces is not None and len(faces):
        v = used_vertices(v, faces)
    rot = canonical_rotation(up, front)
    vr = v @ rot.T
    lo, hi = vr.min(axis=0), vr.max(axis=0)
    centre, extent = (lo + hi) / 2.0, hi - lo
    with np.errstate(over="ignore", invalid="ignore"):
        size = extent.max() if mode == "fit" else np.linalg.norm(extent)
    if not size > 0:
        raise ValueError("mesh has a zero-size bounding box")
    if not np.isfinite(size):
        raise ValueError(f"mesh bounding box is not finite (extent {extent.tolist()})")
    s = 1.0 / size
    T = np.eye(4)
    T[:3, :3] = s * rot
    T[:3, 3] = -s * centre
    if not (np.isfinite(T).all() and s > 0):
        raise ValueError(f"normalisation is not finite (bounding box {lo.tolist()} to {hi.tolist()})")
    return T
