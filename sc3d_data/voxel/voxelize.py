"""Solid occupancy grids from triangle meshes that need not be watertight.

Grid (SPEC.md, "Voxels"): ``G^3`` cells over the cube [-0.5, 0.5]^3 of the canonical frame,
array index order ``[x, y, z]``; voxel (i, j, k) is the closed cube
``[-0.5 + i/G, -0.5 + (i+1)/G] x ...`` with centre ``-0.5 + (i + 0.5)/G`` per axis.

Which voxels count as occupied
------------------------------
A voxel is occupied when at least one of these holds:

1. **surface**: some triangle touches the voxel's closed cube (exact separating-axis
   triangle/box overlap test, Akenine-Moeller, with the cube grown by 1e-6 voxel against
   round-off). A face lying exactly on a plane between two voxels therefore marks both.
   Every point of the mesh inside [-0.5, 0.5]^3 lies in an occupied voxel, so the projected
   voxel cubes cover the rendered silhouette from any camera (``sc3d-data check`` measures it).
2. **inside**: the voxel centre is *spanned* (the line through it along some axis meets the
   surface on both sides of it) and the generalized winding number of the mesh (the fast
   winding number of Barill et al. 2018, as libigl's: exact solid angles of nearby triangles,
   second-order expansions of the field of octree clusters, and of single triangles, farther
   than 2x their radius; works on triangle soups) there has absolute value >= 0.5. The
   absolute value makes meshes with inverted orientation come out solid too. Open meshes
   (a car body without a floor, a box with a deleted face) have winding numbers near 1 in
   most of their interior and near 0 outside, so 0.5 separates them. Winding numbers add up
   over overlapping sheets, so open sheets stacked with the same facing (a floor pan of two
   layers and a plate over it, all facing into the car; a roof over a same-facing inner
   panel) reach 0.5 in a slab of empty space on their outer side, beyond the object: the
   span condition drops such points. Every point inside a closed surface is spanned along all
   three axes, so closed meshes lose nothing, and no voxel cell entirely outside the bounding
   box of the triangles is ever occupied (its centre is spanned along no axis).
3. **enclosed**: the voxel is empty by 1 and 2 but cannot be reached from outside the grid
   through a 6-connected path of empty voxels (as ``scipy.ndimage.binary_fill_holes``). This
   closes cavities and holes smaller than a voxel that winding numbers alone leave.

How it is computed (``voxelize_triangles``): rule 1 by a compiled (numba) separating-axis
test of each triangle against the voxels of its bounding box; the signed crossing counts of
the six axis-aligned rays from every voxel centre (``axis_ray_crossings``, one 2D
rasterisation of the triangles per axis, which also gives the spanned centres) decide rule 2
where all six agree (all non-zero: inside; all zero: outside); winding numbers are evaluated
only at the remaining spanned voxel centres that are not enclosed by the surface and
six-ray-inside voxels (those are occupied by rule 3 whatever their winding number). Geometry
outside [-0.5, 0.5]^3 is ignored (clipped by the grid) except that all triangles count for
winding numbers and for spans. The winding-number queries
walk the octree in blocks of nearby voxel centres, deciding a cluster once for the whole
block where it is clearly near or far and point by point otherwise, and sum the exact solid
angles as the argument of a complex product; both give every point the same value as the
plain per-point evaluation up to round-off (``_winding_kernels._winding_queries``). The
kernels live in one private module per family (numba, compiled on first use and cached in
``__pycache__``): ``_surface_kernel`` (rule 1), ``_ray_kernel`` (the six rays),
``_winding_kernels`` (rule 2) and ``_fill_kernel`` (rule 3).
"""
from __future__ import annotations

import time

import numpy as np

from sc3d_data.geometry.voxel_grid import centre_grid, world_to_index

from ._fill_kernel import fill_holes_kernel
from ._ray_kernel import rays_kernel, rays_spans_kernel
from ._surface_kernel import surface_kernel
from ._winding_kernels import BETA, winding_exact_kernel, winding_kernel

#: a voxel centre is inside when |winding number| reaches this
WINDING_THRESHOLD = 0.5


def _check_triangles(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape [n, 3], got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must have shape [m, 3] (triangles), got {f.shape}")
    if len(f) == 0:
        raise ValueError("mesh has no faces")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"face indices out of range [0, {len(v)}): min {f.min()}, max {f.max()}")
    if not np.isfinite(v).all():
        raise ValueError("vertices contain NaN or infinite coordinates")
    return v, f


def surface_voxels(vertices: np.ndarray, faces: np.ndarray, resolution: int = 32) -> np.ndarray:
    """Voxels whose closed cube touches at least one triangle (rule 1 of the module doc).

    ``vertices [n, 3]`` in the canonical frame (units of the [-0.5, 0.5]^3 grid cube),
    ``faces [m, 3]`` vertex indices. Returns bool ``[G, G, G]``, index ``[x, y, z]``.
    """
    v, f = _check_triangles(vertices, faces)
    G = int(resolution)
    grid = np.zeros((G, G, G), dtype=bool)
    surface_kernel(_voxel_vertices(v, G), f, G, grid)
    return grid


