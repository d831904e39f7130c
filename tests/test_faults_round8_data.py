"""Hostile inputs, round eight (the data commands): damage that a rewrite would launder, two
writers of one ``voxelize --meshes`` folder, cameras that overflow, report files that are hard
links to the data. Real renderer, real HDF5, real worker processes; expected values are derived
by hand from the inputs."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import h5py
import pytest

from sc3d_cli.data import main as data_main
from conftest import SAMPLE_MESHES, run_cli, one_error
from test_faults import FAST, index_of


def flip_bytes_in_a_chunk(shard: Path, dataset: str = "images") -> None:
    """XOR 8 bytes in the middle of the first stored chunk of ``dataset``: the file keeps its
    size, HDF5's Fletcher-32 of that chunk no longer matches, nothing else changes."""
    with h5py.File(shard, "r") as f:
        info = f[dataset].id.get_chunk_info(0)
    with open(shard, "r+b") as g:
        g.seek(info.byte_offset + info.size // 2)
        data = g.read(8)
        g.seek(info.byte_offset + info.size // 2)
        g.write(bytes(b ^ 0x55 for b in data))


@pytest.mark.parametrize("overwrite", [False, True])
def test_voxelize_refuses_a_damaged_shard_instead_of_recording_the_damage_as_good(tmp_path, overwrite):
    """``voxelize SHARDS`` rewrote a shard whose image chunk was damaged, copying the chunk as it
    was, and wrote the new file's SHA-256 into the index: ``info --verify`` then passed and the
    damage could no longer be found. Now it refuses in one line naming the shard, before any
    shard is changed (shard and index byte-identical), and ``info --verify`` still reports it."""
    meshes = tmp_path / "m"
    shutil.copytree(SAMPLE_MESHES / "chair", meshes / "chair")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", meshes, "--out", out, "--objects-per-shard", "1",
                        *([] if not overwrite else ["--voxelize"]), *FAST])
    shards = sorted(out.glob("shard-*.h5"))
    assert len(shards) >= 2
    damaged = shards[-1]
    flip_bytes_in_a_chunk(damaged)
    before = {p.name: p.read_bytes() for p in [*shards, out / "index.json"]}
    res = run_cli(data_main, ["voxelize", out, "--no-progress", *(["--overwrite"] if overwrite else [])],
                  expect_exit=1)
    line = one_error(res.output)
    assert f"{damaged}: SHA-256 differs from the index" in line and "no shard was changed" in line
    assert {p.name: p.read_bytes() for p in [*shards, out / "index.json"]} == before
    res = run_cli(data_main, ["info", out, "--verify"], expect_exit=1)
    assert f"{damaged}: SHA-256 differs from the index" in res.output


def test_voxelize_meshes_takes_the_folders_write_lock_and_parts_share_it(tmp_path):
    """Two ``voxelize --meshes`` into one --out (one at 64^3, one at 32^3 with --overwrite) both ran
    to the end and left a folder of 32^3 and 64^3 files under a voxelize.json saying 32. Now a
    whole run holds the folder's lock alone, and the parts of one ``--part I/N`` job (which
    write into one folder by design) share it, each holding its own part's lock: the other
    process is played here by this one, holding the locks the other command would hold."""
    from sc3d_data.io.outlock import exclusive_lock
    from sc3d_data.pipeline.jobs.voxel_meshes import folder_locks
    from sc3d_data.pipeline.run.partition import Part

    meshes, out = tmp_path / "m", tmp_path / "vox"
    shutil.copytree(SAMPLE_MESHES / "chair", meshes / "chair")
    out.mkdir()
    run = ["voxelize", "--meshes", meshes, "--out", out, "--no-progress", "--workers", "1"]
    with exclusive_lock(out, "sc3d-data voxelize --meshes"):  # a whole run at work
        line = one_error(run_cli(data_main, run, expect_exit=1).output)
        assert f"{out}: another process (PID {os.getpid()}: sc3d-data voxelize --meshes)" in line
        line = one_error(run_cli(data_main, [*run, "--part", "1/2"], expect_exit=1).output)
        assert "is writing to this folder" in line
    assert not list(out.rglob("*.binvox"))
    with folder_locks(out, Part(0, 2)):  # part 0 of 2 at work: part 1 runs, part 0 and a whole run do not
        run_cli(data_main, [*run, "--part", "1/2"])
        done = sorted(out.rglob("*.binvox"))
        assert 0 < len(done) < 4
        one_error(run_cli(data_main, [*run, "--part", "0/2"], expect_exit=1).output)
        one_error(run_cli(data_main, run, expect_exit=1).output)
    run_cli(data_main, run)  # alone: the whole folder
    assert len(sorted(out.rglob("*.binvox"))) == 4


