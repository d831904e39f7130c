"""The training loader: batches assembled whole and sent packed are exactly the stored data, the
same with and without worker processes, and follow the seeded view stream (exact resume)."""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from sc3d_train.data.batch_transfer import PackedBatch, RingBatch, SharedRing, pack, unpack
from conftest import error_lines


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


def test_shared_ring_round_trip_fallback_and_overwrite_check():
    """A batch written into its slot comes back exactly and as a copy (the slot can be reused);
    one too big for a slot travels as a PackedBatch; a slot overwritten by a later batch before
    it was taken is an error, not wrong data (negative control of the slot check)."""
    rng = np.random.default_rng(1)
    arrays = {"images": rng.integers(0, 256, (4, 8, 8, 3), dtype=np.uint8),
              "voxels": (rng.random((4, 5, 5, 5)) > 0.5).astype(np.uint8),
              "K": rng.normal(size=(4, 3, 3)).astype(np.float32)}
    ring = SharedRing(3, 1024)  # 768 + 63 (500 bits) + 144 bytes fit in 1024
    item = ring.put(4, arrays, {"model_id": list("abcd")}, bits=("voxels",))
    assert isinstance(item, RingBatch) and item.seq == 4
    out = ring.take(item)
    assert ring.data[4 % 3].numpy()[:768].tobytes() == arrays["images"].tobytes()  # slot 1 holds it
    for k, a in arrays.items():
        assert out[k].dtype == a.dtype and np.array_equal(out[k], a), k
    ring.data[1].zero_()
    assert out["images"].any()  # a copy: clearing the slot leaves the batch intact
    big = {"images": np.zeros((4, 16, 16, 3), dtype=np.uint8)}  # 3072 bytes > 1024
    assert isinstance(ring.put(5, big, {}), PackedBatch)
    first = ring.put(7, arrays, {}, bits=("voxels",))
    ring.put(10, arrays, {}, bits=("voxels",))  # 10 % 3 == 7 % 3: the same slot
    with pytest.raises(RuntimeError, match="slot 1 holds batch 10, expected 7"):
        ring.take(first)


def test_the_default_cache_holds_2_gib_of_decoded_objects(sample_shards):
    """By default a dataset caches as many decoded objects as 2 GiB hold: one object of the
    sample shards (64 px, 24 views, 48 px self-consistency masks, 32^3 voxels) is, by hand,
    24 x (64*64*3 image + 64*64 mask + 48*48 mask + 1 flag + 24 float32 of camera) + 32^3 =
    483,608 bytes, what its cached arrays hold, so 4,440 objects; the sample split fits, and its
    batches come from the cache."""
    from sc3d_train.data.dataset import ShardDataset, decoded_object_bytes

    by_hand = 24 * (64 * 64 * 3 + 64 * 64 + 48 * 48 + 1 + 24 * 4) + 32 ** 3
    assert by_hand == 483_608 == decoded_object_bytes(64, 24, 48, 32)
    ds = ShardDataset(sample_shards, "train")
    assert sum(a.nbytes for a in ds.object_arrays(0).values()) == by_hand
    assert ds.cache_objects == 2 * 2**30 // by_hand == 4440
    ds.compact_batch([5, 30, 77])
    assert {0, 1, 3} <= set(ds._store())
    assert ShardDataset(sample_shards, "train", require_voxels=False).cache_objects == 2 * 2**30 // (by_hand - 32 ** 3)


def test_a_split_larger_than_the_cache_keeps_no_object(sample_shards):
    """Objects are kept only when the whole split fits: with room for 2 of the 8 training
    objects, reading objects (as the pose targets' one pass does) keeps none, and batches read
    their views from the files; with room for all, each object read is kept."""
    from sc3d_train.data.dataset import ShardDataset

    small = ShardDataset(sample_shards, "train", cache_objects=2)
    assert small.num_objects == 8
    for i in range(small.num_objects):
        small.object_arrays(i)
    small.compact_batch([5, 30, 77])
    assert len(small._store()) == 0
    whole = ShardDataset(sample_shards, "train", cache_objects=8)
    whole.object_arrays(2)
    assert list(whole._store()) == [2]


