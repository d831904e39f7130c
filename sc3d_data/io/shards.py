"""HDF5 shard layout, index and writer (the data contract of SPEC.md, "Shards"); reading is
``sc3d_data.io.shard_reader``.

A dataset is one directory holding shard files ``shard-NNNNN.h5`` and one JSON index
``index.json``. Every per-object dataset has the object axis first (``N``) and is gzip-compressed.
Chunking (not part of the value contract: readers get the same values either way) is the
``chunks`` setting: ``"view"`` (the default) stores one view per chunk for the per-view images
(``images``, ``masks``, ``depth``) and one object per chunk for everything else, so the training
loader, which needs one random view per object, decompresses one view instead of all V (5x
cheaper reads, ~1/3 larger files; docs/benchmarks.md); ``"object"`` (files written before it
existed) stores one object per chunk everywhere.

Per-object datasets (V views, S = image size, G = voxel resolution):

=============  ====================  =======  ===============================================
name           shape                 dtype    meaning
=============  ====================  =======  ===============================================
images         [N, V, S, S, 3]       uint8    RGB on the dataset background colour
masks          [N, V, S, S]          uint8    silhouette, 1 where the object covers the pixel
depth          [N, V, S, S]          float32  camera-frame z (world units), 0 = background;
                                              optional
K              [N, V, 3, 3]          float32  intrinsics in pixels (sc3d_data.geometry.camera)
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
always complete; the index is rewritten atomically (after each shard up to 10,000 objects:
``sc3d_data.pipeline.jobs.shard_output``).

Integrity: every numeric dataset carries HDF5's Fletcher-32 checksum per chunk (a flipped byte
makes the read of that object fail instead of returning wrong numbers), and the index records
each shard's ``bytes`` and ``sha256`` (``shard_reader.verify_shard``: ``sc3d-data info --verify``, ``check``
and a render resume use it; a truncated shard is caught by the size alone). Shard names in the
index must be plain file names inside the dataset folder (``shard_path``); anything else is
refused, so an edited index cannot make a command read or rewrite a file elsewhere.

Length: one module because it is the file-format contract: the layout table, the writer and
the index are changed together whenever the format changes.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import h5py
import numpy as np

from sc3d_data.io.hashing import file_sha256

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
COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True, "fletcher32": True}
#: per-view image arrays ([N, V, S, S, ...]): one view per chunk with the "view" chunk layout
VIEW_CHUNKED = ("images", "masks", "depth")
#: arrays with no view axis ([N, ...]); every other numeric array is per view ([N, V, ...])
OBJECT_ARRAYS = ("to_canonical", "voxels")
#: chunk layouts of the writer (settings key "chunks"); the first is the default
CHUNK_LAYOUTS = ("view", "object")
#: what a shard file name in the index may look like (no folders, no '..')
SHARD_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*\.h5$")


class ShardError(ValueError):
    """A shard file or index entry that cannot be used; the message names the file."""


def io_reason(e: BaseException, folder: Path | None = None, need: int = 0) -> str:
    """One-line reason of an I/O or HDF5 error (``No space left on device``, ``truncated file``...):
    the first ``OSError`` with an errno in its chain (the system's message for that errno where
    the text is HDF5's report of it), else its text. HDF5 often hides a full
    disk behind a later error ("Slist already enabled?"): with ``folder`` given, a folder whose
    file system has less than ``need`` bytes (at least 1 MiB) free is reported as full."""
    seen = e
    while seen is not None:
        if isinstance(seen, OSError) and seen.errno and seen.strerror:
            # HDF5's text of a system error spans lines ("Can't close file (file write failed: time
            # = ...\n, filename = ..., errno = 28, ...)"): the system's own message says it in one
            return os.strerror(seen.errno) if "errno =" in seen.strerror or "\n" in seen.strerror else seen.strerror
        seen = seen.__cause__ or seen.__context__
    if folder is not None:
        import shutil

        try:
            free = shutil.disk_usage(folder).free
        except OSError:
            free = None
        if free is not None and free < max(need, 1 << 20):
            return f"No space left on device ({free // 1024} KiB free)"
    return " ".join(str(e).split()) or type(e).__name__


def one_line(e: BaseException) -> str:
    """The message a command prints for ``e``: an ``OSError`` with a file name becomes
    ``FILE: reason``; anything else its own (file-naming) message; control characters and
    undecodable bytes of names escaped (``io.names.printable``; newlines of a message that is
    several lines by design are kept)."""
    from sc3d_data.io.names import printable

    if isinstance(e, OSError) and e.filename and str(e.filename) not in str(e.strerror or ""):
        return printable(f"{e.filename}: {io_reason(e)}", keep_newlines=True)
    return printable(io_reason(e) if isinstance(e, OSError) else str(e), keep_newlines=True)


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
    arrays: dict[str, "np.ndarray | EncodedArray"] = field(default_factory=dict)
    #: the source file's fingerprint (``io.source_fingerprint``), taken by the worker that read it
    source_file: dict | None = None


@dataclass(frozen=True)
class EncodedArray:
    """One object's array as the shard stores it: ``shape`` and ``dtype`` of the array (no N
    axis), the ``layout`` it was cut by (``chunk_shape``) and its chunks' stored bytes in C
    order of the chunk grid (``chunk_codec.encode_chunk``: shuffled, deflated, checksummed).
    Made where the object is made (``encode_arrays``, in the render worker), so the process
    writing the shard only stores bytes: compression runs in parallel, and ~20 KB instead of
    ~400 KB per object travel to it."""

    shape: tuple[int, ...]
    dtype: str
    layout: str
    chunks: tuple[bytes, ...]


#: the arrays a render worker encodes itself (the bulk of a shard); the small per-view arrays
#: stay plain in the record (the index reads ``clipped``) and are encoded by the writer
ENCODED_BY_WORKER = ("images", "masks", "depth", "voxels")


def encode_array(name: str, array, layout: str) -> EncodedArray:
    """``array`` (one object's ``name`` dataset, no N axis) cut into the chunks of ``layout``
    and encoded (``chunk_codec.encode_chunk``)."""
    from sc3d_data.io.chunk_codec import encode_chunks

    a = np.ascontiguousarray(np.asarray(array, dtype=ARRAY_DTYPES.get(name)))
    per = chunk_shape(name, (1,) + a.shape, layout)[1:]
    blocks = [a[tuple(slice(o, o + c) for o, c in zip(offset, per))] for offset in _chunk_offsets(a.shape, per)]
    return EncodedArray(a.shape, a.dtype.str, layout, tuple(encode_chunks(blocks)))


def _chunk_offsets(shape: tuple[int, ...], per: tuple[int, ...]) -> list[tuple[int, ...]]:
    """The first index of each chunk of shape ``per`` tiling one object's array of ``shape``,
    in C order of the chunk grid (the order of ``EncodedArray.chunks``)."""
    return [tuple(g * c for g, c in zip(idx, per)) for idx in np.ndindex(*[n // c for n, c in zip(shape, per)])]


def encode_arrays(record: ObjectRecord, layout: str, names=ENCODED_BY_WORKER) -> ObjectRecord:
    """``record`` with its arrays ``names`` (those it has) replaced by ``EncodedArray``s."""
    arrays = {k: encode_array(k, v, layout) if k in names and not isinstance(v, EncodedArray) else v
              for k, v in record.arrays.items()}
    return ObjectRecord(record.model_id, record.category, record.split, record.source, arrays, record.source_file)


def border_clipped(masks: np.ndarray) -> np.ndarray:
    """The ``clipped`` dataset of one object: ``[V]`` uint8, 1 where the mask ``[V,S,S]`` of a
    view touches the image border (the object may extend past the frame)."""
    m = np.asarray(masks).astype(bool)
    return (m[:, 0, :].any(-1) | m[:, -1, :].any(-1) | m[:, :, 0].any(-1)
            | m[:, :, -1].any(-1)).astype(np.uint8)


def _unlink_quietly(path: Path) -> None:
    try:
        Path(path).unlink()
    except OSError:
        pass


def create_new_file(path: Path) -> BinaryIO:
    """``path`` open for binary writing as a new, empty file of its own: whatever had that name
    (a temporary file left by a killed run, or a symbolic link planted there, through which
    ``open(path, "wb")`` would write to a file elsewhere) is removed first, and the file is
    created exclusively without following links."""
    _unlink_quietly(path)
    return os.fdopen(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644), "wb")


def atomic_write_bytes(path: Path, data: bytes, shared: bool = False) -> None:
    """Write ``data`` to ``path`` via a temporary file + fsync + rename; on failure (disk
    full...) the temporary file is removed, ``path`` keeps its old content and ``OSError``
    names ``path``. ``shared``: processes that do not lock the folder may write ``path`` at the
    same time (``--part`` jobs), so the temporary file is this process's own (``NAME.PID.tmp``)."""
    path = Path(path)
    tmp = path.with_name(path.name + (f".{os.getpid()}.tmp" if shared else ".tmp"))
    if len(os.fsencode(tmp.name)) > 255:  # a legal name whose suffix passes NAME_MAX: a short one
        tmp = path.with_name(f".{hashlib.sha256(os.fsencode(path.name)).hexdigest()[:16]}" + tmp.name[len(path.name):])
    try:
        with create_new_file(tmp) as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as e:
        _unlink_quietly(tmp)
        raise OSError(e.errno, f"cannot write {path}: {io_reason(e)}", str(path)) from e


def write_json_atomic(path: Path, obj: Any, shared: bool = False) -> None:
    atomic_write_bytes(path, json.dumps(obj, indent=1, sort_keys=False).encode(), shared)


def chunk_shape(name: str, shape: tuple[int, ...], layout: str) -> tuple[int, ...]:
    """HDF5 chunk shape of the per-object dataset ``name`` of ``shape`` ``[N, ...]`` under the
    chunk ``layout`` (``CHUNK_LAYOUTS``): ``(1, 1, S, S, ...)`` for a view-chunked image array,
    else one object ``(1, ...)``."""
    if layout not in CHUNK_LAYOUTS:
        raise ValueError(f"chunks {layout!r}: must be one of {', '.join(CHUNK_LAYOUTS)}")
    if layout == "view" and name in VIEW_CHUNKED:
        return (1, 1) + tuple(shape[2:])
    return (1,) + tuple(shape[1:])


def voxels_attr(record: dict) -> dict[str, str]:
    """The file attribute ``voxels`` of a shard whose grids ``sc3d-data voxelize SHARDS`` made
    (SPEC: over the voxel entries of its ``settings``), from the index's ``voxels`` record (or
    the one being made): JSON of its ``resolution`` and ``occupancy`` rule."""
    return {"voxels": json.dumps({"resolution": record["resolution"], "occupancy": record["occupancy"]})}


def write_shard(path: Path, records: list[ObjectRecord], settings: dict, attrs: dict[str, str] | None = None) -> str:
    """Write ``records`` into the shard file ``path`` (temporary name first, renamed when the
    file is closed and complete; file attributes ``settings`` and ``attrs``) and return its SHA-256. All records must carry the same set
    of arrays. The chunk layout is ``settings["chunks"]`` (default ``CHUNK_LAYOUTS[0]``). On
    failure (disk full...) the temporary file is removed and ``ShardError`` names ``path`` and
    the reason."""
    path = Path(path)
    if not records:
        raise ValueError(f"{path}: refusing to write an empty shard")
    layout = settings.get("chunks", CHUNK_LAYOUTS[0])
    chunk_shape("images", (1, 1), layout)  # an unknown layout fails before any file is made
    tmp = path.with_name(path.name + ".tmp")
    names = sorted(records[0].arrays)
    try:
        with h5py.File(tmp, "w") as f:
            f.attrs["schema_version"] = SCHEMA_VERSION
            f.attrs["sc3d_version"] = package_version()
            f.attrs["settings"] = json.dumps(settings, sort_keys=True)
            f.attrs.update(attrs or {})
            for name in names:
                _write_encoded(f, name, [_encoded(name, r.arrays[name], layout) for r in records])
            for name in STRING_FIELDS:
                f.create_dataset(name, data=[getattr(r, name) for r in records], dtype=STRING_DTYPE)
            f.flush()
        digest = file_sha256(tmp)
        os.replace(tmp, path)
    except (OSError, RuntimeError) as e:  # h5py reports ENOSPC as OSError or RuntimeError
        _unlink_quietly(tmp)
        need = sum(_nbytes(a) for r in records for a in r.arrays.values())
        raise ShardError(f"{path}: cannot write shard ({io_reason(e, path.parent, need)})") from e
    return digest


def _encoded(name: str, array, layout: str) -> EncodedArray:
    if isinstance(array, EncodedArray):
        if array.layout != layout:
            raise ValueError(f"{name}: encoded for chunks {array.layout!r}, the shard has {layout!r}")
        return array
    return encode_array(name, array, layout)


def _nbytes(array) -> int:
    return sum(map(len, array.chunks)) if isinstance(array, EncodedArray) else np.asarray(array).nbytes


def _write_encoded(f: h5py.File, name: str, arrays: list[EncodedArray]) -> None:
    """Dataset ``name`` ``[N, ...]`` of ``f`` from the objects' encoded chunks, stored as they
    are (``write_direct_chunk``; HDF5 reads them through ``COMPRESSION``'s filters)."""
    first = arrays[0]
    if any(a.shape != first.shape or a.dtype != first.dtype for a in arrays):
        raise ValueError(f"{name}: objects of one shard differ in shape or dtype")
    shape = (len(arrays),) + tuple(first.shape)
    per = chunk_shape(name, shape, first.layout)
    dset = f.create_dataset(name, shape=shape, dtype=np.dtype(first.dtype), chunks=per, **COMPRESSION)
    offsets = _chunk_offsets(first.shape, per[1:])
    for row, a in enumerate(arrays):
        for offset, chunk in zip(offsets, a.chunks):
            dset.id.write_direct_chunk((row,) + offset, chunk)


def replace_dataset_atomically(path: Path, name: str, data: np.ndarray, update_index: bool = True,
                               attrs: dict[str, str] | None = None) -> str:
    """Add (or replace) the per-object dataset ``name`` in an existing shard (and set the file's
    attributes ``attrs``, which describe it: ``voxelize`` writes ``voxels``) without ever leaving
    a half-written file named ``*.h5``: the shard is read into memory and modified there, then
    written to ``NAME.tmp`` (``atomic_write_bytes``) and renamed over the original. HDF5 never
    writes to the disk here: an HDF5 file whose writes failed (disk full) could not be closed
    cleanly, and h5py crashed (segfault) closing it; a plain write fails with one ``ShardError``
    line, the temporary file removed and the shard as it was. Memory: the shard's bytes twice.
    Returns the new file's SHA-256, which is also recorded at once
    in the folder's ``index.json`` when that lists the shard (the index never describes the
    old bytes of a rewritten shard), unless ``update_index=False`` (a caller that writes the
    index itself: ``voxelize``)."""
    import hashlib
    import io

    path = Path(path)
    try:
        image = io.BytesIO(path.read_bytes())
        with h5py.File(image, "a") as f:
            n = f["model_id"].shape[0]
            if data.shape[0] != n:
                raise ValueError(f"{path}: {name} has {data.shape[0]} objects, shard has {n}")
            if name in f:
                del f[name]
            data = np.asarray(data, dtype=ARRAY_DTYPES.get(name))
            f.create_dataset(name, data=data, chunks=(1,) + data.shape[1:], **COMPRESSION)
            f.attrs.update(attrs or {})
        new = image.getvalue()
        del image
        atomic_write_bytes(path, new)
    except (OSError, RuntimeError) as e:
        reason = io_reason(e.__cause__ if isinstance(e.__cause__, OSError) else e)  # atomic_write_bytes's own
        raise ShardError(f"{path}: cannot rewrite shard ({reason})") from e
    digest = hashlib.sha256(new).hexdigest()
    if update_index and index_path(path.parent).is_file():
        index = load_index(path.parent)
        listed = [e for e in index["shards"] if isinstance(e, dict) and e.get("file") == path.name]
        for entry in listed:
            entry["bytes"], entry["sha256"] = path.stat().st_size, digest
        if listed:
            write_json_atomic(index_path(path.parent), index)
    return digest


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
                       records: list[ObjectRecord], sha256: str | None = None) -> None:
    """Append the index entries of the shard ``name`` (chunk ``chunk``) just written from
    ``records``: one to ``shards``, one per record (its row) to ``objects``, with the fingerprint
    of its source file (``source_file``: ``io.source_fingerprint``; the worker's, or taken here
    for records read back from a shard) where that is a file.
    ``sha256`` (as returned by ``write_shard``) is recorded; without it ``write_index`` computes
    it."""
    from collections import Counter

    from sc3d_data.io.source_fingerprint import fingerprint

    for row, r in enumerate(records):
        objects.append({"category": r.category, "model_id": r.model_id, "split": r.split,
                        "source": r.source, "shard": name, "row": row, "chunk": chunk,
                        "clipped_views": int(np.asarray(r.arrays["clipped"]).sum())})
        if (source_file := r.source_file or fingerprint(r.source)) is not None:  # a rerun notices a changed mesh
            objects[-1]["source_file"] = source_file
    entry = {"file": name, "chunk": chunk, "objects": len(records),
             "categories": dict(Counter(r.category for r in records)),
             "splits": dict(Counter(r.split for r in records))}
    if sha256:
        entry["sha256"] = sha256
    shards.append(entry)


