"""Defects of the data half found by the sixteenth attack on the commands (2026-11-28): merges that
compared splits and settings by spelling or replaced a dataset whose splits an edited split file
had moved, and the mixed grids of a ``voxelize --resolution`` stopped part-way passing ``info
--verify`` and ``check``. Real renderer, real HDF5; each test fails without its fix."""
from __future__ import annotations

import json
from pathlib import Path

import h5py
import pytest

from sc3d_cli.data import main as data_main
from conftest import SAMPLE_MESHES, one_error, run_cli
from test_faults import index_of
from test_faults_round10_data import _dataset_bytes
from test_import_r2n2 import fake_r2n2  # noqa: F401 - the fixture (fake 3D-R2N2 folders)

FAST = ["--views", "2", "--no-progress", "--workers", "1"]
#: the four sample meshes these tests split (category folder / model id)
SPLITS = "train airplane/centrair101_glider_fgai\ntrain car/peugeot_308cc_scopia\ntrain car/jeep_psionic\n" \
         "test chair/chair2_blendswap\n"


def _parts(folder: Path, *options, n: int = 2) -> list[Path]:
    parts = [folder / f"p{i}" for i in range(n)]
    for i, part in enumerate(parts):
        run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", part, "--part", f"{i}/{n}", *FAST, *options])
    return parts


def test_a_merge_that_would_move_objects_to_another_split_is_refused(tmp_path, monkeypatch):
    """An edited split file, parts rendered again with it, merged into the folder of the first
    merge: the dataset was replaced (an object moved from train to test) with exit 0, where
    ``render`` refuses the same change. Refused in one line naming the object; the folder is
    kept; ``--overwrite`` replaces it."""
    monkeypatch.chdir(tmp_path)
    Path("splits.txt").write_text(SPLITS)
    data = tmp_path / "data"
    run_cli(data_main, ["merge", data, *_parts(tmp_path / "a", "--split-file", "splits.txt")])
    before = _dataset_bytes(data)
    Path("splits.txt").write_text(SPLITS.replace("train car/jeep_psionic", "test car/jeep_psionic"))
    moved = _parts(tmp_path / "b", "--split-file", "splits.txt")
    error = one_error(run_cli(data_main, ["merge", data, *moved], expect_exit=1).output)
    assert "1 object(s) of these parts have another split" in error and "jeep_psionic: train -> test" in error, error
    assert _dataset_bytes(data) == before
    run_cli(data_main, ["merge", data, *moved, "--overwrite"])
    assert {o["model_id"]: o["split"] for o in index_of(data)["objects"]}["jeep_psionic"] == "test"


def test_parts_whose_split_is_spelt_differently_merge(tmp_path, monkeypatch):
    """``--split random:0.7,0.3`` for one part and ``random:0.70,0,0.30`` for the other (data.md's
    own example of one split), or one split file given as ``./splits.txt`` and by its absolute
    path: merge refused them ("split differs"), comparing the split records as typed."""
    monkeypatch.chdir(tmp_path)
    Path("splits.txt").write_text(SPLITS)
    for name, spellings in {"random": (["--split", "random:0.7,0.3"], ["--split", "random:0.70,0,0.30"]),
                            "file": (["--split-file", "./splits.txt"], ["--split-file", str(tmp_path / "splits.txt")])
                            }.items():
        parts = [tmp_path / name / f"p{i}" for i in range(2)]
        for i, (part, options) in enumerate(zip(parts, spellings)):
            run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", part, "--part", f"{i}/2", *FAST,
                                *options])
        run_cli(data_main, ["merge", tmp_path / name / "merged", *parts])


def test_a_split_file_is_recorded_by_the_file_it_names(tmp_path, monkeypatch):
    """``--split-file splits.txt`` was recorded as typed, so a rerun from another folder naming the
    same file by its absolute path was refused as "other settings (split_file differ)". It is
    recorded absolute, and the rerun resumes."""
    Path(tmp_path / "splits.txt").write_text(SPLITS)
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "ds"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", out, "--split-file", "splits.txt", *FAST])
    assert index_of(out)["settings"]["split_file"] == str(tmp_path / "splits.txt")
    monkeypatch.chdir(SAMPLE_MESHES)
    res = run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", out, "--split-file",
                              tmp_path / "splits.txt", *FAST])
    assert "done 0, resumed 4" in res.output, res.output


