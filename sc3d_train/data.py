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
                 labeled_fraction: float = 1.0, seed: int = 0, mask_size: int = 48,
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
        """All arrays of object ``obj_i`` (every view): ``images [V,S,S,3]``, ``masks [V,S,S]``,
        ``masks_sc [V,M,M]``, ``K [V,3,3]``, ``distance [V]``, ``voxels [G,G,G]``, ... (numpy,
        ``masks_sc`` torch)."""
        return self._object(obj_i)

    def _object(self, obj_i: int) -> dict:
        """All arrays of object ``obj_i`` (every view), from this process's LRU cache. A chunk
        holds one whole object, so reading every view costs the same as reading one."""
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
        arrays["masks_sc"] = sc_masks(arrays["masks"], self.mask_size)
        if self.cache_objects > 0:
            self._cache[obj_i] = arrays
            while len(self._cache) > self.cache_objects:
                self._cache.popitem(last=False)
        return arrays

    def __getitem__(self, index: int) -> dict:
        obj_i, view = divmod(int(index), self.num_views)
        ref = self.objects[obj_i]
        a = self._object(obj_i)
        image, mask = a["images"][view], a["masks"][view]
        K = a["K"][view].astype(np.float32)
        item = {
            "images": torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1))).float() / 255.0,
            "masks": torch.from_numpy((mask > 0).astype(np.float32)),
            "masks_sc": a["masks_sc"][view].clone(),
            "K": torch.from_numpy(K),
            "K_sc": torch.from_numpy(scale_intrinsics(K.astype(np.float64), self.mask_size,
                                                      self.image_size).astype(np.float32)),
            "R": torch.from_numpy(a["R"][view].astype(np.float32)),
            "t": torch.from_numpy(a["t"][view].astype(np.float32)),
            "distance": torch.tensor(float(a["distance"][view])),
            "azimuth": torch.tensor(float(a["azimuth"][view])),
            "elevation": torch.tensor(float(a["elevation"][view])),
            "category": ref.category,
            "model_id": ref.model_id,
            "labeled": torch.tensor(bool(self.labeled[obj_i])),
            "index": torch.tensor(int(index)),
        }
        if self.require_voxels:
            item["voxels"] = torch.from_numpy(a["voxels"].astype(np.float32))
        return item


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


def make_loader(dataset: ShardDataset, batch_size: int, seed: int, start: int = 0,
                rank: int = 0, world_size: int = 1, workers: int = 0,
                pin_memory: bool = False) -> torch.utils.data.DataLoader:
    """An endless DataLoader of ``batch_size`` samples per step for this rank, starting at sample
    ``start`` of the rank's stream. A private generator keeps the global torch RNG untouched."""
    sampler = ViewSampler(dataset.num_objects, dataset.num_views, seed, rank, world_size, start)
    return torch.utils.data.DataLoader(
        dataset, batch_size=batch_size, sampler=sampler, num_workers=workers,
        pin_memory=pin_memory, drop_last=True, persistent_workers=False,
        generator=torch.Generator().manual_seed(seed),
        worker_init_fn=_limit_worker_threads if workers else None,
        prefetch_factor=4 if workers else None)


def _limit_worker_threads(_worker_id: int) -> None:
    torch.set_num_threads(1)


def all_views(dataset: ShardDataset) -> list[int]:
    """Every (object, view) index in order: for evaluation."""
    return list(range(len(dataset)))
