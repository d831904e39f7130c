"""A decoded copy of a dataset's per-sample arrays: uncompressed ``.npy`` files read memory-mapped,
so that a batch is a few fancy-indexing gathers instead of ~150 gzip-decompressing HDF5 reads.

Opt-in (``RunConfig.decoded_cache``, ``fit --decoded-cache DIR``): it costs disk, ~470 KiB per
object at 64 px, 24 views and 32^3 voxels (about 22x the compressed shards), and page cache
(datasets larger than RAM are read from disk page by page; nothing is loaded whole).

Layout: ``DIR/<SHA-256 of the shard file>/`` holds, for every row of that shard,
``images.npy [N,V,S,S,3]`` uint8, ``masks.npy [N,V,S,S]`` as stored, ``masks_sc<M>.npy
[N,V,M,M]`` bool (``batch_format.sc_masks_bool``, the 48 px masks) and, with voxels,
``voxels.npy [N,G,G,G]`` uint8: the values h5py decodes, unchanged. The key is the SHA-256 that
the dataset's ``index.json`` records for the shard (computed from the file when the index has
none), so a rewritten shard gets a new folder and a stale copy is never read; old folders are not
deleted (remove ``DIR`` to reclaim the space).

Concurrency: a missing entry is built under an exclusive ``flock`` on ``DIR/<key>.lock`` (other
ranks or runs wait for it, then find it built), into a temporary folder renamed into place when
complete, so a crash leaves no half-written entry (its temporary folder is removed by the next
build of that entry).
"""
from __future__ import annotations

import fcntl
import os
import re
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np

from sc3d_data.io.shard_reader import ShardReader
from sc3d_data.io.shards import ShardError, file_sha256, io_reason, load_index, shard_path
from sc3d_train.batch_format import sc_masks_bool

_KEY = re.compile(r"^[0-9a-f]{64}$")


@contextmanager
def _locked(path: Path) -> Iterator[None]:
    """Hold an exclusive ``flock`` on ``path`` (created if needed), waiting for other holders."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock


def shard_keys(shard_dir: Path) -> dict[str, str]:
    """``{shard path: SHA-256}`` of every shard in the index (from the index; from the file's
    bytes where the index records none)."""
    out = {}
    for entry in load_index(shard_dir).get("shards", []):
        path = shard_path(shard_dir, entry.get("file"))
        key = entry.get("sha256") or file_sha256(path)
        if not _KEY.match(str(key)):
            raise ShardError(f"{path}: the index records a malformed SHA-256 {key!r}")
        out[str(path)] = key
    return out


def _build(reader: ShardReader, path: str, folder: Path, mask_size: int, voxels: bool) -> None:
    """Write the ``.npy`` files of shard ``path`` into ``folder`` (module doc), row by row."""
    fields = ("images", "masks") + (("voxels",) if voxels else ())
    out = {}
    first = reader.read(path, 0, fields)
    n = reader.num_rows(path)
    for k, a in first.items():
        out[k] = np.lib.format.open_memmap(folder / f"{k}.npy", mode="w+", dtype=a.dtype, shape=(n,) + a.shape)
    m = sc_masks_bool(first["masks"], mask_size)
    out["masks_sc"] = np.lib.format.open_memmap(folder / f"masks_sc{mask_size}.npy", mode="w+", dtype=bool,
                                                shape=(n,) + m.shape)
    for row in range(n):
        arrays = first if row == 0 else reader.read(path, row, fields)
        for k, a in arrays.items():
            out[k][row] = a
        out["masks_sc"][row] = sc_masks_bool(arrays["masks"], mask_size)
    for a in out.values():
        a.flush()


class DecodedCache:
    """The decoded copies of the shards ``paths`` of dataset ``shard_dir`` in ``cache_dir``
    (built on construction where missing), opened memory-mapped lazily in each process.
    :meth:`views` gathers a batch. Errors (unwritable folder, full disk, unreadable shard) are
    ``ShardError`` naming the folder or file."""

    def __init__(self, cache_dir: Path, shard_dir: Path, paths: list[str], mask_size: int, voxels: bool):
        self.cache_dir, self.mask_size, self.voxels = Path(cache_dir), mask_size, voxels
        keys = shard_keys(shard_dir)
        self.folders = [self.cache_dir / keys[str(p)] for p in paths]
        self._names = ("images", "masks", f"masks_sc{mask_size}") + (("voxels",) if voxels else ())
        self._maps: list[dict] | None = None
        self._pid = None
        reader = ShardReader(shard_dir)
        try:
            for path, folder in zip(paths, self.folders):
                self._ensure(reader, str(path), folder)
        finally:
            reader.close()

    def _complete(self, folder: Path) -> bool:
        return all((folder / f"{k}.npy").is_file() for k in self._names)

    def _ensure(self, reader: ShardReader, path: str, folder: Path) -> None:
        if self._complete(folder):
            return
        try:
            self.cache_dir.mkdir(parents=True, exist_ok=True)
            with _locked(self.cache_dir / f"{folder.name}.lock"):
                if self._complete(folder):  # another process built it meanwhile
                    return
                for stale in self.cache_dir.glob(f"{folder.name}.tmp-*"):  # left by a crash
                    shutil.rmtree(stale, ignore_errors=True)
                tmp = self.cache_dir / f"{folder.name}.tmp-{os.getpid()}"
                tmp.mkdir()
                have = list(folder.glob("*.npy")) if folder.is_dir() else []
                _build(reader, path, tmp, self.mask_size, self.voxels)
                for p in have:  # an entry built for another mask size or without voxels
                    if not (tmp / p.name).exists():
                        os.replace(p, tmp / p.name)
                shutil.rmtree(folder, ignore_errors=True)
                os.replace(tmp, folder)
        except OSError as e:
            raise ShardError(f"{self.cache_dir}: cannot write the decoded cache ({io_reason(e, self.cache_dir)})") from e

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_maps"], state["_pid"] = None, None  # memory maps are reopened in each process
        return state

    def _arrays(self) -> list[dict]:
        if self._pid != os.getpid():
            self._maps = [{k.rstrip("0123456789"): np.load(f / f"{k}.npy", mmap_mode="r") for k in self._names}
                          for f in self.folders]
            self._pid = os.getpid()
        return self._maps

    def views(self, shard_index: np.ndarray, rows: np.ndarray, views: np.ndarray) -> dict[str, np.ndarray]:
        """``images [B,S,S,3]``, ``masks [B,S,S]``, ``masks_sc [B,M,M]`` and (with voxels)
        ``voxels [B,G,G,G]`` of the B samples (shard number in ``paths``, row, view), as stored."""
        maps = self._arrays()
        out: dict[str, np.ndarray] = {}
        for s in np.unique(shard_index).tolist():
            sel = np.flatnonzero(shard_index == s)
            r, v = rows[sel], views[sel]
            for k, a in maps[s].items():
                got = a[r] if k == "voxels" else a[r, v]
                if k not in out:
                    out[k] = np.empty((len(rows),) + got.shape[1:], dtype=got.dtype)
                out[k][sel] = got
        return out
