"""Data-half defects of the twenty-fourth round (items of the last left-alone list and the
twenty-fourth attack), each with the real loader, renderer and command; expected values come
from hand-built files and from bash itself, never from the code under test."""
from __future__ import annotations

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import FAST, index_of
from test_faults_round21_data import _vertex_coloured_obj


def test_obj_vertex_colours_that_are_not_numbers_are_refused_in_one_line(tmp_path):
    """``v x y z nan nan nan`` (trimesh's deliberately malformed ``models/nancolor.obj``) was cast
    to 0 by the loader: that corner and the faces around it drawn black, exit 0. Now the file is
    refused in one line naming it and the count, with or without a material; the same cube with
    finite colours (the control) renders, and so does every other object of the run."""
    meshes = tmp_path / "m" / "c"
    _vertex_coloured_obj(meshes / "finite", (1, 0, 0))
    for name, mtl in (("nan_plain", None), ("nan_material", "newmtl mat\nKd 1 1 1\n")):
        _vertex_coloured_obj(meshes / name, (1, 0, 0), mtl)
        obj = meshes / name / "m.obj"
        lines = obj.read_text().splitlines()
        first_v = next(i for i, line in enumerate(lines) if line.startswith("v "))
        lines[first_v] = " ".join(lines[first_v].split()[:4] + ["nan", "nan", "nan"])
        obj.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    index = index_of(out)
    assert [o["model_id"] for o in index["objects"]] == ["finite/m"]  # the mesh's path under its category
    reasons = {f["model_id"].split("/")[0]: f["reason"] for f in index["failures"]}
    assert sorted(reasons) == ["nan_material", "nan_plain"]
    for name, reason in reasons.items():
        assert reason == f"{meshes / name / 'm.obj'}: 1 vertex colours are not numbers (NaN/inf), which would be " \
                         "drawn black", reason
