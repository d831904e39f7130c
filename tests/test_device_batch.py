"""A loader batch on its way to a CUDA device: one page-locked buffer, one host-to-device copy,
the device's arrays views of that copy (``batch_transfer.pack_for_device``, ``tensor_views``,
``batch_format.compact_tensors`` with ``one_buffer``, ``expand_batch``). On the CPU the buffer is
not page-locked (that needs CUDA) and the same code runs; the ``gpu`` test counts the copies."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from sc3d_train.data.batch_format import PACKED_KEY, compact_tensors, expand_batch
from sc3d_train.data.batch_transfer import DEVICE_ALIGN, pack, pack_for_device, tensor_views

needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA: torch sees no CUDA device")


def test_one_buffer_holds_every_array_aligned_and_its_views_are_the_arrays():
    """Each array at a multiple of 64 bytes, in the order given, none bit-packed; the views have
    the arrays' dtypes, shapes and bytes and share the buffer's memory (no copy): a byte written
    into the buffer shows in the view. A bit-packed buffer has no views (negative control)."""
    rng = np.random.default_rng(0)
    arrays = {"images": rng.integers(0, 256, (3, 4, 4, 3), dtype=np.uint8),  # 144 bytes
              "masks": rng.random((3, 5, 5)) > 0.5,                           # 75 bytes, bool
              "K": rng.normal(size=(3, 3, 3)).astype(np.float32),             # 108 bytes
              "index": np.array([5, 7, 2**40], dtype=np.int64),                # 24 bytes
              "empty": np.zeros((0, 2), dtype=np.float32)}
    packed = pack_for_device(arrays, {"model_id": ["a", "b", "c"]}, pin=False)
    offsets = [row[3] for row in packed.layout]
    assert DEVICE_ALIGN == 64 and offsets == [0, 192, 320, 448, 512]  # 144 -> 192, 192+75 -> 320, ...
    assert not any(row[5] for row in packed.layout) and packed.other == {"model_id": ["a", "b", "c"]}
    views = tensor_views(packed.buffer, packed.layout)
    for name, a in arrays.items():
        assert views[name].dtype == torch.from_numpy(a).dtype and tuple(views[name].shape) == a.shape, name
        assert views[name].numpy().tobytes() == a.tobytes(), name
    assert views["index"][2].item() == 2**40
    packed.buffer[320:324] = torch.tensor(list(np.float32(2.5).tobytes()), dtype=torch.uint8)
    assert views["K"][0, 0, 0].item() == 2.5  # a view, not a copy
    bits = pack(arrays, bits=("masks",))
    with pytest.raises(ValueError, match="masks: a bit-packed array has no view"):
        tensor_views(bits.buffer, bits.layout)


def _compact(sample_shards):
    from sc3d_train.data.dataset import ShardDataset

    ds = ShardDataset(sample_shards, "train")
    return ds.compact_batch([0, 5, 30, 47, 3])


def test_a_one_buffer_batch_expands_to_the_per_tensor_batch(sample_shards):
    """The same compact batch of the sample shards, as one buffer and as a tensor per array:
    ``expand_batch`` (onto the CPU, ``training_batch``'s call) gives equal tensors, and the
    buffer's key is gone from the training batch; ``training_batch`` drops the pose from both."""
    from sc3d_train.loop.phase_step import POSE_KEYS, training_batch

    arrays, strings = _compact(sample_shards)
    one = compact_tensors(arrays, strings, one_buffer=True)
    per_tensor = compact_tensors(arrays, strings)
    assert PACKED_KEY in one and PACKED_KEY not in per_tensor
    assert one["images"].untyped_storage().data_ptr() == one["voxels"].untyped_storage().data_ptr()
    a = expand_batch(one, "cpu", non_blocking=True)
    b = expand_batch(per_tensor, "cpu")
    assert PACKED_KEY not in a and a.keys() == b.keys()
    for k in b:
        if torch.is_tensor(b[k]):
            assert a[k].dtype == b[k].dtype and torch.equal(a[k], b[k]), k
        else:
            assert a[k] == b[k], k
    assert torch.equal(a["images"][1], torch.from_numpy(arrays["images"][1]).permute(2, 0, 1).float() / 255)
    for batch in (one, per_tensor):
        out = training_batch(batch, "supervised", torch.device("cpu"), channels_last=False)
        assert not set(POSE_KEYS) & set(out) and PACKED_KEY not in out


@pytest.mark.gpu
@needs_cuda
def test_fits_loader_batch_reaches_the_gpu_in_one_copy_and_equal(sample_shards):
    """``make_loader(pin_memory=True)`` (fit on CUDA): the batch's tensors are page-locked views
    of one buffer; ``training_batch`` onto CUDA makes one host-to-device copy (torch.profiler's
    ``Memcpy HtoD`` on the GPU; a pinned tensor per array made 9) and the same training batch,
    bit for bit, as onto the CPU."""
    from torch.profiler import ProfilerActivity, profile

    from sc3d_train.data.dataset import ShardDataset
    from sc3d_train.data.loader import make_loader
    from sc3d_train.loop.phase_step import training_batch

    ds = ShardDataset(sample_shards, "train")
    batch = next(iter(make_loader(ds, 6, seed=0, pin_memory=True)))
    assert batch["images"].is_pinned() and PACKED_KEY in batch
    cuda = torch.device("cuda")
    training_batch(batch, "supervised", cuda, channels_last=False)  # warm-up: first-use allocations
    torch.cuda.synchronize()
    with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
        on_gpu = training_batch(batch, "supervised", cuda, channels_last=False)
        torch.cuda.synchronize()
    copies = sum(e.count for e in prof.key_averages() if e.key.startswith("Memcpy HtoD"))
    assert copies == 1, [(e.key, e.count) for e in prof.key_averages() if "Memcpy" in e.key]
    on_cpu = training_batch(batch, "supervised", torch.device("cpu"), channels_last=False)
    assert on_gpu.keys() == on_cpu.keys()
    for k, v in on_cpu.items():
        if torch.is_tensor(v):
            assert on_gpu[k].is_cuda and torch.equal(on_gpu[k].cpu(), v), k
