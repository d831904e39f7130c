"""The shards' HDF5 filter pipeline (shuffle, deflate level 4, Fletcher-32) applied outside
HDF5, so that workers compress their own objects in parallel and the process writing a shard
only stores finished chunks (``h5py``'s ``write_direct_chunk``).

HDF5 runs a chunk's filters in the order they were set on the dataset; for
``shards.COMPRESSION`` (h5py: ``shuffle=True, compression="gzip", compression_opts=4,
fletcher32=True``) that is:

1. shuffle: the chunk's bytes regrouped by byte position within an element (all first bytes,
   then all second bytes, ...); nothing changes for 1-byte types;
2. deflate: ``zlib`` ``compress2`` at level 4 (the stream ``zlib.compress(data, 4)`` makes);
3. Fletcher-32 of the compressed bytes (``fletcher32``), appended little-endian.

``tests/test_chunk_codec.py`` checks the bytes against chunks HDF5 wrote itself, so the
stored chunks and the file's values are the same whichever side compressed them.
"""
from __future__ import annotations

import zlib

import numpy as np
from numba import njit

DEFLATE_LEVEL = 4


def fletcher32(data: bytes) -> int:
    """HDF5's Fletcher-32 (``H5_checksum_fletcher32``) of ``data``: 16-bit big-endian words
    (an odd last byte is the high byte of a last word), ``sum1`` = sum of the words and
    ``sum2`` = sum of the running ``sum1``, both folded by end-around carry (mod 65535, a
    nonzero sum ending up in 1..65535); ``(sum2 << 16) | sum1``."""
    return int(_fletcher32(np.frombuffer(data, dtype=np.uint8)))


@njit(cache=True, nogil=True)
def _fletcher32(b):  # pragma: no cover - compiled; the loop of H5checksum.c, block by block
    n_words = len(b) // 2
    sum1 = np.uint32(0)
    sum2 = np.uint32(0)
    i = 0
    while n_words > 0:
        block = min(n_words, 360)  # at most 360 words between folds: no 32-bit overflow
        n_words -= block
        for _ in range(block):
            sum1 += (np.uint32(b[i]) << np.uint32(8)) | np.uint32(b[i + 1])
            sum2 += sum1
            i += 2
        sum1 = (sum1 & np.uint32(0xFFFF)) + (sum1 >> np.uint32(16))
        sum2 = (sum2 & np.uint32(0xFFFF)) + (sum2 >> np.uint32(16))
    if len(b) % 2:
        sum1 += np.uint32(b[i]) << np.uint32(8)
        sum2 += sum1
        sum1 = (sum1 & np.uint32(0xFFFF)) + (sum1 >> np.uint32(16))
        sum2 = (sum2 & np.uint32(0xFFFF)) + (sum2 >> np.uint32(16))
    sum1 = (sum1 & np.uint32(0xFFFF)) + (sum1 >> np.uint32(16))
    sum2 = (sum2 & np.uint32(0xFFFF)) + (sum2 >> np.uint32(16))
    return (sum2 << np.uint32(16)) | sum1


def encode_chunk(block: np.ndarray) -> bytes:
    """One chunk's stored bytes: ``block`` (the chunk's elements, C order) shuffled,
    deflated at ``DEFLATE_LEVEL`` and followed by its Fletcher-32."""
    block = np.ascontiguousarray(block)
    size = block.dtype.itemsize
    raw = block.tobytes() if size == 1 else block.view(np.uint8).reshape(-1, size).T.tobytes()
    packed = zlib.compress(raw, DEFLATE_LEVEL)
    return packed + fletcher32(packed).to_bytes(4, "little")
