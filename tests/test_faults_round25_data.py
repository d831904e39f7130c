"""Defects found rendering the test and tutorial meshes of other projects (PyTorch3D's
``docs/tutorials/data`` and ``tests/data``, meshio's ``tests/meshes``), fixed with these tests."""
from __future__ import annotations

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import FAST, index_of
from test_faults_round19_data import _objects, _textured_obj


def test_a_colour_with_a_comment_after_its_numbers_is_read(tmp_path):
    """PyTorch3D's tutorial cow has ``Kd 1.000 1.000 1.000  # white`` in its ``.mtl``: trimesh
    could not read the numbers, dropped the colour, and the texture was drawn at its default 0.4
    (a dark cow, no warning). References: the same materials without the comments."""
    meshes = tmp_path / "m" / "c"
    for name, kd in (("commented", b"Kd 1.000 1.000 1.000  # white\nKs 0 0 0 # black\nNs 10.0 # shine\n"),
                     ("plain", b"Kd 1.000 1.000 1.000\nKs 0 0 0\nNs 10.0\n"),
                     ("grey_commented", b"Kd 0.5 # one value: grey\n"), ("grey", b"Kd 0.5 0.5 0.5\n")):
        _textured_obj(meshes / name, b"newmtl mat\nmap_Kd t.png\n" + kd)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == [] and index_of(out)["warnings"] == []
    objects = _objects(out)
    np.testing.assert_array_equal(objects["commented"]["images"], objects["plain"]["images"])
    np.testing.assert_array_equal(objects["grey_commented"]["images"], objects["grey"]["images"])
    seen = objects["plain"]["masks"] > 0  # the red texture under white is brighter than under grey 0.5
    assert objects["plain"]["images"][seen][:, 0].mean() > objects["grey"]["images"][seen][:, 0].mean() + 30
