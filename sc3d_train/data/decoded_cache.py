"""A decoded copy of a dataset's per-sample arrays: uncompressed ``.npy`` files read memory-mapped,
so that a batch is a few fancy-indexing gathers instead of ~150 gzip-decompressing HDF5 reads.

Opt-in (``RunConfig.decoded_cache``, ``fit --decoded-cache DIR``): it costs disk, ~470 KiB per
object at 64 px, 24 views and 32^3 voxels (about 22x the compressed shards), and page cache
(datasets larger than RAM are read from disk page by page; nothing is loaded whole).

Layout: ``DIR/<SHA-256 of the shard file>/`` holds, for every row of that shard,
``images.npy [N,V,S,S,3]`` uint8, ``masks.npy [N,V,S,S]`` as stored, ``masks_sc<M>.npy
[N,V,M,M]`` bool (``batch_format.sc_masks_bool``, the 48 px masks) and, with voxels,
``voxels.npy [N,G,G,G]`` uint8: the values h5py decodes, unchanged. The key is the SHA-256 that
``index.json`` records for the shard, where the entry has seen the file's stamp (manifest
``shard_stamps``), else the file's (a shard replaced behind its index's back: ``_shard_key``), so
a rewritten shard gets a new folder and a stale copy is never read; old folders are not deleted.

Verification: ``decoded_manifest`` (each entry's ``manifest.json``, checked on every open).

Concurrency: a missing or failing entry is built under an exclusive ``flock`` on
``DIR/<key>.lock`` (other ranks or runs wait for it, then find it built), into a temporary
folder renamed into place when complete, so a crash leaves no half-written entry (its temporary
folder is removed by the next build of that entry; a build that fails, e.g. on a full disk, or
is interrupted removes its own).
"""
from __future__ import annotations

import fcntl
import os
import re
import shutil
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np

from sc3d_data.io.shard_reader import ShardReader
from sc3d_data.io.shards import ShardError, file_sha256, io_reason, load_index, shard_path
from sc3d_data.io.names import printable
from sc3d_data.io.outlock import open_lock_file
from sc3d_train.data.batch_format import sc_masks_bool
from sc3d_train.data.decoded_manifest import (describe, intact_others, remember_shard, shard_key, stamp,
                                              verify_entry, write_manifest)

_KEY = re.compile(r"^[0-9a-f]{64}$")


@contextmanager
def _locked(path: Path) -> Iterator[None]:
    """Hold an exclusive ``flock`` on ``path`` (created if needed), waiting for other holders."""
    fd = open_lock_file(path)
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
    """Write the ``.npy`` files of shard ``path`` into ``folder`` (module doc), row by row, with
    plain writes: a full disk is then an ``OSError`` (ENOSPC), where a store into the memory map
    of a sparse file killed the process with SIGBUS."""
    fields = ("images", "masks") + (("voxels",) if voxels else ())
    n = reader.num_rows(path)
    with ExitStack() as files:
        out = {}
        for row in range(n):
            arrays = reader.read(path, row, fields)
            arrays[f"masks_sc{mask_size}"] = sc_masks_bool(arrays["masks"], mask_size)
            for k, a in arrays.items():
                if k not in out:
                    out[k] = files.enter_context(open(folder / f"{k}.npy", "wb"))
                    np.lib.format.write_array_header_1_0(out[k], {
                        "descr": np.lib.format.dtype_to_descr(a.dtype), "fortran_order": False, "shape": (n,) + a.shape})
                out[k].write(np.ascontiguousarray(a).tobytes())


