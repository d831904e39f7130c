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

Verification: each entry holds ``manifest.json``, written when it is built: the shard's SHA-256
and, per array file, its shape, dtype, size in bytes and SHA-256, and a stamp (inode, size,
ctime in ns) of the file as built. On open, every entry is checked against the shard it is used
for: the manifest must name that shard (a folder swapped with another shard's is caught), each
file must have the recorded size (truncation) and ``.npy`` header (shape, dtype); a file whose
stamp differs (rewritten, copied, touched: any write changes the ctime, which cannot be set
back) is hashed again and must match the recorded SHA-256 (an overwrite). An entry that fails
any check, or has no manifest (built by an older sc3d), is rebuilt from its shard. So a warm open
costs a few ``stat`` and header reads per shard; only changed files are read whole.

Concurrency: a missing or failing entry is built under an exclusive ``flock`` on
``DIR/<key>.lock`` (other ranks or runs wait for it, then find it built), into a temporary
folder renamed into place when complete, so a crash leaves no half-written entry (its temporary
folder is removed by the next build of that entry; a build that fails, e.g. on a full disk, or
is interrupted removes its own).
"""
from __future__ import annotations

import fcntl
import json
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

_KEY = re.compile(r"^[0-9a-f]{64}$")
MANIFEST = "manifest.json"


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


def _stamp(path: Path) -> list[int]:
    st = os.stat(path)
    return [st.st_ino, st.st_size, st.st_ctime_ns]


def _header(path: Path) -> tuple[list[int], str]:
    """``(shape, dtype string)`` from the header of the ``.npy`` file ``path``."""
    fmt = np.lib.format
    with open(path, "rb") as f:
        version = fmt.read_magic(f)
        read = {(1, 0): fmt.read_array_header_1_0, (2, 0): fmt.read_array_header_2_0}.get(version)
        if read is None:
            raise ValueError(f".npy format version {version} not written by sc3d")
        shape, _, dtype = read(f)
    return list(shape), dtype.str


def _describe(path: Path) -> dict:
    """The manifest entry of array file ``path`` (module doc)."""
    shape, dtype = _header(path)
    return {"shape": shape, "dtype": dtype, "bytes": path.stat().st_size, "sha256": file_sha256(path),
            "stamp": _stamp(path)}


def _write_manifest(folder: Path, manifest: dict) -> None:
    tmp = folder / f"{MANIFEST}.{os.getpid()}.tmp"
    tmp.write_text(json.dumps(manifest, indent=1))
    os.replace(tmp, folder / MANIFEST)


def _array_problem(path: Path, entry: dict | None, deep: bool) -> str | None:
    """Why array file ``path`` does not match its manifest ``entry`` (None: it does). ``deep``:
    hash the file when its stamp differs from the recorded one."""
    if entry is None:
        return "not listed in the manifest"
    try:
        if path.stat().st_size != entry["bytes"]:
            return f"{path.stat().st_size} bytes, built with {entry['bytes']} (truncated or rewritten)"
        if _header(path) != (entry["shape"], entry["dtype"]):
            return f"shape/dtype {_header(path)} differ from the built {entry['shape']} {entry['dtype']}"
        if deep and _stamp(path) != entry["stamp"]:
            if file_sha256(path) != entry["sha256"]:
                return "contents differ from what was built (overwritten)"
            entry["stamp"] = _stamp(path)  # same bytes (a copy, a touch): remember this file
    except (OSError, ValueError) as e:
        return f"unreadable ({type(e).__name__}: {e})"
    return None


def verify_entry(folder: Path, names: tuple[str, ...], key: str) -> str | None:
    """One line naming the file and the problem when cache entry ``folder`` is not the decoded
    copy of the shard whose SHA-256 is ``key`` with the arrays ``names`` intact (module doc);
    None when it is (updated stamps are written back where the folder allows)."""
    try:
        manifest = json.loads((folder / MANIFEST).read_text())
        arrays = manifest["arrays"]
    except FileNotFoundError:
        return f"{folder / MANIFEST}: missing (an entry of an older sc3d or an interrupted build)"
    except (OSError, ValueError, KeyError, TypeError) as e:
        return f"{folder / MANIFEST}: unreadable ({type(e).__name__}: {e})"
    if manifest.get("shard_sha256") != key:
        return (f"{folder}: holds the decoded copy of shard {manifest.get('shard_sha256')}, "
                f"not of {key} (folders swapped or copied)")
    before = json.dumps(arrays)
    for name in names:
        problem = _array_problem(folder / f"{name}.npy", arrays.get(f"{name}.npy"), deep=True)
        if problem is not None:
            return f"{folder / (name + '.npy')}: {problem}"
    if json.dumps(arrays) != before:
        try:
            _write_manifest(folder, manifest)
        except OSError:
            pass  # a read-only cache is verified again next time
    return None


class DecodedCache:
    """The decoded copies of the shards ``paths`` of dataset ``shard_dir`` in ``cache_dir``
    (built on construction where missing), opened memory-mapped lazily in each process.
    :meth:`views` gathers a batch. Errors (unwritable folder, full disk, unreadable shard) are
    ``ShardError`` naming the folder or file."""

    def __init__(self, cache_dir: Path, shard_dir: Path, paths: list[str], mask_size: int, voxels: bool):
        self.cache_dir, self.mask_size, self.voxels = Path(cache_dir), mask_size, voxels
        keys = shard_keys(shard_dir)
        self.folders = [self.cache_dir / _shard_key(Path(p), keys[str(p)], self.cache_dir) for p in paths]
        self._names = ("images", "masks", f"masks_sc{mask_size}") + (("voxels",) if voxels else ())
        self._maps: list[dict] | None = None
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
            return _remember_shard(folder, Path(path))
        try:
            self.cache_dir.mkdir(parents=True, exist_ok=True)
            with _locked(self.cache_dir / f"{folder.name}.lock"):
                if verify_entry(folder, self._names, folder.name) is None:  # another process built it
                    return _remember_shard(folder, Path(path))
                for stale in self.cache_dir.glob(f"{folder.name}.tmp-*"):  # left by a crash
                    shutil.rmtree(stale, ignore_errors=True)
                tmp = self.cache_dir / f"{folder.name}.tmp-{os.getpid()}"
                tmp.mkdir()
                try:
                    _build(reader, path, tmp, self.mask_size, self.voxels)
                    for p in _intact_others(folder, tmp):  # an entry built for another mask size or without voxels
                        os.replace(p, tmp / p.name)
                    _write_manifest(tmp, {"shard_sha256": folder.name, "source": Path(path).name,
                                          "shard_stamps": [_stamp(Path(path))],
                                          "arrays": {p.name: _describe(p) for p in sorted(tmp.glob("*.npy"))}})
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


def _shard_key(path: Path, key: str, cache_dir: Path) -> str:
    """The SHA-256 of shard ``path`` as it is now: the index's ``key`` where entry ``key`` was
    built from, or has checked, a file of this stamp (its manifest's ``shard_stamps``); else
    hashed from the file. A shard replaced behind its index's back (restored from a backup,
    copied from another render, a ``voxelize`` killed before it wrote the index) so gets the
    entry of what reading it gives, not the old copy of the bytes the index names."""
    try:
        seen = json.loads((cache_dir / key / MANIFEST).read_text()).get("shard_stamps") or []
    except (OSError, ValueError, AttributeError):
        seen = []
    try:
        return key if _stamp(path) in seen else file_sha256(path)
    except OSError as e:
        raise ShardError(f"{printable(path)}: cannot read the shard ({io_reason(e, path)})") from e


def _remember_shard(folder: Path, path: Path) -> None:
    """Add the stamp of shard ``path`` (its bytes hash to the key of entry ``folder``) to the
    entry's manifest, so that the next open need not hash it (where the folder allows)."""
    try:
        manifest = json.loads((folder / MANIFEST).read_text())
        stamps = manifest.get("shard_stamps") or []
        if _stamp(path) not in stamps:  # the last 8: copies of the dataset sharing the cache
            manifest["shard_stamps"] = (stamps + [_stamp(path)])[-8:]
            _write_manifest(folder, manifest)
    except (OSError, ValueError, AttributeError):
        pass  # read-only: hashed again next time


def _intact_others(folder: Path, tmp: Path) -> list[Path]:
    """Array files of an existing entry ``folder`` that the new build in ``tmp`` lacks (another
    mask size, voxels) and that still match the entry's manifest: worth keeping."""
    try:
        arrays = json.loads((folder / MANIFEST).read_text())["arrays"]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    return [p for p in sorted(folder.glob("*.npy")) if not (tmp / p.name).exists()
            and _array_problem(p, arrays.get(p.name), deep=True) is None]


def _open_map(path: Path) -> np.ndarray:
    """``path`` memory-mapped read-only; ``ShardError`` naming it when it cannot be (e.g. cut
    short after the cache was verified)."""
    try:
        return np.load(path, mmap_mode="r")
    except (OSError, ValueError) as e:
        raise ShardError(f"{printable(path)}: cannot map the decoded cache file ({type(e).__name__}: {e}); "
                         "remove it to have it rebuilt") from e
