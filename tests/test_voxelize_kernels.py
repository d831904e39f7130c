"""The compiled pieces of sc3d_data.voxel.voxelize against slow references."""
from __future__ import annotations

import numpy as np
import trimesh
from scipy import ndimage

from sc3d_data.voxel._fill_kernel import fill_holes_kernel
from sc3d_data.voxel._ray_kernel import rays_kernel
from sc3d_data.voxel._winding_kernels import winding_exact_kernel, winding_kernel
from sc3d_data.voxel.voxelize import winding_numbers


def test_fast_winding_numbers_match_exact_solid_angles():
    rng = np.random.default_rng(0)
    m = trimesh.creation.icosphere(subdivisions=4, radius=0.35)
    m.apply_translation([0.05, -0.02, 0.01])
    keep = m.triangles_center[:, 1] < 0.2  # open: the cap above y = 0.2 is gone
    faces = m.faces[keep]
    pts = rng.uniform(-0.5, 0.5, (400, 3))
    fast = winding_numbers(m.vertices, faces, pts)
    exact = winding_numbers(m.vertices, faces, pts, exact=True)
    assert np.abs(fast - exact).max() < 0.005  # libigl: 0.0014 on these points
    closed = winding_numbers(m.vertices, m.faces, np.array([[0.05, -0.02, 0.01], [0.45, 0.45, 0.45]]))
    np.testing.assert_allclose(closed, [1.0, 0.0], atol=1e-3)


def test_fill_holes_kernel_equals_scipy():
    rng = np.random.default_rng(1)
    for G in (1, 2, 7, 32):
        for p in (0.0, 0.05, 0.3, 0.6, 1.0):
            occ = rng.random((G, G, G)) < p
            if 0 < p < 0.1:
                occ = ndimage.binary_dilation(occ)
            np.testing.assert_array_equal(fill_holes_kernel(occ), ndimage.binary_fill_holes(occ))


def test_rays_kernel_counts_the_nonzero_crossings():
    m = trimesh.creation.box(extents=(0.5, 0.3, 0.4))
    m.apply_translation([0.02, -0.03, 0.05])
    for faces in (m.faces, m.faces[2:]):  # closed, and open (two faces gone)
        vi, f = (m.vertices + 0.5) * 16, np.ascontiguousarray(faces)
        crossings = np.zeros((6, 16, 16, 16), dtype=np.int32)
        nonzero = np.zeros((16, 16, 16), dtype=np.uint8)
        rays_kernel(vi, f, 16, crossings, nonzero)
        np.testing.assert_array_equal(nonzero, (crossings != 0).sum(0))
        alone = np.zeros((16, 16, 16), dtype=np.uint8)  # without the crossing counts
        rays_kernel(vi, f, 16, np.zeros((6, 0, 0, 0), dtype=np.int32), alone)
        np.testing.assert_array_equal(alone, nonzero)
        if len(faces) == 12:  # closed box: all six rays from inside, none from outside
            assert set(np.unique(nonzero)) == {0, 6}
            inside = np.zeros((16, 16, 16), bool)
            lo = np.ceil((m.bounds[0] + 0.5) * 16 - 0.5).astype(int)
            hi = np.floor((m.bounds[1] + 0.5) * 16 - 0.5).astype(int)
            inside[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1] = True
            np.testing.assert_array_equal(nonzero == 6, inside)


def test_winding_without_expansions_equals_the_sum_of_solid_angles():
    """beta = 1e9 opens every cluster, so the fast kernel sums the exact solid angles of all
    triangles: through the complex product of quarter-turned factors (``_winding_queries``),
    which must equal the plain sum of atan2 terms (``winding_exact_kernel``), also where the
    angles wrap around many times (points near the surface of a closed mesh, w = 1) and for a
    point on a vertex (a zero factor, atan2(0, 0) = 0)."""
    rng = np.random.default_rng(2)
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    G = 32
    for faces in (m.faces, m.faces[:, ::-1], m.faces[m.triangles_center[:, 2] < 0.1]):
        vi, f = (m.vertices + 0.5) * G, np.ascontiguousarray(faces)
        dirs = rng.normal(size=(60, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        radii = np.r_[rng.uniform(0.05, 0.295, 30), rng.uniform(0.305, 0.8, 30)]
        pts = np.vstack([(dirs * radii[:, None] + 0.5) * G, (m.vertices[:1] + 0.5) * G])
        fast = winding_kernel(vi, f, pts, float(G), 1e9)
        exact = winding_exact_kernel(vi[f], pts)
        np.testing.assert_allclose(fast, exact, rtol=0, atol=1e-12)
        if len(faces) == len(m.faces):  # closed: +-1 inside, 0 outside, to round-off
            sign = 1.0 if faces is m.faces else -1.0
            np.testing.assert_allclose(fast[:30], sign, atol=1e-12)
            np.testing.assert_allclose(fast[30:60], 0.0, atol=1e-12)


def test_block_walk_decides_each_point_as_alone():
    """Points walked together (one block) get the same value as each walked alone, also when
    a cluster is near some of them and far from others (the point-by-point fallback): one
    triangle of radius 1 (voxel units) and, on its axis, a point at 1.9 (nearer than
    beta * radius = 2: exact solid angle) and one at 2.1 (farther: the triangle's expansion)."""
    c = np.array([10.0, 10.0, 10.0])
    ang = np.deg2rad([90.0, 210.0, 330.0])
    vi = c + np.stack([np.cos(ang), np.sin(ang), np.zeros(3)], axis=1)
    f = np.array([[0, 1, 2]])
    pts = c + np.array([[0.0, 0.0, 1.9], [0.0, 0.0, 2.1]])
    together = winding_kernel(vi, f, pts, 32.0, 2.0)
    alone = np.array([winding_kernel(vi, f, p[None], 32.0, 2.0)[0] for p in pts])
    np.testing.assert_allclose(together, alone, rtol=0, atol=1e-15)
    exact = winding_exact_kernel(vi[f], pts)
    assert abs(together[0] - exact[0]) < 1e-14  # near: the exact solid angle
    assert 1e-7 < abs(together[1] - exact[1]) < 1e-3  # far: the expansion, close to exact
    # a larger cloud near a sphere's surface: many blocks, clusters of every kind
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    vi, f = (m.vertices + 0.5) * 32, np.ascontiguousarray(m.faces[m.triangles_center[:, 1] < 0.15])
    cloud = np.random.default_rng(3).uniform(4, 28, (300, 3))
    together = winding_kernel(vi, f, cloud, 32.0, 2.0)
    alone = np.array([winding_kernel(vi, f, p[None], 32.0, 2.0)[0] for p in cloud])
    np.testing.assert_allclose(together, alone, rtol=0, atol=1e-13)
    assert winding_kernel(vi, f, np.zeros((0, 3)), 32.0, 2.0).shape == (0,)
