"""Reading sc3d datasets: the one place that opens shard files for reading.

``ShardReader(shard_dir)`` is what the training loader, ``check``, ``preview`` and ``voxelize`` use:
it reads the index, summarises each shard from its string fields and shapes (``summaries``),
reads one object's arrays (``read``) or chosen views of many objects at once (``read_views``:
only the chunks holding them are decompressed) through HDF5 handles it keeps per process (a forked worker or a pickled
copy opens its own, never the parent's). Errors are ``ShardError`` naming the
file and pointing at ``sc3d-data info --verify``. The layout itself (dataset names, shapes, dtypes)
is documented in ``sc3d_data.io.shards``.

Length: one module because it is the one place that opens shards for reading: every reader and
every check of a shard against its index (``verify_shard``) share its handles and its errors.
"""
from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import h5py
import numpy as np

from sc3d_data.io.index_check import version_problem
from sc3d_data.io.outlock import writer_of
from sc3d_data.io.shard_layout import grid_problem, layout_problem
from sc3d_data.io.shards import (OBJECT_ARRAYS, SCHEMA_VERSION, STRING_FIELDS, ObjectRecord, ShardError, file_sha256,
                                 held_voxel_resolution, io_reason, load_index, shard_files, shard_path)


@dataclass
class ShardSummary:
    """One shard file as the index and its string fields describe it. ``num_objects``,
    ``num_views``, ``image_size`` from ``images [N, V, S, S, 3]``; ``voxel_resolution`` G of
    ``voxels [N, G, G, G]`` or None without voxels; ``K [3, 3]`` (pixels) of view 0 of object 0
    (all views of a dataset share it); ``distances [N * V]``: every view's camera distance (world
    units; one value for ``render``'s shards, an ``import-r2n2`` dataset keeps 3D-R2N2's, which vary
    by view)."""

    path: Path
    model_id: list[str]
    category: list[str]
    split: list[str]
    num_objects: int
    num_views: int
    image_size: int
    voxel_resolution: int | None
    K: np.ndarray
    distances: np.ndarray