def test_parts_of_an_older_sc3d_merge_with_parts_of_a_newer(tmp_path):
    """An older sc3d did not record ``outside_textures`` (added later; its default, ``warn``, is
    what the older code did). ``render`` resumes such a part; ``merge`` refused to merge it with a
    part the current sc3d resumed ("outside_textures differ"), and refused the parts again into
    the older merge. A setting an index lacks now counts as its default there too; another
    value still differs (control)."""
    parts = _parts(tmp_path)
    for part in parts:
        index = json.loads((part / "index.json").read_text())
        del index["settings"]["outside_textures"]
        (part / "index.json").write_text(json.dumps(index))
    data = tmp_path / "data"
    run_cli(data_main, ["merge", data, *parts])
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", parts[0], "--part", "0/2", *FAST])
    assert index_of(parts[0])["settings"]["outside_textures"] == "warn"
    run_cli(data_main, ["merge", data, *parts])
    index = json.loads((parts[1] / "index.json").read_text())
    index["settings"]["outside_textures"] = "fail"
    (parts[1] / "index.json").write_text(json.dumps(index))
    error = one_error(run_cli(data_main, ["merge", tmp_path / "other", *parts], expect_exit=1).output)
    assert "outside_textures differ" in error, error


def _grid_sides(out: Path) -> list:
    sides = []
    for shard in sorted(out.glob("shard-*.h5")):
        with h5py.File(shard, "r") as f:
            sides.append(f["voxels"].shape[1] if "voxels" in f else None)
    return sides


def test_the_mixed_grids_of_a_voxelize_stopped_part_way_are_reported(tmp_path, monkeypatch):
    """``voxelize --resolution 16`` stopped after its first shard (Ctrl-C) leaves 16^3 grids in
    that shard, whose SHA-256 the index already records, and 32^3 in the others while the
    index's record still says 32^3: ``info --verify`` and ``check`` passed, exit 0. Now both
    name the shard and say to run the voxelize again; once it has finished, they pass."""
    out = tmp_path / "ds"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", out, "--voxelize", "--objects-per-shard", "4",
                        *FAST])
    from sc3d_data.pipeline.jobs import shard_output

    real = shard_output.write_chunks

    def stopped_after_the_first_shard(index, pool, todo, K, n_workers, store):
        def store_then_stop(c, results, last):
            store(c, results, last)
            index.write()  # as the lazy write after a chunk does
            raise KeyboardInterrupt
        return real(index, pool, todo, K, n_workers, store_then_stop)

    with monkeypatch.context() as m:
        m.setattr(shard_output, "write_chunks", stopped_after_the_first_shard)
        run_cli(data_main, ["voxelize", out, "--resolution", "16", *FAST[2:]], expect_exit=None)
    assert _grid_sides(out) == [16, 32, 32], _grid_sides(out)
    res = run_cli(data_main, ["info", out, "--verify"], expect_exit=1)
    assert "BROKEN shards: 1 of 3 (rerun the voxelize command that stopped part-way" in res.output, res.output
    assert "shard-00000.h5: holds 16^3 voxel grids, its index records 32^3" in res.output, res.output
    assert "holds 16^3 voxel grids" in one_error(run_cli(data_main, ["check", out], expect_exit=1).output)

    run_cli(data_main, ["voxelize", out, "--resolution", "16", *FAST[2:]])
    assert _grid_sides(out) == [16, 16, 16]
    run_cli(data_main, ["info", out, "--verify"])


HOLD = """
import sys
from pathlib import Path
from sc3d_data.io.outlock import exclusive_lock, reading_lock
folder, how = Path(sys.argv[1]), sys.argv[2]
with (exclusive_lock(folder, "sc3d-data render") if how == "write" else reading_lock(folder, "merge", "")):
    print("held", flush=True)
    sys.stdin.readline()
"""


