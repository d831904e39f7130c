"""Training data from sc3d shards: a map-style torch Dataset over (object, view) pairs and a
seeded, resumable, rank-aware sampler that draws a random view per object.

* File handles: the dataset never keeps an ``h5py.File`` across pickling or ``fork``. Each
  process (main or DataLoader worker) opens its own handles lazily on first read (keyed by
  the process id), so ``num_workers > 0`` is safe with any start method.
* Randomness lives in :class:`ViewSampler` only (``numpy`` generator seeded by
  ``(seed, epoch)``), so the stream of (object, view) pairs is a pure function of the seed and
  the position; resuming at sample ``k`` reproduces the stream exactly.
* Masks for the self-consistency module (48x48 by default) are the exact area average of the
  64x64 rendered mask (each output pixel covers 4/3 x 4/3 input pixels under the pixel-edge
  convention of ``sc3d_data.camera``; C1's ``area_downsample``), thresholded at >= 0.5; ``K`` is scaled with
  ``sc3d_data.camera.scale_intrinsics``, which keeps the principal point at the image centre.

Batch keys (B samples): ``images`` [B,3,S,S] float in [0,1]; ``voxels`` [B,G,G,G] float {0,1}
(index order [x,y,z]); ``masks`` [B,S,S] float; ``masks_sc`` [B,M,M] float; ``K`` [B,3,3] and
``K_sc`` [B,3,3] (pixels at S and M); ``R`` [B,3,3], ``t`` [B,3] (world->camera, OpenCV);
``distance``, ``azimuth``, ``elevation`` [B] (world units, degrees; the ground-truth pose is for
evaluation only); ``category``, ``model_id`` (lists of str); ``labeled`` [B] bool; ``index``
[B] long (object index * V + view).
"""
from __future__ import annotations

import math
import os
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import h5py
import numpy as np
import torch
from torch.utils.data import Dataset, Sampler

from sc3d_data.camera import scale_intrinsics
from sc3d_data.shards import io_reason, load_index, read_strings, shard_files
from sc3d_train.batch_transfer import PackedBatch, pack, unpack
from sc3d_train.config import MASK_SIZE
from sc3d_train.self_consistency import area_downsample


class DataError(ValueError):
    """Bad training data (missing voxels, wrong image size, empty split, ...)."""


def sc_masks(masks: np.ndarray, mask_size: int) -> torch.Tensor:
    """Self-consistency masks ``[V, M, M]`` float {0, 1} of rendered masks ``[V, S, S]``: exact
    area average (``sc3d_train.self_consistency.area_downsample``) thresholded at >= 0.5. Their
    camera is ``scale_intrinsics(K, M, S)``."""
    m = torch.from_numpy((np.asarray(masks) > 0).astype(np.float32))
    return (area_downsample(m, mask_size) >= 0.5 - 1e-6).float()


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
    ``{"image_size", "num_views", "voxel_resolution" (None without voxels),
    "files_without_voxels", "settings", "K" (3x3 list, pixels), "distance"}`` (camera of the
    first view of the first object: all views share intrinsics and distance, SPEC). Clear errors for a missing/empty directory."""
    shard_dir = Path(shard_dir)
    if not shard_dir.is_dir():
        raise DataError(f"{shard_dir}: shard directory does not exist")
    index = load_index(shard_dir)
    files = shard_files(shard_dir)
    if not files:
        raise DataError(f"{shard_dir}: the index lists no shard files")
    refs: list[ObjectRef] = []
    image_sizes, views, vres, no_vox = set(), set(), set(), []
    for path in files:
        if not path.is_file():
            raise DataError(f"{path}: listed in {shard_dir}/index.json but missing")
        try:
            with h5py.File(path, "r") as f:
                ids, cats, splits = (read_strings(f[k]) for k in ("model_id", "category", "split"))
                n, v, s = f["images"].shape[:3]
                image_sizes.add(int(s))
                views.add(int(v))
                if not refs:
                    camera = {"K": f["K"][0, 0].tolist(), "distance": float(f["distance"][0, 0])}
                if "voxels" in f:
                    vres.add(int(f["voxels"].shape[1]))
                else:
                    no_vox.append(str(path))
        except (OSError, KeyError, RuntimeError) as e:  # truncated / corrupted shard
            raise DataError(f"{path}: broken shard ({io_reason(e)}); see `sc3d-data info --verify "
                            f"{shard_dir}`") from e
        refs += [ObjectRef(str(path), r, ids[r], cats[r], splits[r]) for r in range(n)]
    if len(image_sizes) != 1 or len(views) != 1:
        raise DataError(f"{shard_dir}: shards disagree on image size {image_sizes} or views {views}")
    info = {"image_size": image_sizes.pop(), "num_views": views.pop(),
            "voxel_resolution": vres.pop() if len(vres) == 1 else None,
            "files_without_voxels": no_vox, "settings": index.get("settings", {}),
            "K": camera["K"], "distance": camera["distance"]}
    return refs, info


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
    """The dataset's background colour (RGB 0..255) from the shard settings (white default)."""
    bg = info.get("settings", {}).get("background", [255, 255, 255])
    if isinstance(bg, (int, float)):
        bg = [bg] * 3
    bg = [float(c) for c in bg][:3]
    if max(bg) <= 1.0:  # stored as floats in [0, 1]
        bg = [c * 255.0 for c in bg]
    return [int(round(c)) for c in bg]