def test_reports_never_write_through_a_hard_link_to_the_dataset(tmp_path):
    """``check --json`` and ``preview --out`` refused the dataset's own files by name and through
    symlinks, but a hard link (another name of the same inode) was written in place: the index
    became the report, the shard was truncated. Each is now one line and the dataset keeps its
    bytes; a report beside the data still works."""
    meshes = tmp_path / "m"
    shutil.copytree(SAMPLE_MESHES / "chair", meshes / "chair")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", meshes, "--out", out, "--voxelize", *FAST])
    index, shard = out / "index.json", out / "shard-00000.h5"
    os.link(index, tmp_path / "report.json")
    os.link(shard, tmp_path / "sheet.png")
    before = {p: p.read_bytes() for p in (index, shard)}
    res = run_cli(data_main, ["check", out, "--json", tmp_path / "report.json", "--no-progress"], expect_exit=1)
    assert "the same file as the dataset's index.json" in one_error(res.output) and "hard link" in res.output
    res = run_cli(data_main, ["preview", out, "--out", tmp_path / "sheet.png"], expect_exit=1)
    assert "the same file as the dataset's shard-00000.h5" in one_error(res.output)
    assert {p: p.read_bytes() for p in before} == before
    run_cli(data_main, ["check", out, "--json", tmp_path / "check.json", "--no-progress"])


def test_files_that_are_no_mesh_fail_with_what_is_wrong_with_them(tmp_path):
    """Each of these failed its object, but the reason did not say what was wrong: a truncated
    .gltf read "FileNotFoundError: model.gltf: not found" (a file that does not exist), a .gltf
    holding ``[]`` "AttributeError: 'list' object has no attribute 'get'", a .glb without its
    header "buffer size must be a multiple of element size", an OBJ with 2-coordinate vertices a
    numpy matmul error. Each reason now names the file and the problem; the good mesh renders."""
    meshes = tmp_path / "m" / "chair"
    meshes.mkdir(parents=True)
    shutil.copy(SAMPLE_MESHES / "chair" / "chair2_blendswap.glb", meshes / "good.glb")
    (meshes / "trunc.gltf").write_text('{"asset":{"version":"2.0"')
    (meshes / "list.gltf").write_text("[]")
    (meshes / "magic.glb").write_bytes(b"NOTGLB_____________")
    (meshes / "short.glb").write_bytes(b"glTF")
    (meshes / "flat.obj").write_text("v 1 2\nv 0 0\nv 1 1\nf 1 2 3\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    index = index_of(out)
    assert [o["model_id"] for o in index["objects"]] == ["good"]
    reasons = {Path(f["source"]).name: f["reason"] for f in index["failures"]}
    assert "trunc.gltf: not a glTF document: invalid JSON (Expecting ',' delimiter at line 1 column 26)" in reasons["trunc.gltf"]
    assert "list.gltf: not a glTF document: its JSON is list [], not an object" in reasons["list.gltf"]
    for name in ("magic.glb", "short.glb"):
        assert f"{name}: not a GLB file (no glTF header and JSON chunk)" in reasons[name]
    assert "flat.obj: the vertices of 'flat.obj' have 2 coordinates, expected 3" in reasons["flat.obj"]


def test_a_render_whose_every_mesh_failed_says_why_the_first_did(tmp_path):
    """``render`` of one broken mesh said only "no object was rendered: all 1 failed"; the reason
    took another command (``info``). The error line now carries the first failure's reason."""
    meshes = tmp_path / "m" / "chair"
    meshes.mkdir(parents=True)
    (meshes / "list.gltf").write_text("[]")
    res = run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", tmp_path / "out", *FAST], expect_exit=1)
    line = one_error(res.output)
    assert line.startswith("Error: no object was rendered: all 1 failed (first: ")
    assert f"{meshes / 'list.gltf'}: not a glTF document" in line


def test_info_says_each_failure_once_and_a_gltf_texture_is_a_texture_once(tmp_path):
    """``info`` printed ``bad/cat/degen.obj: bad/cat/degen.obj: zero surface area`` (the reason
    already names its file), and a glTF image that is missing read ``texture texture image 0
    (...) not found``."""
    import json

    from test_gltf_primitives import _cube, _write_gltf

    meshes = tmp_path / "m" / "chair"
    meshes.mkdir(parents=True)
    (meshes / "degen.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    doc = _write_gltf(meshes / "untextured.gltf", [(*_cube(), 4)])
    doc["images"], doc["textures"] = [{"uri": "missing.png"}], [{"source": 0}]  # an image a texture reads
    (meshes / "untextured.gltf").write_text(json.dumps(doc))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    info = run_cli(data_main, ["info", out]).output
    degen = [ln.strip() for ln in info.splitlines() if "degen.obj" in ln]
    assert degen and all(ln.count(str(meshes / "degen.obj")) == 1 for ln in degen), info
    # no material draws that texture: a warning since io.gltf_images, not a failure
    assert "texture image 0 (missing.png) (read by no base colour texture) not found" in info, info
    assert "texture texture" not in info, info
