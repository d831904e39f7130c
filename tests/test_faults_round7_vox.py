"""Hostile inputs, round seven (merge and voxelize): a file of the user's in the merge folder, a
failed voxelize that a rerun should retry, full disks during voxelize, merge and render, and the
dataset kinds voxelize cannot work on. Real renderer, real HDF5, real worker processes, real
ENOSPC (a tmpfs, as ``test_faults._in_tmpfs``); expected values come from the fixtures."""
from __future__ import annotations

import os
import shutil
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from sc3d_cli.data import main as data_main
from conftest import SAMPLE_MESHES, run_cli, one_error
from test_faults import FAST, _in_tmpfs, index_of

CLI = f"{sys.executable} -c 'import sc3d_cli.data as d; d.main()'"


@pytest.fixture(scope="module")
def parts(tmp_path_factory) -> list[Path]:
    """The two part folders of a `render --part I/2` of the chair meshes (4 views)."""
    root = tmp_path_factory.mktemp("parts")
    shutil.copytree(SAMPLE_MESHES / "chair", root / "m" / "chair")
    dirs = [root / f"p{i}" for i in range(2)]
    for i, d in enumerate(dirs):
        run_cli(data_main, ["render", "--meshes", root / "m", "--out", d, "--part", f"{i}/2", *FAST])
    return dirs


def test_merge_refuses_a_file_of_the_users_named_like_a_shard(parts, tmp_path):
    """`render` refuses an unlisted shard-named file that is no shard of its settings; merge
    replaced it silently. It now refuses the same way (nothing written), and --overwrite replaces it."""
    out = tmp_path / "m"
    out.mkdir()
    (out / "shard-00000.h5").write_text("precious\n")
    res = run_cli(data_main, ["merge", out, *parts], expect_exit=1)
    line = one_error(res.output)
    assert f"{out / 'shard-00000.h5'}: named like a shard this merge writes" in line and "--overwrite" in line
    assert (out / "shard-00000.h5").read_text() == "precious\n"
    assert not (out / "index.json").exists() and not (out / "shard-00001.h5").exists()
    run_cli(data_main, ["merge", "--overwrite", out, *parts])
    assert (out / "shard-00000.h5").read_bytes() == (parts[0] / "shard-00000.h5").read_bytes()
    run_cli(data_main, ["merge", out, *parts])  # a rerun over its own (listed) shards still works


def test_merge_copy_on_a_full_disk_names_the_destination_and_leaves_no_tmp(parts):
    """shutil's ENOSPC names the file copied FROM: the error blamed a part's shard and left
    OUT/shard-NNNNN.h5.tmp. Now: the destination is named and no .tmp is left."""
    total = sum((p / "shard-00000.h5").stat().st_size for p in parts) // 1024
    r = _in_tmpfs(textwrap.dedent(f"""
        A=$(df -k --output=avail $T | tail -1)
        fallocate -l $(( (A - {total} / 2) * 1024 )) $T/filler
        {CLI} merge --copy $T/m {parts[0]} {parts[1]}; echo "rc=$?"
        echo "tmp_left=$(ls $T/m | grep -c '\\.tmp$')"
        """), size="1m")
    line = one_error(r.stdout)
    assert "rc=1\n" in r.stdout and "No space left on device" in line, r.stdout
    assert "/m/shard-0000" in line and str(parts[0]) not in line and str(parts[1]) not in line, line
    assert "tmp_left=0" in r.stdout, r.stdout


def _voxels_by_id(out: Path) -> dict:
    import h5py
    import numpy as np

    grids = {}
    for entry in index_of(out)["shards"]:
        with h5py.File(out / entry["file"], "r") as f:
            for mid, g in zip(f["model_id"].asstr()[()], f["voxels"][()]):
                grids[mid] = np.asarray(g)
    return grids


