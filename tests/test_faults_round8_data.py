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
from conftest import SAMPLE_MESHES, run_cli
from test_faults import FAST, index_of


def _one_error(output: str) -> str:
    errors = [ln for ln in output.splitlines() if ln.startswith("Error:")]
    assert len(errors) == 1 and "Traceback" not in output, output
    return errors[0]


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
    line = _one_error(res.output)
    assert f"{damaged}: SHA-256 differs from the index" in line and "no shard was changed" in line
    assert {p.name: p.read_bytes() for p in [*shards, out / "index.json"]} == before
    res = run_cli(data_main, ["info", out, "--verify"], expect_exit=1)
    assert f"{damaged}: SHA-256 differs from the index" in res.output

