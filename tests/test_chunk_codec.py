"""``sc3d_data.io.chunk_codec`` against HDF5 itself: the chunks it encodes must be the bytes
HDF5 stores for the shards' filter settings (``shards.COMPRESSION``), read back with h5py's
``read_direct_chunk`` from files h5py wrote the ordinary way."""
from __future__ import annotations

import zlib

import h5py
import numpy as np
import pytest

from sc3d_data.io.chunk_codec import encode_chunk, fletcher32
from sc3d_data.io.shards import COMPRESSION

RNG = np.random.default_rng(7)
CASES = {
    "incompressible uint8 view": RNG.integers(0, 256, (1, 1, 64, 64, 3), dtype=np.uint8),
    "constant uint8": np.full((1, 1, 64, 64), 7, np.uint8),
    "all zero": np.zeros((1, 24, 3), np.float32),
    "float32 cameras": RNG.normal(size=(1, 24, 3, 3)).astype(np.float32),
    "float64 transform": RNG.normal(size=(1, 4, 4)),
    "odd byte count": RNG.integers(0, 3, (1, 5, 7), dtype=np.uint8),
    "voxels": (RNG.random((1, 32, 32, 32)) > 0.7).astype(np.uint8),
    "depth": np.where(RNG.random((1, 1, 64, 64)) > 0.5, RNG.random((1, 1, 64, 64)) + 2, 0).astype(np.float32),
}


@pytest.fixture(scope="module")
def hdf5_chunks(tmp_path_factory):
    """name -> (filter mask, stored bytes) of each case written by HDF5 as one chunk."""
    path = tmp_path_factory.mktemp("codec") / "ref.h5"
    with h5py.File(path, "w") as f:
        for name, a in CASES.items():
            f.create_dataset(name, data=a, chunks=a.shape, **COMPRESSION)
    with h5py.File(path) as f:
        return {name: f[name].id.read_direct_chunk((0,) * a.ndim) for name, a in CASES.items()}


@pytest.mark.parametrize("name", list(CASES))
def test_encoded_chunk_is_the_bytes_hdf5_stores(name, hdf5_chunks):
    mask, stored = hdf5_chunks[name]
    assert mask == 0  # every filter ran (deflate is kept even when it makes the chunk larger)
    assert encode_chunk(CASES[name]) == stored


def test_wrong_conventions_give_other_bytes(hdf5_chunks):
    """Negative controls: another deflate level, no shuffle of a float array, or the checksum
    appended big-endian are not what HDF5 stores."""
    a = CASES["float32 cameras"]
    stored = hdf5_chunks["float32 cameras"][1]
    shuffled = a.view(np.uint8).reshape(-1, 4).T.tobytes()
    level6 = zlib.compress(shuffled, 6)
    assert level6 + fletcher32(level6).to_bytes(4, "little") != stored
    plain = zlib.compress(a.tobytes(), 4)
    assert plain + fletcher32(plain).to_bytes(4, "little") != stored
    packed = zlib.compress(shuffled, 4)
    assert packed + fletcher32(packed).to_bytes(4, "big") != stored
    assert packed + fletcher32(packed).to_bytes(4, "little") == stored


def test_fletcher32_hand_worked_values():
    """Words (big-endian pairs) w: sum1 = sum(w), sum2 = sum of running sums, mod 65535 with
    a nonzero total kept in 1..65535: b'\\x00\\x01\\x00\\x02' -> w = 1, 2: sum1 3, sum2 1 + 3 = 4.
    b'\\x01' -> w = 0x0100: sum1 = sum2 = 256. 0xffff alone: sum1 = sum2 = 65535 (not 0).
    All-zero data -> 0."""
    assert fletcher32(b"\x00\x01\x00\x02") == (4 << 16) | 3
    assert fletcher32(b"\x01") == (256 << 16) | 256
    assert fletcher32(b"\xff\xff") == (65535 << 16) | 65535
    assert fletcher32(bytes(10)) == 0


def _h5_fletcher32_loop(b: bytes) -> int:
    """H5_checksum_fletcher32 transcribed from HDF5's H5checksum.c (Python ints, folded every
    360 words as the C code does to stay in 32 bits)."""
    n, s1, s2, i = len(b) // 2, 0, 0, 0
    while n:
        t = min(n, 360)
        n -= t
        for _ in range(t):
            s1 += (b[i] << 8) | b[i + 1]
            s2 += s1
            i += 2
        s1, s2 = (s1 & 0xFFFF) + (s1 >> 16), (s2 & 0xFFFF) + (s2 >> 16)
    if len(b) % 2:
        s1 += b[i] << 8
        s2 += s1
        s1, s2 = (s1 & 0xFFFF) + (s1 >> 16), (s2 & 0xFFFF) + (s2 >> 16)
    s1, s2 = (s1 & 0xFFFF) + (s1 >> 16), (s2 & 0xFFFF) + (s2 >> 16)
    return (s2 << 16) | s1


def test_batched_checksums_equal_hdf5s_loop_chunk_by_chunk():
    from sc3d_data.io.chunk_codec import fletcher32_many

    rng = np.random.default_rng(11)
    chunks = [rng.integers(0, 256, n, dtype=np.uint8).tobytes() for n in (1, 2, 3, 719, 720, 721, 5000, 12289)]
    chunks += [b"", bytes(9), b"\xff" * 4000]
    assert fletcher32_many(chunks) == [_h5_fletcher32_loop(c) for c in chunks]