def test_voxelize_rerun_retries_the_objects_that_failed(tmp_path):
    """A voxelize rerun skipped every shard that had voxels, so an object that failed (its mesh
    moved away) kept its empty grid and failure record, and the rerun said `0 failed`. Now a
    rerun voxelizes the failed objects again (the other grids are kept), and counts what still
    fails. Expected grids: a voxelize of the same shards with every mesh in place."""
    meshes = tmp_path / "m" / "chair"
    shutil.copytree(SAMPLE_MESHES / "chair", meshes)
    out, ref = tmp_path / "vr", tmp_path / "ref"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--objects-per-shard", "2", *FAST])
    shutil.copytree(out, ref)
    run_cli(data_main, ["voxelize", ref, "--no-progress"])
    expected = _voxels_by_id(ref)
    victim = meshes / "chair2_blendswap.glb"
    victim.rename(tmp_path / "away.glb")
    res = run_cli(data_main, ["voxelize", out, "--no-progress"])
    assert ", 1 failed" in res.output, res.output
    res = run_cli(data_main, ["voxelize", out, "--no-progress"], expect_exit=None)  # still missing: fails again
    assert ", 1 failed" in res.output and "voxelized 0 objects in 1 shards" in res.output, res.output
    assert res.exit_code == 0 and "Error" not in res.output  # the other objects have their grids
    assert [f["model_id"] for f in index_of(out)["failures"]] == ["chair2_blendswap"]
    (tmp_path / "away.glb").rename(victim)
    res = run_cli(data_main, ["voxelize", out, "--no-progress"])
    assert "voxelized 1 objects in 1 shards" in res.output and ", 0 failed" in res.output, res.output
    index = index_of(out)
    assert index["failures"] == [] and index["voxels"]["failed"] == 0
    got = _voxels_by_id(out)
    assert sorted(got) == sorted(expected) and got["chair2_blendswap"].any()
    for mid, grid in expected.items():
        assert (got[mid] == grid).all(), mid
    run_cli(data_main, ["info", out, "--verify"])


def test_voxelize_on_a_full_disk_fails_in_one_line_and_keeps_the_shard(tmp_path):
    """The disk filling while HDF5 wrote the new voxels into the shard's temporary copy made h5py
    crash (segfault, exit 139, 'Exception ignored' tracebacks) and left a shard-sized .tmp. Now:
    one line naming the shard, exit 1, no .tmp, the shard's bytes unchanged. Free space: the
    shard's size + 4 KiB, so the copy fits and the voxels do not."""
    ds = tmp_path / "ds"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", ds, *FAST])
    r = _in_tmpfs(textwrap.dedent(f"""
        cp -r {ds} $T/ds
        before=$(cat $T/ds/shard-*.h5 | sha256sum)
        K=$(( $(stat -c %s $T/ds/shard-00000.h5) / 1024 )); A=$(df -k --output=avail $T | tail -1)
        fallocate -l $(( (A - K - 4) * 1024 )) $T/filler
        {CLI} voxelize $T/ds --resolution 64 --no-progress; echo "rc=$?"
        echo "tmp_left=$(ls $T/ds | grep -c '\\.tmp$')"
        [ "$(cat $T/ds/shard-*.h5 | sha256sum)" = "$before" ] && echo same
        rm $T/filler
        {CLI} info --verify $T/ds > /dev/null; echo "verify=$?"
        """), size="4m")
    line = one_error(r.stdout)
    assert "Segmentation" not in r.stdout and "Exception ignored" not in r.stdout, r.stdout
    assert line.endswith("/ds/shard-00000.h5: cannot rewrite shard (No space left on device)"), r.stdout
    assert "rc=1\n" in r.stdout and "tmp_left=0" in r.stdout and "same" in r.stdout, r.stdout
    assert "verify=0" in r.stdout, r.stdout