# ----------------------------------------------------------------------------- dataset
class ShardDataset(Dataset):
    """Views of the objects of one split; item ``i`` is view ``i % V`` of object ``i // V``.

    ``subset``: ``"all"``, ``"labeled"`` or ``"unlabeled"`` with the labelled subset chosen by
    :func:`choose_labeled` (``labeled_fraction``, ``seed``). ``require_voxels`` (training,
    evaluation) fails before any work when a shard has no ``voxels``. ``image_size``, when
    given, must match the shards (e.g. the size a checkpoint was trained at).
    ``cache_objects``: decoded objects kept per process (LRU; ~0.45 MB each at 64 px, 24 views).
    """

    def __init__(self, shard_dir: Path, split: str = "train", subset: str = "all",
                 labeled_fraction: float = 1.0, seed: int = 0, mask_size: int = MASK_SIZE,
                 require_voxels: bool = True, image_size: int | None = None,
                 cache_objects: int = 128):
        refs, info = scan_objects(shard_dir)
        self.shard_dir, self.split, self.subset = str(shard_dir), split, subset
        if require_voxels and info["files_without_voxels"]:
            raise DataError(f"{info['files_without_voxels'][0]}: shard has no 'voxels' dataset; "
                            f"run `sc3d-data voxelize {shard_dir}` first")
        if image_size is not None and image_size != info["image_size"]:
            raise DataError(f"{shard_dir}: images are {info['image_size']}x{info['image_size']} but "
                            f"the model expects {image_size}x{image_size}")
        in_split = [r for r in refs if r.split == split]
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
        self.cache_objects = cache_objects
        self._files: dict[str, h5py.File] = {}
        self._cache: OrderedDict[int, dict] = OrderedDict()
        self._pid = None

    def __len__(self) -> int:
        return len(self.objects) * self.num_views

    @property
    def num_objects(self) -> int:
        return len(self.objects)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_files"], state["_cache"], state["_pid"] = {}, OrderedDict(), None
        return state

    def _file(self, path: str) -> h5py.File:
        if self._pid != os.getpid():  # new process (forked worker): never reuse parent handles
            self._files, self._cache, self._pid = {}, OrderedDict(), os.getpid()
        if path not in self._files:
            self._files[path] = h5py.File(path, "r")
        return self._files[path]

    def close(self) -> None:
        for f in self._files.values():
            f.close()
        self._files = {}

    def object_arrays(self, obj_i: int) -> dict:
        """All stored arrays of object ``obj_i`` (every view, numpy): ``images [V,S,S,3]``,
        ``masks [V,S,S]``, ``K [V,3,3]``, ``R``, ``t``, ``distance [V]``, ``azimuth``,
        ``elevation``, ``voxels [G,G,G]`` (with ``require_voxels``)."""
        return self._object(obj_i)

    def _object(self, obj_i: int) -> dict:
        """All arrays of object ``obj_i`` (every view, as stored), from this process's LRU cache.
        A chunk holds one whole object, so reading every view costs the same as reading one."""
        arrays = self._cache.get(obj_i)
        if arrays is not None:
            self._cache.move_to_end(obj_i)
            return arrays
        ref = self.objects[obj_i]
        names = ("images", "masks", "K", "R", "t", "distance", "azimuth", "elevation") + \
            (("voxels",) if self.require_voxels else ())
        try:
            f = self._file(ref.shard)
            arrays = {k: f[k][ref.row] for k in names}
        except (OSError, KeyError, RuntimeError) as e:  # checksum / gzip error: name the file
            raise DataError(f"{ref.shard}: object {ref.model_id} (row {ref.row}) cannot be read "
                            f"({io_reason(e)}); see `sc3d-data info --verify`") from e
        m = self.mask_size
        arrays["masks_sc"] = np.zeros((self.num_views, m, m), dtype=bool)  # filled per view
        arrays["has_sc"] = np.zeros(self.num_views, dtype=bool)            # by _masks_sc
        if self.cache_objects > 0:
            self._cache[obj_i] = arrays
            while len(self._cache) > self.cache_objects:
                self._cache.popitem(last=False)
        return arrays

    def __getitem__(self, index: int) -> dict:
        """One sample (the keys of the module docstring without the batch axis)."""
        batch = self.get_batch([index])
        return {k: v[0] for k, v in batch.items()}

    def get_batch(self, indices) -> dict:
        """The batch of dataset ``indices`` (length B): the keys of the module docstring, equal
        to ``default_collate`` of the single items."""
        return expand_batch(*self.compact_batch(indices))

    def compact_batch(self, indices) -> tuple[dict[str, np.ndarray], dict]:
        """The batch of ``indices`` in stored dtypes, as ``(arrays, strings)``: ``images``
        [B,S,S,3] uint8 (HWC), ``masks`` [B,S,S] and ``masks_sc`` [B,M,M] bool, ``voxels``
        [B,G,G,G] uint8 (with ``require_voxels``), ``K``, ``K_sc``, ``R``, ``t``, ``distance``,
        ``azimuth``, ``elevation`` float32, ``labeled`` bool, ``index`` int64; strings:
        ``category``, ``model_id``. Objects are decoded once (LRU cache) and the 48 px masks
        computed once per (object, view)."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        objs, views = np.divmod(idx, self.num_views)
        arrays = [self._object(int(o)) for o in objs]

        def gather(name: str) -> np.ndarray:
            return np.stack([a[name][v] for a, v in zip(arrays, views)])

        raw_masks = gather("masks")
        K = gather("K").astype(np.float32)
        out = {"images": gather("images"), "masks": raw_masks > 0,
               "masks_sc": self._masks_sc(arrays, views, raw_masks), "K": K,
               "K_sc": np.asarray(scale_intrinsics(K.astype(np.float64), self.mask_size,
                                                   self.image_size), dtype=np.float32)}
        for name in ("R", "t", "distance", "azimuth", "elevation"):
            out[name] = gather(name).astype(np.float32)
        out["labeled"] = self.labeled[objs].astype(bool)
        out["index"] = idx
        if self.require_voxels:
            out["voxels"] = np.stack([a["voxels"] for a in arrays])
        strings = {"category": [self.objects[o].category for o in objs],
                   "model_id": [self.objects[o].model_id for o in objs]}
        return out, strings

    def _masks_sc(self, arrays: list[dict], views: np.ndarray, masks: np.ndarray) -> np.ndarray:
        """``masks_sc [B, M, M]`` bool of the B views (stored ``masks [B, S, S]``), computed with
        :func:`sc_masks` for the views not yet in their object's cache entry, then cached."""
        todo = [i for i, (a, v) in enumerate(zip(arrays, views)) if not a["has_sc"][v]]
        if todo:
            new = sc_masks(masks[todo], self.mask_size).bool().numpy()
            for i, m in zip(todo, new):
                arrays[i]["masks_sc"][views[i]], arrays[i]["has_sc"][views[i]] = m, True
        return np.stack([a["masks_sc"][v] for a, v in zip(arrays, views)])