class ShardReader:
    """Read access to the dataset in ``shard_dir`` (module doc). Usable as a context manager;
    ``close()`` closes the handles this process opened."""

    def __init__(self, shard_dir: Path):
        self.shard_dir = Path(shard_dir)
        self.index = load_index(self.shard_dir)
        self.files = shard_files(self.shard_dir)
        self._handles: dict[str, h5py.File] = {}
        self._datasets: dict[tuple[str, str], h5py.Dataset] = {}
        self._pid = os.getpid()

    @property
    def settings(self) -> dict:
        return self.index.get("settings", {})

    def summaries(self) -> list[ShardSummary]:
        """A ``ShardSummary`` per shard file in index order (reads strings and shapes only)."""
        out = []
        listed = Counter(o.get("shard") for o in self.index.get("objects", []))  # objects per shard file
        for path in self.files:
            if not path.is_file():
                raise ShardError(f"{path}: listed in {self.shard_dir}/index.json but missing")
            with open_shard(path) as f:
                try:
                    ids, cats, splits = (read_strings(f[k]) for k in ("model_id", "category", "split"))
                    n, v, s = f["images"].shape[:3]
                    if path.name in listed and listed[path.name] != n:
                        raise ShardError(f"{path}: holds {n} objects, {self.shard_dir}/index.json lists "
                                         f"{listed[path.name]} in it; see `sc3d-data info --verify {self.shard_dir}`")
                    out.append(ShardSummary(path, ids, cats, splits, int(n), int(v), int(s),
                                            int(f["voxels"].shape[1]) if "voxels" in f else None,
                                            f["K"][0, 0], np.asarray(f["distance"][()], np.float64).ravel()))
                except (OSError, KeyError, RuntimeError) as e:  # truncated / corrupted shard
                    raise ShardError(f"{path}: broken shard ({io_reason(e)}); see `sc3d-data info --verify "
                                     f"{self.shard_dir}`") from e
        return out

    def _handle(self, path: Path) -> h5py.File:
        if self._pid != os.getpid():  # forked: never use the parent's handles
            self._handles, self._datasets, self._pid = {}, {}, os.getpid()
        key = str(path)
        if key not in self._handles:
            self._handles[key] = open_shard(path).file
        return self._handles[key]

    def _dataset(self, path: Path, name: str) -> h5py.Dataset:
        """Dataset ``name`` of shard file ``path``, kept per process (h5py makes a new object,
        ~0.2 ms, on every ``f[name]``)."""
        f = self._handle(Path(path))
        key = (str(path), name)
        if key not in self._datasets:
            self._datasets[key] = f[name]
        return self._datasets[key]

    def num_rows(self, path: Path) -> int:
        """Objects in shard file ``path`` (rows of its ``images``)."""
        try:
            return int(self._dataset(path, "images").shape[0])
        except (OSError, KeyError, RuntimeError) as e:
            raise ShardError(f"{path}: cannot be read ({io_reason(e)}); see `sc3d-data info --verify`") from e

    def holds(self, path: Path, name: str) -> bool:
        """Whether shard file ``path`` has the array ``name`` (e.g. ``voxels``)."""
        try:
            return name in self._handle(Path(path))
        except (OSError, RuntimeError) as e:
            raise ShardError(f"{path}: cannot be read ({io_reason(e)}); see `sc3d-data info --verify`") from e

    def read(self, path: Path, row: int, fields: tuple[str, ...]) -> dict[str, np.ndarray]:
        """Arrays ``fields`` of object ``row`` of shard file ``path`` (one of ``self.files``),
        without the object axis: every view of the object. ``ShardError`` naming the file when a
        checksum or gzip check fails."""
        try:
            return {k: self._dataset(path, k)[row] for k in fields}
        except (OSError, KeyError, RuntimeError) as e:
            raise ShardError(f"{path}: row {row} cannot be read ({io_reason(e)}); "
                             "see `sc3d-data info --verify`") from e

    def read_views(self, path: Path, rows, views, fields: tuple[str, ...]) -> dict[str, np.ndarray]:
        """Arrays ``fields`` of the B pairs ``(rows[i], views[i])`` of shard file ``path``, in the
        order given: a per-view dataset ``[N, V, ...]`` gives ``[B, ...]`` (that view), a
        per-object one (``OBJECT_ARRAYS``, e.g. ``voxels [N, G, G, G]``) ``[B, ...]`` (that row).
        Each distinct pair (per-object: row) is read once, in file order, so only the chunks
        holding a requested view are decompressed (one per view with the ``"view"`` chunk
        layout, one per object with ``"object"``). ``ShardError`` as :meth:`read`.

        One read per pair: a single HDF5 read of the union of the pairs' hyperslabs was 20x
        slower per sample (HDF5 2.0.0, chunks not in the chunk cache)."""
        rows, views = np.asarray(rows, dtype=np.int64), np.asarray(views, dtype=np.int64)
        per_row = int(views.max(initial=0)) + 1
        keys, pair_of = np.unique(rows * per_row + views, return_inverse=True)
        pairs = np.stack(np.divmod(keys, per_row), 1)
        objects, object_of = np.unique(rows, return_inverse=True)
        try:
            out = {}
            for k in fields:
                ds = self._dataset(path, k)
                if k in OBJECT_ARRAYS:
                    out[k] = np.stack([ds[r] for r in objects.tolist()])[object_of.reshape(-1)]
                else:
                    out[k] = np.stack([ds[r, v] for r, v in pairs.tolist()])[pair_of.reshape(-1)]
            return out
        except (OSError, KeyError, RuntimeError, ValueError) as e:
            raise ShardError(f"{path}: rows {sorted(set(rows.tolist()))} cannot be read ({io_reason(e)}); "
                             "see `sc3d-data info --verify`") from e

    def read_whole(self, path: Path, fields: tuple[str, ...]) -> dict[str, np.ndarray]:
        """Datasets ``fields`` of shard file ``path`` whole (``[N, ...]``: meant for the small
        per-view cameras and poses, ~2.3 KB per object). ``ShardError`` as :meth:`read`."""
        try:
            return {k: self._dataset(path, k)[()] for k in fields}
        except (OSError, KeyError, RuntimeError) as e:
            raise ShardError(f"{path}: cannot be read ({io_reason(e)}); see `sc3d-data info --verify`") from e

    def close(self) -> None:
        for f in self._handles.values():
            f.close()
        self._handles, self._datasets = {}, {}

    def __enter__(self) -> "ShardReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_handles"], state["_datasets"], state["_pid"] = {}, {}, None
        return state


def read_strings(ds) -> list[str]:
    return [s.decode() if isinstance(s, bytes) else str(s) for s in ds[()]]


def iter_objects(shard_dir: Path, fields: tuple[str, ...] | None = None) -> Iterator[dict]:
    """Yield one dict per object over all shards: string fields plus the requested array
    fields (all present ones when ``fields`` is None), plus ``shard`` and ``row``. A shard
    that cannot be read raises ``ShardError`` naming it."""
    for path in shard_files(shard_dir):
        with open_shard(path) as f:
            try:
                strings = {k: read_strings(f[k]) for k in STRING_FIELDS if k in f}
                names = [k for k in (fields or f.keys()) if k in f and k not in STRING_FIELDS]
                rows = range(f["model_id"].shape[0])
            except (OSError, KeyError, RuntimeError) as e:
                raise ShardError(f"{path}: broken shard ({io_reason(e)}); see `sc3d-data info --verify`") from e
            for row in rows:
                obj = {k: v[row] for k, v in strings.items()}
                try:
                    obj.update({k: f[k][row] for k in names})
                except (OSError, RuntimeError) as e:
                    raise ShardError(f"{path}: row {row} cannot be read ({io_reason(e)}); "
                                     "see `sc3d-data info --verify`") from e
                obj["shard"], obj["row"] = path.name, row
                yield obj