def test_render_on_a_full_disk_says_no_space_in_one_line(tmp_path):
    """With ~150 KiB free, writing the first shard failed in HDF5's close, whose two-line report
    ('Can't close file (file write failed: time = ...\\n, filename = ..., errno = 28, ...)') was
    printed as the reason. Now the reason is the system's one line for errno 28."""
    r = _in_tmpfs(textwrap.dedent(f"""
        A=$(df -k --output=avail $T | tail -1)
        fallocate -l $(( (A - 150) * 1024 )) $T/filler
        {CLI} render --meshes {SAMPLE_MESHES} --out $T/out --workers 2 --no-progress; echo "rc=$?"
        echo "tmp_left=$(ls $T/out | grep -c '\\.tmp$')"
        """), size="2m")
    line = one_error(r.stdout)
    assert line.endswith("/out/shard-00000.h5: cannot write shard (No space left on device)"), r.stdout
    assert "rc=1\n" in r.stdout and "tmp_left=0" in r.stdout and "errno =" not in r.stdout, r.stdout


def test_voxelize_refuses_an_r2n2_import_in_one_line(tmp_path):
    """An import-r2n2 dataset has R2N2's own voxels and never had meshes; voxelize answered that
    none of its 'source meshes' exists (the rendering folders) 'also looked for under None'.
    Now one line says what the dataset is, and its shards are not touched."""
    from test_import_r2n2 import synthesize

    renderings, voxels, _ = synthesize(tmp_path / "r2n2", seed=3)
    out = tmp_path / "imported"
    run_cli(data_main, ["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out", out, "--no-progress"])
    before = {p.name: p.read_bytes() for p in out.glob("*.h5")}
    for extra in ([], ["--resolution", "64"], ["--overwrite"]):
        res = run_cli(data_main, ["voxelize", out, "--no-progress", *extra], expect_exit=1)
        line = one_error(res.output)
        assert f"{out}: imported from 3D-R2N2" in line and "32^3 voxels" in line and "None" not in line, line
    assert {p.name: p.read_bytes() for p in out.glob("*.h5")} == before


def test_voxelize_shards_honours_timeout(tmp_path):
    """`voxelize SHARDS` accepted --timeout and ignored it (no limit: a hung mesh loader stalled
    the run for ever). Fixture: a glTF rendered with its buffer a regular file, whose buffer is
    then replaced by a FIFO nobody writes (the .gltf itself, the file fingerprinted, is
    unchanged), so its loader blocks. Now that object fails with the time limit's reason, the
    others get their grids, and the run ends."""
    import subprocess

    from conftest import write_hanging_gltf

    chair = tmp_path / "m" / "chair"
    chair.mkdir(parents=True)
    shutil.copy(SAMPLE_MESHES / "chair" / "chair2_blendswap.glb", chair)
    gltf = write_hanging_gltf(chair)
    buffer = chair / "hang.bin"
    buffer.unlink()
    buffer.write_bytes(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0]], np.float32).tobytes())  # one triangle
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["counts"]["total"] == 2
    buffer.unlink()
    os.mkfifo(buffer)
    r = subprocess.run([sys.executable, "-c", "import sc3d_cli.data as d; d.main()", "voxelize", str(out),
                        "--no-progress", "--timeout", "2", "--workers", "1"], timeout=90,
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert r.returncode == 0 and "voxelized 1 objects" in r.stdout and ", 1 failed" in r.stdout, r.stdout
    [failure] = index_of(out)["failures"]
    assert failure["stage"] == "voxelize" and failure["source"] == str(gltf)
    assert "timed out after 2 s (--timeout)" in failure["reason"], failure


def test_merge_removes_the_temporary_files_of_a_killed_merge(parts, tmp_path):
    """A merge killed while placing a shard or writing the index leaves ``NAME.tmp`` files
    (``_place``, the atomic index writer); render's rerun deletes those of a killed render, and
    merge's rerun now does the same: after it the folder holds the shards and the index only."""
    out = tmp_path / "m"
    out.mkdir()
    for name in ("shard-00000.h5.tmp", "shard-00007.h5.tmp", "index.json.tmp"):
        (out / name).write_bytes(b"half of a file")
    run_cli(data_main, ["merge", out, *parts])
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == \
        ["index.json", "shard-00000.h5", "shard-00001.h5"]