class DecodedCache:
    """The decoded copies of the shards ``paths`` of dataset ``shard_dir`` in ``cache_dir``
    (built on construction where missing), opened memory-mapped lazily in each process.
    :meth:`views` gathers a batch. Errors (unwritable folder, full disk, unreadable shard) are
    ``ShardError`` naming the folder or file."""

    def __init__(self, cache_dir: Path, shard_dir: Path, paths: list[str], mask_size: int, voxels: bool):
        self.cache_dir, self.mask_size, self.voxels = Path(cache_dir), mask_size, voxels
        keys = shard_keys(shard_dir)
        self.folders = [self.cache_dir / shard_key(Path(p), keys[str(p)], self.cache_dir) for p in paths]
        self._names = ("images", "masks", f"masks_sc{mask_size}") + (("voxels",) if voxels else ())
        self._maps: list[dict] | None = None
        self._inodes: list[dict] = []  # of the mapped files (_refuse_cut_short)
        self._pid = None
        reader = ShardReader(shard_dir)
        try:
            for path, folder in zip(paths, self.folders):
                self._ensure(reader, str(path), folder)
        finally:
            reader.close()

    def _ensure(self, reader: ShardReader, path: str, folder: Path) -> None:
        """Make ``folder`` the verified decoded copy of shard ``path`` (module doc): keep it when
        it passes :func:`verify_entry`, else (re)build it under the entry's lock."""
        if verify_entry(folder, self._names, folder.name) is None:
            return remember_shard(folder, Path(path))
        try:
            self.cache_dir.mkdir(parents=True, exist_ok=True)
            with _locked(self.cache_dir / f"{folder.name}.lock"):
                if verify_entry(folder, self._names, folder.name) is None:  # another process built it
                    return remember_shard(folder, Path(path))
                for stale in self.cache_dir.glob(f"{folder.name}.tmp-*"):  # left by a crash
                    shutil.rmtree(stale, ignore_errors=True)
                tmp = self.cache_dir / f"{folder.name}.tmp-{os.getpid()}"
                tmp.mkdir()
                try:
                    _build(reader, path, tmp, self.mask_size, self.voxels)
                    for p in intact_others(folder, tmp):  # an entry built for another mask size or without voxels
                        os.replace(p, tmp / p.name)
                    write_manifest(tmp, {"shard_sha256": folder.name, "source": Path(path).name,
                                          "shard_stamps": [stamp(Path(path))],
                                          "arrays": {p.name: describe(p) for p in sorted(tmp.glob("*.npy"))}})
                except BaseException:  # a full disk or a Ctrl-C: the partial copy is not left filling the disk
                    shutil.rmtree(tmp, ignore_errors=True)
                    raise
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
            self._maps = [{k.rstrip("0123456789"): _open_map(f / f"{k}.npy") for k in self._names}
                          for f in self.folders]
            self._inodes = [{k: os.stat(m.filename).st_ino for k, m in maps.items()} for maps in self._maps]
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
            _refuse_cut_short(maps[s], self._inodes[s])
            for k, a in maps[s].items():
                got = a[r] if k == "voxels" else a[r, v]
                if k not in out:
                    out[k] = np.empty((len(rows),) + got.shape[1:], dtype=got.dtype)
                out[k][sel] = got
        return out


def _refuse_cut_short(maps: dict[str, np.memmap], inodes: dict[str, int]) -> None:
    """``ShardError`` naming a mapped file now shorter than its map (cut short after it was
    mapped: a read of the pages past its end is a SIGBUS, not an exception). A file replaced or
    removed since is fine: the map keeps the file it was made of."""
    for k, m in maps.items():
        try:
            st = os.stat(m.filename)
        except OSError:
            continue
        if st.st_ino == inodes[k] and st.st_size < m.offset + m.nbytes:
            raise ShardError(f"{printable(m.filename)}: cut short while this run reads it ({st.st_size} bytes, "
                             f"{m.offset + m.nbytes} mapped); remove it to have it rebuilt")


def _open_map(path: Path) -> np.ndarray:
    """``path`` memory-mapped read-only; ``ShardError`` naming it when it cannot be (e.g. cut
    short after the cache was verified)."""
    try:
        return np.load(path, mmap_mode="r")
    except (OSError, ValueError) as e:
        raise ShardError(f"{printable(path)}: cannot map the decoded cache file ({type(e).__name__}: {e}); "
                         "remove it to have it rebuilt") from e
