"""Hostile inputs, round two (issue 26), one test per finding E1-E7: names that are not UTF-8,
ShapeNetCore v2 textures, outside textures, the decoded cache, two ``fit`` in one folder, bad
images for ``predict``, and what ``render`` reads and deletes. Real renderer, HDF5, training and
processes; every fixture is built here. Expected values come from the fixtures (a texture's
known colour, the shard's own arrays read by h5py), never from the code under test."""
from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest
from PIL import Image

from sc3d_cli.data import main as data_main
from conftest import REPO, SAMPLE_MESHES, run_cli
from test_faults import CUBE_F, CUBE_V, FAST, index_of, obj_text

CUBE = obj_text(CUBE_V, CUBE_F)


def _no_raw_control(text: str) -> None:
    """No escape/control byte and no undecodable byte in command output."""
    bad = [c for c in text if (ord(c) < 32 and c not in "\n") or 0x7f <= ord(c) < 0xa0 or 0xd800 <= ord(c) < 0xe000]
    assert not bad, f"raw control characters {bad!r} in:\n{text}"


# ----------------------------------------------------------------------------- E1
def test_e1_names_that_are_not_utf8_are_one_failure_each_and_the_rest_renders(tmp_path):
    root = tmp_path / "m"
    chair = root / "chair"
    chair.mkdir(parents=True)
    (chair / "good.obj").write_text(CUBE)
    (chair / "ok\x1bname.obj").write_text(CUBE)                   # valid UTF-8 with an escape: renders
    (chair / "broken\x1b[2J\nx.obj").write_text("not a mesh\n")   # fails; its reason names it
    bad_file = chair / os.fsdecode(b"bad\xff.obj")
    bad_file.write_text(CUBE)
    bad_folder = root / os.fsdecode(b"caf\xe9")                   # a Latin-1 category folder
    bad_folder.mkdir()
    for name in ("a.obj", "b.obj"):
        (bad_folder / name).write_text(CUBE)
    out = tmp_path / "out"
    res = run_cli(data_main, ["render", "--meshes", root, "--out", out, *FAST])
    assert "done 2, resumed 0, skipped 0, failed 3" in res.output
    index = index_of(out)
    assert sorted(Path(o["source"]).name for o in index["objects"]) == ["good.obj", "ok\x1bname.obj"]
    failures = {os.fsencode(f["source"]): f["reason"] for f in index["failures"]}   # lossless names
    assert set(failures) == {os.fsencode(bad_file), os.fsencode(bad_folder), os.fsencode(chair / "broken\x1b[2J\nx.obj")}
    assert failures[os.fsencode(bad_file)].startswith(f"{chair}/bad\\xff.obj: the name is not valid UTF-8")
    assert f"{root}/caf\\xe9: the name is not valid UTF-8" in failures[os.fsencode(bad_folder)]
    assert "(2 under this folder)" in failures[os.fsencode(bad_folder)]
    info = run_cli(data_main, ["info", out]).output
    _no_raw_control(info)
    assert "bad\\xff.obj" in info and "caf\\xe9" in info and "broken\\x1b[2J\\nx.obj" in info
    with h5py.File(out / "shard-00000.h5") as f:
        assert [Path(s.decode()).name for s in f["source"][()]] == ["good.obj", "ok\x1bname.obj"]

    # voxelize --meshes wrote a .binvox for every mesh before and still does (the name is kept)
    vox = tmp_path / "vox"
    run_cli(data_main, ["voxelize", "--meshes", root, "--out", vox, "--no-progress"])
    assert (vox / "chair" / os.fsdecode(b"bad\xff.binvox")).is_file()
    assert (vox / os.fsdecode(b"caf\xe9") / "a.binvox").is_file()


def test_e1_import_r2n2_imports_the_rest_beside_a_model_folder_that_is_not_utf8(tmp_path):
    from test_import_r2n2 import synthesize

    renderings, voxels, _ = synthesize(tmp_path / "r2n2", seed=3)
    syn = sorted(p for p in renderings.iterdir())[0]
    model = sorted(syn.iterdir())[0]
    bad = os.fsdecode(b"model\xff")
    shutil.copytree(model, syn / bad)
    shutil.copytree(voxels / syn.name / model.name, voxels / syn.name / bad)
    out = tmp_path / "out"
    res = run_cli(data_main, ["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out", out,
                              "--no-progress", "--workers", "1"])
    assert "imported 3 of 3 models" in res.output and "1 failed" in res.output
    _no_raw_control(res.output)
    (failure,) = index_of(out)["failures"]
    assert os.fsencode(failure["source"]) == os.fsencode(syn / bad)
    assert f"{syn}/model\\xff: the name is not valid UTF-8" in failure["reason"]