def test_workers_send_every_batch_through_the_ring(sample_shards, monkeypatch):
    """With workers, no batch takes the per-batch tensor path (``pack`` raising in the forked
    workers would surface here), and batches kept while the loader wraps its ring 3 times stay
    equal to the in-process ones (each is copied out of its slot before it is yielded)."""
    import sc3d_train.data.batch_transfer as transfer
    from sc3d_train.data.dataset import ShardDataset
    from sc3d_train.data.loader import make_loader

    ds = ShardDataset(sample_shards, "train", cache_objects=0)
    expected = iter(make_loader(ds, 3, seed=5, workers=0))
    expected = [next(expected) for _ in range(60)]
    loader = make_loader(ds, 3, seed=5, workers=2)  # (2 * 2 + 1) * 4 = 20 slots

    def no_pack(*args, **kwargs):
        raise AssertionError("a batch did not fit its ring slot")

    monkeypatch.setattr(transfer, "pack", no_pack)
    it = iter(loader)
    kept = [next(it) for _ in range(60)]
    del it
    for a, b in zip(expected, kept):
        for k in a:
            assert (torch.equal(a[k], b[k]) if torch.is_tensor(a[k]) else a[k] == b[k]), k


def _stored(ds, index):
    """One sample straight from the HDF5 file (SPEC layout), without the loader's code."""
    obj, view = divmod(index, ds.num_views)
    ref = ds.objects[obj]
    with h5py.File(ref.shard, "r") as f:
        return {k: f[k][ref.row] for k in ("images", "masks", "K", "R", "voxels")}, view


@pytest.mark.parametrize("cache_objects,decoded", [(128, False), (0, False), (0, True)],
                         ids=["decoded-objects-cached", "views-read-per-batch", "decoded-cache-folder"])
def test_loader_batches_are_the_stored_data_with_and_without_workers(sample_shards, cache_objects, decoded,
                                                                      tmp_path):
    from sc3d_train.data.batch_format import expand_batch, sc_masks
    from sc3d_train.data.dataset import ShardDataset
    from sc3d_train.data.loader import ViewSampler, make_loader

    ds = ShardDataset(sample_shards, "train", cache_objects=cache_objects,
                      decoded_cache=tmp_path / "decoded" if decoded else None)
    B = 5
    first = iter(make_loader(ds, B, seed=3, workers=0))
    compact = [next(first) for _ in range(3)]
    # the loader yields compact batches (1 byte per image value / mask / voxel)
    assert compact[0]["images"].dtype == torch.uint8 and compact[0]["images"].shape == (B, 64, 64, 3)
    assert compact[0]["masks"].dtype == torch.bool and compact[0]["voxels"].dtype == torch.uint8
    in_process = [expand_batch(b) for b in compact]
    second = iter(make_loader(ds, B, seed=3, workers=2))
    with_workers = [expand_batch(next(second)) for _ in range(3)]
    # resume at sample 2B: the third batch again
    resumed = expand_batch(next(iter(make_loader(ds, B, seed=3, start=2 * B, workers=2))))
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


def test_view_chunks_are_the_default_and_both_layouts_load_the_same_values(sample_shards, tmp_path):
    """The writer's default layout stores one view per chunk (recorded as the "chunks" setting);
    the same objects rewritten one object per chunk load to identical batches, with and
    without the decoded-object cache (values do not depend on chunking)."""
    import json
    import shutil

    from sc3d_data.io.shard_reader import read_records
    from sc3d_data.io.shards import load_index, write_index, write_shard
    from sc3d_train.data.batch_format import expand_batch
    from sc3d_train.data.dataset import ShardDataset
    from sc3d_train.data.loader import make_loader

    index = load_index(sample_shards)
    assert index["settings"]["chunks"] == "view"
    old = tmp_path / "object_chunks"
    shutil.copytree(sample_shards, old)
    settings = {**index["settings"], "chunks": "object"}
    for entry in index["shards"]:
        path = old / entry["file"]
        assert h5py.File(path)["images"].chunks == (1, 1, 64, 64, 3)
        write_shard(path, read_records(path), settings)
        with h5py.File(path) as f:
            assert f["images"].chunks == (1, 24, 64, 64, 3) and f["masks"].chunks == (1, 24, 64, 64)
            assert json.loads(f.attrs["settings"])["chunks"] == "object"
        del entry["sha256"], entry["bytes"]
    write_index(old, complete=True, settings=settings, split=index["split"], shards=index["shards"],
                objects=index["objects"], failures=[], skipped=[], warnings=[])
    for cache in (0, 128):
        new_ds, old_ds = (ShardDataset(d, "train", cache_objects=cache) for d in (sample_shards, old))
        for a, b in zip(make_loader(new_ds, 7, seed=1), make_loader(old_ds, 7, seed=1)):
            a, b = expand_batch(a), expand_batch(b)
            for k in a:
                assert (torch.equal(a[k], b[k]) if torch.is_tensor(a[k]) else a[k] == b[k]), k
            break
    with pytest.raises(ValueError, match="chunks 'rows'"):
        write_shard(tmp_path / "x.h5", read_records(old / index["shards"][0]["file"]), {"chunks": "rows"})