#: arrays of a compact batch that are 0/1 and travel bit-packed between processes
BINARY_KEYS = ("masks", "masks_sc", "voxels")


def expand_batch(arrays: dict[str, np.ndarray], strings: dict, pin: bool = False) -> dict:
    """The training batch (module docstring) of a compact batch (``ShardDataset.compact_batch``):
    images to float ``[B,3,S,S]`` / 255, masks and voxels to float, the rest as tensors. Done
    with numpy (one thread: torch's intra-op threads only contend on a loaded CPU); ``pin``
    puts the large tensors in page-locked memory (CUDA host-to-device copies)."""
    def new(shape) -> torch.Tensor:
        return torch.empty(shape, dtype=torch.float32, pin_memory=pin)

    images = arrays["images"]
    b, s = images.shape[:2]
    batch = {"images": new((b, 3, s, s))}
    np.divide(images.transpose(0, 3, 1, 2), np.float32(255.0), out=batch["images"].numpy(),
              dtype=np.float32)
    for name in ("masks", "masks_sc") + (("voxels",) if "voxels" in arrays else ()):
        batch[name] = new(arrays[name].shape)
        batch[name].numpy()[...] = arrays[name]
    for name in ("K", "K_sc", "R", "t", "distance", "azimuth", "elevation", "labeled", "index"):
        batch[name] = torch.from_numpy(np.array(arrays[name]))
    batch.update({k: list(v) for k, v in strings.items()})
    return batch