def _holding(tmp_path: Path, folder: Path, how: str):
    """A process holding ``folder``'s lock with sc3d's own code: as a writer, or as a reader (a merge)."""
    import subprocess
    import sys

    script = tmp_path / f"hold_{how}.py"
    script.write_text(HOLD)
    proc = subprocess.Popen([sys.executable, script, folder, how], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_merge_and_a_writer_of_its_parts_exclude_each_other(tmp_path):
    """``merge`` read its parts without a lock: a part being rendered again could be linked half
    way (a shard replaced after its checksum was read). A part being written is now refused,
    naming its writer, and a writer of a part that a merge is reading is refused, naming the
    merge's process; once each has ended, the other runs (controls)."""
    parts = _parts(tmp_path)
    writer = _holding(tmp_path, parts[1], "write")
    try:
        error = one_error(run_cli(data_main, ["merge", tmp_path / "data", *parts], expect_exit=1).output)
        assert f"{parts[1]}: another process (PID {writer.pid}: sc3d-data render) is writing" in error, error
        assert error.endswith("merge when it has finished"), error
    finally:
        writer.stdin.close()
        writer.wait(timeout=30)
    assert not (tmp_path / "data").exists()
    reader = _holding(tmp_path, parts[0], "read")
    try:
        rerun = ["render", "--meshes", SAMPLE_MESHES, "--out", parts[0], "--part", "0/2", *FAST]
        error = one_error(run_cli(data_main, rerun, expect_exit=1).output)
        assert f"{parts[0]}: another process (PID {reader.pid}: hold_read.py {parts[0]} read) is using this folder" \
            in error, error
        run_cli(data_main, ["merge", tmp_path / "data", *parts])  # readers share the parts
    finally:
        reader.stdin.close()
        reader.wait(timeout=30)
    run_cli(data_main, rerun)


def test_import_r2n2_into_a_merged_folder_names_its_own_command(fake_r2n2, tmp_path):  # noqa: F811
    """``import-r2n2 --out`` a merged folder of imported parts said "render parts into their own
    folders and merge again": the command to run is import-r2n2."""
    renderings, voxels, _ = fake_r2n2
    source = ["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--no-progress"]
    parts = [tmp_path / f"r{i}" for i in range(2)]
    for i, part in enumerate(parts):
        run_cli(data_main, [*source, "--out", part, "--part", f"{i}/2"])
    run_cli(data_main, ["merge", tmp_path / "data", *parts])
    error = one_error(run_cli(data_main, [*source, "--out", tmp_path / "data"], expect_exit=1).output)
    assert "is a merged dataset (sc3d-data merge); import-r2n2 parts into their own folders" in error, error


def test_a_merge_lists_only_the_backends_that_rendered(tmp_path):
    """A part with no object to render starts no worker and records no backend; the merge listed
    ``"None"`` among the parts' GL backends."""
    parts = [tmp_path / f"p{i}" for i in range(2)]
    for i, part in enumerate(parts):
        run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "table", "--out", part, "--part", f"{i}/2", *FAST])
    used = [index_of(p)["settings"]["backend"] for p in parts]
    assert sorted(map(str, used))[0] == "None"  # the empty part's
    run_cli(data_main, ["merge", tmp_path / "data", *parts])
    assert index_of(tmp_path / "data")["merged"]["backends"] == [b for b in used if b]


def test_parts_whose_split_files_have_the_same_content_merge(tmp_path):
    """Each node kept its own copy of the split file (``a/splits.txt``, ``b/splits.txt``, the same
    lines): merge refused the parts ("split_file differ"), comparing the paths although the split
    record holds the files' SHA-256. Merged now; a copy with other lines is still refused."""
    copies = []
    for name, text in (("a", SPLITS), ("b", SPLITS), ("c", SPLITS.replace("train car/jeep", "test car/jeep"))):
        (tmp_path / name).mkdir()
        copies.append(tmp_path / name / "splits.txt")
        copies[-1].write_text(text)
    parts = [tmp_path / f"p{i}" for i in range(2)]
    for i, (part, split_file) in enumerate(zip(parts, copies)):
        run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", part, "--part", f"{i}/2", *FAST,
                            "--split-file", split_file])
    run_cli(data_main, ["merge", tmp_path / "data", *parts])
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", tmp_path / "q1", "--part", "1/2", *FAST,
                        "--split-file", copies[2]])
    error = one_error(run_cli(data_main, ["merge", tmp_path / "other", parts[0], tmp_path / "q1"], expect_exit=1).output)
    assert "split differs" in error, error


# ------------------------------------------------------------------ voxelize --meshes: whose grid is kept
def _vox(meshes: Path, out: Path, *options) -> str:
    return run_cli(data_main, ["voxelize", "--meshes", meshes, "--out", out, "--workers", "1", "--no-progress",
                               *options]).output


