"""Defects of the data half found by the fifteenth attack on the commands (2026-11-28): a merge that
replaced another merged dataset without a word, a re-merge after voxelizing the parts refused
with a false reason, and ``info --verify`` calling a dataset broken while ``voxelize`` rewrote it.
Real renderer, real HDF5, real locks held by real processes; each test fails without its fix."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

from sc3d_data.io import outlock
from sc3d_cli.data import main as data_main
from conftest import SAMPLE_MESHES, one_error, run_cli
from test_faults import FAST, index_of
from test_faults_round10_data import _dataset_bytes, _two_chairs, _voxel_shapes
from test_faults_round8_data import flip_bytes_in_a_chunk


def _render_parts(meshes: Path, folder: Path, *extra) -> list[Path]:
    parts = [folder / f"p{i}" for i in range(2)]
    for i, part in enumerate(parts):
        run_cli(data_main, ["render", "--meshes", meshes, "--out", part, "--part", f"{i}/2", *FAST, *extra])
    return parts


# ------------------------------------------------------------------ merge over another merge
def test_a_merge_of_other_settings_does_not_replace_a_merged_dataset(tmp_path):
    """``merge data r0 r1`` with parts of other settings (an import, other views...) replaced the
    merged dataset in ``data`` and exited 0: with the first parts deleted, as scale.md allows,
    that dataset was gone. It is refused in one line naming what differs, and ``data`` is left as
    it was; ``--overwrite`` replaces it."""
    meshes = _two_chairs(tmp_path)
    parts = _render_parts(meshes, tmp_path / "a")
    data = tmp_path / "data"
    run_cli(data_main, ["merge", data, *parts])
    before = _dataset_bytes(data)
    others = _render_parts(meshes, tmp_path / "b", "--image-size", "32")
    res = run_cli(data_main, ["merge", data, *others], expect_exit=1)
    error = one_error(res.output)
    assert "holds a merge made with other settings" in error and "image_size" in error, error
    assert "--overwrite" in error, error
    assert _dataset_bytes(data) == before

    run_cli(data_main, ["merge", data, *others, "--overwrite"])
    assert index_of(data)["settings"]["image_size"] == 32


def test_a_merge_of_the_same_settings_merges_again(tmp_path):
    """Control: parts of the same settings (a copy of them, a part rerun after a fix) merge into
    the folder again without ``--overwrite``."""
    meshes = _two_chairs(tmp_path)
    parts = _render_parts(meshes, tmp_path / "a")
    data = tmp_path / "data"
    run_cli(data_main, ["merge", data, *parts])
    copies = [shutil.copytree(p, tmp_path / f"copy{i}") for i, p in enumerate(parts)]
    run_cli(data_main, ["merge", data, *copies])
    assert sorted(map(Path, index_of(data)["merged"]["parts"])) == sorted(copies)


# ------------------------------------------------------------------ merge after voxelizing the parts
def test_parts_voxelized_after_the_merge_merge_again_with_their_grids(tmp_path):
    """scale.md says to voxelize the parts, then merge. A merge run again after that was refused:
    "its shards were given voxels by `sc3d-data voxelize` after the merge", though the merged
    folder held no voxels at all. Now the parts' grids are merged in."""
    parts = _render_parts(_two_chairs(tmp_path), tmp_path)
    data = tmp_path / "data"
    run_cli(data_main, ["merge", data, *parts])
    assert set(_voxel_shapes(data)) == {None}
    for part in parts:
        run_cli(data_main, ["voxelize", part, "--no-progress", "--workers", "1"])
    res = run_cli(data_main, ["merge", data, *parts])
    assert "given voxels" not in res.output
    assert set(_voxel_shapes(data)) == {(32, 32, 32)}
    assert index_of(data)["voxels"]["resolution"] == 32

    run_cli(data_main, ["voxelize", data, "--no-progress", "--workers", "1", "--resolution", "16"])
    res = run_cli(data_main, ["merge", data, *parts])  # control: OUT's own grids are still kept
    assert "1 already there" in res.output and set(_voxel_shapes(data)) == {(16, 16, 16)}, res.output


# ------------------------------------------------------------------ readers beside a live writer
HOLD_LOCK = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from sc3d_data.io.outlock import exclusive_lock
    with exclusive_lock(Path(sys.argv[1]), "sc3d-data voxelize"):
        print("held", flush=True)
        sys.stdin.readline()
