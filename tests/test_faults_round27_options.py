"""Data-half defects of the twenty-seventh round (an attack on workflows across commands): an empty option value (an unset shell
variable, ``--split-file "$SPLITS"``) that was taken as "not given", or as the current folder,
instead of refused in one line. Real commands, real files written here."""
from __future__ import annotations

import pytest

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import CUBE_F, CUBE_V, FAST, index_of


def _cube_meshes(root):
    """``root/chair/a.obj``, ``root/chair/b.obj``: two unit cubes."""
    folder = root / "chair"
    folder.mkdir(parents=True)
    text = "".join(f"v {x} {y} {z}\n" for x, y, z in CUBE_V) + "".join(
        f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in CUBE_F)
    for name in ("a", "b"):
        (folder / f"{name}.obj").write_text(text)
    return root


@pytest.mark.parametrize("files", [[""], ["GOOD", ""]])
def test_an_empty_split_file_is_refused(tmp_path, monkeypatch, files):
    """``render --split-file ''`` rendered with the default random split (exit 0: the objects in
    other splits than the user's file says); beside a real file, ``''`` was the current folder and
    its ``*.txt`` files (notes, a licence) were read as split lists. Both are refused in one line
    before any work, and nothing is written."""
    meshes = _cube_meshes(tmp_path / "m")
    good = tmp_path / "sp.txt"
    good.write_text("test chair/a\ntest chair/b\n")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("train chair/a\n")  # a list in the current folder: not the user's
    args = [a for f in files for a in ("--split-file", good if f == "GOOD" else f)]
    out = tmp_path / "out"
    res = run_cli(data_main, ["render", "--meshes", meshes, "--out", out, *args, *FAST], expect_exit=2)
    assert "is empty: give a split file (an unset variable?)" in res.output, res.output
    assert not (out / "index.json").exists()


def test_a_good_split_file_still_splits(tmp_path):
    """Control: the one file given is read (both objects in test)."""
    meshes = _cube_meshes(tmp_path / "m")
    good = tmp_path / "sp.txt"
    good.write_text("test chair/a\ntest chair/b\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", meshes, "--out", out, "--split-file", good, *FAST])
    assert sorted(o["split"] for o in index_of(out)["objects"]) == ["test", "test"]


@pytest.mark.parametrize("spec", ["", ","])
def test_import_r2n2_categories_that_name_nothing_are_refused(tmp_path, spec):
    """``import-r2n2 --categories ''`` imported every category (``render`` refuses it: round 6's
    F8); ``,`` was refused already. Both now say the option names no category, before any work."""
    renderings, voxels = tmp_path / "ShapeNetRendering", tmp_path / "ShapeNetVox32"
    (renderings / "03001627").mkdir(parents=True)
    (voxels / "03001627").mkdir(parents=True)
    res = run_cli(data_main, ["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out",
                              tmp_path / "out", "--categories", spec, "--no-progress"], expect_exit=1)
    assert f"Error: --categories {spec!r} names no category" in res.output, res.output


@pytest.mark.parametrize("option", ["--json", "--png"])
def test_check_refuses_an_empty_report_path(tmp_path, option):
    """``check --json ''`` wrote no JSON and exited 0 (a CI step reading ``$REPORT`` found
    nothing); ``--png ''`` drew the default picture. Both are refused in one line."""
    meshes = _cube_meshes(tmp_path / "m")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", meshes, "--out", out, "--voxelize", *FAST])
    res = run_cli(data_main, ["check", out, option, "", "--no-progress"], expect_exit=2)
    assert "is empty: give a file (an unset variable?)" in res.output, res.output
