"""HDF5 shard layout, writer and reader (the data contract of SPEC.md, "Shards").

A dataset is one directory holding shard files ``shard-NNNNN.h5`` and one JSON index
``index.json``. Every per-object dataset has the object axis first (``N``) and is chunked one
object per chunk and gzip-compressed, so a random object read touches one chunk.

Per-object datasets (V views, S = image size, G = voxel resolution):

=============  ====================  =======  ===============================================
name           shape                 dtype    meaning
=============  ====================  =======  ===============================================
images         [N, V, S, S, 3]       uint8    RGB on the dataset background colour
masks          [N, V, S, S]          uint8    silhouette, 1 where the object covers the pixel
depth          [N, V, S, S]          float32  camera-frame z (world units), 0 = background;
                                              optional
K              [N, V, 3, 3]          float32  intrinsics in pixels (sc3d_data.camera)
R, t           [N, V, 3, 3], [N,V,3] float32  world->camera, OpenCV axes
azimuth        [N, V]                float32  degrees
elevation      [N, V]                float32  degrees
distance       [N, V]                float32  world units
clipped        [N, V]                uint8    1 where the mask touches the image border
to_canonical   [N, 4, 4]             float64  source-mesh coordinates -> canonical frame
                                              (the normalisation and --up/--front rotation)
voxels         [N, G, G, G]          uint8    occupancy, index order [x, y, z]; optional
                                              (added by ``sc3d-data voxelize``)
model_id       [N]                   str      object id (ShapeNet model id where known)
category       [N]                   str      ShapeNet synset id where known, else the name
split          [N]                   str      train / val / test / ...
source         [N]                   str      path of the source mesh
=============  ====================  =======  ===============================================

File attributes: ``schema_version``, ``sc3d_version``, ``settings`` (JSON of every setting).
Files are written under ``NAME.tmp`` and renamed when complete, so a file named ``*.h5`` is
always complete; the index is rewritten atomically after each shard.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import h5py
import numpy as np

SCHEMA_VERSION = 1
INDEX_NAME = "index.json"
SHARD_PATTERN = "shard-{:05d}.h5"
STRING_DTYPE = h5py.string_dtype("utf-8")

#: dtype of every numeric per-object dataset
ARRAY_DTYPES: dict[str, Any] = {
    "images": np.uint8, "masks": np.uint8, "depth": np.float32, "K": np.float32,
    "R": np.float32, "t": np.float32, "azimuth": np.float32, "elevation": np.float32,
    "distance": np.float32, "clipped": np.uint8, "to_canonical": np.float64, "voxels": np.uint8,
}
STRING_FIELDS = ("model_id", "category", "split", "source")
COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True}


def package_version() -> str:
    try:
        from importlib.metadata import version

        return version("sc3d")
    except Exception:  # running from a source tree that is not installed
        return "0+unknown"


@dataclass
class ObjectRecord:
    """Everything stored for one object; arrays as documented in the module table
    (without the leading N axis). ``depth`` and ``voxels`` are optional."""

    model_id: str
    category: str
    split: str
    source: str
    arrays: dict[str, np.ndarray] = field(default_factory=dict)


def border_clipped(masks: np.ndarray) -> np.ndarray:
    """The ``clipped`` dataset of one object: ``[V]`` uint8, 1 where the mask ``[V,S,S]`` of a
    view touches the image border (the object may extend past the frame)."""
    m = np.asarray(masks).astype(bool)
    return (m[:, 0, :].any(-1) | m[:, -1, :].any(-1) | m[:, :, 0].any(-1)
            | m[:, :, -1].any(-1)).astype(np.uint8)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file + fsync + rename."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def write_json_atomic(path: Path, obj: Any) -> None:
    atomic_write_bytes(path, json.dumps(obj, indent=1, sort_keys=False).encode())


def write_shard(path: Path, records: list[ObjectRecord], settings: dict) -> None:
    """Write ``records`` into the shard file ``path`` (temporary name first, renamed when the
    file is closed and complete). All records must carry the same set of arrays."""
    path = Path(path)
    if not records:
        raise ValueError(f"{path}: refusing to write an empty shard")
    tmp = path.with_name(path.name + ".tmp")
    names = sorted(records[0].arrays)
    with h5py.File(tmp, "w") as f:
        f.attrs["schema_version"] = SCHEMA_VERSION
        f.attrs["sc3d_version"] = package_version()
        f.attrs["settings"] = json.dumps(settings, sort_keys=True)
        for name in names:
            stacked = np.stack([np.asarray(r.arrays[name], dtype=ARRAY_DTYPES.get(name))
                                for r in records])
            f.create_dataset(name, data=stacked, chunks=(1,) + stacked.shape[1:], **COMPRESSION)
        for name in STRING_FIELDS:
            f.create_dataset(name, data=[getattr(r, name) for r in records], dtype=STRING_DTYPE)
        f.flush()
    os.replace(tmp, path)


def replace_dataset_atomically(path: Path, name: str, data: np.ndarray) -> None:
    """Add (or replace) the per-object dataset ``name`` in an existing shard without ever leaving
    a half-written file named ``*.h5``: the shard is copied to ``NAME.tmp``, modified, and
    renamed over the original."""
    import shutil

    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    shutil.copyfile(path, tmp)
    with h5py.File(tmp, "a") as f:
        n = f["model_id"].shape[0]
        if data.shape[0] != n:
            raise ValueError(f"{path}: {name} has {data.shape[0]} objects, shard has {n}")
        if name in f:
            del f[name]
        data = np.asarray(data, dtype=ARRAY_DTYPES.get(name))
        f.create_dataset(name, data=data, chunks=(1,) + data.shape[1:], **COMPRESSION)
    os.replace(tmp, path)


# ----------------------------------------------------------------------------- index
def index_path(shard_dir: Path) -> Path:
    return Path(shard_dir) / INDEX_NAME


def index_counts(objects: list[dict]) -> dict:
    """``{"total", "by_split", "by_category": {category: {split: n}}}`` of index objects."""
    from collections import Counter, defaultdict

    by_cat: dict = defaultdict(Counter)
    for o in objects:
        by_cat[o["category"]][o["split"]] += 1
    by_split = Counter(o["split"] for o in objects)
    return {"total": len(objects), "by_split": dict(sorted(by_split.items())),
            "by_category": {c: dict(sorted(v.items())) for c, v in sorted(by_cat.items())}}


def add_shard_to_index(shards: list[dict], objects: list[dict], name: str, chunk: int,
                       records: list[ObjectRecord]) -> None:
    """Append the index entries of the shard ``name`` (chunk ``chunk``) just written from
    ``records``: one to ``shards``, one per record (its row) to ``objects``."""
    from collections import Counter

    for row, r in enumerate(records):
        objects.append({"category": r.category, "model_id": r.model_id, "split": r.split,
                        "source": r.source, "shard": name, "row": row, "chunk": chunk,
                        "clipped_views": int(np.asarray(r.arrays["clipped"]).sum())})
    shards.append({"file": name, "chunk": chunk, "objects": len(records),
                   "categories": dict(Counter(r.category for r in records)),
                   "splits": dict(Counter(r.split for r in records))})


def write_index(shard_dir: Path, *, complete: bool, settings: dict, split: dict, shards: list[dict],
                objects: list[dict], failures: list[dict], skipped: list[dict], warnings: list[dict],
                empty_chunks: list[int] = ()) -> None:
    """Write ``index.json`` of ``shard_dir`` atomically: the given lists plus the derived
    ``counts`` and ``clipped`` totals, shards ordered by chunk. ``complete`` = every planned
    object is in a shard or in ``failures`` (else ``sc3d-data info`` says INCOMPLETE)."""
    write_json_atomic(index_path(shard_dir), {
        "schema_version": SCHEMA_VERSION, "sc3d_version": package_version(),
        "complete": complete, "settings": settings, "split": split,
        "counts": index_counts(objects),
        "clipped": {"views": sum(o["clipped_views"] for o in objects),
                    "objects": sum(1 for o in objects if o["clipped_views"])},
        "shards": sorted(shards, key=lambda s: s["chunk"]),
        "empty_chunks": sorted(empty_chunks),
        "objects": objects, "failures": failures, "skipped": skipped, "warnings": warnings,
    })


def load_index(shard_dir: Path) -> dict:
    """Read ``index.json`` of a shard directory; a clear error if it is missing or broken."""
    p = index_path(shard_dir)
    if not p.is_file():
        raise FileNotFoundError(f"{shard_dir}: no {INDEX_NAME} (not an sc3d shard directory?)")
    try:
        return json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{p}: index is not valid JSON ({e})") from e


def shard_files(shard_dir: Path) -> list[Path]:
    """Complete shard files listed in the index, in order."""
    index = load_index(shard_dir)
    return [Path(shard_dir) / s["file"] for s in index.get("shards", [])]


# ----------------------------------------------------------------------------- reading
def read_strings(ds) -> list[str]:
    return [s.decode() if isinstance(s, bytes) else str(s) for s in ds[()]]


def iter_objects(shard_dir: Path, fields: tuple[str, ...] | None = None) -> Iterator[dict]:
    """Yield one dict per object over all shards: string fields plus the requested array
    fields (all present ones when ``fields`` is None), plus ``shard`` and ``row``."""
    for path in shard_files(shard_dir):
        with h5py.File(path, "r") as f:
            strings = {k: read_strings(f[k]) for k in STRING_FIELDS if k in f}
            names = [k for k in (fields or f.keys()) if k in f and k not in STRING_FIELDS]
            for row in range(f["model_id"].shape[0]):
                obj = {k: v[row] for k, v in strings.items()}
                obj.update({k: f[k][row] for k in names})
                obj["shard"], obj["row"] = path.name, row
                yield obj
