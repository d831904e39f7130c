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
    from sc3d_data.io.obj_loader_text import check_obj_indices

    (p := tmp_path / "x.obj").write_text(_vertex_lines() + line + "\n")
    check_obj_indices(p.read_bytes())


# ----------------------------------------------------------------------------- F2
@pytest.mark.parametrize("line, problem", [("Train chair/a", None), ("validation chair/a", "'validation'"),
                                           ("\x1b[2Jtrain chair/a", "'\\x1b[2Jtrain'")])
def test_f2_split_file_names_other_than_train_val_test_are_refused(tmp_path, line, problem):
    """A plain split file's ``SPLIT ID`` lines took any word as the split: ``validation`` (not
    ``val``) put objects into a split ``sc3d-train`` never reads, and escape codes reached the
    terminal through ``info``. Now the split is train, val or test in any case (``Train`` is
    train), anything else fails naming the file, the line and the word, escaped."""
    from sc3d_data.formats.splits import read_split_lines

    (p := tmp_path / "splits.txt").write_text("# a comment\n" + line + "\n")
    if problem is None:
        assert read_split_lines(p) == [(2, "train", "chair/a")]
        return
    with pytest.raises(ValueError) as e:
        read_split_lines(p)
    assert str(e.value) == f"{p}:2: split {problem} is none of train, val, test (lines are 'SPLIT ID' or 'ID')"


def _render_refused(tmp_path, options: list) -> str:
    """The output of ``render`` with ``options`` over a folder holding one cube, which must fail
    before any work (no index written)."""
    chair = tmp_path / "m" / "chair"
    chair.mkdir(parents=True)
    (chair / "cube.obj").write_text(obj_text(CUBE_V, CUBE_F))
    res = run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", tmp_path / "out", *options, *FAST],
                  expect_exit=None)
    assert res.exit_code != 0 and not (tmp_path / "out" / "index.json").exists(), res.output
    return res.output


@pytest.mark.parametrize("spec", ["random:nan,0,1", "random:0.9,nan", "random:inf,-inf,1", "random:1.5,-0.5"])
def test_f3_random_split_fractions_must_be_finite_and_in_0_1(tmp_path, spec):
    """``random:nan,0,1`` passed both checks (NaN is neither < 0 nor far from a sum of 1) and
    wrote ``NaN``, which is not JSON, into ``index.json``; now ``render`` refuses it in one line
    before any work."""
    output = _render_refused(tmp_path, ["--split", spec])
    assert f"split {spec!r}: give 2 or 3 fractions in [0, 1] that sum to 1" in output, output


# ----------------------------------------------------------------------------- F4
def test_f4_voxelize_killed_between_shard_and_index_is_repaired_by_the_rerun(tmp_path):
    """``voxelize SHARDS`` replaces a shard (atomically) and writes the index after it; killed in
    between, the index kept the shard's old size and checksum, the rerun skipped the shard
    because it held voxels, and ``info --verify`` called it broken for good (its advice,
    re-rendering, dropped the voxels). Now the rerun voxelizes such a shard again: exit 0,
    ``info --verify`` passes, and the voxels equal those of the uninterrupted voxelize."""
    import h5py

    chair = tmp_path / "m" / "chair"
    chair.mkdir(parents=True)
    (chair / "cube.obj").write_text(obj_text(CUBE_V, CUBE_F))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    before = (out / "index.json").read_bytes()
    run_cli(data_main, ["voxelize", out, "--resolution", "16", "--no-progress"])
    with h5py.File(out / "shard-00000.h5") as f:
        whole = f["voxels"][:]
    (out / "index.json").write_bytes(before)   # what a kill after the shard's replacement leaves
    assert run_cli(data_main, ["info", out, "--verify"], expect_exit=None).exit_code != 0
    res = run_cli(data_main, ["voxelize", out, "--resolution", "16", "--no-progress"])
    assert "voxelized 1 objects in 1 shards" in res.output, res.output
    run_cli(data_main, ["info", out, "--verify"])
    with h5py.File(out / "shard-00000.h5") as f:
        np.testing.assert_array_equal(f["voxels"][:], whole)
    assert whole.any()
    # a further rerun skips the shard
    res = run_cli(data_main, ["voxelize", out, "--resolution", "16", "--no-progress"])
    assert "1 shards already done" in res.output, res.output


