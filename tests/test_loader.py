"""The training loader: batches assembled whole and sent packed are exactly the stored data, the
same with and without worker processes, and follow the seeded view stream (exact resume)."""
from __future__ import annotations

import h5py
import numpy as np
import torch

from sc3d_train.batch_transfer import pack, unpack


def test_pack_round_trip_is_exact_and_packs_only_binary_arrays():
    rng = np.random.default_rng(0)
    arrays = {"masks": rng.random((3, 5, 7)) > 0.5,                       # bool: bit-packed
              "voxels": (rng.random((2, 4, 4, 4)) > 0.5).astype(np.uint8),  # 0/1: bit-packed
              "labels": np.array([0, 1, 2], dtype=np.uint8),                # not binary: raw
              "K": rng.normal(size=(3, 3, 3)).astype(np.float32),
              "index": np.array([5, 7, 2**40], dtype=np.int64)}
    p = pack(arrays, {"model_id": ["a", "b", "c"]}, bits=("masks", "voxels", "labels"))
    # 105 + 128 bits -> 14 + 16 bytes, 3 raw bytes, 108 bytes of float32, 24 of int64
    assert p.buffer.dtype == torch.uint8 and p.buffer.numel() == 14 + 16 + 3 + 108 + 24
    out = unpack(p)
    for k, a in arrays.items():
        assert out[k].dtype == a.dtype and out[k].shape == a.shape
        np.testing.assert_array_equal(out[k], a)
    assert out["labels"][2] == 2  # a value of 2 would be lost by bit packing
    assert p.other == {"model_id": ["a", "b", "c"]}


def _stored(ds, index):
    """One sample straight from the HDF5 file (SPEC layout), without the loader's code."""
    obj, view = divmod(index, ds.num_views)
    ref = ds.objects[obj]
    with h5py.File(ref.shard, "r") as f:
        return {k: f[k][ref.row] for k in ("images", "masks", "K", "R", "voxels")}, view


def test_loader_batches_are_the_stored_data_with_and_without_workers(sample_shards):
    from sc3d_train.data import ShardDataset, sc_masks
    from sc3d_train.loader import ViewSampler, make_loader

    ds = ShardDataset(sample_shards, "train")
    B = 5
    first = iter(make_loader(ds, B, seed=3, workers=0))
    in_process = [next(first) for _ in range(3)]
    second = iter(make_loader(ds, B, seed=3, workers=2))
    with_workers = [next(second) for _ in range(3)]
    # resume at sample 2B: the third batch again
    resumed = next(iter(make_loader(ds, B, seed=3, start=2 * B, workers=2)))
    stream = iter(ViewSampler(ds.num_objects, ds.num_views, seed=3))
    expected_index = [next(stream) for _ in range(3 * B)]
    for batches in (in_process, with_workers):
        assert torch.cat([b["index"] for b in batches]).tolist() == expected_index
    for a, b in zip(in_process + [in_process[2]], with_workers + [resumed]):
        assert a.keys() == b.keys()
        for k in a:
            if torch.is_tensor(a[k]):
                assert a[k].dtype == b[k].dtype and torch.equal(a[k], b[k]), k
            else:
                assert a[k] == b[k], k
    batch = in_process[1]
    assert batch["images"].shape == (B, 3, 64, 64) and batch["images"].dtype == torch.float32
    assert batch["voxels"].shape == (B, 32, 32, 32) and batch["masks_sc"].shape == (B, 48, 48)
    for i, index in enumerate(batch["index"].tolist()):
        stored, view = _stored(ds, index)
        image = torch.from_numpy(stored["images"][view]).permute(2, 0, 1).double() / 255
        assert torch.allclose(batch["images"][i].double(), image, atol=1e-7, rtol=0)
        # bit-identical to the previous per-item loader's conversion
        previous = torch.from_numpy(stored["images"][view].transpose(2, 0, 1).copy()).float() / 255.0
        assert torch.equal(batch["images"][i], previous)
        assert torch.equal(batch["masks"][i], torch.from_numpy(stored["masks"][view] > 0).float())
        # the 48 px masks of one view equal those computed for the whole object at once
        assert torch.equal(batch["masks_sc"][i], sc_masks(stored["masks"], 48)[view])
        assert torch.equal(batch["voxels"][i], torch.from_numpy(stored["voxels"]).float())
        K = stored["K"][view]
        assert torch.equal(batch["K"][i], torch.from_numpy(K))
        np.testing.assert_allclose(batch["K_sc"][i].numpy(), K * [[0.75], [0.75], [1]], rtol=1e-6)
        assert torch.equal(batch["R"][i], torch.from_numpy(stored["R"][view]))
        assert batch["model_id"][i] == ds.objects[index // ds.num_views].model_id
    # the per-item path (evaluation) gives the same sample
    item = ds[int(batch["index"][2])]
    for k in ("images", "masks", "masks_sc", "voxels", "K_sc", "t", "azimuth", "labeled"):
        assert torch.equal(item[k], batch[k][2]), k
