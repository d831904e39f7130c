"""Hostile inputs, round six: defects that earlier rounds noticed and left alone. F1: an OBJ whose
faces count vertices from 0 (some exporters write 0-based indices), which trimesh reads without
complaint as other triangles. Real renderer and HDF5; every fixture is built here, and expected
values come from the fixtures (the cube's own triangles), never from the code under test."""
from __future__ import annotations

import numpy as np
import pytest

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import CUBE_F, CUBE_V, FAST, index_of, obj_text


def _vertex_lines() -> str:
    return "".join(f"v {x} {y} {z}\n" for x, y, z in CUBE_V)


def test_f1_obj_faces_counting_from_0_are_refused_naming_the_line(tmp_path):
    """The cube written with 0-based indices fails with the line that names index 0; the same cube
    written 1-based (with a commented-out 0-based face) and with relative (negative) indices
    renders, and both give the same masks. Negative control: trimesh alone reads the 0-based file
    without an error, as triangles that are not the cube's."""
    import trimesh

    chair = tmp_path / "m" / "chair"
    chair.mkdir(parents=True)
    zero_faces = "".join(f"f {a} {b} {c}\n" for a, b, c in CUBE_F)
    (chair / "zero_based.obj").write_text(_vertex_lines() + zero_faces)
    (chair / "one_based.obj").write_text("# f 0 1 2 (0-based, commented out)\n" + obj_text(CUBE_V, CUBE_F))
    n = len(CUBE_V)
    (chair / "relative.obj").write_text(_vertex_lines() + "".join(f"f {a - n} {b - n} {c - n}\n" for a, b, c in CUBE_F))
    (chair / "normal_zero.obj").write_text(_vertex_lines() + "vn 0 0 1\n" + "".join(
        f"f {a + 1}//0 {b + 1}//0 {c + 1}//0\n" for a, b, c in CUBE_F))

    loaded = trimesh.load(str(chair / "zero_based.obj"), process=False, force="mesh")
    assert sorted(map(tuple, loaded.faces.tolist())) != sorted(map(tuple, CUBE_F)), "trimesh now reads 0-based faces"

    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    reasons = {f["model_id"]: f["reason"] for f in index_of(out)["failures"]}
    first_face = len(CUBE_V) + 1   # the line after the vertices
    a, b, c = CUBE_F[0]
    assert reasons == {
        "zero_based": f"{chair / 'zero_based.obj'}: line {first_face} ('f {a} {b} {c}') names index 0, but OBJ "
                      "indices count from 1 (an exporter that writes 0-based indices?); not read",
        "normal_zero": f"{chair / 'normal_zero.obj'}: line {first_face + 1} ('f {a + 1}//0 {b + 1}//0 {c + 1}//0') "
                       "names index 0, but OBJ indices count from 1 (an exporter that writes 0-based indices?); not read"}
    objs = {mid: o for (_, mid), o in objects_by_id(out).items()}
    assert set(objs) == {"one_based", "relative"}
    assert objs["one_based"]["masks"].any()
    np.testing.assert_array_equal(objs["one_based"]["masks"], objs["relative"]["masks"])


@pytest.mark.parametrize("line", ["f 1 2 10", "f 1/10/1 2/1/1 3/1/1", "f -1 -2 -3", "vt 0 0", "f 1 2 3 # 0",
                                  "l 0 1"])
def test_f1_indices_that_are_not_zero_pass_the_check(tmp_path, line):
    """Tokens that contain a 0 but are not index 0 (10, a comment, a texture coordinate, a line
    statement) are not refused by the check."""
    from sc3d_data.io.meshes import check_obj_indices

    (p := tmp_path / "x.obj").write_text(_vertex_lines() + line + "\n")
    check_obj_indices(p)
