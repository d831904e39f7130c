"""numba kernel of rule 1 of ``sc3d_data.voxel.voxelize``: the voxels a surface touches.

The triangles come as vertices ``vi [n, 3]`` float64 in voxel units (the grid spans
``[0, G]^3``, voxel ``(i, j, k)`` is the cube ``[i, i+1] x [j, j+1] x [k, k+1]``) and faces
``f [m, 3]`` int64, read in place (no ``[m, 3, 3]`` copy of the corners). Compiled once and
cached in ``__pycache__`` (``cache=True``; ``scripts/setup.sh`` compiles it at install).
"""
from __future__ import annotations

import math

from numba import njit


#: half-width of a voxel cube in voxel units, grown slightly so touching counts under round-off
HALF = 0.5 + 1e-6


@njit(cache=True, nogil=True)
def surface_kernel(vi, f, G, grid):
    """Marks in ``grid [G, G, G]`` every voxel whose closed cube (half-size HALF) overlaps a
    triangle (``vi [n, 3]``, ``f [m, 3]``): the separating-axis test of Akenine-Moeller."""
    for t in range(f.shape[0]):
        x0, y0, z0 = vi[f[t, 0], 0], vi[f[t, 0], 1], vi[f[t, 0], 2]
        x1, y1, z1 = vi[f[t, 1], 0], vi[f[t, 1], 1], vi[f[t, 1], 2]
        x2, y2, z2 = vi[f[t, 2], 0], vi[f[t, 2], 1], vi[f[t, 2], 2]
        mnx, mny, mnz = min(x0, x1, x2), min(y0, y1, y2), min(z0, z1, z2)
        mxx, mxy, mxz = max(x0, x1, x2), max(y0, y1, y2), max(z0, z1, z2)
        if mxx < -1e-6 or mxy < -1e-6 or mxz < -1e-6 or mnx > G + 1e-6 or mny > G + 1e-6 or mnz > G + 1e-6:
            continue
        lx = min(max(int(math.floor(mnx - 1e-6)), 0), G - 1)
        ly = min(max(int(math.floor(mny - 1e-6)), 0), G - 1)
        lz = min(max(int(math.floor(mnz - 1e-6)), 0), G - 1)
        hx = min(max(int(math.floor(mxx + 1e-6)), 0), G - 1)
        hy = min(max(int(math.floor(mxy + 1e-6)), 0), G - 1)
        hz = min(max(int(math.floor(mxz + 1e-6)), 0), G - 1)
        count = (hx - lx + 1) * (hy - ly + 1) * (hz - lz + 1)
        if count <= 2:
            # one voxel, or two: the triangle crosses the plane between them and touches both
            for i in range(lx, hx + 1):
                for j in range(ly, hy + 1):
                    for k in range(lz, hz + 1):
                        grid[i, j, k] = True
            continue
        e0x, e0y, e0z = x1 - x0, y1 - y0, z1 - z0
        e1x, e1y, e1z = x2 - x1, y2 - y1, z2 - z1
        e2x, e2y, e2z = x0 - x2, y0 - y2, z0 - z2
        nx = e0y * e1z - e0z * e1y
        ny = e0z * e1x - e0x * e1z
        nz = e0x * e1y - e0y * e1x
        rn = HALF * (abs(nx) + abs(ny) + abs(nz)) + 1e-12
        for i in range(lx, hx + 1):
            cx = i + 0.5
            for j in range(ly, hy + 1):
                cy = j + 0.5
                for k in range(lz, hz + 1):
                    if grid[i, j, k]:
                        continue
                    cz = k + 0.5
                    # plane of the triangle vs box
                    if abs(nx * (x0 - cx) + ny * (y0 - cy) + nz * (z0 - cz)) > rn:
                        continue
                    ax, ay, az = x0 - cx, y0 - cy, z0 - cz
                    bx, by, bz = x1 - cx, y1 - cy, z1 - cz
                    qx, qy, qz = x2 - cx, y2 - cy, z2 - cz
                    ok = True
                    for e in range(3):
                        if e == 0:
                            ex, ey, ez = e0x, e0y, e0z
                        elif e == 1:
                            ex, ey, ez = e1x, e1y, e1z
                        else:
                            ex, ey, ez = e2x, e2y, e2z
                        # axis e x X: projections ez*y - ey*z
                        p0, p1, p2 = ez * ay - ey * az, ez * by - ey * bz, ez * qy - ey * qz
                        r = HALF * (abs(ez) + abs(ey)) + 1e-12
                        if min(p0, p1, p2) > r or max(p0, p1, p2) < -r:
                            ok = False
                            break
                        # axis e x Y: ex*z - ez*x
                        p0, p1, p2 = ex * az - ez * ax, ex * bz - ez * bx, ex * qz - ez * qx
                        r = HALF * (abs(ex) + abs(ez)) + 1e-12
                        if min(p0, p1, p2) > r or max(p0, p1, p2) < -r:
                            ok = False
                            break
                        # axis e x Z: ey*x - ex*y
                        p0, p1, p2 = ey * ax - ex * ay, ey * bx - ex * by, ey * qx - ex * qy
                        r = HALF * (abs(ey) + abs(ex)) + 1e-12
                        if min(p0, p1, p2) > r or max(p0, p1, p2) < -r:
                            ok = False
                            break
                    if ok:
                        grid[i, j, k] = True