# ----------------------------------------------------------------------------- F5
def test_f5_every_material_file_an_obj_names_is_read(tmp_path):
    """``mtllib a.mtl b.mtl`` (several files in one statement, as OBJ allows) was warned about as
    one missing file "a.mtl b.mtl", and a second ``mtllib`` statement was never read (trimesh
    reads the first statement only): faces using a material of ``b.mtl`` rendered grey. Now both
    forms render the faces in ``b.mtl``'s blue (Kd 0 0 1), with no warning. Control: an OBJ that
    names only ``a.mtl`` renders the same faces without blue, warned of (``usemtl blue`` is not
    defined there)."""
    folder = tmp_path / "m" / "thing"
    folder.mkdir(parents=True)
    (folder / "a.mtl").write_text("newmtl red\nKd 1 0 0\n")
    (folder / "b.mtl").write_text("newmtl blue\nKd 0 0 1\n")
    body = _vertex_lines() + "usemtl blue\n" + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in CUBE_F)
    (folder / "one_statement.obj").write_text("mtllib a.mtl b.mtl\n" + body)
    (folder / "two_statements.obj").write_text("mtllib a.mtl\nmtllib b.mtl\n" + body)
    (folder / "only_a.obj").write_text("mtllib a.mtl\n" + body)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    index = index_of(out)
    assert index["failures"] == []
    assert [(w["source"].rsplit("/", 1)[1], w["warning"].split(": ", 1)[1]) for w in index["warnings"]] == [
        ("only_a.obj", "usemtl names blue, which its material files do not define; those faces are drawn with the "
         "default material")]
    colour = {mid: o["images"][o["masks"].astype(bool)].astype(float).mean(0) for (_, mid), o in objects_by_id(out).items()}
    for name in ("one_statement", "two_statements"):
        r, g, b = colour[name]
        assert b > 100 and r < 20 and g < 20, (name, colour[name])
    r, g, b = colour["only_a"]
    assert not (b > 100 and r < 20 and g < 20), colour["only_a"]


# ----------------------------------------------------------------------------- F6
def test_f6_voxelize_meshes_refuses_a_folder_of_other_grids(tmp_path):
    """``voxelize --meshes M --out V --resolution 64`` on a folder voxelized at 16 skipped the
    existing file and exited 0: the folder kept a 16^3 grid (and would mix grids as meshes are
    added); other axes were ignored alike. Now a rerun with other grid settings is refused in one
    line naming them, the same settings resume, and ``--overwrite`` redoes the file at the new
    resolution (its header says so)."""
    chair = tmp_path / "m" / "chair"
    chair.mkdir(parents=True)
    (chair / "cube.obj").write_text(obj_text(CUBE_V, CUBE_F))
    out = tmp_path / "vox"
    base = ["voxelize", "--meshes", tmp_path / "m", "--out", out, "--no-progress"]
    run_cli(data_main, [*base, "--resolution", "16"])
    for extra, changed in ((["--resolution", "64"], "--resolution 16 -> 64"),
                           (["--resolution", "16", "--up", "+Z", "--front", "-Y"], "--up '+Y' -> '+Z', --front 'auto' -> '-Y'")):
        res = run_cli(data_main, [*base, *extra], expect_exit=None)
        assert res.exit_code != 0
        assert f"Error: {out}: holds .binvox files voxelized with other settings ({changed})" in res.output, res.output
    assert "1 already there" in run_cli(data_main, [*base, "--resolution", "16"]).output
    run_cli(data_main, [*base, "--resolution", "64", "--overwrite"])
    assert (out / "chair" / "cube.binvox").read_bytes().split(b"\n")[1] == b"dim 64 64 64"


