"""numba kernel of the six-ray test of ``sc3d_data.voxel.voxelize`` (rule 2 where all six
agree): signed crossing counts of the axis rays from every voxel centre.

Mesh arguments as in ``_surface_kernel`` (``vi [n, 3]`` float64 in voxel units, ``f [m, 3]``
int64, read in place). Compiled once and cached in ``__pycache__`` (``cache=True``); its
helpers live in this file, as every kernel family's do (``_winding_kernels`` says why).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _axis_histogram(vi, f, G, a, hist, first, last):
    """Rasterises the triangles (``vi``, ``f``) along axis ``a`` (0 x, 1 y, 2 z): for the
    ray line through voxel centres (ib + 0.5, ic + 0.5) of the other two axes b = a + 1,
    c = a + 2 (mod 3), ``hist [G, G, G + 1]`` (zeroed here) gets at [ib, ic, n] the signed
    crossings (+1 where the triangle's normal points along +a) that lie between the centres
    n - 1 and n along a (n = 0: below the first centre, n = G: above the last), and
    ``first [G, G]`` / ``last [G, G]`` the lowest / highest such n of any crossing of the line
    whatever its sign (G + 1 / -1 where the line meets no triangle): crossings of opposite
    sign in one bin cancel in ``hist`` but still count there."""
    b = (a + 1) % 3
    c = (a + 2) % 3
    hist[:] = 0
    first[:] = G + 1
    last[:] = -1
    for t in range(f.shape[0]):
        b0, b1, b2 = vi[f[t, 0], b], vi[f[t, 1], b], vi[f[t, 2], b]
        c0, c1, c2 = vi[f[t, 0], c], vi[f[t, 1], c], vi[f[t, 2], c]
        area = (b1 - b0) * (c2 - c0) - (c1 - c0) * (b2 - b0)
        if abs(area) <= 1e-12:
            continue
        lb = min(max(int(math.ceil(min(b0, b1, b2) - 0.5)), 0), G)
        lc = min(max(int(math.ceil(min(c0, c1, c2) - 0.5)), 0), G)
        hb = min(max(int(math.floor(max(b0, b1, b2) - 0.5)), -1), G - 1)
        hc = min(max(int(math.floor(max(c0, c1, c2) - 0.5)), -1), G - 1)
        if hb < lb or hc < lc:
            continue
        sgn = 1 if area > 0 else -1
        d0, d1, d2 = vi[f[t, 0], a], vi[f[t, 1], a], vi[f[t, 2], a]
        for ib in range(lb, hb + 1):
            qb = ib + 0.5
            for ic in range(lc, hc + 1):
                qc = ic + 0.5
                w0 = (b2 - b1) * (qc - c1) - (c2 - c1) * (qb - b1)
                w1 = (b0 - b2) * (qc - c2) - (c0 - c2) * (qb - b2)
                w2 = (b1 - b0) * (qc - c0) - (c1 - c0) * (qb - b0)
                if sgn > 0:
                    if w0 < 0 or w1 < 0 or w2 < 0:
                        continue
                elif w0 > 0 or w1 > 0 or w2 > 0:
                    continue
                d = (w0 * d0 + w1 * d1 + w2 * d2) / area
                below = min(max(int(math.ceil(d - 0.5)), 0), G)
                hist[ib, ic, below] += sgn
                if below < first[ib, ic]:
                    first[ib, ic] = below
                if below > last[ib, ic]:
                    last[ib, ic] = below


@njit(cache=True, nogil=True, inline="always")
def _column_counts(hist, ib, ic, G, col):
    """Signed crossing counts of the rays along +a and -a from the G voxel centres of the
    column (ib, ic) of ``hist`` (``_axis_histogram``): ``col[0, ia]`` (+a) and ``col[1, ia]``
    (-a), with ``col [2, G]`` int32."""
    total = 0
    for ia in range(G + 1):
        total += hist[ib, ic, ia]
    prefix = 0
    for ia in range(G):
        prefix += hist[ib, ic, ia]  # crossings at or below this centre
        col[0, ia] = total - prefix
        col[1, ia] = -prefix


@njit(cache=True, nogil=True, inline="always")
def _voxel_of(a, ia, ib, ic):
    """Grid index (x, y, z) of the voxel at ``ia`` along axis ``a`` in column (ib, ic)."""
    if a == 0:
        return ia, ib, ic
    if a == 1:
        return ic, ia, ib
    return ib, ic, ia


@njit(cache=True, nogil=True)
def rays_kernel(vi, f, G, crossings, nonzero):
    """Signed crossing counts of the six axis rays (+x, -x, +y, -y, +z, -z) from every voxel
    centre (see ``axis_ray_crossings``): written into ``crossings [6, G, G, G]`` int32 if it
    has that shape (pass ``[6, 0, 0, 0]`` to skip them), and the number of rays with a non-zero
    count added into ``nonzero [G, G, G]`` uint8 (zeroed by the caller). ``rays_spans_kernel``
    also marks the spanned voxels."""
    rays_spans_kernel(vi, f, G, crossings, nonzero, np.zeros((0, 0, 0), dtype=np.bool_))


@njit(cache=True, nogil=True)
def rays_spans_kernel(vi, f, G, crossings, nonzero, spanned):
    """``rays_kernel``, and sets ``spanned [G, G, G]`` bool (zeroed by the caller; pass
    ``[0, 0, 0]`` to skip it) True at every voxel whose centre lies between two crossings of one
    axis line: some triangle on the ray along +a and some on the ray along -a, for some axis a
    (a crossing exactly at the centre counts on the -a side). A point inside a closed surface is
    spanned along every axis; a voxel cell entirely outside the bounding box of the triangles
    (its centre beyond their extent along some axis, so no line through it meets one on both
    sides) is spanned along none."""
    full = crossings.shape[1] == G
    spans = spanned.shape[0] == G
    hist = np.empty((G, G, G + 1), dtype=np.int32)
    first = np.empty((G, G), dtype=np.int32)
    last = np.empty((G, G), dtype=np.int32)
    col = np.empty((2, G), dtype=np.int32)
    for a in range(3):
        _axis_histogram(vi, f, G, a, hist, first, last)
        for ib in range(G):
            for ic in range(G):
                _column_counts(hist, ib, ic, G, col)
                lo, hi = first[ib, ic], last[ib, ic]  # spanned along a: lo <= ia < hi
                for ia in range(G):
                    x, y, z = _voxel_of(a, ia, ib, ic)
                    if full:
                        crossings[2 * a, x, y, z] = col[0, ia]
                        crossings[2 * a + 1, x, y, z] = col[1, ia]
                    nonzero[x, y, z] += (col[0, ia] != 0) + (col[1, ia] != 0)
                    if spans and lo <= ia < hi:
                        spanned[x, y, z] = True
