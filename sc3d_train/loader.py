"""Batches for training and evaluation: a seeded, resumable, rank-aware sampler that draws a
random view per object (:class:`ViewSampler`) and whole batches read per worker and handed over
through shared memory (:func:`make_loader`).

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

from sc3d_train.batch_transfer import PackedBatch, RingBatch, SharedRing, pack, unpack
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
    (``drop_last``), yielded as ``(k, indices)``: batch ``k`` holds samples
    ``k*B .. k*B+B-1`` of the rank's stream, exactly the batches
    ``DataLoader(batch_size=B, sampler=views, drop_last=True)`` forms; ``k`` (counted from this
    loader's start) picks the batch's :class:`~sc3d_train.batch_transfer.SharedRing` slot."""

    def __init__(self, views: ViewSampler, batch_size: int):
        self.views, self.batch_size = views, batch_size

    def __iter__(self) -> Iterator[tuple[int, list[int]]]:
        it = iter(self.views)
        k = 0
        while True:
            yield k, [next(it) for _ in range(self.batch_size)]
            k += 1

    def __len__(self):
        return len(self.views) // self.batch_size


class _RingBatches(Dataset):
    """``dataset.compact_batch`` as a map-style dataset keyed by ``(k, indices)``: in a loader
    worker the batch is packed into slot ``k`` of :attr:`ring` (:mod:`sc3d_train.batch_transfer`)
    and only its layout travels; in-process it is returned as it is. One worker assembles one
    whole batch."""

    def __init__(self, dataset: ShardDataset):
        self.dataset = dataset
        self.ring: SharedRing | None = None  # set by BatchLoader before its workers start

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, key: tuple[int, list[int]]) -> RingBatch | PackedBatch | tuple[dict, dict]:
        seq, indices = key
        arrays, strings = self.dataset.compact_batch(indices)
        if torch.utils.data.get_worker_info() is None:  # in-process: nothing to send
            return arrays, strings
        return self.ring.put(seq, arrays, strings, bits=BINARY_KEYS)

    def slot_bytes(self, batch_size: int) -> int:
        """Bytes of one packed batch of ``batch_size`` samples: ``batch_size`` times those of
        sample 0 (every array has the batch axis first; a bit-packed array of B samples needs at
        most B times the bytes of one). A batch whose arrays are not all binary where sample 0's
        are (then not bit-packed) does not fit and travels the usual way."""
        arrays, strings = self.dataset.compact_batch([0])
        return batch_size * pack(arrays, strings, bits=BINARY_KEYS).buffer.numel()


class BatchLoader(torch.utils.data.DataLoader):
    """A DataLoader of whole batches whose iterator yields compact batches
    (:func:`~sc3d_train.batch_format.compact_tensors`: uint8 images, bool masks, uint8 voxels); the
    training step expands them on its device (:func:`~sc3d_train.batch_format.expand_batch`).
    With workers, each iteration makes a :class:`~sc3d_train.batch_transfer.SharedRing` of
    ``prefetch_factor * num_workers + 1`` slots (~0.8 MB each at batch 48, 64 px, 32^3) that its
    workers write batches into; batches are copied out of it before they are yielded."""

    def __init__(self, *args, pin: bool = False, batch_bytes: int = 0, **kwargs):
        super().__init__(*args, **kwargs)
        self.pin, self.batch_bytes = pin, batch_bytes

    def __iter__(self):
        ring = None
        if self.num_workers:
            ring = SharedRing(self.prefetch_factor * self.num_workers + 1, self.batch_bytes)
            self.dataset.ring = ring  # the workers this iteration starts take this ring with them
        for item in super().__iter__():
            if isinstance(item, RingBatch):
                item = ring.take(item), item.other
            elif isinstance(item, PackedBatch):  # did not fit its slot: sent the usual way
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
    ``workers=0``), written into shared memory made once per iteration (:class:`BatchLoader`),
    and yielded compact (uint8 images, bool masks, uint8
    voxels: :func:`~sc3d_train.batch_format.compact_tensors`); ``sc3d_train.batch_format.expand_batch``
    (called by the training step, on its device) makes the float training batch. Workers run
    one torch thread. ``pin_memory`` (CUDA) returns page-locked tensors. A private generator
    keeps the global torch RNG untouched."""
    sampler = BatchSampler(ViewSampler(dataset.num_objects, dataset.num_views, seed, rank,
                                       world_size, start), batch_size)
    batches = _RingBatches(dataset)
    return BatchLoader(
        batches, batch_size=None, sampler=sampler, num_workers=workers,
        collate_fn=_keep, pin=pin_memory, persistent_workers=False,
        batch_bytes=batches.slot_bytes(batch_size) if workers else 0,
        generator=torch.Generator().manual_seed(seed),
        worker_init_fn=_limit_worker_threads if workers else None,
        prefetch_factor=4 if workers else None)


def _keep(batch):
    return batch


def _limit_worker_threads(_worker_id: int) -> None:
    torch.set_num_threads(1)