def test_read_views_returns_the_requested_views_in_order(sample_shards):
    """``ShardReader.read_views`` (repeated and unsorted pairs) equals plain h5py indexing."""
    from sc3d_data.io.shard_reader import ShardReader

    reader = ShardReader(sample_shards)
    path = reader.files[0]
    rows, views = [3, 0, 3, 5, 0, 3], [7, 23, 7, 0, 1, 2]
    got = reader.read_views(path, rows, views, ("images", "masks", "K", "azimuth", "voxels"))
    with h5py.File(path) as f:
        for k, a in got.items():
            expected = np.stack([f[k][r] if k == "voxels" else f[k][r, v] for r, v in zip(rows, views)])
            assert a.dtype == expected.dtype and np.array_equal(a, expected), k
        assert got["azimuth"].tolist() == [105.0, 345.0, 105.0, 0.0, 15.0, 30.0]  # 15 degrees per view


def test_sc_masks_equal_the_upsample_and_pool_reference():
    """The separable ``W m W^T`` form of the 48 px masks equals ``area_downsample`` (nearest
    upsampling to the common multiple + average pooling) thresholded at 0.5, on masks where many
    output pixels sit exactly at half coverage; hand case: a 64 px mask with only row 1 set
    covers output row 0 by 1/4 and row 1 by 1/2 (its 4/3-pixel areas)."""
    from sc3d_train.data.batch_format import sc_masks
    from sc3d_train.paper.self_consistency import area_downsample

    rng = np.random.default_rng(0)
    for size, m in ((64, 48), (64, 32), (48, 64), (50, 48)):
        for p in (0.1, 0.5, 0.9):
            masks = rng.random((6, size, size)) < p
            reference = area_downsample(torch.from_numpy(masks).float(), m) >= 0.5 - 1e-6
            assert torch.equal(sc_masks(masks, m), reference.float()), (size, m, p)
    row = np.zeros((1, 64, 64), dtype=np.uint8)
    row[0, 1, :] = 1
    assert sc_masks(row, 48)[0, :, 0].tolist()[:3] == [0.0, 1.0, 0.0]  # 1/4 < 0.5 <= 1/2


