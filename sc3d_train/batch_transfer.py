"""Moving loader batches between processes cheaply.

A DataLoader worker hands each batch to the main process through shared memory: one segment and
one file descriptor per tensor, and page faults for every byte. The float32 batch of the
training loader is ~10 MB at batch 48 (voxels alone 6.3 MB) in 14 tensors, which made worker
processes slower than none. Here a batch travels as ONE uint8 tensor holding every array in its
compact dtype (uint8 images, 0/1 masks and voxels bit-packed with ``numpy.packbits``): ~1 MB,
one descriptor. :func:`unpack` restores the arrays exactly (bit packing is used only for
boolean arrays and for uint8 arrays whose values are all 0 or 1).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class PackedBatch:
    """Arrays packed into ``buffer`` (uint8 [n_bytes]); ``layout`` rows are
    ``(name, dtype str, shape, offset, n_bytes, bits)`` with ``bits`` True where the array is
    bit-packed (one bit per element); ``other`` holds the non-array fields (lists of str)."""

    buffer: torch.Tensor
    layout: list[tuple[str, str, tuple[int, ...], int, int, bool]]
    other: dict


def _is_binary(a: np.ndarray) -> bool:
    return a.dtype == np.bool_ or (a.dtype == np.uint8 and a.size > 0 and int(a.max()) <= 1)


def pack(arrays: dict[str, np.ndarray], other: dict | None = None, bits: tuple[str, ...] = ()) -> PackedBatch:
    """Pack ``arrays`` (any numeric dtypes and shapes) into one uint8 tensor. Arrays named in
    ``bits`` are bit-packed when they are binary (bool, or uint8 with values in {0, 1})."""
    parts, layout, offset = [], [], 0
    for name, a in arrays.items():
        a = np.ascontiguousarray(a)
        packed = name in bits and _is_binary(a)
        raw = np.packbits(a.reshape(-1).astype(bool)) if packed else a.reshape(-1).view(np.uint8)
        layout.append((name, a.dtype.str, a.shape, offset, raw.size, packed))
        parts.append(raw)
        offset += raw.size
    buffer = torch.from_numpy(np.concatenate(parts)) if parts else torch.empty(0, dtype=torch.uint8)
    return PackedBatch(buffer, layout, dict(other or {}))


def unpack(p: PackedBatch) -> dict[str, np.ndarray]:
    """The arrays of :func:`pack`, bit-identical, as numpy views of (or, for bit-packed arrays,
    copies from) ``p.buffer``."""
    buf = p.buffer.numpy()
    out = {}
    for name, dtype, shape, offset, n, packed in p.layout:
        raw = buf[offset:offset + n]
        count = int(np.prod(shape))
        if packed:  # 0/1 bytes; bool and uint8 take them as they are
            bits = np.unpackbits(raw, count=count)
            dt = np.dtype(dtype)
            out[name] = (bits.view(dt) if dt.itemsize == 1 else bits.astype(dt)).reshape(shape)
        else:
            out[name] = raw.view(np.dtype(dtype)).reshape(shape)
    return out