def _voxel_vertices(v: np.ndarray, G: int) -> np.ndarray:
    """Vertices ``[n, 3]`` in voxel units (the grid spans [0, G]^3); the kernels read the
    triangles' corners through the faces."""
    return np.ascontiguousarray(world_to_index(v, G))


def voxel_centers(resolution: int = 32) -> np.ndarray:
    """Centres of all voxels, float64 ``[G, G, G, 3]`` (x, y, z) in the canonical frame."""
    return centre_grid(resolution)


def winding_numbers(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                    exact: bool = False) -> np.ndarray:
    """Generalized winding number ``[P]`` of a triangle soup at ``points [P, 3]`` (about 1 inside
    a closed outward-oriented mesh, 0 outside). Fast winding number (Barill et al. 2018: exact
    solid angles of triangles near a point, second-order expansions of octree clusters farther
    than ``_winding_kernels.BETA`` times their radius); ``exact=True`` sums all solid angles."""
    v, f = _check_triangles(vertices, faces)
    q = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if len(q) == 0:
        return np.zeros(0)
    vi = _voxel_vertices(v, 1)
    if exact:
        return winding_exact_kernel(vi[f], q + 0.5)
    return winding_kernel(vi, f, q + 0.5, 1.0, BETA)


def axis_ray_crossings(vertices: np.ndarray, faces: np.ndarray, resolution: int = 32) -> np.ndarray:
    """Signed crossing counts of the six axis-aligned rays (+x, -x, +y, -y, +z, -z) from every
    voxel centre to infinity, int32 ``[6, G, G, G]``.

    A crossing counts +1 where the ray leaves through a triangle (normal along the ray) and
    -1 where it enters; for a closed, outward-oriented mesh every count is 1 inside and 0
    outside, and their mean is a six-direction estimate of the generalized winding number.
    Rays that graze an edge may count it twice or not at all; ``voxelize_triangles`` only
    trusts these counts where all six agree.
    """
    v, f = _check_triangles(vertices, faces)
    G = int(resolution)
    out = np.zeros((6, G, G, G), dtype=np.int32)
    rays_kernel(_voxel_vertices(v, G), f, G, out, np.zeros((G, G, G), dtype=np.uint8))
    return out


def voxelize_triangles(vertices: np.ndarray, faces: np.ndarray, resolution: int = 32,
                       timings: dict | None = None) -> np.ndarray:
    """Solid occupancy of a triangle mesh (rules in the module doc).

    ``vertices [n, 3]`` float, canonical frame (the object normalised into [-0.5, 0.5]^3),
    ``faces [m, 3]`` int. Works on open meshes, holes, self-intersections and overlapping
    parts. Returns bool ``[G, G, G]`` with ``G = resolution``, index order ``[x, y, z]``.
    ``timings``, if given, accumulates milliseconds per stage (surface, rays, enclosed,
    winding, fill) and the number of winding-number queries (winding_points).
    """
    v, f = _check_triangles(vertices, faces)
    G = int(resolution)
    if G < 1:
        raise ValueError(f"resolution must be positive, got {resolution}")
    clock = [time.perf_counter()]

    def lap(name):
        clock.append(time.perf_counter())
        if timings is not None:
            timings[name] = timings.get(name, 0.0) + (clock[-1] - clock[-2]) * 1e3

    vi = _voxel_vertices(v, G)
    surface = np.zeros((G, G, G), dtype=bool)
    surface_kernel(vi, f, G, surface)
    lap("surface")
    nonzero = np.zeros((G, G, G), dtype=np.uint8)  # rays with a non-zero crossing count, 0..6
    spanned = np.zeros((G, G, G), dtype=bool)  # centre between two crossings of an axis line
    rays_spans_kernel(vi, f, G, np.zeros((6, 0, 0, 0), dtype=np.int32), nonzero, spanned)
    lap("rays")
    # rule 3 applied early: voxels enclosed by surface and six-ray-inside voxels end up occupied
    # whatever the winding numbers say (filling is monotone), so they need no query
    occupied = fill_holes_kernel(surface | (nonzero == 6))
    ambiguous = ~occupied & (nonzero > 0) & spanned  # rule 2 needs a spanned centre
    lap("enclosed")
    pts = np.argwhere(ambiguous).astype(np.float64) + 0.5  # voxel centres, voxel units
    added = False
    if len(pts):
        inside = np.abs(winding_kernel(vi, f, pts, float(G), BETA)) >= WINDING_THRESHOLD
        occupied[ambiguous] = inside
        added = bool(inside.any())
    lap("winding")
    if timings is not None:
        timings["winding_points"] = timings.get("winding_points", 0) + len(pts)
    # ``occupied`` is already hole-free unless winding numbers added voxels (filling is idempotent)
    out = fill_holes_kernel(occupied) if added else occupied
    lap("fill")
    return out