def write_index(shard_dir: Path, *, complete: bool, settings: dict, split: dict, shards: list[dict],
                objects: list[dict], failures: list[dict], skipped: list[dict], warnings: list[dict],
                empty_chunks: list[int] = (), extra: dict | None = None) -> None:
    """Write ``index.json`` of ``shard_dir`` atomically: the given lists plus the derived
    ``counts`` and ``clipped`` totals, shards ordered by chunk. ``complete`` = every planned
    object is in a shard or in ``failures`` (else ``sc3d-data info`` says INCOMPLETE). Shard
    entries without ``bytes``/``sha256`` get them from their file (once: the dicts are updated).
    ``extra``: further top-level keys (``part`` of a partitioned run, ``merged`` of a merge)."""
    for entry in shards:
        record_checksum(shard_dir, entry)
    write_json_atomic(index_path(shard_dir), {
        "schema_version": SCHEMA_VERSION, "sc3d_version": package_version(),
        "complete": complete, "settings": settings, "split": split,
        "counts": index_counts(objects),
        "clipped": {"views": sum(o["clipped_views"] for o in objects),
                    "objects": sum(1 for o in objects if o["clipped_views"])},
        "shards": sorted(shards, key=lambda s: s["chunk"]),
        "empty_chunks": sorted(empty_chunks),
        "objects": objects, "failures": failures, "skipped": skipped, "warnings": warnings,
        **(extra or {}),
    })