# ----------------------------------------------------------------------------- E2
TEXTURE_RGB = (0, 200, 0)


def _shapenet_v2_model(root: Path, texture: bool = True) -> Path:
    """``root/03001627/m1/models/model_normalized.{obj,mtl}`` whose material (white Kd) takes
    its colour from ``../images/texture0.jpg``, a uniform TEXTURE_RGB image, as in ShapeNetCore v2."""
    model = root / "03001627" / "m1"
    (model / "models").mkdir(parents=True)
    (model / "images").mkdir()
    if texture:
        Image.new("RGB", (16, 16), TEXTURE_RGB).save(model / "images" / "texture0.jpg", quality=95)
    lines = ["mtllib model_normalized.mtl", "usemtl textured"] + [f"v {x} {y} {z}" for x, y, z in CUBE_V]
    lines += [f"vt {x} {y}" for x, y, _ in CUBE_V] + ["f " + " ".join(f"{i + 1}/{i + 1}" for i in f) for f in CUBE_F]
    (model / "models" / "model_normalized.obj").write_text("\n".join(lines) + "\n")
    (model / "models" / "model_normalized.mtl").write_text("newmtl textured\nKd 1 1 1\nmap_Kd ../images/texture0.jpg\n")
    return model


def test_e2_shapenet_v2_textures_in_images_render_with_their_colour(tmp_path):
    _shapenet_v2_model(tmp_path / "v2")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "v2", "--out", out, *FAST])
    index = index_of(out)
    assert index["counts"]["total"] == 1 and index["warnings"] == []
    with h5py.File(out / "shard-00000.h5") as f:
        images, masks = f["images"][0], f["masks"][0].astype(bool)
    inside = images[masks]                                    # [P, 3] pixels of the object
    # shading multiplies the base colour: red and blue of a (0, 200, 0) texture stay 0 (JPEG: a few
    # levels); green is at least the ambient term, (200/255 * 0.2) ** (1/2.2) * 255 = 110. The flat
    # white material drawn instead of the texture would be grey (R = G = B >= 122).
    assert inside[:, 0].max() <= 8 and inside[:, 2].max() <= 8
    assert inside[:, 1].min() >= 105


def test_e2_a_named_texture_that_is_not_loaded_fails_or_is_warned(tmp_path):
    _shapenet_v2_model(tmp_path / "v2", texture=False)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "v2", "--out", out, *FAST], expect_exit=1)
    (failure,) = index_of(out)["failures"]
    assert "model_normalized.obj: texture ../images/texture0.jpg (from model_normalized.mtl) not found" in failure["reason"]
    run_cli(data_main, ["render", "--meshes", tmp_path / "v2", "--out", tmp_path / "fb", "--bad-texture", "fallback",
                        *FAST])
    index = index_of(tmp_path / "fb")
    assert index["counts"]["total"] == 1
    (warning,) = index["warnings"]
    assert "texture0.jpg" in warning["warning"] and "rendered with material colours" in warning["warning"]


# ----------------------------------------------------------------------------- E3
_OPENED: list | None = None


def _audit(event: str, args) -> None:
    if _OPENED is not None and event == "open" and isinstance(args[0], (str, bytes, os.PathLike)):
        _OPENED.append(os.fsdecode(args[0]))


def test_e3_outside_textures_are_judged_from_the_path_and_never_opened(tmp_path):
    """An absolute texture path and an ``.mtl`` outside the dataset folder: ``refuse`` fails
    before opening either; ``warn`` renders without them and says so; nothing outside is opened
    (Python's audit hook sees every ``open``)."""
    global _OPENED
    from sc3d_data.io.meshes import MeshError, load_mesh

    outside = tmp_path / "outside"
    outside.mkdir()
    Image.new("RGB", (8, 8), (200, 30, 30)).save(outside / "secret.png")
    (outside / "far.mtl").write_text(f"newmtl m\nKd 1 1 1\nmap_Kd {outside / 'secret.png'}\n")
    d = tmp_path / "ds" / "chair"
    d.mkdir(parents=True)
    (d / "abs.mtl").write_text(f"newmtl m\nKd 1 1 1\nmap_Kd {outside / 'secret.png'}\n")
    (d / "abs.obj").write_text(obj_text(CUBE_V, CUBE_F, "mtllib abs.mtl\nusemtl m"))
    (d / "far.obj").write_text(obj_text(CUBE_V, CUBE_F, "mtllib ../../outside/far.mtl\nusemtl m"))
    sys.addaudithook(_audit)
    for name, leaked in (("abs.obj", "secret.png"), ("far.obj", "far.mtl")):
        _OPENED = []
        with pytest.raises(MeshError, match=f"{name}: .*{leaked}.* outside the dataset folder.*refused"):
            load_mesh(d / name, root=tmp_path / "ds", outside_textures="refuse")
        refused = _OPENED
        _OPENED = []
        scene, _, _, warnings = load_mesh(d / name, root=tmp_path / "ds", outside_textures="warn")
        warned, _OPENED = _OPENED, None
        assert not [p for p in refused + warned if p.startswith(str(outside))], (refused, warned)
        assert any(leaked in w and "not read; rendered without it" in w for w in warnings), warnings
        assert all(getattr(getattr(g.visual, "material", None), "image", None) is None for g in scene.geometry.values())


