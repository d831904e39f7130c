"""Read and write binvox voxel files (the format of ShapeNetVox32, used by 3D-R2N2).

Format (binvox 1, https://www.patrickmin.com/binvox/binvox.html)
------------------------------------------------------------------
An ASCII header, one item per line::

    #binvox 1
    dim D D D
    translate tx ty tz
    scale s
    data

then binary run-length data: pairs of bytes ``(value, count)`` with value 0 or 1 and
1 <= count <= 255, covering all ``D^3`` voxels. Voxel order in the data ("xzy"): the
y index runs fastest, then z, then x, i.e. flat index ``x * D * D + z * D + y``.
Voxel (i, j, k) has its centre at model coordinates
``((i, j, k) + 0.5) / D * scale + (tx, ty, tz)``.

Axis mapping between binvox files and sc3d grids
------------------------------------------------
``read_binvox`` returns the grid re-ordered to sc3d's index order ``[x, y, z]`` (binvox's
i = x, j = y, k = z after de-interleaving the "xzy" storage): the array that a binvox file
stores as ``data.reshape(D, D, D)[x, z, y]`` becomes ``voxels[x, y, z]``. No axis is
flipped or swapped beyond that: ShapeNetVox32 files are in the frame of the ShapeNetCore v1
models (+Y up, front +X); ``sc3d_data.formats.r2n2`` turns them to sc3d's front +Z and places the
grid (ShapeNetVox32 was written with ``binvox -cb``, whose header ``translate`` is the mesh's
bounding-box minimum, not the grid corner: docs/data.md). sc3d grids cover
[-0.5, 0.5]^3, which is ``translate = (-0.5, -0.5, -0.5)``, ``scale = 1``; ``write_binvox``
writes that header by default.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: header of an sc3d grid over [-0.5, 0.5]^3
SC3D_TRANSLATE = (-0.5, -0.5, -0.5)
SC3D_SCALE = 1.0


@dataclass
class Binvox:
    """A binvox grid: ``voxels`` bool ``[D, D, D]`` in sc3d index order ``[x, y, z]``,
    ``translate`` (3 floats) and ``scale`` mapping normalised voxel coordinates in [0, 1]
    to model coordinates (module doc)."""

    voxels: np.ndarray
    translate: tuple[float, float, float] = SC3D_TRANSLATE
    scale: float = SC3D_SCALE


def _parse_header(f, path) -> tuple[tuple[int, int, int], tuple[float, ...], float]:
    first = f.readline().strip()
    if not first.startswith(b"#binvox"):
        raise ValueError(f"{path}: not a binvox file (first line {first[:40]!r})")
    version = first.split()[1:] or [b"1"]
    if version[0] != b"1":
        raise ValueError(f"{path}: binvox version {version[0].decode()} is not supported (only 1)")
    dims, translate, scale = None, (0.0, 0.0, 0.0), 1.0
    while True:
        line = f.readline()
        if not line:
            raise ValueError(f"{path}: header ends before the 'data' line")
        words = line.split()
        if not words:
            continue
        key = words[0]
        try:
            if key == b"data":
                break
            if key == b"dim":
                dims = tuple(int(w) for w in words[1:4])
            elif key == b"translate":
                translate = tuple(float(w) for w in words[1:4])
            elif key == b"scale":
                scale = float(words[1])
        except (ValueError, IndexError) as e:
            raise ValueError(f"{path}: bad header line {line.strip()!r} ({e})") from e
    if dims is None or len(dims) != 3:
        raise ValueError(f"{path}: header has no 'dim D D D' line")
    if len(set(dims)) != 1 or dims[0] < 1:
        raise ValueError(f"{path}: only cubic grids are supported, got dim {dims}")
    if not (0 < scale < math.inf and all(map(math.isfinite, translate))):
        raise ValueError(f"{path}: header scale {scale} / translate {' '.join(map(str, translate))}: the scale must "
                         "be a positive number and the translation finite (the grid's place in the mesh's frame)")
    return dims, translate, scale


def decode_rle(data: bytes, n: int, path="binvox data") -> np.ndarray:
    """Run-length data (value, count) byte pairs -> flat bool ``[n]`` in file order."""
    raw = np.frombuffer(data, dtype=np.uint8)
    if len(raw) % 2:
        raw = raw[:-1] if raw[-1] in (0x0a, 0x0d, 0x20) else raw
        if len(raw) % 2:
            raise ValueError(f"{path}: run-length data has an odd number of bytes")
    values, counts = raw[0::2], raw[1::2].astype(np.int64)
    total = int(counts.sum())
    if total != n:
        raise ValueError(f"{path}: run-length data covers {total} voxels, the header says {n}")
    if (counts == 0).any():
        raise ValueError(f"{path}: run-length data has a run of length 0")
    return np.repeat(values > 0, counts)


def encode_rle(flat: np.ndarray) -> bytes:
    """Flat bool array (file order) -> run-length bytes: (value, count) pairs, count 1..255."""
    flat = np.asarray(flat, dtype=np.uint8).ravel()
    if len(flat) == 0:
        return b""
    change = np.flatnonzero(np.diff(flat)) + 1
    starts = np.concatenate([[0], change])
    lengths = np.diff(np.concatenate([starts, [len(flat)]]))
    out = bytearray()
    for value, length in zip(flat[starts], lengths):
        full, rest = divmod(int(length), 255)
        out += bytes((int(value), 255)) * full
        if rest:
            out += bytes((int(value), rest))
    return bytes(out)


def binvox_to_sc3d(file_order: np.ndarray) -> np.ndarray:
    """Grid reshaped from binvox file order ``[x, z, y]`` -> sc3d ``[x, y, z]``."""
    return np.transpose(file_order, (0, 2, 1))


def sc3d_to_binvox(voxels: np.ndarray) -> np.ndarray:
    """sc3d grid ``[x, y, z]`` -> binvox file order ``[x, z, y]`` (y fastest when flattened)."""
    return np.transpose(voxels, (0, 2, 1))


def binvox_resolution(path: str | Path) -> int | None:
    """The grid side ``D`` of ``.binvox`` file ``path`` from its header alone; None when the file
    cannot be read or is not a binvox file."""
    try:
        with open(path, "rb") as f:
            return _parse_header(f, path)[0][0]
    except (OSError, ValueError, IndexError):
        return None


def binvox_intact(path: str | Path, resolution: int) -> bool:
    """Whether ``path`` is a whole ``.binvox`` file of a ``resolution``^3 grid: its header says so
    and its run-length data decodes to exactly that many voxels (a file cut short by a copy or a
    full disk keeps its header: ``read_binvox`` checks the run lengths against it)."""
    try:
        return read_binvox(path).voxels.shape == (resolution,) * 3
    except (OSError, ValueError, IndexError):
        return False


def read_binvox(path: str | Path) -> Binvox:
    """Read a binvox file; voxels come back in sc3d order ``[x, y, z]`` (module doc)."""
    path = Path(path)
    with open(path, "rb") as f:
        dims, translate, scale = _parse_header(f, path)
        data = f.read()
    D = dims[0]
    flat = decode_rle(data, D ** 3, path)
    return Binvox(np.ascontiguousarray(binvox_to_sc3d(flat.reshape(D, D, D))), translate, scale)


def _number(v) -> str:
    """Shortest text of a header number: binvox's own 6 significant digits when exact
    (so ShapeNetVox32 headers round-trip byte for byte), else Python's repr."""
    v = float(v)
    short = f"{v:g}"
    return short if float(short) == v else repr(v)


def binvox_bytes(grid: Binvox) -> bytes:
    """The bytes of a binvox file holding ``grid`` (header + run-length data)."""
    vox = np.asarray(grid.voxels).astype(bool)
    if vox.ndim != 3 or len(set(vox.shape)) != 1:
        raise ValueError(f"binvox needs a cubic [D, D, D] grid, got shape {vox.shape}")
    D = vox.shape[0]
    tx, ty, tz = (_number(v) for v in grid.translate)
    header = (f"#binvox 1\ndim {D} {D} {D}\ntranslate {tx} {ty} {tz}\n"
              f"scale {_number(grid.scale)}\ndata\n").encode()
    return header + encode_rle(sc3d_to_binvox(vox).ravel())


def write_binvox(path: str | Path, voxels: np.ndarray, translate=SC3D_TRANSLATE,
                 scale: float = SC3D_SCALE) -> None:
    """Write ``voxels`` (sc3d order ``[x, y, z]``) as a binvox file; the default header
    describes sc3d's [-0.5, 0.5]^3 cube. Written to ``NAME.tmp`` and renamed."""
    from sc3d_data.io.shards import atomic_write_bytes

    atomic_write_bytes(Path(path), binvox_bytes(Binvox(voxels, tuple(translate), scale)))