def test_a_kept_binvox_made_by_another_mesh_of_the_same_id_is_done_again(tmp_path):
    """``x.glb`` (a chair) and ``x.GLB`` (a jeep) have one id and write one ``x.binvox``; with the
    one used deleted, the rerun kept its grid as the other's ("1 already there"), exit 0. The
    folder's record of which mesh made each file (``sources.json``) sends it to be done again:
    expected, the grid of a fresh run on the mesh that is left."""
    import shutil

    meshes = tmp_path / "m" / "chair"
    meshes.mkdir(parents=True)
    shutil.copy(SAMPLE_MESHES / "chair" / "chair2_blendswap.glb", meshes / "x.glb")
    shutil.copy(SAMPLE_MESHES / "car" / "jeep_psionic.glb", meshes / "x.GLB")
    _vox(meshes.parent, tmp_path / "vox")
    (duplicate,) = json.loads((tmp_path / "vox" / "failures.json").read_text())
    used = Path(duplicate["reason"].split("also ")[1].split(", which is used")[0])
    used.unlink()
    res = _vox(meshes.parent, tmp_path / "vox")
    assert "1 of them again: made by another mesh or with other settings" in res, res
    _vox(meshes.parent, tmp_path / "fresh")
    assert (tmp_path / "vox/chair/x.binvox").read_bytes() == (tmp_path / "fresh/chair/x.binvox").read_bytes()
    assert "1 already there" in _vox(meshes.parent, tmp_path / "vox")  # control: now kept


def test_parts_voxelized_with_old_settings_are_done_again_after_a_part_re_records_them(tmp_path):
    """``voxelize --meshes --part 0/2 --normalize diagonal --overwrite`` re-records the folder's
    settings; part 1's files, made with ``fit``, were then kept by every rerun (also a whole
    run): a folder of mixed grids, exit 0. They are done again; expected: the files of a fresh
    ``--normalize diagonal`` run, byte for byte."""
    out = tmp_path / "vox"
    for i in range(2):
        _vox(SAMPLE_MESHES, out, "--part", f"{i}/2")
    _vox(SAMPLE_MESHES, out, "--part", "0/2", "--normalize", "diagonal", "--overwrite")
    res = _vox(SAMPLE_MESHES, out, "--part", "1/2", "--normalize", "diagonal")
    assert "of them again: made by another mesh or with other settings" in res, res
    _vox(SAMPLE_MESHES, tmp_path / "fresh", "--normalize", "diagonal")
    files = sorted(p.relative_to(out) for p in out.rglob("*.binvox"))
    assert len(files) == 11
    assert [f for f in files if (out / f).read_bytes() != (tmp_path / "fresh" / f).read_bytes()] == []
    assert "(11 already there)" in _vox(SAMPLE_MESHES, out, "--normalize", "diagonal")


def test_voxelize_of_a_dataset_without_shards_fails_in_one_line(tmp_path):
    """A dataset every object of which failed to render holds no shard; ``voxelize`` of it said
    "voxelized 0 objects in 0 shards" and exited 0, where ``check``, ``preview`` and ``fit``
    refuse it. It fails in one line now, saying why."""
    broken = tmp_path / "m" / "chair"
    broken.mkdir(parents=True)
    (broken / "broken.obj").write_text("v 0 0 0\nf 1 2 3\n")
    out = tmp_path / "ds"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST], expect_exit=1)
    assert index_of(out)["shards"] == []
    error = one_error(run_cli(data_main, ["voxelize", out, "--no-progress"], expect_exit=1).output)
    assert "holds no shard, so nothing was voxelized" in error, error
    assert "voxelized 0 objects" not in run_cli(data_main, ["voxelize", out, "--no-progress"], expect_exit=1).output


def test_voxelize_of_shards_held_by_a_writer_does_not_advise_another_out(tmp_path):
    """``voxelize SHARDS`` has no ``--out``; refused beside a writer it said "use another --out"."""
    out = tmp_path / "ds"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "table", "--out", out, *FAST])
    writer = _holding(tmp_path, out, "write")
    try:
        error = one_error(run_cli(data_main, ["voxelize", out, "--no-progress"], expect_exit=1).output)
    finally:
        writer.stdin.close()
        writer.wait(timeout=30)
    assert error.endswith("is writing to this folder; wait for it to finish"), error


