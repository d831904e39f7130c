"""Training data from sc3d shards: a map-style torch Dataset over (object, view) pairs.

* File handles: reads go through ``sc3d_data.io.shard_reader.ShardReader``, which never keeps a
  handle across pickling or ``fork``: each process (main or DataLoader worker) opens its own
  lazily on first read, so ``num_workers > 0`` is safe with any start method.
* Sampling and batching (seeded, resumable, rank-aware) are ``sc3d_train.data.loader``; the batch
  format (compact batches, 48 px masks, float expansion) is ``sc3d_train.data.batch_format``.

Training batch keys (B samples; ``batch_format.expand_batch`` of a compact batch):
``images`` [B,3,S,S] float in [0,1]; ``voxels`` [B,G,G,G] float {0,1} (index order [x,y,z]);
``masks`` [B,S,S] float; ``masks_sc`` [B,M,M] float; ``K`` [B,3,3] and ``K_sc`` [B,3,3]
(pixels at S and M); ``R`` [B,3,3], ``t`` [B,3] (world->camera, OpenCV); ``distance``,
``azimuth``, ``elevation`` [B] (world units, degrees; the ground-truth pose is for evaluation
only); ``category``, ``model_id`` (lists of str); ``labeled`` [B] bool; ``index`` [B] long
(object index * V + view).

Length: one module because the three ways a batch is gathered (decoded objects kept per process,
views read per batch, a decoded cache folder) must give the same batch from the same fields.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from torch.utils.data import Dataset

from sc3d_data.geometry.camera import scale_intrinsics
from sc3d_data.io.failed_grids import voxelize_failures
from sc3d_data.io.shard_reader import ShardReader
from sc3d_data.io.names import printable, shell_word
from sc3d_data.io.shards import ShardError
from sc3d_train.data.value_checks import nonbinary_voxels, nonfinite_camera, nonfinite_summary
from sc3d_train.data.batch_format import compact_tensors, expand_batch, sc_masks_bool
from sc3d_train.settings.config import MASK_SIZE, OBJECT_ORDERS
from sc3d_train.data.decoded_cache import DecodedCache
from sc3d_train.data.object_store import ObjectStore


#: the per-view cameras and poses of a sample (small: read whole per shard for large splits)
CAMERA_FIELDS = ("K", "R", "t", "distance", "azimuth", "elevation")
#: the per-view pictures of a sample, read from the files (with ``voxels``, per object, when
#: voxels are required); its cameras come from :data:`CAMERA_FIELDS`, read once per split
IMAGE_FIELDS = ("images", "masks")


class DataError(ValueError):
    """Bad training data (missing voxels, wrong image size, empty split, ...)."""


# ----------------------------------------------------------------------------- objects
@dataclass(frozen=True)
class ObjectRef:
    """Where one object lives: shard file, row, and its string fields."""

    shard: str
    row: int
    model_id: str
    category: str
    split: str


def scan_objects(shard_dir: Path) -> tuple[list[ObjectRef], dict]:
    """All objects of a shard directory (reading only string fields) and facts about the data:
    ``{"image_size", "num_views", "voxel_resolution" (None without voxels or where the shards
    disagree), "files_without_voxels", "voxel_resolutions" ({G: first shard file of G^3 grids}),
    "settings", "K" (3x3 list, pixels; the first view's: all views share it), "distance" (world
    units, the median of every view's), "distance_range" ([min, max] of every view's: one value
    for ``render``'s shards, 3D-R2N2's imports vary by view), "left_out",
    "complete" (the index's: false while a render was cut short)}``. Objects whose
    voxelization failed are left out (``sc3d_data.io.failed_grids``; ``left_out``: their
    ``category/model_id``, also told once on stderr). Clear errors for a missing/empty directory."""
    shard_dir = Path(shard_dir)
    if not shard_dir.is_dir():
        raise DataError(f"{shard_dir}: shard directory does not exist")
    try:
        reader = ShardReader(shard_dir)
        if not reader.files:
            raise DataError(f"{shard_dir}: the index lists no shard files")
        summaries = reader.summaries()
    except ShardError as e:
        raise DataError(str(e)) from e
    refs = [ObjectRef(str(sm.path), r, sm.model_id[r], sm.category[r], sm.split[r])
            for sm in summaries for r in range(sm.num_objects)]
    failed = voxelize_failures(reader.index)
    left_out = [r for r in refs if (Path(r.shard).name, r.row) in failed]
    if left_out:
        refs = [r for r in refs if (Path(r.shard).name, r.row) not in failed]
        tell_once(f"note: {shard_dir}: {len(left_out)} object(s) left out, their voxelization failed and their "
                  f"grid is an empty placeholder (index.json failures): "
                  + ", ".join(printable(f"{r.category}/{r.model_id}") for r in left_out[:3]) + (", ..." if len(left_out) > 3 else ""))
    image_sizes = {sm.image_size for sm in summaries}
    views = {sm.num_views for sm in summaries}
    vres = {sm.voxel_resolution for sm in summaries if sm.voxel_resolution is not None}
    vres_files = {}  # {resolution: the first shard file of it}
    for sm in summaries:
        if sm.voxel_resolution is not None:
            vres_files.setdefault(sm.voxel_resolution, sm.path.name)
    no_vox = [str(sm.path) for sm in summaries if sm.voxel_resolution is None]
    if (problem := nonfinite_summary(summaries)) is not None:
        raise DataError(problem)
    distances = np.concatenate([sm.distances for sm in summaries])
    camera = {"K": summaries[0].K.tolist(), "distance": float(np.median(distances)),
              "distance_range": [float(distances.min()), float(distances.max())]}
    if len(image_sizes) != 1 or len(views) != 1:
        raise DataError(f"{shard_dir}: shards disagree on image size {image_sizes} or views {views}")
    info = {"image_size": image_sizes.pop(), "num_views": views.pop(),
            "voxel_resolution": vres.pop() if len(vres) == 1 else None,
            "files_without_voxels": no_vox, "voxel_resolutions": vres_files, "settings": reader.settings,
            "K": camera["K"], "distance": camera["distance"], "distance_range": camera["distance_range"],
            "left_out": [f"{r.category}/{r.model_id}" for r in left_out],
            "complete": reader.index.get("complete", True) is not False}
    return refs, info


def require_one_voxel_resolution(shard_dir: Path, info: dict) -> None:
    """``DataError`` when the shards of ``shard_dir`` (``info`` of :func:`scan_objects`) hold voxel
    grids of more than one resolution: what a ``voxelize --resolution`` cut short leaves."""
    found = info["voxel_resolutions"]
    if len(found) > 1:
        sizes = ", ".join(f"{g}^3 in {name}" for g, name in sorted(found.items()))
        raise DataError(f"{shard_dir}: shards disagree on voxel resolution ({sizes}; a voxelize at another "
                        f"--resolution cut short?): run `sc3d-data voxelize {shell_word(shard_dir)} --resolution G` with the one G "
                        "to train on (it redoes the shards of the other size)")


_TOLD: set[str] = set()


def tell_once(line: str) -> None:
    """Print ``line`` to stderr the first time this process is told it (datasets of one run are
    made several times: training, labelled/unlabelled, validation)."""
    import sys

    if line not in _TOLD:
        _TOLD.add(line)
        print(line, file=sys.stderr, flush=True)


def choose_labeled(refs: list[ObjectRef], fraction: float, seed: int) -> set[str]:
    """The labelled subset, chosen by object and stratified by category: in each category of
    ``n_c`` objects (sorted by model_id), ``max(1, round(fraction * n_c))`` objects drawn with
    ``numpy.random.default_rng([seed, c])`` (c = the category's rank in sorted order); returns
    their ``shard:row`` keys. Deterministic and independent of the shard order."""
    by_category: dict[str, list[ObjectRef]] = {}
    for r in refs:
        by_category.setdefault(r.category, []).append(r)
    keys = set()
    for c, category in enumerate(sorted(by_category)):
        order = sorted(by_category[category], key=lambda r: (r.model_id, r.shard, r.row))
        k = min(len(order), max(1, round(fraction * len(order))))
        pick = np.random.default_rng([seed, c]).permutation(len(order))[:k]
        keys |= {f"{order[i].shard}:{order[i].row}" for i in pick}
    return keys


def background_of(info: dict) -> list[int]:
    """The dataset's background colour (RGB 0..255) from the shard settings (white default).
    sc3d-data records integers 0..255 (``--background 1,1,1`` is nearly black); only a colour
    written as fractions (floats, none above 1) is scaled by 255."""
    bg = info.get("settings", {}).get("background", [255, 255, 255])
    if isinstance(bg, (int, float)):
        bg = [bg] * 3
    bg = list(bg)[:3]
    if any(isinstance(c, float) for c in bg) and max(bg) <= 1.0:  # stored as fractions in [0, 1]
        bg = [c * 255.0 for c in bg]
    return [int(round(float(c))) for c in bg]


# ----------------------------------------------------------------------------- dataset
#: bytes of decoded objects a dataset keeps per process by default (``cache_objects=None``): a
#: split that fits is decoded once and each batch gathers from memory (~0.6 CPU-ms per batch of
#: 48 against ~4 from the gzip-compressed files on the CPU box, docs/benchmarks.md); 2 GiB holds
#: the ~4,400 objects of a 64 px dataset, so the 136 training objects of the bundled 195 meshes
#: and single-category subsets up to that size
CACHE_BYTES = 2 * 2**30



def decoded_object_bytes(image_size: int, num_views: int, mask_size: int, voxel_resolution: int) -> int:
    """Bytes of one decoded object in the cache: per view an RGB image ``[S,S,3]`` uint8, a mask
    ``[S,S]`` uint8, a mask ``[M,M]`` bool at the self-consistency size and its flag, the camera
    (K, R: 9 float32 each; t: 3; distance, azimuth, elevation: 1 each); and the voxel grid
    ``[G,G,G]`` uint8 (``voxel_resolution`` 0: none)."""
    per_view = image_size * image_size * 4 + mask_size * mask_size + 1 + (9 + 9 + 3 + 3) * 4
    return num_views * per_view + voxel_resolution ** 3


class ShardDataset(Dataset):
    """Views of the objects of one split; item ``i`` is view ``i % V`` of object ``i // V``.

    ``order`` (:data:`OBJECT_ORDERS`): the order of :attr:`objects`, which the item indices and
    so a loader's seeded shuffle follow. ``subset``: ``"all"``, ``"labeled"`` or ``"unlabeled"`` with the labelled subset chosen by
    :func:`choose_labeled` (``labeled_fraction``, ``seed``). ``require_voxels`` (training,
    evaluation) fails before any work when a shard has no ``voxels``. ``image_size``, when
    given, must match the shards (e.g. the size a checkpoint was trained at).
    ``cache_objects``: how many decoded objects a process may keep; None: as many as
    :data:`CACHE_BYTES` holds (:func:`decoded_object_bytes`: ~0.48 MB each at 64 px, 24 views,
    32^3 voxels, so ~4,400 objects). Batches use it only when the whole split fits
    (``num_objects <= cache_objects``); larger splits read just the views a batch needs
    (:meth:`compact_batch`). ``decoded_cache``: a
    folder for a decoded, memory-mapped copy of the arrays (:mod:`sc3d_train.data.decoded_cache`;
    opt-in, ~22x the shards' disk space), built here where missing; batches then gather from it.
    """

    def __init__(self, shard_dir: Path, split: str = "train", subset: str = "all",
                 labeled_fraction: float = 1.0, seed: int = 0, mask_size: int = MASK_SIZE,
                 require_voxels: bool = True, image_size: int | None = None,
                 cache_objects: int | None = None, decoded_cache: Path | str | None = None,
                 order: str = OBJECT_ORDERS[0]):
        if order not in OBJECT_ORDERS:
            raise ValueError(f"order must be one of {OBJECT_ORDERS}, got {order!r}")
        refs, info = scan_objects(shard_dir)
        self.shard_dir, self.split, self.subset = str(shard_dir), split, subset
        if require_voxels:
            require_one_voxel_resolution(shard_dir, info)
        if require_voxels and info["files_without_voxels"]:
            raise DataError(f"{info['files_without_voxels'][0]}: shard has no 'voxels' dataset; "
                            f"run `sc3d-data voxelize {shell_word(shard_dir)}` first")
        if image_size is not None and image_size != info["image_size"]:
            raise DataError(f"{shard_dir}: images are {info['image_size']}x{info['image_size']} but "
                            f"the model expects {image_size}x{image_size}")
        in_split = [r for r in refs if r.split == split]
        if order == "category/model_id":  # stable: objects of one name keep the shards' order
            in_split.sort(key=lambda r: (r.category, r.model_id))
        if not in_split:
            splits = sorted({r.split for r in refs})
            raise DataError(f"{shard_dir}: split {split!r} is empty (splits present: {splits})")
        labeled_keys = choose_labeled(in_split, labeled_fraction, seed) if labeled_fraction < 1 \
            else {f"{r.shard}:{r.row}" for r in in_split}
        self.objects = [r for r in in_split if subset == "all"
                        or (subset == "labeled") == (f"{r.shard}:{r.row}" in labeled_keys)]
        if not self.objects:
            raise DataError(f"{shard_dir}: no {subset} objects in split {split!r} "
                            f"(labelled fraction {labeled_fraction})")
        self.labeled = np.array([f"{r.shard}:{r.row}" in labeled_keys for r in self.objects])
        self.info = info
        self.image_size, self.num_views = info["image_size"], info["num_views"]
        self.mask_size, self.require_voxels = mask_size, require_voxels
        self.cache_objects = cache_objects if cache_objects is not None else CACHE_BYTES // decoded_object_bytes(
            self.image_size, self.num_views, mask_size, info["voxel_resolution"] if require_voxels else 0)
        self._reader = ShardReader(shard_dir)
        self._shards = sorted({r.shard for r in self.objects})
        number = {shard: i for i, shard in enumerate(self._shards)}
        self._shard_index = np.array([number[r.shard] for r in self.objects], dtype=np.int64)
        self._rows = np.array([r.row for r in self.objects], dtype=np.int64)
        self._cache: ObjectStore | None = None  # made per process (_store)
        self._pid = None
        try:
            self._decoded = DecodedCache(Path(decoded_cache), Path(shard_dir), self._shards, mask_size,
                                         require_voxels) if decoded_cache else None
        except ShardError as e:
            raise DataError(str(e)) from e
        self._cameras = self._read_cameras()  # every path gathers a batch's cameras from these

    def __len__(self) -> int:
        return len(self.objects) * self.num_views

    @property
    def num_objects(self) -> int:
        return len(self.objects)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_cache"], state["_pid"] = None, None
        return state

    def close(self) -> None:
        self._reader.close()

    def object_arrays(self, obj_i: int) -> dict:
        """All stored arrays of object ``obj_i`` (every view, numpy): ``images [V,S,S,3]``,
        ``masks [V,S,S]``, ``K [V,3,3]``, ``R``, ``t``, ``distance [V]``, ``azimuth``,
        ``elevation``, ``voxels [G,G,G]`` (with ``require_voxels``)."""
        return self._object(obj_i)

    def _store(self) -> ObjectStore:
        """This process's :class:`ObjectStore` (a forked worker makes its own)."""
        if self._pid != os.getpid():
            self._cache, self._pid = ObjectStore(self.num_objects), os.getpid()
        return self._cache

    def _object(self, obj_i: int) -> dict:
        """All arrays of object ``obj_i`` (every view, as stored), kept in this process's cache
        (:class:`ObjectStore`) when the whole split fits in ``cache_objects`` (each object is then
        decoded once; a larger split's objects are read when asked for and not kept: one pass
        over them, as the pose targets' search makes, would only fill memory)."""
        store = self._store()
        if obj_i in store:
            arrays = store.get(obj_i)
        else:
            ref = self.objects[obj_i]
            names = IMAGE_FIELDS + (("voxels",) if self.require_voxels else ())
            try:
                arrays = self._reader.read(ref.shard, ref.row, names)
            except ShardError as e:  # checksum / gzip error: the reader names the file and row
                raise DataError(f"{e} (object {ref.model_id})") from e
            m = self.mask_size
            arrays["masks_sc"] = np.zeros((self.num_views, m, m), dtype=bool)  # filled per view
            arrays["has_sc"] = np.zeros(self.num_views, dtype=bool)            # by _masks_sc
            if self.cache_objects >= self.num_objects:
                arrays = store.put(obj_i, arrays)
        return {**arrays, **{k: a[obj_i] for k, a in self._cameras.items()}}  # cameras: read once, at the start

    def __getitem__(self, index: int) -> dict:
        """One sample (the keys of the module docstring without the batch axis)."""
        batch = self.get_batch([index])
        return {k: v[0] for k, v in batch.items()}

    def get_batch(self, indices) -> dict:
        """The batch of dataset ``indices`` (length B): the keys of the module docstring, equal
        to ``default_collate`` of the single items."""
        return expand_batch(compact_tensors(*self.compact_batch(indices)))

    def compact_batch(self, indices) -> tuple[dict[str, np.ndarray], dict]:
        """The batch of ``indices`` in stored dtypes, as ``(arrays, strings)``: ``images``
        [B,S,S,3] uint8 (HWC), ``masks`` [B,S,S] and ``masks_sc`` [B,M,M] bool, ``voxels``
        [B,G,G,G] uint8 (with ``require_voxels``), ``K``, ``K_sc``, ``R``, ``t``, ``distance``,
        ``azimuth``, ``elevation`` float32, ``labeled`` bool, ``index`` int64; strings:
        ``category``, ``model_id``. With a ``decoded_cache`` the arrays are gathered from it. When the
        split fits in ``cache_objects``, objects are decoded
        whole once (cache) and the 48 px masks computed once per (object, view); otherwise
        (large datasets: an object comes back once per epoch, so a cache would only miss) only
        the batch's views are read, grouped by shard (``ShardReader.read_views``)."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        objs, views = np.divmod(idx, self.num_views)
        if self._decoded is not None:
            got = self._decoded.views(self._shard_index[objs], self._rows[objs], views)
            got.update({k: a[objs, views] for k, a in self._cameras.items()})
            masks_sc = got["masks_sc"]
        elif self.cache_objects >= self.num_objects:
            store = self._store()
            for o in np.unique(objs[~store.filled[objs]]).tolist():
                self._object(o)
            got = {name: store.arrays[name][objs, views] for name in IMAGE_FIELDS}
            got.update({k: a[objs, views] for k, a in self._cameras.items()})
            if self.require_voxels:
                got["voxels"] = store.arrays["voxels"][objs]
            masks_sc = self._masks_sc(store, objs, views, got["masks"])
        else:
            got = self._read_views(objs, views)
            masks_sc = sc_masks_bool(got["masks"], self.mask_size)
        K = got["K"].astype(np.float32)
        out = {"images": got["images"], "masks": got["masks"] > 0, "masks_sc": masks_sc, "K": K,
               "K_sc": np.asarray(scale_intrinsics(K.astype(np.float64), self.mask_size,
                                                   self.image_size), dtype=np.float32)}
        for name in ("R", "t", "distance", "azimuth", "elevation"):
            out[name] = got[name].astype(np.float32)
        out["labeled"] = self.labeled[objs].astype(bool)
        out["index"] = idx
        if self.require_voxels:
            out["voxels"] = got["voxels"]
            if (problem := nonbinary_voxels(got["voxels"], lambda i: self._where(int(objs[i])))) is not None:
                raise DataError(problem)
        strings = {"category": [self.objects[o].category for o in objs],
                   "model_id": [self.objects[o].model_id for o in objs]}
        return out, strings

    def _where(self, obj_i: int) -> str:
        """``SHARD: row R (object ID)``: object ``obj_i`` as errors name it."""
        ref = self.objects[obj_i]
        return f"{self._shards[self._shard_index[obj_i]]}: row {ref.row} (object {ref.model_id})"

    def _read_cameras(self) -> dict[str, np.ndarray]:
        """``CAMERA_FIELDS`` of every object of the split, ``[num_objects, V, ...]`` as stored
        (~2.3 KB per object at 24 views; read once here, in the process that makes the
        dataset, and shared with forked loader workers)."""
        out: dict[str, np.ndarray] = {}
        for s, path in enumerate(self._shards):
            mine = np.flatnonzero(self._shard_index == s)
            try:
                whole = self._reader.read_whole(path, CAMERA_FIELDS)
            except ShardError as e:
                raise DataError(str(e)) from e
            ids = [self.objects[i].model_id for i in mine]
            if (problem := nonfinite_camera(path, whole, self._rows[mine], ids)) is not None:
                raise DataError(problem)
            for k, a in whole.items():
                if k not in out:
                    out[k] = np.empty((self.num_objects,) + a.shape[1:], dtype=a.dtype)
                out[k][mine] = a[self._rows[mine]]
        return out

    def _read_views(self, objs: np.ndarray, views: np.ndarray) -> dict[str, np.ndarray]:
        """``IMAGE_FIELDS`` and ``CAMERA_FIELDS`` (+ ``voxels``) of the B (object, view) pairs,
        ``[B, ...]`` as stored: images, masks and voxels read from the files (one ``read_views``
        per shard the batch touches), the cameras from :meth:`_read_cameras`."""
        names = IMAGE_FIELDS + (("voxels",) if self.require_voxels else ())
        shard_of = self._shard_index[objs]
        out: dict[str, np.ndarray] = {k: a[objs, views] for k, a in self._cameras.items()}
        for s in np.unique(shard_of).tolist():
            sel = np.flatnonzero(shard_of == s)
            path = self._shards[s]
            try:
                got = self._reader.read_views(path, self._rows[objs[sel]], views[sel], names)
            except ShardError as e:  # checksum / gzip error: the reader names the file and rows
                raise DataError(str(e)) from e
            for k, a in got.items():
                if k not in out:
                    out[k] = np.empty((len(objs),) + a.shape[1:], dtype=a.dtype)
                out[k][sel] = a
        return out

    def _masks_sc(self, store: ObjectStore, objs: np.ndarray, views: np.ndarray, masks: np.ndarray) -> np.ndarray:
        """``masks_sc [B, M, M]`` bool of the B (object, view) pairs (stored ``masks [B, S, S]``),
        computed with :func:`sc_masks` for the views not yet in ``store``, then kept there."""
        masks_sc, has_sc = store.arrays["masks_sc"], store.arrays["has_sc"]
        todo = ~has_sc[objs, views]
        if todo.any():
            masks_sc[objs[todo], views[todo]] = sc_masks_bool(masks[todo], self.mask_size)
            has_sc[objs[todo], views[todo]] = True
        return masks_sc[objs, views]