def test_a_corrupted_view_fails_naming_the_file_and_other_views_still_load(sample_shards, tmp_path):
    """A flipped byte inside one view's image chunk: reading that view fails with the file named
    (HDF5 Fletcher-32), through the reader and through the loader's per-batch reads; a view of
    another chunk of the same object still reads."""
    import shutil

    from sc3d_data.io.shard_reader import ShardReader
    from sc3d_data.io.shards import ShardError
    from sc3d_train.data.dataset import DataError, ShardDataset

    bad = tmp_path / "bad"
    shutil.copytree(sample_shards, bad)
    ds = ShardDataset(bad, "train", cache_objects=0)
    path, row = Path(ds.objects[0].shard), ds.objects[0].row
    with h5py.File(path) as f:
        info = f["images"].id.get_chunk_info_by_coord((row, 5, 0, 0, 0))
    with open(path, "r+b") as fh:
        fh.seek(info.byte_offset + info.size // 2)
        byte = fh.read(1)
        fh.seek(info.byte_offset + info.size // 2)
        fh.write(bytes([byte[0] ^ 0xFF]))
    reader = ShardReader(bad)
    with pytest.raises(ShardError, match=f"{path}: rows \\[{row}\\] cannot be read"):
        reader.read_views(path, [row], [5], ("images",))
    assert reader.read_views(path, [row], [6], ("images",))["images"].shape == (1, 64, 64, 3)
    with pytest.raises(DataError, match=str(path)):
        ds.compact_batch([5])  # object 0, view 5


def _index_sha(shard_dir, name):
    import hashlib
    import json

    entry = [e for e in json.loads((Path(shard_dir) / "index.json").read_text())["shards"] if e["file"] == name][0]
    assert entry["sha256"] == hashlib.sha256((Path(shard_dir) / name).read_bytes()).hexdigest()
    return entry["sha256"]


def test_decoded_cache_is_keyed_by_the_shard_sha256_and_rebuilt_for_a_changed_shard(sample_shards, tmp_path):
    """The decoded copy lies in CACHE/<SHA-256 of the shard>/ and holds what h5py reads; a second
    dataset reuses it (not rewritten); a shard rewritten with one changed pixel (its index
    updated) gets a new folder with the new value, and the old folder still holds the old one
    (a stale copy is never read). An unusable folder fails in one line naming it."""
    import json
    import shutil

    from sc3d_train.data.dataset import DataError, ShardDataset

    data = tmp_path / "data"
    shutil.copytree(sample_shards, data)
    cache = tmp_path / "cache"
    ds = ShardDataset(data, "train", decoded_cache=cache)
    name = Path(ds.objects[0].shard).name
    folder = cache / _index_sha(data, name)
    with h5py.File(data / name) as f:
        stored_images, stored_voxels = f["images"][()], f["voxels"][()]
    assert np.array_equal(np.load(folder / "images.npy"), stored_images)
    assert np.array_equal(np.load(folder / "voxels.npy"), stored_voxels)
    assert sorted(p.name for p in cache.iterdir()) == sorted([folder.name, folder.name + ".lock"])
    built = (folder / "images.npy").stat().st_mtime_ns
    ShardDataset(data, "train", decoded_cache=cache).close()
    assert (folder / "images.npy").stat().st_mtime_ns == built

    ds.close()  # its HDF5 handles: the shard is rewritten below
    row = ds.objects[0].row
    with h5py.File(data / name, "r+") as f:
        old = int(f["images"][row, 0, 0, 0, 0])
        f["images"][row, 0, 0, 0, 0] = 255 - old
    index = json.loads((data / "index.json").read_text())
    from sc3d_data.io.shards import file_sha256

    for e in index["shards"]:
        if e["file"] == name:
            e["sha256"], e["bytes"] = file_sha256(data / name), (data / name).stat().st_size
    (data / "index.json").write_text(json.dumps(index))
    new = ShardDataset(data, "train", decoded_cache=cache)
    assert new.compact_batch([0])[0]["images"][0, 0, 0, 0] == 255 - old  # object 0, view 0
    assert ds.compact_batch([0])[0]["images"][0, 0, 0, 0] == old          # the old copy, untouched
    assert (cache / _index_sha(data, name)).is_dir() and folder.is_dir()

    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(DataError, match=f"{blocker / 'cache'}: cannot write the decoded cache"):
        ShardDataset(data, "train", decoded_cache=blocker / "cache")


def test_decoded_cache_build_waits_for_the_lock(sample_shards, tmp_path):
    """A process that needs a missing entry waits while another process holds the entry's lock,
    then builds it; no temporary folder is left behind (one of a killed build included)."""
    import subprocess
    import sys
    import threading

    from sc3d_train.data.dataset import ShardDataset

    ds = ShardDataset(sample_shards, "train")
    key = _index_sha(sample_shards, Path(ds.objects[0].shard).name)
    cache = tmp_path / "cache"
    (cache / f"{key}.tmp-99999999").mkdir(parents=True)  # what a build killed half-way leaves
    holder = subprocess.Popen(
        [sys.executable, "-c", "import fcntl, os, sys; fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT); "
         "fcntl.flock(fd, fcntl.LOCK_EX); print('locked', flush=True); sys.stdin.read()", str(cache / f"{key}.lock")],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "locked"
    built = []
    waiter = threading.Thread(target=lambda: built.append(ShardDataset(sample_shards, "train", decoded_cache=cache)))
    waiter.start()
    waiter.join(1.5)
    assert waiter.is_alive() and not (cache / key).exists()  # waiting for the lock
    holder.communicate("", timeout=10)  # the holder exits: its lock goes
    waiter.join(60)
    assert built and (cache / key / "images.npy").is_file()
    assert sorted(p.name for p in cache.iterdir()) == sorted([key, f"{key}.lock"])


def test_fit_option_decoded_cache_reaches_the_run_datasets(sample_shards, tmp_path, monkeypatch):
    """``fit --decoded-cache DIR`` (relative) is stored absolute in the run's config, may change
    on resume, and the run's datasets build the folder and gather from it."""
    from click.testing import CliRunner

    from sc3d_cli.train import main
    from sc3d_train.settings.config import RESUMABLE_FIELDS, RunConfig
    from sc3d_train.loop.streams import run_datasets

    assert "decoded_cache" in RESUMABLE_FIELDS
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(main, ["fit", "--shards", str(sample_shards), "--out", "run", "--tiny", "--steps", "1",
                                    "--batch-size", "4", "--no-progress", "--decoded-cache", "cache"])
    assert res.exit_code == 0, res.output
    cfg = RunConfig.load(tmp_path / "run" / "config.yaml")
    cache = tmp_path / "cache"
    assert cfg.decoded_cache == str(cache.resolve())
    ds = run_datasets(cfg)["all"]
    key = _index_sha(sample_shards, Path(ds.objects[0].shard).name)
    assert (cache / key / "images.npy").is_file() and ds._decoded.folders[0] == cache / key


def test_fit_records_workers_auto_and_keeps_a_number_given(sample_shards, tmp_path):
    """fit's default writes ``workers: null`` (auto: the batches are built in the training
    process, on the CPU and on CUDA alike); ``--workers 1`` is written as 1."""
    import yaml
    from tests.conftest import run_cli
    from sc3d_cli.train import main

    args = ["--shards", sample_shards, "--steps", "2", "--batch-size", "2", "--tiny", "--no-progress",
            "--val-every", "0"]
    run_cli(main, ["fit", "--out", tmp_path / "auto", *args])
    assert yaml.safe_load((tmp_path / "auto" / "config.yaml").read_text())["workers"] is None
    run_cli(main, ["fit", "--out", tmp_path / "one", *args, "--workers", "1"])
    assert yaml.safe_load((tmp_path / "one" / "config.yaml").read_text())["workers"] == 1


def test_a_loader_with_workers_maps_one_ring_of_the_slots_it_needs(sample_shards):
    """A loader with workers maps one shared-memory ring when iterated: one slot per batch of
    every task the DataLoader keeps ahead (2 per worker, 4 batches a task) plus one task, each
    slot one packed batch; without workers, none."""
    from sc3d_train.data.dataset import ShardDataset
    from sc3d_train.data.loader import make_loader

    ds = ShardDataset(sample_shards, "train")
    loader = make_loader(ds, 4, seed=0, workers=2)
    it = iter(loader)
    next(it)
    assert loader.dataset.ring.slots == (2 * 2 + 1) * 4
    assert loader.dataset.ring.data.numel() == loader.dataset.ring.slots * loader.batch_bytes > 0
    del it
    assert make_loader(ds, 4, seed=0, workers=0).batch_bytes == 0


def test_a_dev_shm_too_small_for_the_workers_is_one_line(sample_shards, tmp_path):
    """``fit --workers 4`` where /dev/shm holds 8 MiB (a container's is 64 MB by default) and the
    rings need ~29 MiB: one line naming shared memory, --workers and --shm-size, not a
    traceback. Runs in its own mount namespace (``unshare -m``, root), skipped where that is
    not allowed."""
    import subprocess
    import sys

    probe = subprocess.run(["unshare", "-m", "sh", "-c", "mount -t tmpfs -o size=8m tmpfs /dev/shm"],
                           capture_output=True)
    if probe.returncode != 0:
        pytest.skip("needs unshare -m and mount (root in a namespace-capable container)")
    fit = (f"{sys.executable} -c 'from sc3d_cli.train import main; main()' fit --shards {sample_shards} "
           f"--out {tmp_path / 'run'} --steps 2 --batch-size 48 --tiny --workers 4 --no-progress --val-every 0")
    res = subprocess.run(["unshare", "-m", "sh", "-c", f"mount -t tmpfs -o size=8m tmpfs /dev/shm && {fit}"],
                         capture_output=True, text=True)
    assert res.returncode == 1, res.stdout + res.stderr
    errors = error_lines(res.stderr)
    assert len(errors) == 1 and "could not map" in errors[0] and "shared memory" in errors[0], res.stderr
    assert "--shm-size" in errors[0] and "Traceback" not in res.stderr