# ----------------------------------------------------------------------------- F7
def test_f7_a_mesh_changed_after_rendering_is_rendered_again(tmp_path):
    """A mesh re-exported after its object was rendered was "resumed" by the rerun (the index
    knew only its path), and ``voxelize SHARDS`` voxelized the new file with the old transform:
    images of one shape, voxels of another. Now the index records each source's fingerprint
    (size, time, SHA-256): ``voxelize`` fails such an object (naming the change) while a source
    differs, the render
    rerun renders that object again (its masks now those of the new mesh, which a fresh render
    of it gives), and a copy of the meshes with new times but the same content still resumes."""
    import os

    import h5py

    chair = tmp_path / "m" / "chair"
    chair.mkdir(parents=True)
    (chair / "a.obj").write_text(obj_text(CUBE_V, CUBE_F))
    out = tmp_path / "out"
    render = ["render", "--meshes", tmp_path / "m", "--out", out, *FAST]
    run_cli(data_main, render)
    flat_box = [[x, y, z * 0.2] for x, y, z in CUBE_V]                # the re-exported mesh
    (chair / "a.obj").write_text(obj_text(flat_box, CUBE_F))
    res = run_cli(data_main, ["voxelize", out, "--resolution", "16", "--no-progress"], expect_exit=None)
    assert res.exit_code != 0 and "no object was voxelized: all 1 failed" in res.output, res.output
    (failure,) = index_of(out)["failures"]
    size_was, size_now = len(obj_text(CUBE_V, CUBE_F)), (chair / "a.obj").stat().st_size
    assert failure["reason"] == (f"{chair / 'a.obj'}: changed since it was rendered ({size_was} -> {size_now} bytes); "
                                 "its voxels would not match its images: render it again, then voxelize")
    res = run_cli(data_main, render)
    assert "changed since it was rendered" in res.output and "done 1, resumed 0" in res.output, res.output
    fresh = tmp_path / "fresh"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", fresh, *FAST])
    with h5py.File(out / "shard-00000.h5") as a, h5py.File(fresh / "shard-00000.h5") as b:
        np.testing.assert_array_equal(a["masks"][:], b["masks"][:])
    os.utime(chair / "a.obj", ns=(1, 1))                               # a copy that kept no times
    assert "done 0, resumed 1" in run_cli(data_main, render).output
    run_cli(data_main, ["voxelize", out, "--resolution", "16", "--no-progress"])


def test_f6_a_binvox_of_another_resolution_is_done_again(tmp_path):
    """``voxelize.json`` is one record for the folder, so ``--part I/N --overwrite`` with a new
    resolution re-records it for parts whose files it did not redo; those files were then kept.
    Now a rerun keeps only files whose header has its resolution and redoes the others (here the
    record is rewritten as such a part run leaves it)."""
    import json

    chair = tmp_path / "m" / "chair"
    chair.mkdir(parents=True)
    for name in ("a", "b"):
        (chair / f"{name}.obj").write_text(obj_text(CUBE_V, CUBE_F))
    out = tmp_path / "vox"
    base = ["voxelize", "--meshes", tmp_path / "m", "--out", out, "--no-progress"]
    run_cli(data_main, [*base, "--resolution", "16"])
    record = json.loads((out / "voxelize.json").read_text())
    (out / "voxelize.json").write_text(json.dumps({**record, "resolution": 8}))
    res = run_cli(data_main, [*base, "--resolution", "8"])
    assert "wrote 2 .binvox files" in res.output and "(0 already there)" in res.output, res.output
    for name in ("a", "b"):
        assert (out / "chair" / f"{name}.binvox").read_bytes().split(b"\n")[1] == b"dim 8 8 8"
    assert "(2 already there)" in run_cli(data_main, [*base, "--resolution", "8"]).output


# ----------------------------------------------------------------------------- F8
@pytest.mark.parametrize("spec", [",", " , ,"])
def test_f8_categories_that_name_nothing_are_refused(tmp_path, spec):
    """``--categories ,`` filtered every mesh away and said "no mesh files found" of a folder
    full of meshes; now one line says the option names no category, before any work."""
    output = _render_refused(tmp_path, ["--categories", spec])
    assert f"Error: --categories {spec!r} names no category" in output, output


# ----------------------------------------------------------------------------- F9
def test_f9_a_single_shapenet_mesh_keeps_its_synset_and_model_id(tmp_path, monkeypatch):
    """``--meshes SYNSET/MODEL_ID/model.obj`` (one ShapeNetCore file) took the model id for the
    category and ``model`` for the id; a folder of such files gives SYNSET and MODEL_ID, and so
    does the single file now, for v1 and v2 layouts, given absolutely or relatively. A file
    outside that layout keeps the flat rule (its folder's name, also for a bare file name)."""
    from sc3d_data.formats.discover import discover_meshes

    model = tmp_path / "03001627" / "1a2b3c"
    (model / "models").mkdir(parents=True)
    for path in (model / "model.obj", model / "models" / "model_normalized.obj", tmp_path / "loose.obj"):
        path.write_text(obj_text(CUBE_V, CUBE_F))

    def ids(root):
        (entry,), _ = discover_meshes(root)
        return entry.category, entry.model_id

    assert ids(model / "model.obj") == ids(model / "models" / "model_normalized.obj") == ("03001627", "1a2b3c")
    monkeypatch.chdir(model)
    assert ids("model.obj") == ids("models/model_normalized.obj") == ("03001627", "1a2b3c")
    monkeypatch.chdir(tmp_path)
    assert ids("loose.obj") == (tmp_path.name, "loose")