def record_checksum(shard_dir: Path, entry: dict) -> None:
    """Give the index shard ``entry`` its ``bytes`` and ``sha256`` from its file where missing."""
    if "bytes" in entry and "sha256" in entry:
        return
    path = shard_path(shard_dir, entry["file"])
    entry["bytes"] = path.stat().st_size
    if "sha256" not in entry:
        entry["sha256"] = file_sha256(path)


def shard_path(shard_dir: Path, name: str) -> Path:
    """``shard_dir / name`` for a shard file name from the index; ``ShardError`` when the name
    is not a plain ``*.h5`` file name or leads outside ``shard_dir`` (symlink included)."""
    shard_dir = Path(shard_dir)
    if not isinstance(name, str) or not SHARD_NAME.match(name):
        raise ShardError(f"{index_path(shard_dir)}: shard file {name!r} is not a plain file name "
                         "inside the dataset folder; refused")
    path = shard_dir / name
    if path.exists():
        try:
            path.resolve().relative_to(shard_dir.resolve())
        except ValueError:
            raise ShardError(f"{path}: leads outside the dataset folder {shard_dir} "
                             f"(to {path.resolve()}); refused") from None
    return path


def refuse_dataset_file(shard_dir: Path, path: Path, option: str) -> None:
    """``ValueError`` naming ``option`` when ``path``, a report a command is about to write into
    (``check --png/--json``, ``preview --out``), is the dataset's own ``index.json`` or an
    ``.h5`` file in its folder, by name, through a symlink or as a hard link to one: writing it
    would destroy finished output."""
    target = Path(path).resolve()
    if target.parent == Path(shard_dir).resolve() and (target.name == INDEX_NAME or target.suffix.lower() == ".h5"):
        raise ValueError(f"{option} {path}: that is the dataset's own {target.name} in {shard_dir}; refused "
                         "(write the report elsewhere)")
    if not target.exists():
        return
    for own in [Path(shard_dir) / INDEX_NAME, *sorted(Path(shard_dir).glob("*.h5"))]:
        # another name of one of those files (a hard link): writing it in place writes the data
        if own.exists() and os.path.samefile(target, own):
            raise ValueError(f"{option} {path}: the same file as the dataset's {own.name} in {shard_dir} (a "
                             "hard link); refused (write the report elsewhere)")


