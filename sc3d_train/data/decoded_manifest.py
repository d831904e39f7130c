"""The manifest of a decoded-cache entry (``decoded_cache``) and its checks.

Verification: each entry holds ``manifest.json``, written when it is built: the shard's SHA-256
and, per array file, its shape, dtype, size in bytes and SHA-256, and a stamp (inode, size,
ctime in ns) of the file as built. On open, every entry is checked against the shard it is used
for: the manifest must name that shard (a folder swapped with another shard's is caught), each
file must have the recorded size (truncation) and ``.npy`` header (shape, dtype); a file whose
stamp differs (rewritten, copied, touched: any write changes the ctime, which cannot be set
back) is hashed again and must match the recorded SHA-256 (an overwrite). An entry that fails
any check, or has no manifest (built by an older sc3d), is rebuilt from its shard. So a warm open
costs a few ``stat`` and header reads per shard; only changed files are read whole.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from sc3d_data.io.names import printable
from sc3d_data.io.shards import ShardError, file_sha256, io_reason

MANIFEST = "manifest.json"


def stamp(path: Path) -> list[int]:
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


def describe(path: Path) -> dict:
    """The manifest entry of array file ``path`` (module doc)."""
    shape, dtype = _header(path)
    return {"shape": shape, "dtype": dtype, "bytes": path.stat().st_size, "sha256": file_sha256(path),
            "stamp": stamp(path)}


def write_manifest(folder: Path, manifest: dict) -> None:
    tmp = folder / f"{MANIFEST}.{os.getpid()}.tmp"
    tmp.write_text(json.dumps(manifest, indent=1))
    os.replace(tmp, folder / MANIFEST)


def array_problem(path: Path, entry: dict | None, deep: bool) -> str | None:
    """Why array file ``path`` does not match its manifest ``entry`` (None: it does). ``deep``:
    hash the file when its stamp differs from the recorded one."""
    if entry is None:
        return "not listed in the manifest"
    try:
        if path.stat().st_size != entry["bytes"]:
            return f"{path.stat().st_size} bytes, built with {entry['bytes']} (truncated or rewritten)"
        if _header(path) != (entry["shape"], entry["dtype"]):
            return f"shape/dtype {_header(path)} differ from the built {entry['shape']} {entry['dtype']}"
        if deep and stamp(path) != entry["stamp"]:
            if file_sha256(path) != entry["sha256"]:
                return "contents differ from what was built (overwritten)"
            entry["stamp"] = stamp(path)  # same bytes (a copy, a touch): remember this file
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
        problem = array_problem(folder / f"{name}.npy", arrays.get(f"{name}.npy"), deep=True)
        if problem is not None:
            return f"{folder / (name + '.npy')}: {problem}"
    if json.dumps(arrays) != before:
        try:
            write_manifest(folder, manifest)
        except OSError:
            pass  # a read-only cache is verified again next time
    return None


def shard_key(path: Path, key: str, cache_dir: Path) -> str:
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
        return key if stamp(path) in seen else file_sha256(path)
    except OSError as e:
        raise ShardError(f"{printable(path)}: cannot read the shard ({io_reason(e, path)})") from e


def remember_shard(folder: Path, path: Path) -> None:
    """Add the stamp of shard ``path`` (its bytes hash to the key of entry ``folder``) to the
    entry's manifest, so that the next open need not hash it (where the folder allows)."""
    try:
        manifest = json.loads((folder / MANIFEST).read_text())
        stamps = manifest.get("shard_stamps") or []
        if stamp(path) not in stamps:  # the last 8: copies of the dataset sharing the cache
            manifest["shard_stamps"] = (stamps + [stamp(path)])[-8:]
            write_manifest(folder, manifest)
    except (OSError, ValueError, AttributeError):
        pass  # read-only: hashed again next time


def intact_others(folder: Path, tmp: Path) -> list[Path]:
    """Array files of an existing entry ``folder`` that the new build in ``tmp`` lacks (another
    mask size, voxels) and that still match the entry's manifest: worth keeping."""
    try:
        arrays = json.loads((folder / MANIFEST).read_text())["arrays"]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    return [p for p in sorted(folder.glob("*.npy")) if not (tmp / p.name).exists()
            and array_problem(p, arrays.get(p.name), deep=True) is None]
