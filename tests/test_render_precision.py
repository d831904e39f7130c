"""A mesh far from its origin (georeferenced or CAD coordinates) renders as the same mesh at its
origin: the renderer's float32 vertex positions must not carry the offset. Real renderer and
HDF5; the expected images are those of the same triangles without the offset (the normalisation
puts both in the same canonical place), not anything the code under test computes."""
from __future__ import annotations

import numpy as np
import pytest

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST


def _ellipsoid(offset: float):
    """An icosphere scaled to 0.5 x 0.3 x 0.2 (unequal axes: its views differ), moved by
    ``offset`` along x and z."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=3)
    m.apply_scale([0.5, 0.3, 0.2])
    m.apply_translation([offset, 0.0, offset])
    return m


@pytest.mark.parametrize("offset", [1e6, 1e9])
def test_a_mesh_far_from_its_origin_renders_as_it_does_at_the_origin(tmp_path, offset):
    """At 1e6 units float32 keeps 1/16 of a unit (the ellipsoid is 1 unit long): before the fix
    872 of ~10,300 mask pixels differed from the mesh at the origin; at 1e9 the mesh collapsed.
    Now images and masks equal those of the mesh at the origin, and the voxels too."""
    folder = tmp_path / "m" / "thing"
    folder.mkdir(parents=True)
    _ellipsoid(0.0).export(folder / "near.obj")
    _ellipsoid(offset).export(folder / "far.obj")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--voxelize", *FAST])
    objs = objects_by_id(out)
    near, far = objs[("thing", "near")], objs[("thing", "far")]
    assert near["masks"].sum() > 1000
    differ = int((near["masks"] != far["masks"]).sum())
    assert differ == 0, f"{differ} mask pixels differ between the mesh at 0 and at {offset:g}"
    assert int(np.abs(near["images"].astype(int) - far["images"].astype(int)).max()) <= 1
    assert np.array_equal(near["voxels"], far["voxels"])
