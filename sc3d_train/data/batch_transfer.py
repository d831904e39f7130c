"""Moving loader batches between processes cheaply.

A batch travels in its compact dtypes (uint8 images, 0/1 masks and voxels bit-packed with
``numpy.packbits``: ~0.8 MB at batch 48 instead of ~10 MB of float32) and ONE buffer:
:func:`pack` / :func:`unpack` restore the arrays exactly (bit packing is used only for boolean
arrays and for uint8 arrays whose values are all 0 or 1).

Workers write that buffer into a :class:`SharedRing`: slots of shared memory made once, before
the workers start, so that a batch costs no new shared-memory segment and no file descriptor.
Sending a tensor through a DataLoader queue instead (``torch.multiprocessing``'s default
``file_descriptor`` strategy) costs, per batch, a new segment, its page faults on both sides and
a socket handshake (connect, HMAC challenge, fd passing) with a thread of the worker that needs
the worker's GIL while it decodes the next batch; on a loaded 2-core machine that made 2 workers
no faster than none. Through the ring only a :class:`RingBatch` (slot number, layout, strings:
a few hundred bytes) is pickled.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

#: ``(name, dtype str, shape, offset, n_bytes, bits)``: where one array lies in a packed buffer
Layout = list[tuple[str, str, tuple[int, ...], int, int, bool]]


@dataclass
class PackedBatch:
    """Arrays packed into ``buffer`` (uint8 [n_bytes]); ``layout`` rows are
    ``(name, dtype str, shape, offset, n_bytes, bits)`` with ``bits`` True where the array is
    bit-packed (one bit per element); ``other`` holds the non-array fields (lists of str)."""

    buffer: torch.Tensor
    layout: Layout
    other: dict


@dataclass
class RingBatch:
    """A batch a worker wrote into slot ``seq % slots`` of a :class:`SharedRing` (``layout`` as
    :class:`PackedBatch`); ``seq`` is the batch's position in the loader's stream."""

    seq: int
    layout: Layout
    other: dict


def _is_binary(a: np.ndarray) -> bool:
    return a.dtype == np.bool_ or (a.dtype == np.uint8 and a.size > 0 and int(a.max()) <= 1)


def _encode(arrays: dict[str, np.ndarray], bits: tuple[str, ...]) -> tuple[list[np.ndarray], Layout]:
    """The byte strings (uint8 [n]) of ``arrays`` and their layout (offsets from 0)."""
    parts, layout, offset = [], [], 0
    for name, a in arrays.items():
        a = np.ascontiguousarray(a)
        packed = name in bits and _is_binary(a)
        raw = np.packbits(a.reshape(-1).astype(bool)) if packed else a.reshape(-1).view(np.uint8)
        layout.append((name, a.dtype.str, a.shape, offset, raw.size, packed))
        parts.append(raw)
        offset += raw.size
    return parts, layout


def pack(arrays: dict[str, np.ndarray], other: dict | None = None, bits: tuple[str, ...] = ()) -> PackedBatch:
    """Pack ``arrays`` (any numeric dtypes and shapes) into one uint8 tensor. Arrays named in
    ``bits`` are bit-packed when they are binary (bool, or uint8 with values in {0, 1})."""
    parts, layout = _encode(arrays, bits)
    buffer = torch.from_numpy(np.concatenate(parts)) if parts else torch.empty(0, dtype=torch.uint8)
    return PackedBatch(buffer, layout, dict(other or {}))


def pack_into(arrays: dict[str, np.ndarray], out: np.ndarray, bits: tuple[str, ...] = ()) -> Layout | None:
    """:func:`pack` written into ``out`` (uint8 [capacity]); the layout, or None (``out``
    untouched) when the packed arrays need more than ``out.size`` bytes."""
    parts, layout = _encode(arrays, bits)
    if sum(p.size for p in parts) > out.size:
        return None
    for p, (_, _, _, offset, n, _) in zip(parts, layout):
        out[offset:offset + n] = p
    return layout


def unpack_buffer(buf: np.ndarray, layout: Layout, copy: bool = False) -> dict[str, np.ndarray]:
    """The arrays packed in ``buf`` (uint8) at ``layout``, bit-identical: numpy views of ``buf``
    (``copy=False``) or new arrays; bit-packed arrays are always new arrays."""
    out = {}
    for name, dtype, shape, offset, n, packed in layout:
        raw = buf[offset:offset + n]
        count = math.prod(shape)
        if packed:  # 0/1 bytes; bool and uint8 take them as they are
            bits = np.unpackbits(raw, count=count)
            dt = np.dtype(dtype)
            out[name] = (bits.view(dt) if dt.itemsize == 1 else bits.astype(dt)).reshape(shape)
        else:
            a = raw.view(np.dtype(dtype)).reshape(shape)
            out[name] = a.copy() if copy else a
    return out


def unpack(p: PackedBatch) -> dict[str, np.ndarray]:
    """The arrays of :func:`pack`, bit-identical, as numpy views of (or, for bit-packed arrays,
    copies from) ``p.buffer``."""
    return unpack_buffer(p.buffer.numpy(), p.layout)


def shm_full(what: str, e: Exception) -> OSError:
    """The one-line error of a loader that could not ``what`` in /dev/shm (``e``: the error met):
    it names /dev/shm and what to do, where the bare ``No space left on device`` reads like a
    full disk."""
    return OSError(f"the loader could not {what} ({str(e).splitlines()[0][:120]}); use fewer --workers "
                   f"(0: none), or give the machine more /dev/shm (docker run --shm-size)")


class SharedRing:
    """``slots`` buffers of ``capacity`` bytes in shared memory, made in the main process before
    the loader's workers start (forked workers inherit the mapping; spawned ones receive it once
    when the dataset is pickled to them), plus the stream position each slot holds.

    Batch ``seq`` goes to slot ``seq % slots``. A DataLoader sends a new task only when it hands
    out a batch, and keeps at most ``prefetch_factor * num_workers`` tasks ahead of the batch it
    hands out (documented: "a total of prefetch_factor * num_workers batches prefetched"), so
    with ``slots > prefetch_factor * num_workers`` no worker writes a slot whose batch has not
    been copied out (:meth:`take`). :meth:`take` checks the slot's position before and after
    copying and raises if a worker overwrote it (it never should)."""

    def __init__(self, slots: int, capacity: int):
        try:  # both in the try: /dev/shm may hold the batches but not the page of the positions
            self.data = torch.zeros(slots, capacity, dtype=torch.uint8).share_memory_()
            self.seqs = torch.full((slots,), -1, dtype=torch.int64).share_memory_()
        except RuntimeError as e:  # /dev/shm full or too small (a container's 64 MB default)
            raise shm_full(f"map {slots * capacity / 2 ** 20:.0f} MiB of shared memory for its workers' batches",
                           e) from e

    @property
    def slots(self) -> int:
        return self.data.shape[0]

    def put(self, seq: int, arrays: dict[str, np.ndarray], other: dict,
            bits: tuple[str, ...] = ()) -> RingBatch | PackedBatch:
        """Write a batch into its slot (worker side); a :class:`PackedBatch` (sent the usual
        way) when it does not fit."""
        slot, seqs = seq % self.slots, self.seqs.numpy()
        seqs[slot] = -1
        layout = pack_into(arrays, self.data[slot].numpy(), bits)
        if layout is None:
            return pack(arrays, other, bits)
        seqs[slot] = seq
        return RingBatch(seq, layout, dict(other))

    def take(self, item: RingBatch) -> dict[str, np.ndarray]:
        """The arrays of ``item``, copied out of its slot (main side)."""
        slot, seqs = item.seq % self.slots, self.seqs.numpy()
        if seqs[slot] != item.seq:
            raise RuntimeError(f"loader ring: slot {slot} holds batch {seqs[slot]}, expected {item.seq}")
        arrays = unpack_buffer(self.data[slot].numpy(), item.layout, copy=True)
        if seqs[slot] != item.seq:
            raise RuntimeError(f"loader ring: slot {slot} was overwritten while batch {item.seq} was read")
        return arrays