# ----------------------------------------------------------------------------- E4
@pytest.fixture(scope="module")
def chair_shards(tmp_path_factory) -> Path:
    """The sample chairs, one per shard, 4 views each."""
    out = tmp_path_factory.mktemp("chairs") / "data"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "chair", "--out", out, "--objects-per-shard", "1",
                        "--split", "random:1,0,0", *FAST])
    assert len(index_of(out)["shards"]) >= 2
    return out


def _stored_views(paths: list[str]) -> dict:
    """Each shard's images and masks of row 0 as h5py reads them: the reference."""
    out = {}
    for i, p in enumerate(paths):
        with h5py.File(p) as f:
            out[i] = {"images": f["images"][0], "masks": f["masks"][0]}
    return out


def _assert_cache_matches(cache, stored: dict) -> None:
    n, V = len(stored), stored[0]["images"].shape[0]
    shard = np.repeat(np.arange(n), V)
    got = cache.views(shard, np.zeros(n * V, dtype=int), np.tile(np.arange(V), n))
    for i in range(n):
        np.testing.assert_array_equal(got["images"][i * V:(i + 1) * V], stored[i]["images"])
        np.testing.assert_array_equal(got["masks"][i * V:(i + 1) * V], stored[i]["masks"])


def test_e4_decoded_cache_entries_are_verified_against_their_shard(chair_shards, tmp_path):
    from sc3d_data.io.shards import ShardError, load_index, shard_path
    from sc3d_train.data.decoded_cache import DecodedCache

    paths = [str(shard_path(chair_shards, e["file"])) for e in load_index(chair_shards)["shards"]]
    keys = [e["sha256"] for e in load_index(chair_shards)["shards"]]
    stored = _stored_views(paths)
    cache_dir = tmp_path / "cache"

    def reopen():
        return DecodedCache(cache_dir, chair_shards, paths, 48, False)

    _assert_cache_matches(reopen(), stored)
    a, b = cache_dir / keys[0], cache_dir / keys[1]
    os.rename(a, tmp_path / "swap")                      # swap two shards' entries
    os.rename(b, a)
    os.rename(tmp_path / "swap", b)
    _assert_cache_matches(reopen(), stored)
    images = cache_dir / keys[0] / "images.npy"
    with open(images, "r+b") as f:                       # overwrite: same size, pixels zeroed
        f.seek(-4096, os.SEEK_END)
        f.write(bytes(4096))
    _assert_cache_matches(reopen(), stored)
    with open(images, "r+b") as f:                       # truncation
        f.truncate(images.stat().st_size // 2)
    _assert_cache_matches(reopen(), stored)
    # cut short after it was verified: the mapping fails in one line naming the file
    cache = reopen()
    with open(images, "r+b") as f:
        f.truncate(1000)
    with pytest.raises(ShardError, match=f"{images}: cannot map the decoded cache file"):
        cache.views(np.zeros(1, dtype=int), np.zeros(1, dtype=int), np.zeros(1, dtype=int))


# ----------------------------------------------------------------------------- E5
def test_e5_a_second_fit_into_the_same_folder_is_refused(sample_shards, tmp_path):
    from sc3d_cli.train import main as train_main

    run = tmp_path / "run"
    common = ["--shards", sample_shards, "--out", run, "--batch-size", "2", "--tiny", "--base-channels", "4",
              "--no-progress", "--checkpoint-every", "1"]
    first = subprocess.Popen([sys.executable, "-c", "import sc3d_cli.train as t; t.main()", "fit", *map(str, common),
                              "--steps", "100000", "--seed", "1"], cwd=REPO, stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True, env=dict(os.environ, PYTHONPATH=str(REPO)))
    try:
        deadline = time.monotonic() + 240
        while not (run / "checkpoints" / "last.pt").is_file():
            assert first.poll() is None and time.monotonic() < deadline, first.stdout.read() if first.poll() else "timeout"
            time.sleep(0.2)
        config = (run / "config.yaml").read_text()
        res = run_cli(train_main, ["fit", *common, "--steps", "2", "--seed", "2"], expect_exit=1)
        assert f"{run}: another process (PID {first.pid}: sc3d-train fit) is writing to this folder" in res.output
        assert len(res.output.strip().splitlines()) == 1
        res = run_cli(train_main, ["fit", *common, "--steps", "100001", "--resume"], expect_exit=1)
        assert f"PID {first.pid}" in res.output
        assert (run / "config.yaml").read_text() == config and "seed: 1" in config
    finally:
        first.kill()
        first.wait()
    # the lock died with its process: the run can be resumed
    res = run_cli(train_main, ["fit", "--out", run, "--resume", "--steps", "2", "--no-progress"], expect_exit=None)
    assert "another process" not in res.output


# ----------------------------------------------------------------------------- E6
def _png_header_only(path: Path, width: int, height: int) -> None:
    """A PNG whose header says ``width`` x ``height`` (8-bit RGB) with one empty IDAT: the size
    of a decompression bomb without its bytes."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"")) +
                     chunk(b"IEND", b""))


def test_e6_predict_names_a_huge_or_broken_image_in_one_line(trained_run, tmp_path):
    from sc3d_cli.train import main as train_main

    ckpt = trained_run / "checkpoints" / "last.pt"
    _png_header_only(tmp_path / "bomb.png", 20000, 20000)          # 400 Mpx: over PIL's bomb limit
    _png_header_only(tmp_path / "big.png", 10000, 10000)           # 100 Mpx: PIL only warns
    _png_header_only(tmp_path / "cut.png", 64, 64)                 # right size, no pixel data
    (tmp_path / "text.png").write_text("not an image\n")
    expected = {"bomb.png": "image too large to open", "big.png": "image too large to open",
                "cut.png": "cannot read image", "text.png": "cannot read image"}
    for name, reason in expected.items():
        r = run_cli(train_main, ["predict", "--checkpoint", ckpt, tmp_path / name, "--out", tmp_path / "p"],
                    expect_exit=1)
        assert r.output.startswith(f"Error: {tmp_path / name}: {reason}"), r.output
        assert len(r.output.strip().splitlines()) == 1 and "Traceback" not in r.output
    assert not (tmp_path / "p").exists()


# ----------------------------------------------------------------------------- E7
def test_e7_overwrite_deletes_only_the_files_its_index_lists(tmp_path):
    (tmp_path / "m" / "chair").mkdir(parents=True)
    (tmp_path / "m" / "chair" / "cube.obj").write_text(CUBE)
    out = tmp_path / "out"
    args = ["render", "--meshes", tmp_path / "m", "--out", out, *FAST]
    run_cli(data_main, args)
    foreign = out / "shard-00007.h5"                     # named like a shard, not written by sc3d
    foreign.write_bytes(b"not written by sc3d")
    listed = (out / "shard-00000.h5").stat().st_ino
    os.link(out / "shard-00000.h5", tmp_path / "old.h5")  # holds the old inode: a new file cannot reuse it
    run_cli(data_main, args + ["--overwrite"])
    assert foreign.read_bytes() == b"not written by sc3d"
    assert index_of(out)["counts"]["total"] == 1 and (out / "shard-00000.h5").stat().st_ino != listed


def test_e7_big_and_special_mesh_files_are_refused_before_parsing(tmp_path):
    root = tmp_path / "m" / "chair"
    root.mkdir(parents=True)
    (root / "cube.obj").write_text(CUBE)
    (root / "padded.obj").write_text(CUBE + "# " + "x" * (2 * 2**20) + "\n")   # 2 MiB of comment
    os.symlink("/dev/zero", root / "zero.obj")
    os.mkfifo(root / "fifo.obj")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--max-file-mib", "1", *FAST])
    index = index_of(out)
    assert [Path(o["source"]).name for o in index["objects"]] == ["cube.obj"]
    (failure,) = index["failures"]
    assert failure["reason"] == (f"{root / 'padded.obj'}: {(root / 'padded.obj').stat().st_size:,} bytes, over the "
                                 f"limit of {2**20:,} per mesh file (--max-file-mib); not parsed")
    skipped = {Path(s["source"]).name: s["reason"] for s in index["skipped"]}
    assert skipped["zero.obj"] == "not a regular file (character device, a symlink to /dev/zero); not read"
    assert skipped["fifo.obj"] == "not a regular file (FIFO); not read"
    from sc3d_data.io.meshes import MeshError, load_mesh

    for name, kind in (("zero.obj", "character device"), ("fifo.obj", "FIFO")):  # never opened: no hang
        with pytest.raises(MeshError, match=f"{name}: not a regular file but a {kind}"):
            load_mesh(root / name)
