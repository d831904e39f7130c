"""Checks of a shard file's layout when it is opened for reading (``shard_reader.open_shard``), so
that a damaged, hand-made or hostile file is refused in one line naming it and the dataset,
before any reader indexes into it.

Refused:

* storage outside the file: a member that is not a hard link (an HDF5 soft or external link),
  a dataset with external storage (raw bytes of another file) or a virtual dataset (views of
  other files): readers would take their values from anywhere on disk;
* a member that is a group, not a dataset;
* the per-object arrays of ``sc3d_data.io.shards`` with other dimensions than the layout's (the
  objects ``N`` and views ``V`` of the cameras ``K [N, V, 3, 3]`` in every array, the image size
  ``S`` of ``images [N, V, S, S, 3]`` in every per-view image, cubic voxel grids), or with a
  dtype of another kind (``images`` must be 8-bit: ``uint8``);
* string fields (``model_id``, ``category``, ``split``, ``source``) that are not ``[N]`` strings
  of UTF-8.

Only metadata and the string fields (``N`` short strings) are read.
"""
from __future__ import annotations

import h5py
import numpy as np

from sc3d_data.io.shards import ARRAY_DTYPES, STRING_FIELDS

#: arrays without which a file is no sc3d shard
REQUIRED = ("images", "masks", "K", "R", "t", "model_id", "category", "split")


def _storage_problem(f: h5py.File, name: str) -> str | None:
    link = f.get(name, getlink=True)
    if not isinstance(link, h5py.HardLink):
        return f"'{name}' is a {type(link).__name__}, not data stored in the file"
    member = f[name]
    if not isinstance(member, h5py.Dataset):
        return f"'{name}' is a {type(member).__name__}, not a dataset"
    if member.is_virtual:
        return f"'{name}' is a virtual dataset (its values live in other files)"
    if member.external:
        return f"'{name}' has external storage (its values live in another file)"
    return None


def expected_shape(name: str, n: int, views: int, size: int, shape: tuple[int, ...]) -> tuple[int, ...] | None:
    """The shape the layout gives array ``name`` of a shard of ``n`` objects, ``views`` views of
    ``size`` x ``size`` pixels (``shape``: the array's own, for a voxel grid's side); None for
    an array the layout does not name."""
    per_view = {"images": (size, size, 3), "masks": (size, size), "depth": (size, size), "K": (3, 3),
                "R": (3, 3), "t": (3,), "azimuth": (), "elevation": (), "distance": (), "clipped": ()}
    if name in per_view:
        return (n, views, *per_view[name])
    if name == "to_canonical":
        return (n, 4, 4)
    if name == "voxels":
        side = shape[1] if len(shape) == 4 else -1
        return (n, side, side, side)
    return None


def _dtype_ok(name: str, dtype: np.dtype) -> bool:
    want = np.dtype(ARRAY_DTYPES[name])
    if name == "images":
        return dtype == want
    if want.kind == "f":
        return dtype.kind == "f"
    return dtype.kind in "uib"  # 0/1 arrays: uint8 as written, bool or other integers as made elsewhere


def layout_problem(f: h5py.File) -> str | None:
    """What is wrong with the layout of shard ``f`` (open for reading), in words naming the
    dataset, or None (module doc)."""
    for name in f:
        if (problem := _storage_problem(f, name)) is not None:
            return problem
    missing = [k for k in REQUIRED if k not in f]
    if missing:
        return f"no {', '.join(repr(k) for k in missing)} dataset"
    images, cameras = f["images"], f["K"]
    if images.ndim != 5 or images.shape[2] != images.shape[3] or images.shape[4] != 3:
        return f"'images' has shape {list(images.shape)}, not [N, V, S, S, 3]"
    if cameras.ndim != 4 or cameras.shape[2:] != (3, 3):
        return f"'K' has shape {list(cameras.shape)}, not [N, V, 3, 3]"
    (n, views), size = cameras.shape[:2], images.shape[2]  # every other array is held to these
    for name in f:
        ds = f[name]
        if name in STRING_FIELDS:
            if ds.shape != (n,) or (h5py.check_string_dtype(ds.dtype) is None and ds.dtype.kind != "O"):
                return f"'{name}' is {ds.dtype} {ds.shape}, not [{n}] strings"
            try:
                for value in ds[()]:
                    value.decode() if isinstance(value, bytes) else str(value)
            except UnicodeDecodeError as e:
                return f"'{name}' holds a string that is not UTF-8 ({e.reason} at byte {e.start})"
            continue
        want = expected_shape(name, n, views, size, ds.shape)
        if want is None:
            continue  # not in the layout: readers do not read it
        if ds.shape != want:
            dims = "[N, G, G, G]" if name == "voxels" else str(list(want))
            return f"'{name}' has shape {list(ds.shape)}, not {dims} (N = {n} objects, V = {views} views, S = {size})"
        if not _dtype_ok(name, ds.dtype):
            return f"'{name}' is {ds.dtype}, not {np.dtype(ARRAY_DTYPES[name])}"
    return None


def grid_problem(f: h5py.File, resolution: int | None) -> str | None:
    """How the voxel grids of shard ``f`` differ from the side ``resolution`` its index records
    (None: no grids; ``shards.held_voxel_resolution``), or None when they agree: the shards of a
    ``sc3d-data voxelize --resolution R`` stopped part-way hold R^3 grids, and the others the old
    ones, while the index (whose record is written at the end) names one size."""
    side = f["voxels"].shape[1] if "voxels" in f else None
    if side == resolution:
        return None

    def grids(g):
        return "no voxel grids" if g is None else f"{g}^3 voxel grids"

    return (f"holds {grids(side)}, its index records {grids(resolution)} (a `sc3d-data voxelize` stopped part-way? "
            "run it again to finish it)")
