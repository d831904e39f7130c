"""Damaged shards, values: a NaN or infinity written into ``K``, ``R`` or ``t`` of one view
of a shard (a hand edit with h5py, a bad import) passed the layout check, which reads metadata
only; ``fit`` trained on it and ``eval`` scored it (rotation error 91.3 instead of 90.1 on the sample
shards, exit 0) without a word. Now the split's cameras are checked when they are read, and the
dataset refuses in one line naming the shard, dataset, row, object and view. Real shards, no mocks."""
from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

from sc3d_train.data.dataset import DataError, ShardDataset


def _damaged_copy(sample_shards, tmp_path, name, split):
    """A copy of the sample shards with ``name`` of view 3 of the first ``split`` object set to inf."""
    out = tmp_path / "shards"
    shutil.copytree(sample_shards, out, ignore=shutil.ignore_patterns(".sc3d.lock"))
    shard = out / "shard-00000.h5"
    with h5py.File(shard, "r+") as f:
        row = [s.decode() if isinstance(s, bytes) else s for s in f["split"][()]].index(split)
        values = f[name][()]
        values[row, 3].flat[0] = np.inf if name != "t" else np.nan
        f[name][...] = values
    return out, shard, row


@pytest.mark.parametrize("name,split", [("R", "test"), ("t", "train"), ("K", "train")])
def test_nonfinite_camera_refused_naming_shard(sample_shards, tmp_path, name, split):
    shards, shard, row = _damaged_copy(sample_shards, tmp_path, name, split)
    with pytest.raises(DataError) as e:
        ShardDataset(shards, split=split)
    message = str(e.value)
    assert str(shard) in message and f"'{name}' of row {row}" in message and "view 3" in message
    assert "\n" not in message


def test_clean_cameras_pass(sample_shards):
    assert len(ShardDataset(sample_shards, split="test")) > 0


@pytest.mark.parametrize("workers_like", [False, True])
def test_nonbinary_voxels_refused_naming_object(sample_shards, tmp_path, workers_like):
    """Voxels of 7 (and 200) were BCE targets without a word; now the batch that holds them is refused."""
    out = tmp_path / "shards"
    shutil.copytree(sample_shards, out, ignore=shutil.ignore_patterns(".sc3d.lock"))
    shard = out / "shard-00000.h5"
    with h5py.File(shard, "r+") as f:
        v = f["voxels"][()]
        v[v == 1] = 7
        f["voxels"][...] = v
    ds = ShardDataset(out, split="train", cache_objects=0 if workers_like else None)
    with pytest.raises(DataError) as e:
        ds.get_batch(list(range(len(ds))))
    assert str(shard) in str(e.value) and "'voxels' holds 7, not 0 or 1" in str(e.value)


def test_nonfinite_first_intrinsics_named_by_fit(sample_shards, tmp_path):
    """A NaN in the first view's K (the one ``fit`` copies into its config) failed as "intrinsics
    must be a 3x3 list of finite numbers", naming no file; now the shard is named."""
    from sc3d_cli.train import main as train_main
    from conftest import run_cli

    out = tmp_path / "shards"
    shutil.copytree(sample_shards, out, ignore=shutil.ignore_patterns(".sc3d.lock"))
    with h5py.File(out / "shard-00000.h5", "r+") as f:
        K = f["K"][()]
        K[0, 0, 0, 0] = np.nan
        f["K"][...] = K
    result = run_cli(train_main, ["fit", "--shards", out, "--out", tmp_path / "run", "--tiny", "--steps", 1,
                                  "--device", "cpu"], expect_exit=1)
    assert f"{out / 'shard-00000.h5'}: 'K' holds nan" in result.output
