"""Batches for training and evaluation: a seeded, resumable, rank-aware sampler that draws a
random view per object (:class:`ViewSampler`) and whole batches read per worker and sent packed
(:func:`make_loader`).

Randomness lives in :class:`ViewSampler` only (``numpy`` generator seeded by ``(seed, epoch)``),
so the stream of (object, view) pairs is a pure function of the seed and the position; resuming
at sample ``k`` reproduces the stream exactly. Batch keys: ``sc3d_train.data``.
"""
from __future__ import annotations

import math
from typing import Iterator

import numpy as np
import torch
from torch.utils.data import Dataset, Sampler

from sc3d_train.batch_transfer import PackedBatch, pack, unpack
from sc3d_train.batch_format import BINARY_KEYS, compact_tensors
from sc3d_train.data import ShardDataset


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
    """A DataLoader of packed batches whose iterator yields compact batches
    (:func:`~sc3d_train.batch_format.compact_tensors`: uint8 images, bool masks, uint8 voxels); the
    training step expands them on its device (:func:`~sc3d_train.batch_format.expand_batch`)."""

    def __init__(self, *args, pin: bool = False, **kwargs):
        super().__init__(*args, **kwargs)
        self.pin = pin

    def __iter__(self):
        for item in super().__iter__():
            if isinstance(item, PackedBatch):
                item = unpack(item), item.other
            batch = compact_tensors(*item)
            if self.pin:
                batch = {k: v.pin_memory() if torch.is_tensor(v) else v for k, v in batch.items()}
            yield batch


def make_loader(dataset: ShardDataset, batch_size: int, seed: int, start: int = 0,
                rank: int = 0, world_size: int = 1, workers: int = 0,
                pin_memory: bool = False) -> torch.utils.data.DataLoader:
    """An endless loader of ``batch_size`` samples per step for this rank, starting at sample
    ``start`` of the rank's stream (batch ``k`` = samples ``k*B .. k*B+B-1``, whatever
    ``workers``). Each batch is assembled whole by one worker process (or in-process with
    ``workers=0``), sent packed, and yielded compact (uint8 images, bool masks, uint8
    voxels: :func:`~sc3d_train.batch_format.compact_tensors`); ``sc3d_train.batch_format.expand_batch``
    (called by the training step, on its device) makes the float training batch. Workers run
    one torch thread. ``pin_memory`` (CUDA) returns page-locked tensors. A private generator
    keeps the global torch RNG untouched."""
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