""")


def _holder(folder: Path) -> subprocess.Popen:
    """A process that holds ``folder``'s write lock (sc3d's own lock code) until its stdin closes."""
    proc = subprocess.Popen([sys.executable, "-c", HOLD_LOCK, str(folder)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_info_names_the_writer_instead_of_calling_shards_broken(tmp_path):
    """``info --verify`` during ``voxelize SHARDS`` (which replaces each shard, then rewrites the
    index) said "BROKEN shards ... rerun the render command". With a writer holding the folder
    the reader names it and says to run again when it ends; once it has ended the same
    mismatch is reported as broken (control)."""
    out = tmp_path / "ds"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "table", "--out", out, *FAST])
    index = json.loads((out / "index.json").read_text())
    flip_bytes_in_a_chunk(out / index["shards"][0]["file"])  # a new shard in place, the index not yet rewritten
    holder = _holder(out)
    try:
        res = run_cli(data_main, ["info", out, "--verify"], expect_exit=1)
        error = one_error(res.output)
        assert f"PID {holder.pid}: sc3d-data voxelize" in error and "run this again" in error, error
        assert "BROKEN" not in res.output
        res = run_cli(data_main, ["check", out], expect_exit=1)
        assert f"PID {holder.pid}" in one_error(res.output)
        assert outlock.writer_of(out) == f"PID {holder.pid}: sc3d-data voxelize"
    finally:
        holder.stdin.close()
        holder.wait(timeout=30)
    assert outlock.writer_of(out) is None
    res = run_cli(data_main, ["info", out, "--verify"], expect_exit=1)
    assert "BROKEN shards: 1" in res.output


def test_writer_of_names_only_another_process_holding_the_lock(tmp_path):
    """No lock file, a lock file no one holds, and this process's own lock: no writer."""
    assert outlock.writer_of(tmp_path) is None
    with outlock.exclusive_lock(tmp_path, "sc3d-data render"):
        assert outlock.writer_of(tmp_path) is None
    assert outlock.writer_of(tmp_path) is None


def test_a_render_that_kept_every_object_prints_no_rate(tmp_path):
    """A rerun that had everything already rendered printed "(0 views/s, 0 workers, ...)", which
    reads as a fault; it says there was nothing to render."""
    out = tmp_path / "ds"
    first = run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "table", "--out", out, *FAST]).output
    again = run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "table", "--out", out, *FAST]).output
    assert " views/s, 1 workers" in first, first
    assert "done 0, resumed 1" in again and "nothing to render" in again and "views/s" not in again, again


def test_a_command_refused_on_its_inputs_leaves_no_folders_behind(tmp_path):
    """``render``/``import-r2n2``/``fit`` refused on their inputs into a new ``--out a/b/c`` left
    ``a/b/c/.sc3d.lock`` (render, import-r2n2) or ``a/b`` (fit): folders the user never asked
    for, found later beside real output. Now none of them is left; a folder that existed before
    stays (control)."""
    from sc3d_cli.train import main as train_main

    empty = tmp_path / "empty"
    empty.mkdir()
    commands = {
        "render": (data_main, ["render", "--meshes", empty, *FAST]),
        "import-r2n2": (data_main, ["import-r2n2", "--renderings", empty, "--voxels", empty, "--no-progress"]),
        "fit": (train_main, ["fit", "--shards", empty, "--steps", "2", "--tiny", "--no-progress"]),
    }
    for name, (group, args) in commands.items():
        one_error(run_cli(group, [*args, "--out", tmp_path / "a" / "b" / "c"], expect_exit=1).output)
        assert not (tmp_path / "a").exists(), name
        (tmp_path / "kept").mkdir(exist_ok=True)
        one_error(run_cli(group, [*args, "--out", tmp_path / "kept" / "c"], expect_exit=1).output)
        assert (tmp_path / "kept").is_dir() and not (tmp_path / "kept" / "c").exists(), name
        one_error(run_cli(group, [*args, "--out", tmp_path / "new" / ".." / "kept"], expect_exit=1).output)
        assert (tmp_path / "kept").is_dir(), name  # the user's empty folder, named through a folder not yet made
        assert not (tmp_path / "new").exists(), name
