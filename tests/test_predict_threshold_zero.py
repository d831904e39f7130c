"""``predict --threshold 0``: every voxel is occupied (``probabilities >= 0``), so the ``.obj`` must
be the whole grid's cube, as ``.binvox`` and ``.npz`` say, also where probabilities underflowed to
exactly 0.0 (sigmoid of a logit below about -88 in float32: a confident network's empty space, or
a prediction that is empty everywhere). Marching cubes at level 0 took those voxels for the zero
padding: an empty prediction gave an empty ``.obj`` ("no voxel reached the threshold") beside a
full ``.binvox``, and a partly zero one an ``.obj`` with holes where the ``.binvox`` is full."""
import numpy as np
import pytest


@pytest.mark.parametrize("case", ["all_zero", "some_zero"])
def test_threshold_zero_meshes_the_whole_cube_whatever_the_probabilities(case):
    from sc3d_train.evaluation.predict import voxel_mesh

    probs = np.zeros((8, 8, 8), dtype=np.float32)
    if case == "some_zero":
        probs[:4] = np.random.default_rng(0).uniform(0.01, 1.0, (4, 8, 8))
    verts, faces = voxel_mesh(probs, 0.0)
    assert len(faces) > 0, "an empty mesh for a grid that is occupied everywhere"
    np.testing.assert_allclose(verts.min(axis=0), [-0.5] * 3, atol=1e-6)
    np.testing.assert_allclose(verts.max(axis=0), [0.5] * 3, atol=1e-6)
    # only the cube's six faces: no vertex inside the grid (no hole around the zero voxels)
    assert np.isclose(np.abs(verts), 0.5, atol=1e-6).any(axis=1).all()