class open_shard:
    """``with open_shard(path) as f``: an ``h5py.File`` read-only; ``ShardError`` naming the
    file when it is missing, truncated, not HDF5, or of a schema version this sc3d does not read."""

    def __init__(self, path: Path):
        self.path = Path(path)
        try:
            self.file = h5py.File(self.path, "r")
        except (OSError, RuntimeError) as e:
            raise ShardError(f"{self.path}: cannot open shard ({io_reason(e)}); "
                             "see `sc3d-data info --verify`") from e
        problem = version_problem(self.file.attrs.get("schema_version"), "schema_version" in self.file.attrs,
                                  SCHEMA_VERSION)
        if problem is None:
            problem = layout_problem(self.file)
        if problem:
            self.file.close()
            raise ShardError(f"{self.path}: {problem}")

    def __enter__(self) -> h5py.File:
        return self.file

    def __exit__(self, *exc) -> None:
        self.file.close()


def read_records(path: Path) -> list[ObjectRecord]:
    """All objects of one shard back as ``ObjectRecord`` s (to rewrite a shard with more objects)."""
    with open_shard(path) as f:
        try:
            strings = {k: read_strings(f[k]) for k in STRING_FIELDS}
            arrays = {k: f[k][()] for k in f if k not in STRING_FIELDS}
        except (OSError, KeyError, RuntimeError) as e:
            raise ShardError(f"{path}: broken shard ({io_reason(e)})") from e
    return [ObjectRecord(model_id=strings["model_id"][i], category=strings["category"][i],
                         split=strings["split"][i], source=strings["source"][i],
                         arrays={k: v[i] for k, v in arrays.items()})
            for i in range(len(strings["model_id"]))]


def verify_shard(shard_dir: Path, entry: dict, full: bool = True, grids: int | None | bool = False) -> str | None:
    """Problem of the shard of index ``entry`` (missing, size or SHA-256 differs from the index,
    not readable), or None when it is intact. ``full=False`` checks existence and size only
    (cheap). Entries without a recorded checksum (older datasets) are checked by reading every
    dataset (HDF5 Fletcher-32 / gzip errors). ``grids``: the voxel grid side the index records
    (None: no grids), checked against the file's (``shard_layout.grid_problem``); False: not checked."""
    problem = _file_problem(shard_dir, entry, full)
    if problem is None and grids is not False:
        path = shard_path(shard_dir, entry.get("file"))
        try:
            with open_shard(path) as f:
                problem = grid_problem(f, grids)
        except ShardError as e:
            return str(e)
        return f"{path}: {problem}" if problem else None
    return problem


def _file_problem(shard_dir: Path, entry: dict, full: bool) -> str | None:
    """:func:`verify_shard` without the grids."""
    try:
        path = shard_path(shard_dir, entry.get("file"))
    except ShardError as e:
        return str(e)
    if not path.is_file():
        return f"{path}: listed in the index but missing"
    size = path.stat().st_size
    if "bytes" in entry and size != entry["bytes"]:
        return f"{path}: {size} bytes, the index says {entry['bytes']} (truncated or modified)"
    if not full:
        return None
    if "sha256" in entry:
        if file_sha256(path) != entry["sha256"]:
            return f"{path}: SHA-256 differs from the index (corrupted or modified)"
        try:  # the file the index records, but of a layout sc3d reads?
            with open_shard(path):
                return None
        except ShardError as e:
            return str(e)
    try:
        with h5py.File(path, "r") as f:
            for name in f:
                f[name][()]
    except Exception as e:  # noqa: BLE001 - any HDF5 failure means the file is broken
        return f"{path}: not readable ({io_reason(e)})"
    return None


def refuse_changed(shard_dir: Path, entries: list[dict], consequence: str) -> None:
    """``ShardError`` (one line: the problem, then ``consequence``) at the first shard of index
    ``entries`` that is not the file the index records (:func:`verify_shard`: missing, size,
    SHA-256, unreadable), for a command about to rewrite those shards."""
    for entry in entries:
        if (problem := verify_shard(shard_dir, entry)) is not None:
            raise ShardError(f"{problem}; {consequence}")


def verify_shards(shard_dir: Path, full: bool = True) -> list[str]:
    """Problems (one line each, naming the file) of every shard listed in the index, their voxel
    grids against the index's record included; ``ShardError``
    naming the writer instead when another process writes the folder (``voxelize`` rewriting its
    shards, a resumed ``render``), whose shards and index are then not yet each other's."""
    for _ in range(2):  # a writer that ended between reading and asking left them matching: look again
        index = load_index(shard_dir)
        grids = held_voxel_resolution(index)
        problems = [p for e in index.get("shards", []) if (p := verify_shard(shard_dir, e, full, grids))]
        if not problems:
            return []
        if writer := writer_of(shard_dir):
            raise ShardError(f"{shard_dir}: another process ({writer}) is writing to this folder, so its shards do "
                             "not match its index yet; run this again when it has finished")
    return problems
