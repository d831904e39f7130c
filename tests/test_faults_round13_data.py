"""Defects of the data half found by the thirteenth attack on the commands (2026-11-28), each test
failing without its fix: ``render --split-file`` given twice used the last file only; a plain split
list named ``holdout_test.txt`` was read as a PTN file (every whole line an id of split test); a
render that selected no object exited 0 with an empty dataset; ``check SHARDS --shards OTHER``
checked OTHER alone. Real meshes, the real commands."""
from __future__ import annotations

import numpy as np
import pytest

from sc3d_cli.data import main as data_main
from conftest import SAMPLE_MESHES, error_lines, run_cli
from test_faults import FAST, index_of


def _splits(out) -> dict[str, str]:
    return {o["model_id"]: o["split"] for o in index_of(out)["objects"]}


def test_render_takes_every_split_file_given(tmp_path):
    """Two ``--split-file`` options (as ``import-r2n2`` takes them): the objects of both files, each
    in its file's split, and both files recorded; before, click kept the last one and the jeep was
    skipped as listed by no file."""
    (tmp_path / "a.txt").write_text("train car/jeep_psionic\n")
    (tmp_path / "b.txt").write_text("test chair/chair2_blendswap\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", out, *FAST,
                        "--split-file", tmp_path / "a.txt", "--split-file", tmp_path / "b.txt"])
    assert _splits(out) == {"jeep_psionic": "train", "chair2_blendswap": "test"}
    assert [p.rsplit("/", 1)[-1] for p in index_of(out)["split"]["files"]] == ["a.txt", "b.txt"]


@pytest.mark.parametrize("name,lines,expected", [
    # a plain list whose name ends in _test.txt: its lines say the split (docs/data.md)
    ("holdout_test.txt", "train car/jeep_psionic\ntest chair/chair2_blendswap\n",
     {"jeep_psionic": "train", "chair2_blendswap": "test"}),
    ("cars_test.txt", "jeep_psionic\n", {"jeep_psionic": "train"}),  # one word: train
    # PTN's names (any prefix ending in _) and exactly test.txt still give the split
    ("02958343_testids.txt", "car/jeep_psionic\n", {"jeep_psionic": "test"}),
    ("test.txt", "car/jeep_psionic\n", {"jeep_psionic": "test"}),
], ids=["plain-list-named-_test", "one-word-id-named-_test", "ptn-testids", "test.txt"])
def test_only_ptn_and_bare_split_names_give_a_files_split(tmp_path, name, lines, expected):
    (tmp_path / name).write_text(lines)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", out, *FAST, "--split-file", tmp_path / name])
    assert _splits(out) == expected


def test_a_render_that_selects_no_object_fails_in_one_line(tmp_path):
    """A split file that lists no mesh: every object skipped, nothing rendered: exit 1 with one
    line saying so and the first reason (it exited 0 and left an empty dataset for the next step
    of a script); the index with the skipped objects is still written."""
    (tmp_path / "none.txt").write_text("no_such_model\n")
    out = tmp_path / "out"
    res = run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", out, *FAST,
                              "--split-file", tmp_path / "none.txt"], expect_exit=1)
    errors = error_lines(res.output)
    assert len(errors) == 1 and errors[0].startswith("Error: no object was rendered: all 12 were skipped (first: "), \
        res.output
    assert "no_such_model" in errors[0] and f"sc3d-data info {out}" in errors[0]
    assert len(index_of(out)["skipped"]) == 12 and index_of(out)["objects"] == []


def test_check_refuses_two_different_shard_folders(tmp_path):
    """``check A --shards B`` named two datasets and checked B alone, reporting PASS for A; now a
    usage error naming both, before anything is read. The same folder both ways is one folder."""
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    res = run_cli(data_main, ["check", a, "--shards", b, "--no-progress"], expect_exit=2)
    errors = error_lines(res.output)
    assert len(errors) == 1 and errors[0] == f"Error: two shard directories: {a} and --shards {b}; give one " \
                                             "(check one dataset at a time)", res.output
    same = run_cli(data_main, ["check", a, "--shards", str(a) + "/", "--no-progress"], expect_exit=None)
    assert "two shard directories" not in same.output


def test_voxelize_meshes_does_again_a_mesh_edited_since_its_binvox(tmp_path):
    """``voxelize --meshes``: a rerun after the mesh was replaced (a box, then a sphere) kept the
    box's grid; now a mesh newer than its ``.binvox`` is done again, counted in the summary, and
    its grid equals a fresh run's; an untouched rerun still skips it. Expected grid: the fresh
    run's (an independent run of the same command on the sphere)."""
    import os

    import trimesh

    from sc3d_data.io.binvox import read_binvox

    (tmp_path / "m" / "x").mkdir(parents=True)
    mesh = tmp_path / "m" / "x" / "a.obj"
    trimesh.creation.box([1, 0.2, 0.2]).export(mesh)
    args = ["voxelize", "--meshes", tmp_path / "m", "--no-progress", "--workers", "1"]
    run_cli(data_main, [*args, "--out", tmp_path / "vo"])
    binvox = tmp_path / "vo" / "x" / "a.binvox"
    box = read_binvox(binvox).voxels.copy()
    trimesh.creation.icosphere().export(mesh)
    now = binvox.stat().st_mtime_ns  # the grid as written 10 s ago, the edit 5 s ago (clear of any
    os.utime(binvox, ns=(now - 10 * 10**9,) * 2)  # file system's time resolution)
    os.utime(mesh, ns=(now - 5 * 10**9,) * 2)
    res = run_cli(data_main, [*args, "--out", tmp_path / "vo"])
    assert "wrote 1 .binvox files" in res.output and "1 of them again: their mesh is newer" in res.output, res.output
    run_cli(data_main, [*args, "--out", tmp_path / "fresh"])
    redone = read_binvox(binvox).voxels
    assert np.array_equal(redone, read_binvox(tmp_path / "fresh" / "x" / "a.binvox").voxels)
    assert not np.array_equal(redone, box)
    again = run_cli(data_main, [*args, "--out", tmp_path / "vo"])
    assert "wrote 0 .binvox files" in again.output and "(1 already there)" in again.output, again.output
