"""Shared fixtures: the bundled sample meshes rendered and voxelized once per test session
with the real renderer and voxelizer (through the CLI, as a user would)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
from click.testing import CliRunner

REPO = Path(__file__).resolve().parents[1]
SAMPLE_MESHES = REPO / "assets" / "sample_meshes"

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")


def write_hanging_gltf(folder: Path, name: str = "hang") -> Path:
    """``folder/NAME.gltf`` whose buffer is a FIFO nobody writes to: its loader blocks forever
    (a real pathological input for the per-object time limit)."""
    import json

    os.mkfifo(folder / f"{name}.bin")
    path = folder / f"{name}.gltf"
    path.write_text(json.dumps({
        "asset": {"version": "2.0"}, "buffers": [{"uri": f"{name}.bin", "byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}], "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}], "scene": 0}))
    return path


def objects_by_id(out: Path) -> dict:
    """``{(category, model_id): {name: array or string}}`` over the dataset's index, checking
    that each id appears once."""
    from sc3d_data.io.shard_reader import iter_objects

    objs = {}
    for o in iter_objects(out):
        key = (o["category"], o["model_id"])
        assert key not in objs, f"{key} twice in {out}"
        objs[key] = {k: v for k, v in o.items() if k not in ("shard", "row")}
    return objs


def shard_settings(out: Path) -> set[str]:
    """The distinct ``settings`` attributes of the dataset's shard files."""
    import h5py

    vals = set()
    for p in out.glob("shard-*.h5"):
        with h5py.File(p) as f:
            vals.add(f.attrs["settings"])
    return vals


def assert_same_dataset(a: Path, b: Path) -> None:
    """The datasets in folders ``a`` and ``b`` hold the same object ids, each once, with identical
    arrays (dtype, shape, values) and strings, one identical shard ``settings`` attribute, and
    the same counts and split in complete indexes."""
    import json

    import numpy as np

    oa, ob = objects_by_id(a), objects_by_id(b)
    assert sorted(oa) == sorted(ob)
    for key in oa:
        assert oa[key].keys() == ob[key].keys(), key
        for name, va in oa[key].items():
            vb = ob[key][name]
            if isinstance(va, np.ndarray):
                assert va.dtype == vb.dtype and va.shape == vb.shape, (key, name)
                np.testing.assert_array_equal(va, vb, err_msg=f"{key} {name}")
            else:
                assert va == vb, (key, name)
    assert shard_settings(a) == shard_settings(b) and len(shard_settings(a)) == 1
    ia, ib = (json.loads((d / "index.json").read_text()) for d in (a, b))
    assert ia["counts"] == ib["counts"] and ia["complete"] and ib["complete"]
    assert ia["split"] == ib["split"]


def run_cli(group, args: list[str], expect_exit: int | None = 0):
    """Invoke a click group in-process; fail with the command's output when the exit code differs."""
    result = CliRunner().invoke(group, [str(a) for a in args], catch_exceptions=False)
    if expect_exit is not None and result.exit_code != expect_exit:
        raise AssertionError(f"{args} exited {result.exit_code}, expected {expect_exit}:\n{result.output}")
    return result


@pytest.fixture(scope="session")
def sample_shards(tmp_path_factory) -> Path:
    """Shards of the 11 bundled sample meshes: 24 views of 64x64, masks, cameras and 32^3 voxels,
    default split (seeded 70/10/20 by object)."""
    from sc3d_cli.data import main

    out = tmp_path_factory.mktemp("sample_shards")
    run_cli(main, ["render", "--meshes", SAMPLE_MESHES, "--out", out, "--voxelize", "--workers", "2"])
    return out


#: optimiser steps of the shared short training run (tiny model, batch 8, lr 1e-3 so that it learns in few steps)
TRAINED_RUN_STEPS = 120


@pytest.fixture(scope="session")
def trained_run(sample_shards, tmp_path_factory) -> Path:
    """A short supervised run of a tiny model on the sample shards through `sc3d-train fit`
    (run directory; checkpoints at half way and the end, every step logged)."""
    from sc3d_cli.train import main

    out = tmp_path_factory.mktemp("trained_run") / "run"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", out, "--steps", TRAINED_RUN_STEPS,
                   "--batch-size", 8, "--tiny", "--base-channels", 4, "--lr", 1e-3, "--lr-schedule", "constant", "--log-every", 1,
                   "--checkpoint-every", TRAINED_RUN_STEPS // 2, "--no-progress", "--seed", 0])
    return out
