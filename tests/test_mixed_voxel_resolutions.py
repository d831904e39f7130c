"""Shards whose voxel grids have two resolutions: what ``voxelize SHARDS --resolution G
--overwrite`` leaves when it is killed after replacing some shards (it records each replaced
shard in ``index.json`` as it goes). Before: ``fit`` said "shards have no voxels; run
``sc3d-data voxelize`` first", and a ``ShardDataset`` crashed on a resolution of None. Now one
line names both resolutions with a shard of each and the command that makes them one. Real
renders, a real voxelize, the real commands."""
from __future__ import annotations

import shutil

import h5py
import pytest

from sc3d_cli.data import main as data_main
from sc3d_cli.train import main as train_main
from conftest import SAMPLE_MESHES, run_cli, error_lines
from tests.test_check import record_in_index
from tests.test_train import TINY


@pytest.fixture(scope="module")
def mixed_shards(tmp_path_factory):
    """The two sample cars, one object per shard at 32^3, then shard-00001.h5 replaced by its
    16^3 copy and recorded in the index, as a cut-short ``voxelize --resolution 16`` leaves it."""
    root = tmp_path_factory.mktemp("mixed")
    shards, redone = root / "shards", root / "redone"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "car", "--out", shards, "--voxelize", "--no-progress",
                        "--workers", 1, "--objects-per-shard", 1])
    shutil.copytree(shards, redone)
    run_cli(data_main, ["voxelize", redone, "--resolution", 16, "--overwrite", "--no-progress"])
    shutil.copyfile(redone / "shard-00001.h5", shards / "shard-00001.h5")
    record_in_index(shards, shards / "shard-00001.h5")
    with h5py.File(shards / "shard-00000.h5") as a, h5py.File(shards / "shard-00001.h5") as b:
        assert a["voxels"].shape[1:] == (32, 32, 32) and b["voxels"].shape[1:] == (16, 16, 16)
    return shards


def _expected(shards) -> str:
    return (f"{shards}: shards disagree on voxel resolution (16^3 in shard-00001.h5, 32^3 in shard-00000.h5; "
            f"a voxelize at another --resolution cut short?): run `sc3d-data voxelize {shards} --resolution G` "
            "with the one G to train on (it redoes the shards of the other size)")


def test_fit_names_both_voxel_resolutions_in_one_line(mixed_shards, tmp_path):
    out = tmp_path / "run"
    res = run_cli(train_main, ["fit", "--shards", mixed_shards, "--out", out, "--steps", 1, "--batch-size", 2, *TINY,
                               "--val-every", 0, "--device", "cpu", "--split", "train", "--no-progress"], expect_exit=1)
    errors = error_lines(res.output)
    assert errors == [f"Error: {_expected(mixed_shards)}"], res.output
    assert "no voxels" not in res.output and "Traceback" not in res.output
    assert not (out / "checkpoints").exists()


def test_a_dataset_of_two_voxel_resolutions_is_refused_as_such(mixed_shards):
    from sc3d_train.data.dataset import DataError, ShardDataset

    with pytest.raises(DataError) as e:
        ShardDataset(mixed_shards, "train")
    assert str(e.value) == _expected(mixed_shards)
    ShardDataset(mixed_shards, "train", require_voxels=False).close()  # images alone are still readable


def test_the_advised_voxelize_makes_them_one_resolution(mixed_shards, tmp_path):
    from sc3d_train.data.dataset import ShardDataset

    shards = tmp_path / "shards"
    shutil.copytree(mixed_shards, shards)
    kept = (shards / "shard-00000.h5").read_bytes()  # at 32^3 already
    run_cli(data_main, ["voxelize", shards, "--resolution", 32, "--no-progress"])  # as advised: no --overwrite
    assert (shards / "shard-00000.h5").read_bytes() == kept
    dataset = ShardDataset(shards, "train")
    assert dataset.info["voxel_resolution"] == 32 and dataset.info["voxel_resolutions"].keys() == {32}
    dataset.close()