# ----------------------------------------------------------------------------- sampling
class ViewSampler(Sampler):
    """An endless, seeded stream of dataset indices ``object * V + view`` for one DDP rank.

    Epoch ``e`` shuffles the objects with ``default_rng([seed, e])`` and draws one random view
    per object; the permutation is padded to a multiple of ``world_size`` and rank ``r`` takes
    every ``world_size``-th entry from ``r`` (DistributedSampler's partitioning). ``start`` skips
    the first ``start`` indices of this rank's stream (resume), without drawing them.
    """

    def __init__(self, num_objects: int, num_views: int, seed: int = 0, rank: int = 0,
                 world_size: int = 1, start: int = 0):
        self.n, self.v, self.seed = num_objects, num_views, seed
        self.rank, self.world, self.start = rank, world_size, start
        self.per_rank = math.ceil(num_objects / world_size)

    def epoch_indices(self, epoch: int) -> np.ndarray:
        rng = np.random.default_rng([self.seed, epoch])
        perm = rng.permutation(self.n)
        views = rng.integers(0, self.v, size=self.n)
        idx = perm * self.v + views[perm]
        pad = self.per_rank * self.world - self.n
        idx = np.concatenate([idx, idx[:pad]]) if pad else idx
        return idx[self.rank::self.world]

    def __iter__(self) -> Iterator[int]:
        epoch, offset = divmod(self.start, self.per_rank)
        while True:
            for i in self.epoch_indices(epoch)[offset:]:
                yield int(i)
            epoch, offset = epoch + 1, 0

    def __len__(self):  # endless; DataLoader only needs this for len(loader)
        return 2 ** 62


class BatchSampler(Sampler):
    """The stream of :class:`ViewSampler` cut into consecutive lists of ``batch_size`` indices
    (``drop_last``), so batch ``k`` holds samples ``k*B .. k*B+B-1`` of the rank's stream:
    exactly the batches ``DataLoader(batch_size=B, sampler=views, drop_last=True)`` forms."""

    def __init__(self, views: ViewSampler, batch_size: int):
        self.views, self.batch_size = views, batch_size

    def __iter__(self) -> Iterator[list[int]]:
        it = iter(self.views)
        while True:
            yield [next(it) for _ in range(self.batch_size)]

    def __len__(self):
        return len(self.views) // self.batch_size


class _PackedBatches(Dataset):
    """``dataset.compact_batch`` as a map-style dataset keyed by whole lists of indices, packed
    for the trip to the main process (:mod:`sc3d_train.batch_transfer`): one loader worker
    assembles one whole batch and sends one ~1 MB tensor instead of ~10 MB in 14 tensors."""

    def __init__(self, dataset: ShardDataset):
        self.dataset = dataset

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, indices: list[int]) -> PackedBatch | tuple[dict, dict]:
        arrays, strings = self.dataset.compact_batch(indices)
        if torch.utils.data.get_worker_info() is None:  # in-process: nothing to send
            return arrays, strings
        return pack(arrays, strings, bits=BINARY_KEYS)


class BatchLoader(torch.utils.data.DataLoader):
    """A DataLoader of packed batches whose iterator yields expanded training batches (the
    expansion runs in the consuming process, :func:`expand_batch`)."""

    def __init__(self, *args, pin: bool = False, **kwargs):
        super().__init__(*args, **kwargs)
        self.pin = pin

    def __iter__(self):
        for item in super().__iter__():
            if isinstance(item, PackedBatch):
                item = unpack(item), item.other
            yield expand_batch(*item, pin=self.pin)


def make_loader(dataset: ShardDataset, batch_size: int, seed: int, start: int = 0,
                rank: int = 0, world_size: int = 1, workers: int = 0,
                pin_memory: bool = False) -> torch.utils.data.DataLoader:
    """An endless loader of ``batch_size`` samples per step for this rank, starting at sample
    ``start`` of the rank's stream (batch ``k`` = samples ``k*B .. k*B+B-1``, whatever
    ``workers``). Each batch is assembled whole by one worker process (or in-process with
    ``workers=0``) from its decoded-object cache, sent packed, and expanded to float here;
    workers run one torch thread. ``pin_memory`` (CUDA) returns page-locked tensors. A
    private generator keeps the global torch RNG untouched."""
    sampler = BatchSampler(ViewSampler(dataset.num_objects, dataset.num_views, seed, rank,
                                       world_size, start), batch_size)
    return BatchLoader(
        _PackedBatches(dataset), batch_size=None, sampler=sampler, num_workers=workers,
        collate_fn=_keep, pin=pin_memory, persistent_workers=False,
        generator=torch.Generator().manual_seed(seed),
        worker_init_fn=_limit_worker_threads if workers else None,
        prefetch_factor=4 if workers else None)


def _keep(batch):
    return batch


def _limit_worker_threads(_worker_id: int) -> None:
    torch.set_num_threads(1)


def all_views(dataset: ShardDataset) -> list[int]:
    """Every (object, view) index in order: for evaluation."""
    return list(range(len(dataset)))
