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

DEFLATE_LEVEL = 4


def fletcher32(data: bytes) -> int:
    """HDF5's Fletcher-32 (``H5_checksum_fletcher32``) of ``data``: 16-bit big-endian words
    (an odd last byte is the high byte of a last word), ``sum1`` = sum of the words and
    ``sum2`` = sum of the running ``sum1``, both folded by end-around carry (mod 65535, a
    nonzero sum ending up in 1..65535, never 0); ``(sum2 << 16) | sum1``."""
    return fletcher32_many([data])[0]


def fletcher32_many(chunks: list[bytes]) -> list[int]:
    """:func:`fletcher32` of each of ``chunks`` with a few numpy calls for all of them (a
    render worker checksums ~50 chunks per object): the words of all chunks in one array,
    per-chunk sums by ``np.add.reduceat``. Word ``i`` of a chunk that ends before word ``end``
    is in ``end - i`` of the chunk's running sums; with that count taken mod 65535 each term is
    below 2^32, so the 64-bit sums are exact for any chunk size."""
    if not all(chunks):  # an empty chunk sums to 0
        sums = iter(fletcher32_many([c for c in chunks if c]))
        return [next(sums) if c else 0 for c in chunks]
    padded = [c + b"\0" if len(c) % 2 else c for c in chunks]  # odd length: a last high byte
    b = np.frombuffer(b"".join(padded), dtype=np.uint8)
    words = (b[0::2].astype(np.int64) << 8) | b[1::2]
    counts = np.array([len(c) // 2 for c in padded])
    ends = np.cumsum(counts)
    starts = ends - counts
    in_running_sums = (np.repeat(ends, counts) - np.arange(len(words), dtype=np.int64)) % 65535
    total = np.add.reduceat(words, starts)
    sum1 = total % 65535
    sum2 = np.add.reduceat(words * in_running_sums, starts) % 65535
    sum1 = np.where(sum1 == 0, 65535, sum1)  # a positive total folds into 1..65535
    sum2 = np.where(sum2 == 0, 65535, sum2)
    return [int((c2 << 16) | c1) if t else 0 for c1, c2, t in zip(sum1, sum2, total)]


def encode_chunk(block: np.ndarray) -> bytes:
    """One chunk's stored bytes: ``block`` (the chunk's elements, C order) shuffled,
    deflated at ``DEFLATE_LEVEL`` and followed by its Fletcher-32."""
    return encode_chunks([block])[0]


def encode_chunks(blocks) -> list[bytes]:
    """:func:`encode_chunk` of each of ``blocks``, the checksums computed together."""
    packed = []
    for block in blocks:
        block = np.ascontiguousarray(block)
        size = block.dtype.itemsize
        raw = block.tobytes() if size == 1 else block.view(np.uint8).reshape(-1, size).T.tobytes()
        packed.append(zlib.compress(raw, DEFLATE_LEVEL))
    return [p + f.to_bytes(4, "little") for p, f in zip(packed, fletcher32_many(packed))]
