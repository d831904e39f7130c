"""numba kernels of rule 2 of ``sc3d_data.voxel.voxelize``: generalized winding numbers at
query points, fast (Barill et al. 2018, as libigl's fast winding number: a loose octree of
triangle clusters with second-order expansions of their fields, walked by blocks of query
points) and exact (the sum of all solid angles, the tests' reference).

Meshes come as vertices ``vi [n, 3]`` float64 in the units of a grid spanning ``[0, G]^3`` and
faces ``f [m, 3]`` int64, read in place: no ``[m, 3, 3]`` array of corners is built, which on
a large mesh would be a fresh allocation of megabytes per call.

Length: one module because the tree build, the cluster expansions, the block walk and the
exact solid angles call each other, and numba's on-disk cache (``cache=True``) is checked
against the source file of the cached kernel only: a kernel that called a helper in another
file would go on running its stale compiled copy after that file changed. Each family of
kernels (surface, rays, fill, winding numbers) is therefore one self-contained file.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


TREE_DEPTH = 5
#: index pairs (j, k) of the symmetric second moments
_JJ = np.array([0, 1, 2, 0, 0, 1])
_KK = np.array([0, 1, 2, 1, 2, 2])
#: a cluster of triangles (or one triangle) is replaced by the second-order expansion of its
#: field when the query point is farther than BETA times its radius from its centre (libigl's
#: fast winding number uses 2)
BETA = 2.0


@njit(cache=True, nogil=True, inline="always")
def _solid_angle_args(tri, t, px, py, pz):
    """(y, x) with the signed solid angle of triangle ``t`` seen from (px, py, pz) equal to
    2 atan2(y, x) (Van Oosterom & Strackee)."""
    ax, ay, az = tri[t, 0, 0] - px, tri[t, 0, 1] - py, tri[t, 0, 2] - pz
    bx, by, bz = tri[t, 1, 0] - px, tri[t, 1, 1] - py, tri[t, 1, 2] - pz
    cx, cy, cz = tri[t, 2, 0] - px, tri[t, 2, 1] - py, tri[t, 2, 2] - pz
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
    div = la * lb * lc + (ax * bx + ay * by + az * bz) * lc \
        + (bx * cx + by * cy + bz * cz) * la + (cx * ax + cy * ay + cz * az) * lb
    return det, div


@njit(cache=True, nogil=True, inline="always")
def _solid_angle(tri, t, px, py, pz):
    """Signed solid angle of triangle ``t`` seen from (px, py, pz)."""
    det, div = _solid_angle_args(tri, t, px, py, pz)
    return 2.0 * math.atan2(det, div)


@njit(cache=True, nogil=True, inline="always")
def _centroid_area(vi, f, t):
    """Centroid (c0, c1, c2) and vector area (n0, n1, n2: half the cross product of two edges)
    of triangle ``t``."""
    c0 = (vi[f[t, 0], 0] + vi[f[t, 1], 0] + vi[f[t, 2], 0]) / 3.0
    c1 = (vi[f[t, 0], 1] + vi[f[t, 1], 1] + vi[f[t, 2], 1]) / 3.0
    c2 = (vi[f[t, 0], 2] + vi[f[t, 1], 2] + vi[f[t, 2], 2]) / 3.0
    ux, uy, uz = vi[f[t, 1], 0] - vi[f[t, 0], 0], vi[f[t, 1], 1] - vi[f[t, 0], 1], vi[f[t, 1], 2] - vi[f[t, 0], 2]
    vx, vy, vz = vi[f[t, 2], 0] - vi[f[t, 0], 0], vi[f[t, 2], 1] - vi[f[t, 0], 1], vi[f[t, 2], 2] - vi[f[t, 0], 2]
    return c0, c1, c2, 0.5 * (uy * vz - uz * vy), 0.5 * (uz * vx - ux * vz), 0.5 * (ux * vy - uy * vx)


@njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def winding_kernel(vi, f, pts, G, beta):
    """Generalized winding numbers of the triangle soup (``vi``, ``f``) at ``pts [P, 3]``
    (both in the units of a grid spanning [0, G]^3): the fast winding number of Barill et al.
    2018 (as libigl's): exact solid angles of the triangles near a point; clusters of a loose
    octree farther than ``beta`` times their radius by the Taylor expansion of their field to
    second order."""
    start, child, node, order = _winding_tree(vi, f, G)
    return _winding_queries(vi, f, pts, beta, start, child, node, order, G / 8.0)


@njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _winding_tree(vi, f, G):
    """The loose octree of ``winding_kernel`` and the expansions of its clusters.

    Returns ``start [n + 1]`` (cluster c owns the triangles ``order[start[c]:start[c + 1]]``),
    ``child [n, 8]`` (-1: none), ``node [n, 44]`` (one packed row per cluster, see below) and
    ``order [m]``. Per-triangle quantities (centroid, vector area) are recomputed in each pass
    over the triangles rather than stored: the passes read the triangles in order and write only
    per-cluster sums, so a large mesh touches little fresh memory."""
    m = f.shape[0]
    # dense ids of the octree cells of all levels: level l has (2^l)^3 cells from off[l]
    off = np.zeros(TREE_DEPTH + 2, dtype=np.int64)
    for lv in range(TREE_DEPTH + 1):
        s = 1 << lv
        off[lv + 1] = off[lv] + s * s * s
    n_dense = off[TREE_DEPTH + 1]
    node_of_tri = np.empty(m, dtype=np.int64)  # dense cell ids first, compact ids below
    compact = np.full(n_dense, -1, dtype=np.int64)
    for t in range(m):
        tc0, tc1, tc2, _, _, _ = _centroid_area(vi, f, t)
        rt2 = 0.0
        for q in range(3):
            dx, dy, dz = vi[f[t, q], 0] - tc0, vi[f[t, q], 1] - tc1, vi[f[t, q], 2] - tc2
            rt2 = max(rt2, dx * dx + dy * dy + dz * dz)
        rt = math.sqrt(rt2)  # sqrt is monotonic: the largest of the three square roots
        # loose octree: the deepest level whose cells are at least twice the triangle's radius,
        # so one large triangle does not make a cluster of small ones look near
        lv = TREE_DEPTH
        while lv > 0 and rt > 0.5 * G / (1 << lv):
            lv -= 1
        s = 1 << lv
        i = min(max(int(math.floor(tc0 / G * s)), 0), s - 1)
        j = min(max(int(math.floor(tc1 / G * s)), 0), s - 1)
        k = min(max(int(math.floor(tc2 / G * s)), 0), s - 1)
        node_of_tri[t] = off[lv] + (i * s + j) * s + k
        while True:  # mark the cell and its ancestors as used
            dn = off[lv] + (i * s + j) * s + k
            if compact[dn] == 0:
                break
            compact[dn] = 0
            if lv == 0:
                break
            lv -= 1
            s >>= 1
            i >>= 1
            j >>= 1
            k >>= 1
    # compact ids for the used cells, in level order (parents before children)
    n = 0
    for dn in range(n_dense):
        if compact[dn] == 0:
            compact[dn] = n
            n += 1
    parent = np.full(n, -1, dtype=np.int64)
    child = np.full((n, 8), -1, dtype=np.int64)
    for lv in range(1, TREE_DEPTH + 1):
        s = 1 << lv
        for dn in range(off[lv], off[lv + 1]):
            c = compact[dn]
            if c < 0:
                continue
            loc = dn - off[lv]
            i, j, k = loc // (s * s), (loc // s) % s, loc % s
            h = s >> 1
            pc = compact[off[lv - 1] + ((i >> 1) * h + (j >> 1)) * h + (k >> 1)]
            parent[c] = pc
            child[pc, (i & 1) * 4 + (j & 1) * 2 + (k & 1)] = c
    start = np.zeros(n + 1, dtype=np.int64)
    for t in range(m):
        node_of_tri[t] = compact[node_of_tri[t]]
        start[node_of_tri[t] + 1] += 1
    for c in range(n):
        start[c + 1] += start[c]
    fill = start[:n].copy()
    order = np.empty(m, dtype=np.int64)
    for t in range(m):
        order[fill[node_of_tri[t]]] = t
        fill[node_of_tri[t]] += 1
    # cluster sums: area, area-weighted centre (plain centroid mean for zero area), vector area
    area = np.zeros(n)
    cnt = np.zeros(n)
    cen = np.zeros((n, 3))
    plain = np.zeros((n, 3))
    nrm = np.zeros((n, 3))
    for t in range(m):
        c = node_of_tri[t]
        tc0, tc1, tc2, n0, n1, n2 = _centroid_area(vi, f, t)
        a = math.sqrt(n0 ** 2 + n1 ** 2 + n2 ** 2)
        area[c] += a
        cnt[c] += 1
        cen[c, 0] += a * tc0
        cen[c, 1] += a * tc1
        cen[c, 2] += a * tc2
        plain[c, 0] += tc0
        plain[c, 1] += tc1
        plain[c, 2] += tc2
        nrm[c, 0] += n0
        nrm[c, 1] += n1
        nrm[c, 2] += n2
    for c in range(n - 1, 0, -1):  # children have larger ids than their parents
        pc = parent[c]
        area[pc] += area[c]
        cnt[pc] += cnt[c]
        for d in range(3):
            cen[pc, d] += cen[c, d]
            plain[pc, d] += plain[c, d]
            nrm[pc, d] += nrm[c, d]
    for c in range(n):
        for d in range(3):
            cen[c, d] = cen[c, d] / area[c] if area[c] > 0 else plain[c, d] / cnt[c]
    # radius (farthest vertex from the centre) and moments about the centre: own triangles first
    rad = np.zeros(n)
    quad = np.zeros((n, 3, 3))   # first moments: integral of n_i s_j dA, s = x - centre
    cub = np.zeros((n, 3, 6))    # second moments: integral of n_i s_j s_k dA, (j, k) in _JJ, _KK
    for t in range(m):
        c = node_of_tri[t]
        tc0, tc1, tc2, n0, n1, n2 = _centroid_area(vi, f, t)
        e0, e1, e2 = cen[c, 0], cen[c, 1], cen[c, 2]
        g0, g1, g2 = tc0 - e0, tc1 - e1, tc2 - e2  # the centroid about the cluster's centre
        # integral over the triangle of s s^T = area / 12 (sum_v s_v s_v^T + 9 s_c s_c^T)
        m00, m11, m22 = 9.0 * g0 * g0, 9.0 * g1 * g1, 9.0 * g2 * g2
        m01, m02, m12 = 9.0 * g0 * g1, 9.0 * g0 * g2, 9.0 * g1 * g2
        far2 = 0.0
        for v in range(3):
            s0, s1, s2 = vi[f[t, v], 0] - e0, vi[f[t, v], 1] - e1, vi[f[t, v], 2] - e2
            far2 = max(far2, s0 * s0 + s1 * s1 + s2 * s2)
            m00 += s0 * s0
            m11 += s1 * s1
            m22 += s2 * s2
            m01 += s0 * s1
            m02 += s0 * s2
            m12 += s1 * s2
        rad[c] = max(rad[c], math.sqrt(far2))
        for d in range(3):
            nd = n0 if d == 0 else (n1 if d == 1 else n2)
            quad[c, d, 0] += nd * g0
            quad[c, d, 1] += nd * g1
            quad[c, d, 2] += nd * g2
            cub[c, d, 0] += nd * m00 / 12.0  # (j, k) in the order of _JJ, _KK
            cub[c, d, 1] += nd * m11 / 12.0
            cub[c, d, 2] += nd * m22 / 12.0
            cub[c, d, 3] += nd * m01 / 12.0
            cub[c, d, 4] += nd * m02 / 12.0
            cub[c, d, 5] += nd * m12 / 12.0
    for c in range(n - 1, 0, -1):  # then the children's, shifted: s_parent = s_child + delta
        pc = parent[c]
        dl0, dl1, dl2 = cen[c, 0] - cen[pc, 0], cen[c, 1] - cen[pc, 1], cen[c, 2] - cen[pc, 2]
        delta = (dl0, dl1, dl2)
        rad[pc] = max(rad[pc], math.sqrt(dl0 * dl0 + dl1 * dl1 + dl2 * dl2) + rad[c])
        for d in range(3):
            for q in range(6):
                jj, kk = _JJ[q], _KK[q]
                cub[pc, d, q] += cub[c, d, q] + quad[c, d, jj] * delta[kk] \
                    + quad[c, d, kk] * delta[jj] + nrm[c, d] * delta[jj] * delta[kk]
            for e in range(3):
                quad[pc, d, e] += quad[c, d, e] + nrm[c, d] * delta[e]
    # one packed row per cluster for the queries: centre, radius, vector area N, tr T, u, v
    # (u_k = sum_i C_iik, v_i = sum_j C_ijj), T (row-major), C (3 x 6, off-diagonal pairs doubled)
    node = np.empty((n, 44))
    for c in range(n):
        for d in range(3):
            node[c, d] = cen[c, d]
            node[c, 4 + d] = nrm[c, d]
            node[c, 8 + d] = 0.0
            node[c, 11 + d] = 0.0
        node[c, 3] = rad[c]
        node[c, 7] = quad[c, 0, 0] + quad[c, 1, 1] + quad[c, 2, 2]
        for q in range(6):
            jj, kk = _JJ[q], _KK[q]
            for d in range(3):
                cq = cub[c, d, q]
                node[c, 26 + 6 * d + q] = cq if jj == kk else 2.0 * cq
                if jj == kk:
                    node[c, 11 + d] += cq      # v_d
                if d == jj:
                    node[c, 8 + kk] += cq      # u_k: C_{d d k}
                if d == kk and jj != kk:
                    node[c, 8 + jj] += cq      # and its mirror C_{d k j}
        for d in range(3):
            for e in range(3):
                node[c, 14 + 3 * d + e] = quad[c, d, e]
    return start, child, node, order


@njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _fill_cluster(vi, f, order, lo, hi, beta, tdat, tri_s):
    """Rows ``lo:hi`` (one cluster's own triangles, cluster order) of ``tri_s [m, 3, 3]`` (the
    triangles) and ``tdat [m, 17]``: centroid, (beta * radius)^2, vector area N, M N, tr M, M
    (xx yy zz xy xz yz) with M = 1/12 sum_v s_v s_v^T about the centroid: the triangle's own
    second-order expansion."""
    for q in range(lo, hi):
        t = order[q]
        tc0, tc1, tc2, n0, n1, n2 = _centroid_area(vi, f, t)
        m0 = m1 = m2 = m3 = m4 = m5 = 0.0
        rt2 = 0.0
        for v in range(3):
            for d in range(3):
                tri_s[q, v, d] = vi[f[t, v], d]
            s0, s1, s2 = vi[f[t, v], 0] - tc0, vi[f[t, v], 1] - tc1, vi[f[t, v], 2] - tc2
            rt2 = max(rt2, s0 * s0 + s1 * s1 + s2 * s2)
            m0 += s0 * s0 / 12.0
            m1 += s1 * s1 / 12.0
            m2 += s2 * s2 / 12.0
            m3 += s0 * s1 / 12.0
            m4 += s0 * s2 / 12.0
            m5 += s1 * s2 / 12.0
        br = beta * math.sqrt(rt2)
        tdat[q, 0], tdat[q, 1], tdat[q, 2], tdat[q, 3] = tc0, tc1, tc2, br * br
        tdat[q, 4], tdat[q, 5], tdat[q, 6] = n0, n1, n2
        tdat[q, 7] = m0 * n0 + m3 * n1 + m4 * n2
        tdat[q, 8] = m3 * n0 + m1 * n1 + m5 * n2
        tdat[q, 9] = m4 * n0 + m5 * n1 + m2 * n2
        tdat[q, 10] = m0 + m1 + m2
        tdat[q, 11], tdat[q, 12], tdat[q, 13] = m0, m1, m2
        tdat[q, 14], tdat[q, 15], tdat[q, 16] = m3, m4, m5


#: 2^-600 and 2^600: exact rescalings of the running product of ``_winding_queries``
_TINY = 2.0 ** -600
_HUGE = 2.0 ** 600


@njit(cache=True, nogil=True, inline="always")
def _cluster_term(node, c, px, py, pz):
    """Second-order Taylor expansion of cluster ``c``'s field at (px, py, pz), times 4 pi.

    The terms libigl's fast winding number uses. With R = centre - point, D = |R|,
    g(r) = r / |r|^3, s = x - centre:
    w = N.g(R) + sum_ij T_ij d_j g_i(R) + 1/2 sum_ijk C_ijk d_j d_k g_i(R),
    T_ij = int n_i s_j dA, C_ijk = int n_i s_j s_k dA, which gives
    (N.R + tr T) / D^3 - 3 R.T.R / D^5 - 3/2 (2 R.u + R.v) / D^5 + 15/2 C(R,R,R) / D^7."""
    r0, r1, r2 = node[c, 0] - px, node[c, 1] - py, node[c, 2] - pz
    d2 = r0 * r0 + r1 * r1 + r2 * r2
    dist = math.sqrt(d2)
    d3 = d2 * dist
    d5 = d3 * d2
    q0, q1, q2 = r0 * r0, r1 * r1, r2 * r2
    q3, q4, q5 = r0 * r1, r0 * r2, r1 * r2
    rc0 = node[c, 26] * q0 + node[c, 27] * q1 + node[c, 28] * q2 + node[c, 29] * q3 + node[c, 30] * q4 + node[c, 31] * q5
    rc1 = node[c, 32] * q0 + node[c, 33] * q1 + node[c, 34] * q2 + node[c, 35] * q3 + node[c, 36] * q4 + node[c, 37] * q5
    rc2 = node[c, 38] * q0 + node[c, 39] * q1 + node[c, 40] * q2 + node[c, 41] * q3 + node[c, 42] * q4 + node[c, 43] * q5
    rrr = r0 * rc0 + r1 * rc1 + r2 * rc2
    rtr = r0 * (node[c, 14] * r0 + node[c, 15] * r1 + node[c, 16] * r2) \
        + r1 * (node[c, 17] * r0 + node[c, 18] * r1 + node[c, 19] * r2) \
        + r2 * (node[c, 20] * r0 + node[c, 21] * r1 + node[c, 22] * r2)
    ru = r0 * node[c, 8] + r1 * node[c, 9] + r2 * node[c, 10]
    rv = r0 * node[c, 11] + r1 * node[c, 12] + r2 * node[c, 13]
    return (node[c, 4] * r0 + node[c, 5] * r1 + node[c, 6] * r2 + node[c, 7]) / d3 \
        - (3.0 * rtr + 1.5 * (2.0 * ru + rv)) / d5 + 7.5 * rrr / (d5 * d2)


@njit(cache=True, nogil=True, inline="always")
def _triangle_term(tdat, q, px, py, pz):
    """Triangle ``q``'s own second-order expansion at (px, py, pz) (T = 0), times 4 pi."""
    r0, r1, r2 = tdat[q, 0] - px, tdat[q, 1] - py, tdat[q, 2] - pz
    d2 = r0 * r0 + r1 * r1 + r2 * r2
    d5 = d2 * d2 * math.sqrt(d2)
    nr = tdat[q, 4] * r0 + tdat[q, 5] * r1 + tdat[q, 6] * r2
    rmr = tdat[q, 11] * r0 * r0 + tdat[q, 12] * r1 * r1 + tdat[q, 13] * r2 * r2 \
        + 2.0 * (tdat[q, 14] * r0 * r1 + tdat[q, 15] * r0 * r2 + tdat[q, 16] * r1 * r2)
    ru = tdat[q, 7] * r0 + tdat[q, 8] * r1 + tdat[q, 9] * r2
    return nr * d2 / d5 - 1.5 * (2.0 * ru + nr * tdat[q, 10]) / d5 + 7.5 * nr * rmr / (d5 * d2)


@njit(cache=True, nogil=True, inline="always")
def _angle_factor(tri_s, q, px, py, pz):
    """x + iy with triangle ``q``'s solid angle at (px, py, pz) = 2 atan2(y, x), turned by
    whole quarter turns (exact: swaps and sign changes) into the first quadrant: returns the
    turned x, y and the number of quarter turns (a float). A point on a vertex (x = y = 0,
    atan2 0) gives 1 + 0i."""
    y, x = _solid_angle_args(tri_s, q, px, py, pz)
    if y >= 0.0:
        if x > 0.0:
            return x, y, 0.0
        if x == 0.0 and y == 0.0:
            return 1.0, 0.0, 0.0
        return y, -x, 1.0
    if x >= 0.0:
        return -y, x, -1.0
    return -x, -y, -2.0


@njit(cache=True, nogil=True, inline="always")
def _multiply_turned(acc, j, x, y, turns):
    """Multiplies the running product ``acc[j] = (re, im, quarter turns)`` of
    ``_winding_queries`` by a factor of ``_angle_factor``, and turns the product back into the
    first quadrant (it stays within a factor 2^600 of 1)."""
    pr, pim = acc[j, 0], acc[j, 1]
    pr, pim = pr * x - pim * y, pr * y + pim * x
    if pr < 0.0:  # the product left the first quadrant
        pr, pim = pim, -pr
        turns += 1.0
    size = abs(pr) + abs(pim)
    if size > _HUGE:
        pr *= _TINY
        pim *= _TINY
    elif size < _TINY:
        pr *= _HUGE
        pim *= _HUGE
    acc[j, 0], acc[j, 1] = pr, pim
    acc[j, 2] += turns


#: most query points evaluated together (one block)
_BLOCK = 64
#: relative margin by which a box distance must clear a cluster's radius to decide for a block
_MARGIN = 1e-9


@njit(cache=True, nogil=True, inline="always")
def _box_distances(lo, hi, x, y, z):
    """Squared distances from (x, y, z) to the nearest and the farthest point of box lo..hi."""
    near = 0.0
    far = 0.0
    for d in range(3):
        v = x if d == 0 else (y if d == 1 else z)
        a, b = lo[d] - v, v - hi[d]
        g = max(a, b, 0.0)
        near += g * g
        f = max(abs(a), abs(b))
        far += f * f
    return near, far


@njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _winding_queries(vi, f, pts, beta, start, child, node, order, cell):
    """Winding numbers ``[P]`` at ``pts [P, 3]`` from the tree of ``_winding_tree``.

    Query points are taken in blocks of at most ``_BLOCK`` that share a cube of side ``cell``,
    and the block walks the tree once: a cluster (or a near cluster's triangle) farther than
    its radius times ``beta`` from the whole box of the block (with a relative margin far
    above round-off) is expanded for every point, one nearer than that from the whole box is
    opened for every point, and only the others are decided point by point. Each point thus
    gets exactly the terms, in the same order, that its own walk would give.

    The per-triangle data of a cluster (``_fill_cluster``) is computed the first time some
    query point comes near it, so few queries on a large mesh touch few triangles.
    The exact solid angles 2 atan2(y_t, x_t) of the near triangles (Van Oosterom & Strackee)
    are summed as the argument of the product of the complex numbers x_t + i y_t: each factor
    is first turned by whole quarter turns into the first quadrant (exact: swaps and sign
    changes, counted), and so is the running product after each multiplication, so the sum is
    the quarter turns times pi / 2 plus one atan2 at the end, with no 2 pi ambiguity. This
    equals the sum of the atan2 terms up to round-off (a few 1e-16 per term) and costs a
    complex multiplication instead of an atan2 per triangle."""
    m = f.shape[0]
    P = pts.shape[0]
    tdat = np.empty((m, 17))
    tri_s = np.empty((m, 3, 3))
    ready = np.zeros(node.shape[0], dtype=np.bool_)
    out = np.zeros(P)
    if P == 0:
        return out
    # blocks: points sorted by their cube of side ``cell``
    lo = np.empty(3)
    hi = np.empty(3)
    for d in range(3):
        lo[d] = pts[:, d].min()
        hi[d] = pts[:, d].max()
    nc = np.empty(3, dtype=np.int64)
    for d in range(3):
        nc[d] = int((hi[d] - lo[d]) / cell) + 1
    key = np.empty(P, dtype=np.int64)
    for p in range(P):
        i = int((pts[p, 0] - lo[0]) / cell)
        j = int((pts[p, 1] - lo[1]) / cell)
        k = int((pts[p, 2] - lo[2]) / cell)
        key[p] = (i * nc[1] + j) * nc[2] + k
    perm = np.argsort(key, kind="mergesort")
    w = np.empty(_BLOCK)
    acc = np.empty((_BLOCK, 3))  # running product (re, im) and quarter turns per point
    # the active points of the open clusters: stacked segments of point ids and their
    # coordinates (contiguous, so that the loops over a segment vectorise), and scratch
    L = _BLOCK * (TREE_DEPTH + 2)
    ids = np.empty(L, dtype=np.int64)
    X = np.empty(L)
    Y = np.empty(L)
    Z = np.empty(L)
    tmp = np.empty(L)
    tmp_y = np.empty(L)
    tmp_t = np.empty(L)
    stack = np.empty((8 * (TREE_DEPTH + 2), 3), dtype=np.int64)  # cluster, its segment
    b0 = 0
    while b0 < P:
        b1 = b0 + 1
        while b1 < P and b1 - b0 < _BLOCK and key[perm[b1]] == key[perm[b0]]:
            b1 += 1
        nb = b1 - b0
        for d in range(3):
            lo[d] = np.inf
            hi[d] = -np.inf
        for j in range(nb):
            p = perm[b0 + j]
            X[j], Y[j], Z[j] = pts[p, 0], pts[p, 1], pts[p, 2]
            w[j] = 0.0
            acc[j, 0], acc[j, 1], acc[j, 2] = 1.0, 0.0, 0.0
            ids[j] = j
            lo[0], hi[0] = min(lo[0], X[j]), max(hi[0], X[j])
            lo[1], hi[1] = min(lo[1], Y[j]), max(hi[1], Y[j])
            lo[2], hi[2] = min(lo[2], Z[j]), max(hi[2], Z[j])
        stack[0, 0], stack[0, 1], stack[0, 2] = 0, 0, nb
        top = 1
        while top > 0:
            top -= 1
            c, s0, s1 = stack[top, 0], stack[top, 1], stack[top, 2]
            free = s1  # segments above s1 belonged to clusters already done
            br = beta * node[c, 3]
            br2 = br * br
            near2, far2 = _box_distances(lo, hi, node[c, 0], node[c, 1], node[c, 2])
            if near2 > br2 * (1.0 + _MARGIN):  # far from every point
                for i in range(s0, s1):
                    tmp[i] = _cluster_term(node, c, X[i], Y[i], Z[i])
                for i in range(s0, s1):
                    w[ids[i]] += tmp[i]
                continue
            if far2 >= br2 * (1.0 - _MARGIN):  # point by point; the near ones go on
                for i in range(s0, s1):
                    r0, r1, r2 = node[c, 0] - X[i], node[c, 1] - Y[i], node[c, 2] - Z[i]
                    if r0 * r0 + r1 * r1 + r2 * r2 > br2:
                        w[ids[i]] += _cluster_term(node, c, X[i], Y[i], Z[i])
                    else:
                        ids[free], X[free], Y[free], Z[free] = ids[i], X[i], Y[i], Z[i]
                        free += 1
                if free == s1:
                    continue
                s0, s1 = s1, free
            if start[c] < start[c + 1]:
                if not ready[c]:
                    _fill_cluster(vi, f, order, start[c], start[c + 1], beta, tdat, tri_s)
                    ready[c] = True
                for q in range(start[c], start[c + 1]):
                    near2, far2 = _box_distances(lo, hi, tdat[q, 0], tdat[q, 1], tdat[q, 2])
                    if near2 > tdat[q, 3] * (1.0 + _MARGIN):
                        for i in range(s0, s1):
                            tmp[i] = _triangle_term(tdat, q, X[i], Y[i], Z[i])
                        for i in range(s0, s1):
                            w[ids[i]] += tmp[i]
                    elif far2 < tdat[q, 3] * (1.0 - _MARGIN):
                        for i in range(s0, s1):
                            tmp[i], tmp_y[i], tmp_t[i] = _angle_factor(tri_s, q, X[i], Y[i], Z[i])
                        for i in range(s0, s1):
                            _multiply_turned(acc, ids[i], tmp[i], tmp_y[i], tmp_t[i])
                    else:
                        for i in range(s0, s1):
                            r0, r1, r2 = tdat[q, 0] - X[i], tdat[q, 1] - Y[i], tdat[q, 2] - Z[i]
                            if r0 * r0 + r1 * r1 + r2 * r2 > tdat[q, 3]:
                                w[ids[i]] += _triangle_term(tdat, q, X[i], Y[i], Z[i])
                            else:
                                x, y, t = _angle_factor(tri_s, q, X[i], Y[i], Z[i])
                                _multiply_turned(acc, ids[i], x, y, t)
            for q in range(8):
                if child[c, q] >= 0:
                    stack[top, 0], stack[top, 1], stack[top, 2] = child[c, q], s0, s1
                    top += 1
        for j in range(nb):
            ang = 2.0 * (acc[j, 2] * (0.5 * math.pi) + math.atan2(acc[j, 1], acc[j, 0]))
            out[perm[b0 + j]] = (w[j] + ang) / (4.0 * math.pi)
        b0 = b1
    return out


@njit(cache=True, nogil=True)
def winding_exact_kernel(tri, pts):
    """Exact generalized winding numbers (sum of all solid angles): the reference for tests."""
    out = np.zeros(pts.shape[0])
    for p in range(pts.shape[0]):
        px, py, pz = pts[p, 0], pts[p, 1], pts[p, 2]
        w = 0.0
        for t in range(tri.shape[0]):
            w += _solid_angle(tri, t, px, py, pz)
        out[p] = w / (4.0 * math.pi)
    return out