def held_voxel_resolution(index: dict) -> int | None:
    """The side of the voxel grids that the shards of ``index`` (a parsed ``index.json``) hold: the
    ``voxels`` record's (``sc3d-data voxelize SHARDS``), else the run's own (``render --voxelize``,
    ``import-r2n2``), else None (no grids)."""
    record, settings = index.get("voxels"), index.get("settings", {})
    if record:
        return record.get("resolution")
    if settings.get("voxelize") or settings.get("source") == "3D-R2N2":
        return settings.get("voxel_resolution")
    return None


def load_index(shard_dir: Path, listing: bool = True) -> dict:
    """Read ``index.json`` of a shard directory; a clear error if it is missing or broken, of a
    newer schema, or malformed where readers look (``sc3d_data.io.index_check``). ``listing``:
    also refuse ``shards`` and ``objects`` that disagree (``index_check.listing_problems``; a shard
    name that is not plain is left to :func:`shard_path`, whose refusal says more); False for a
    render rerun, which renders such shards' chunks again."""
    from sc3d_data.io.index_check import index_problem, listing_problems

    p = index_path(shard_dir)
    if not p.is_file():
        raise FileNotFoundError(f"{shard_dir}: no {INDEX_NAME} (not an sc3d shard directory?)")
    try:
        index = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ShardError(f"{p}: index is not valid JSON ({e})") from e
    except OSError as e:
        raise ShardError(f"{p}: cannot read index ({io_reason(e)})") from e
    problem = index_problem(index, SCHEMA_VERSION)
    if problem:
        raise ShardError(f"{p}: {problem}")
    shards = index.get("shards", [])
    if not isinstance(shards, list) or not all(isinstance(e, dict) and isinstance(e.get("file"), str)
                                               and isinstance(e.get("chunk", 0), int) for e in shards):
        raise ShardError(f"{p}: not an sc3d index (malformed shard list)")
    if listing and all(SHARD_NAME.match(e["file"]) for e in shards) and (problems := listing_problems(index)):
        raise ShardError(f"{p}: malformed: {next(iter(problems.values()))} (hand-edited?); render or merge "
                         "it again")
    return index


def shard_files(shard_dir: Path) -> list[Path]:
    """Complete shard files listed in the index, in order."""
    index = load_index(shard_dir)
    return [shard_path(shard_dir, s["file"]) for s in index.get("shards", [])]
