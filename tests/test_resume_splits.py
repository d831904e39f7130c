"""A rerun into an existing output folder must not keep objects under one split in their shards
while ``index.json`` states another. Before: ``render`` (and ``import-r2n2``) resumed the kept
objects with the split stored in their shards and wrote the new split rule's counts into the
index (an edited ``--split-file``, or ``--split r2n2`` over a folder that gained meshes), so
training on the index's ``train`` read test objects. Now such a rerun is refused in one line
before any work, and the folder is left as it was; the default random split, which never moves
an object when others are added, still resumes. Real renders of tiny OBJ cubes; the expected
splits come from the split files written here and from the rules as documented (3D-R2N2: per
category, ids sorted, first int(0.8 n) train), never from the code under test."""
from __future__ import annotations

import hashlib
from collections import Counter
from pathlib import Path

import h5py

from conftest import run_cli
from sc3d_cli.data import main as data_main
from test_faults import CUBE_F, CUBE_V, FAST, index_of, obj_text


def _cubes(folder: Path, names) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        (folder / f"{name}.obj").write_text(obj_text(CUBE_V, CUBE_F))


def _render(meshes: Path, out: Path, *extra, expect_exit: int = 0):
    return run_cli(data_main, ["render", "--meshes", meshes, "--out", out, *FAST, *extra], expect_exit=expect_exit)


def _shard_splits(out: Path) -> dict[str, str]:
    """``{model_id: split}`` as the shards the index lists hold them."""
    found = {}
    for s in index_of(out)["shards"]:
        with h5py.File(out / s["file"], "r") as f:
            for mid, split in zip(f["model_id"][()], f["split"][()]):
                found[mid.decode()] = split.decode()
    return found


def _index_splits(out: Path) -> dict[str, str]:
    return {o["model_id"]: o["split"] for o in index_of(out)["objects"]}


def _folder_bytes(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.iterdir()) if p.is_file()}


def _assert_refused(res, out: Path, n: int, example: str) -> None:
    lines = res.output.strip().splitlines()
    assert len(lines) == 1, res.output
    line = lines[0]
    assert str(out) in line and f"{n} kept object" in line and example in line, line
    assert "--out" in line and "split" in line, line


def test_edited_split_file_is_refused_and_the_folder_is_left_unchanged(tmp_path):
    _cubes(tmp_path / "m" / "chair", ["a", "b"])
    split_file, out = tmp_path / "split.txt", tmp_path / "out"
    split_file.write_text("train chair/a\ntrain chair/b\n")
    _render(tmp_path / "m", out, "--split-file", split_file)
    assert _shard_splits(out) == _index_splits(out) == {"a": "train", "b": "train"}
    before = _folder_bytes(out)

    split_file.write_text("test chair/a\ntrain chair/b\n")  # a moves train -> test
    res = _render(tmp_path / "m", out, "--split-file", split_file, expect_exit=1)
    _assert_refused(res, out, 1, "/a: train -> test")
    assert _folder_bytes(out) == before
    assert _shard_splits(out) == _index_splits(out) == {"a": "train", "b": "train"}

    # the unchanged split file still resumes everything
    split_file.write_text("train chair/a\ntrain chair/b\n")
    assert "done 0, resumed 2" in _render(tmp_path / "m", out, "--split-file", split_file).output


def test_r2n2_split_over_added_meshes_that_move_a_kept_object_is_refused(tmp_path):
    meshes, out = tmp_path / "m", tmp_path / "out"
    _cubes(meshes / "chair", ["a", "b"])
    _render(meshes, out, "--split", "r2n2")
    # 2 chairs: int(0.8 * 2) = 1 train -> a train, b test
    assert _shard_splits(out) == _index_splits(out) == {"a": "train", "b": "test"}
    before = _folder_bytes(out)

    _cubes(meshes / "chair", ["c", "d"])  # 4 chairs: int(0.8 * 4) = 3 train -> b becomes train
    res = _render(meshes, out, "--split", "r2n2", expect_exit=1)
    _assert_refused(res, out, 1, "/b: test -> train")
    assert _folder_bytes(out) == before


def test_default_random_split_over_added_meshes_still_resumes(tmp_path):
    meshes, out = tmp_path / "m", tmp_path / "out"
    _cubes(meshes / "chair", ["a", "b"])
    _render(meshes, out)
    first = _index_splits(out)
    assert sorted(first) == ["a", "b"]

    _cubes(meshes / "chair", ["c", "d"])
    res = _render(meshes, out)
    assert "done 2, resumed 2" in res.output, res.output
    index = index_of(out)
    assert sorted(o["model_id"] for o in index["objects"]) == ["a", "b", "c", "d"]
    assert _index_splits(out) == _shard_splits(out)
    assert {k: v for k, v in _index_splits(out).items() if k in first} == first
    assert index["split"]["counts"] == dict(Counter(_shard_splits(out).values()))
    # the documented rule: u = int(sha256(f"{seed}/{category}/{model_id}")[:16], 16) / 2**64, 0.7/0.1/0.2
    for o in index["objects"]:
        u = int(hashlib.sha256(f"0/{o['category']}/{o['model_id']}".encode()).hexdigest()[:16], 16) / 2.0 ** 64
        assert o["split"] == ("train" if u < 0.7 else "val" if u < 0.8 else "test"), o


def test_import_r2n2_with_an_edited_split_file_is_refused(tmp_path):
    from test_import_r2n2 import synthesize

    renderings, voxels, _ = synthesize(tmp_path / "r2n2", seed=3)  # c182_fgai, chair2_blendswap, dining_chair_katorlegaz
    split_file, out = tmp_path / "split.txt", tmp_path / "out"
    args = ["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out", out, "--no-progress",
            "--workers", "1", "--split-file", split_file]
    split_file.write_text("train c182_fgai\ntrain chair2_blendswap\ntest dining_chair_katorlegaz\n")
    run_cli(data_main, args)
    expected = {"c182_fgai": "train", "chair2_blendswap": "train", "dining_chair_katorlegaz": "test"}
    assert _shard_splits(out) == _index_splits(out) == expected
    before = _folder_bytes(out)

    split_file.write_text("train c182_fgai\ntest chair2_blendswap\ntrain dining_chair_katorlegaz\n")
    res = run_cli(data_main, args, expect_exit=1)
    _assert_refused(res, out, 2, "/chair2_blendswap: train -> test")
    assert _folder_bytes(out) == before
