"""Training-half defects of the twenty-fourth round (items of the last left-alone list and the
twenty-fourth attack); expected values are derived by hand, never from the code under test."""
from __future__ import annotations

import numpy as np


def test_the_predicted_mesh_stays_inside_the_grid_at_low_thresholds():
    """``predict``'s mesh is marching cubes of the zero-padded probabilities; at a threshold below
    half a border voxel's probability the surface crossed between that voxel's centre and the
    padding's, outside the grid's cube [-0.5, 0.5]^3 which the documentation promises (at
    ``--threshold 0`` on the padding itself, half a voxel out). By hand, an 8^3 grid (voxel
    centres at -0.5 + (i + 0.5)/8) with a 3^3 block of probability 1 in its low corner:

    - threshold 0.1: the inner faces cross 0.9 of the way from the centre of voxel 2 (-0.1875)
      to that of voxel 3 (-0.0625), at -0.075; the outer faces end on the cube's faces, -0.5;
    - threshold 0.5 (the control, unchanged): the inner faces half-way, -0.125; outer -0.5;
    - threshold 0 of probabilities all above 0: every voxel is occupied, so the surface is the
      cube's, from -0.5 to 0.5 on every axis.
    """
    from sc3d_train.evaluation.predict import voxel_mesh

    block = np.zeros((8, 8, 8), dtype=np.float32)
    block[:3, :3, :3] = 1.0
    for threshold, inner in ((0.1, -0.075), (0.5, -0.125)):
        verts, faces = voxel_mesh(block, threshold)
        assert len(faces) > 0
        np.testing.assert_allclose(verts.min(axis=0), [-0.5] * 3, atol=1e-6, err_msg=str(threshold))
        np.testing.assert_allclose(verts.max(axis=0), [inner] * 3, atol=1e-6, err_msg=str(threshold))
    everywhere = np.random.default_rng(0).uniform(0.01, 1.0, (8, 8, 8)).astype(np.float32)
    verts, faces = voxel_mesh(everywhere, 0.0)
    assert len(faces) > 0
    np.testing.assert_allclose(verts.min(axis=0), [-0.5] * 3, atol=1e-6)
    np.testing.assert_allclose(verts.max(axis=0), [0.5] * 3, atol=1e-6)
