"""The compiled pieces of sc3d_data.voxel.voxelize against slow references."""
from __future__ import annotations

import numpy as np
import trimesh
from scipy import ndimage

from sc3d_data.voxel import _kernels as K
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
            np.testing.assert_array_equal(K.fill_holes_kernel(occ), ndimage.binary_fill_holes(occ))