def test_a_slurm_array_that_cannot_be_submitted_leaves_no_folders(tmp_path):
    """``--executor slurm`` where there is no SLURM fails in one line, as it should, but left
    ``OUT/parts/part-000-of-002/`` ... (render) or an empty ``--out`` (voxelize --meshes) behind."""
    import shutil as sh

    if sh.which("sbatch") or sh.which("srun"):
        pytest.skip("this machine has SLURM")
    for args in (["render", "--meshes", SAMPLE_MESHES / "table", *FAST],
                 ["voxelize", "--meshes", SAMPLE_MESHES / "table", "--no-progress"]):
        error = one_error(run_cli(data_main, [*args, "--out", tmp_path / "new" / "out", "--executor", "slurm",
                                              "--slurm-parts", "2"], expect_exit=1).output)
        assert "--executor slurm" in error, error
        assert not (tmp_path / "new").exists(), args[0]


def test_swapped_meshes_and_an_overwrite_that_stops_or_fails_leave_no_wrong_grid(tmp_path, monkeypatch):
    """The review of the record: (1) two meshes swapped by ``mv`` (times kept) were kept under
    each other's names; (2) an ``--overwrite --normalize diagonal`` stopped after its first file
    (Ctrl-C) left the others' ``fit`` grids unrecorded, and the next run kept them; (3) under
    ``--overwrite`` a mesh that fails kept its old grid, which the next run counted as done.
    Expected throughout: the files of a fresh run of the same meshes and settings."""
    import os
    import shutil

    meshes = tmp_path / "m" / "chair"
    shutil.copytree(SAMPLE_MESHES / "chair", meshes)
    out = tmp_path / "vox"
    _vox(meshes.parent, out)
    a, b = meshes / "chair2_blendswap.glb", meshes / "silla_blanca_blendswap.glb"
    a.rename(meshes / "tmp.glb")
    b.rename(a)
    (meshes / "tmp.glb").rename(b)
    assert "2 of them again" in _vox(meshes.parent, out)
    _vox(meshes.parent, tmp_path / "fresh")
    same = lambda x, y: (x / "chair" / a.with_suffix(".binvox").name).read_bytes() == (y / "chair" / a.with_suffix(".binvox").name).read_bytes()  # noqa: E731
    assert same(out, tmp_path / "fresh")

    from sc3d_data.pipeline.executors import executor

    real = executor.start_executor

    def stopped_after_one(*args, **kwargs):
        pool = real(*args, **kwargs)
        run = pool.run

        def first_then_ctrl_c(tasks):
            for i, result in enumerate(run(tasks)):
                yield result
                raise KeyboardInterrupt
        pool.run = first_then_ctrl_c
        return pool

    with monkeypatch.context() as m:
        m.setattr(executor, "start_executor", stopped_after_one)
        res = run_cli(data_main, ["voxelize", "--meshes", meshes.parent, "--out", out, "--workers", "1",
                                  "--no-progress", "--normalize", "diagonal", "--overwrite"], expect_exit=None)
    assert res.exit_code != 0
    _vox(meshes.parent, out, "--normalize", "diagonal")
    _vox(meshes.parent, tmp_path / "fresh_diagonal", "--normalize", "diagonal")
    files = sorted(p.relative_to(out) for p in out.rglob("*.binvox"))
    assert [f for f in files if (out / f).read_bytes() != (tmp_path / "fresh_diagonal" / f).read_bytes()] == []

    broken = meshes / "dining_chair_katorlegaz.glb"
    times = broken.stat()
    broken.write_bytes(b"not a mesh")
    os.utime(broken, ns=(times.st_atime_ns, times.st_mtime_ns))  # not newer than its grid: --overwrite redoes it
    res = _vox(meshes.parent, out, "--normalize", "fit", "--overwrite")
    (failure,) = json.loads((out / "failures.json").read_text())
    assert failure["removed"].endswith("(made before --overwrite)"), failure
    assert not (out / "chair" / "dining_chair_katorlegaz.binvox").exists()


def test_merge_leaves_no_lock_file_in_a_folder_that_is_no_part(tmp_path):
    """``merge data p0 Documents`` is refused ("no index.json"), and it left
    ``Documents/.sc3d.lock`` beside the user's files: a folder without an index is not locked."""
    parts = _parts(tmp_path)
    docs = tmp_path / "Documents"
    docs.mkdir()
    (docs / "notes.txt").write_text("mine")
    one_error(run_cli(data_main, ["merge", tmp_path / "data", parts[0], docs], expect_exit=1).output)
    assert sorted(p.name for p in docs.iterdir()) == ["notes.txt"]
