"""numba kernels of sc3d_data.voxelize (compiled once, cached in __pycache__)."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

HALF = 0.5 + 1e-6


@njit(cache=True, nogil=True)
def surface_kernel(tri, G, grid):
    """Marks in ``grid [G, G, G]`` every voxel whose closed cube (half-size HALF) overlaps a
    triangle of ``tri [m, 3, 3]`` (voxel units): the separating-axis test of Akenine-Moeller."""
    for t in range(tri.shape[0]):
        x0, y0, z0 = tri[t, 0, 0], tri[t, 0, 1], tri[t, 0, 2]
        x1, y1, z1 = tri[t, 1, 0], tri[t, 1, 1], tri[t, 1, 2]
        x2, y2, z2 = tri[t, 2, 0], tri[t, 2, 1], tri[t, 2, 2]
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


@njit(cache=True, nogil=True)
def crossings_kernel(tri, G, out):
    """Signed crossing counts of the six axis rays from every voxel centre, ``out [6, G, G, G]``
    int32 (see ``axis_ray_crossings``)."""
    hist = np.zeros((G, G, G + 1), dtype=np.int32)
    for a in range(3):
        b = (a + 1) % 3
        c = (a + 2) % 3
        hist[:] = 0
        for t in range(tri.shape[0]):
            b0, b1, b2 = tri[t, 0, b], tri[t, 1, b], tri[t, 2, b]
            c0, c1, c2 = tri[t, 0, c], tri[t, 1, c], tri[t, 2, c]
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
            d0, d1, d2 = tri[t, 0, a], tri[t, 1, a], tri[t, 2, a]
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
        for ib in range(G):
            for ic in range(G):
                total = 0
                for ia in range(G + 1):
                    total += hist[ib, ic, ia]
                prefix = 0
                for ia in range(G):
                    prefix += hist[ib, ic, ia]  # crossings at or below this centre
                    if a == 0:
                        out[0, ia, ib, ic] = total - prefix
                        out[1, ia, ib, ic] = -prefix
                    elif a == 1:
                        out[2, ic, ia, ib] = total - prefix
                        out[3, ic, ia, ib] = -prefix
                    else:
                        out[4, ib, ic, ia] = total - prefix
                        out[5, ib, ic, ia] = -prefix


#: octree depth of the winding-number tree: leaves are 1/32 of the grid cube per axis
TREE_DEPTH = 5
#: a cluster of triangles is replaced by its dipole when the query point is farther than
#: BETA times the cluster's radius from its centre (libigl's fast winding number uses 2)
BETA = 2.0


@njit(cache=True, nogil=True, inline="always")
def _solid_angle(tri, t, px, py, pz):
    """Signed solid angle of triangle ``t`` seen from (px, py, pz) (Van Oosterom & Strackee)."""
    ax, ay, az = tri[t, 0, 0] - px, tri[t, 0, 1] - py, tri[t, 0, 2] - pz
    bx, by, bz = tri[t, 1, 0] - px, tri[t, 1, 1] - py, tri[t, 1, 2] - pz
    cx, cy, cz = tri[t, 2, 0] - px, tri[t, 2, 1] - py, tri[t, 2, 2] - pz
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
    div = la * lb * lc + (ax * bx + ay * by + az * bz) * lc \
        + (bx * cx + by * cy + bz * cz) * la + (cx * ax + cy * ay + cz * az) * lb
    return 2.0 * math.atan2(det, div)


@njit(cache=True, nogil=True)
def winding_kernel(tri, pts, G, beta):
    """Generalized winding numbers of the triangle soup ``tri [m, 3, 3]`` at ``pts [P, 3]``
    (both in voxel units of a grid spanning [0, G]): exact solid angles of the triangles near a
    point, first-order (dipole) approximations of octree clusters far from it (Barill et al.
    2018, as libigl's fast winding number)."""
    m = tri.shape[0]
    n_lvl = TREE_DEPTH + 1
    # node offsets per level: level l has (2^l)^3 nodes
    off = np.zeros(n_lvl + 1, dtype=np.int64)
    for lv in range(n_lvl):
        s = 1 << lv
        off[lv + 1] = off[lv] + s * s * s
    n_nodes = off[n_lvl]
    area = np.zeros(n_nodes)
    cen = np.zeros((n_nodes, 3))       # area-weighted centre (sums first)
    plain = np.zeros((n_nodes, 3))     # unweighted centroid sums (fallback for zero area)
    nrm = np.zeros((n_nodes, 3))       # sum of vector areas
    cnt = np.zeros(n_nodes, dtype=np.int64)
    rad = np.zeros(n_nodes)
    quad = np.zeros((n_nodes, 3, 3))   # second moments: sum of vector area (x) (centroid - centre)
    varea = np.empty((m, 3))
    leaf = np.empty(m, dtype=np.int64)
    tc = np.empty((m, 3))
    for t in range(m):
        for d in range(3):
            tc[t, d] = (tri[t, 0, d] + tri[t, 1, d] + tri[t, 2, d]) / 3.0
        rt = 0.0
        for q in range(3):
            dx, dy, dz = tri[t, q, 0] - tc[t, 0], tri[t, q, 1] - tc[t, 1], tri[t, q, 2] - tc[t, 2]
            rt = max(rt, math.sqrt(dx * dx + dy * dy + dz * dz))
        # loose octree: the deepest level whose cells are at least twice the triangle's radius,
        # so one large triangle does not make a cluster of small ones look near
        lv = TREE_DEPTH
        while lv > 0 and rt > 0.5 * G / (1 << lv):
            lv -= 1
        s = 1 << lv
        li = min(max(int(math.floor(tc[t, 0] / G * s)), 0), s - 1)
        lj = min(max(int(math.floor(tc[t, 1] / G * s)), 0), s - 1)
        lk = min(max(int(math.floor(tc[t, 2] / G * s)), 0), s - 1)
        node = off[lv] + (li * s + lj) * s + lk
        leaf[t] = node
        ux, uy, uz = tri[t, 1, 0] - tri[t, 0, 0], tri[t, 1, 1] - tri[t, 0, 1], tri[t, 1, 2] - tri[t, 0, 2]
        vx, vy, vz = tri[t, 2, 0] - tri[t, 0, 0], tri[t, 2, 1] - tri[t, 0, 1], tri[t, 2, 2] - tri[t, 0, 2]
        nx, ny, nz = 0.5 * (uy * vz - uz * vy), 0.5 * (uz * vx - ux * vz), 0.5 * (ux * vy - uy * vx)
        a = math.sqrt(nx * nx + ny * ny + nz * nz)
        varea[t, 0] = nx
        varea[t, 1] = ny
        varea[t, 2] = nz
        area[node] += a
        nrm[node, 0] += nx
        nrm[node, 1] += ny
        nrm[node, 2] += nz
        cnt[node] += 1
        for d in range(3):
            cen[node, d] += a * tc[t, d]
            plain[node, d] += tc[t, d]
    # triangles sorted by leaf (counting sort)
    start = np.zeros(n_nodes + 1, dtype=np.int64)
    for t in range(m):
        start[leaf[t] + 1] += 1
    for i in range(n_nodes):
        start[i + 1] += start[i]
    fill = start.copy()
    order = np.empty(m, dtype=np.int64)
    for t in range(m):
        order[fill[leaf[t]]] = t
        fill[leaf[t]] += 1
    # sums of the parents, from the leaves up
    for lv in range(TREE_DEPTH - 1, -1, -1):
        s = 1 << lv
        for i in range(s):
            for j in range(s):
                for k in range(s):
                    node = off[lv] + (i * s + j) * s + k
                    for ci in range(2):
                        for cj in range(2):
                            for ck in range(2):
                                ch = off[lv + 1] + ((2 * i + ci) * 2 * s + 2 * j + cj) * 2 * s + 2 * k + ck
                                area[node] += area[ch]
                                cnt[node] += cnt[ch]
                                for d in range(3):
                                    cen[node, d] += cen[ch, d]
                                    plain[node, d] += plain[ch, d]
                                    nrm[node, d] += nrm[ch, d]
    for node in range(n_nodes):
        if cnt[node] == 0:
            continue
        for d in range(3):
            if area[node] > 0:
                cen[node, d] /= area[node]
            else:
                cen[node, d] = plain[node, d] / cnt[node]
    # radius of each leaf: farthest vertex of its triangles from its centre; parents bound children
    for t in range(m):
        node = leaf[t]
        for q in range(3):
            dx, dy, dz = tri[t, q, 0] - cen[node, 0], tri[t, q, 1] - cen[node, 1], tri[t, q, 2] - cen[node, 2]
            r = math.sqrt(dx * dx + dy * dy + dz * dz)
            if r > rad[node]:
                rad[node] = r
    for lv in range(TREE_DEPTH - 1, -1, -1):
        s = 1 << lv
        for i in range(s):
            for j in range(s):
                for k in range(s):
                    node = off[lv] + (i * s + j) * s + k
                    for ci in range(2):
                        for cj in range(2):
                            for ck in range(2):
                                ch = off[lv + 1] + ((2 * i + ci) * 2 * s + 2 * j + cj) * 2 * s + 2 * k + ck
                                if cnt[ch] == 0:
                                    continue
                                dx, dy, dz = cen[ch, 0] - cen[node, 0], cen[ch, 1] - cen[node, 1], cen[ch, 2] - cen[node, 2]
                                r = math.sqrt(dx * dx + dy * dy + dz * dz) + rad[ch]
                                if r > rad[node]:
                                    rad[node] = r
    for t in range(m):
        node = leaf[t]
        for d in range(3):
            for e in range(3):
                quad[node, d, e] += varea[t, d] * (tc[t, e] - cen[node, e])
    for lv in range(TREE_DEPTH - 1, -1, -1):
        s = 1 << lv
        for i in range(s):
            for j in range(s):
                for k in range(s):
                    node = off[lv] + (i * s + j) * s + k
                    if cnt[node] == 0:
                        continue
                    for ci in range(2):
                        for cj in range(2):
                            for ck in range(2):
                                ch = off[lv + 1] + ((2 * i + ci) * 2 * s + 2 * j + cj) * 2 * s + 2 * k + ck
                                if cnt[ch] == 0:
                                    continue
                                for d in range(3):
                                    for e in range(3):
                                        quad[node, d, e] += quad[ch, d, e] + nrm[ch, d] * (cen[ch, e] - cen[node, e])
    out = np.zeros(pts.shape[0])
    stack_lv = np.empty(8 * n_lvl + 8, dtype=np.int64)
    stack_ix = np.empty((8 * n_lvl + 8, 3), dtype=np.int64)
    for p in range(pts.shape[0]):
        px, py, pz = pts[p, 0], pts[p, 1], pts[p, 2]
        w = 0.0
        top = 0
        stack_lv[0] = 0
        stack_ix[0, 0] = 0
        stack_ix[0, 1] = 0
        stack_ix[0, 2] = 0
        top = 1
        while top > 0:
            top -= 1
            lv = stack_lv[top]
            i, j, k = stack_ix[top, 0], stack_ix[top, 1], stack_ix[top, 2]
            s = 1 << lv
            node = off[lv] + (i * s + j) * s + k
            if cnt[node] == 0:
                continue
            dx, dy, dz = cen[node, 0] - px, cen[node, 1] - py, cen[node, 2] - pz
            dist = math.sqrt(dx * dx + dy * dy + dz * dz)
            if dist > beta * rad[node]:
                # second-order expansion of the dipole field of the cluster about its centre
                d3 = dist * dist * dist
                tr = quad[node, 0, 0] + quad[node, 1, 1] + quad[node, 2, 2]
                rtr = (dx * (quad[node, 0, 0] * dx + quad[node, 0, 1] * dy + quad[node, 0, 2] * dz)
                       + dy * (quad[node, 1, 0] * dx + quad[node, 1, 1] * dy + quad[node, 1, 2] * dz)
                       + dz * (quad[node, 2, 0] * dx + quad[node, 2, 1] * dy + quad[node, 2, 2] * dz))
                w += (nrm[node, 0] * dx + nrm[node, 1] * dy + nrm[node, 2] * dz + tr) / d3 \
                    - 3.0 * rtr / (d3 * dist * dist)
            else:
                for q in range(start[node], start[node + 1]):
                    t = order[q]
                    w += _solid_angle(tri, t, px, py, pz)
                if lv < TREE_DEPTH:
                    for ci in range(2):
                        for cj in range(2):
                            for ck in range(2):
                                stack_lv[top] = lv + 1
                                stack_ix[top, 0] = 2 * i + ci
                                stack_ix[top, 1] = 2 * j + cj
                                stack_ix[top, 2] = 2 * k + ck
                                top += 1
        out[p] = w / (4.0 * math.pi)
    return out


@njit(cache=True, nogil=True)
def winding_exact_kernel(tri, pts):
    """Exact generalized winding numbers (sum of all solid angles): the reference for tests."""
    out = np.zeros(pts.shape[0])
    for p in range(pts.shape[0]):
        px, py, pz = pts[p, 0], pts[p, 1], pts[p, 2]
        w = 0.0
        for t in range(tri.shape[0]):
            ax, ay, az = tri[t, 0, 0] - px, tri[t, 0, 1] - py, tri[t, 0, 2] - pz
            bx, by, bz = tri[t, 1, 0] - px, tri[t, 1, 1] - py, tri[t, 1, 2] - pz
            cx, cy, cz = tri[t, 2, 0] - px, tri[t, 2, 1] - py, tri[t, 2, 2] - pz
            la = math.sqrt(ax * ax + ay * ay + az * az)
            lb = math.sqrt(bx * bx + by * by + bz * bz)
            lc = math.sqrt(cx * cx + cy * cy + cz * cz)
            det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
            div = la * lb * lc + (ax * bx + ay * by + az * bz) * lc \
                + (bx * cx + by * cy + bz * cz) * la + (cx * ax + cy * ay + cz * az) * lb
            w += 2.0 * math.atan2(det, div)
        out[p] = w / (4.0 * math.pi)
    return out


@njit(cache=True, nogil=True)
def fill_holes_kernel(occ):
    """``occ`` plus every empty voxel that no 6-connected path of empty voxels links to the
    grid's border (``scipy.ndimage.binary_fill_holes`` with its default structure)."""
    X, Y, Z = occ.shape
    outside = np.zeros(occ.shape, dtype=np.bool_)
    stack = np.empty((X * Y * Z, 3), dtype=np.int32)
    top = 0
    for i in range(X):
        for j in range(Y):
            for k in range(Z):
                if (i == 0 or j == 0 or k == 0 or i == X - 1 or j == Y - 1 or k == Z - 1) \
                        and not occ[i, j, k]:
                    outside[i, j, k] = True
                    stack[top, 0] = i
                    stack[top, 1] = j
                    stack[top, 2] = k
                    top += 1
    while top > 0:
        top -= 1
        i, j, k = stack[top, 0], stack[top, 1], stack[top, 2]
        for n in range(6):
            a, b, c = i, j, k
            if n == 0:
                a -= 1
            elif n == 1:
                a += 1
            elif n == 2:
                b -= 1
            elif n == 3:
                b += 1
            elif n == 4:
                c -= 1
            else:
                c += 1
            if a < 0 or b < 0 or c < 0 or a >= X or b >= Y or c >= Z:
                continue
            if occ[a, b, c] or outside[a, b, c]:
                continue
            outside[a, b, c] = True
            stack[top, 0] = a
            stack[top, 1] = b
            stack[top, 2] = c
            top += 1
    return ~outside
