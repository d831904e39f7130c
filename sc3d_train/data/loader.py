"""Batches for training and evaluation: a seeded, resumable, rank-aware sampler that draws a
random view per object (:class:`ViewSampler`) and whole batches read per worker and handed over
through shared memory (:func:`make_loader`).

Randomness lives in :class:`ViewSampler` only (``numpy`` generator seeded by ``(seed, epoch)``),
so the stream of (object, view) pairs is a pure function of the seed and the position; resuming
at sample ``k`` reproduces the stream exactly. Batch keys: ``sc3d_train.data.dataset``.

Errors: a broken shard (a chunk whose HDF5 checksum fails, a decoded-cache file cut short) raises
the same exception, with the same one-line message naming the file and the problem, whatever
``workers``: a worker sends such an error (:data:`DATA_ERRORS`) back in its batch's place
(:class:`WorkerError`) and the loader raises it as itself when the stream reaches that batch,
not inside PyTorch's "Caught ... in DataLoader worker process N. Original Traceback ..." text.
Any other error in a worker (a bug) keeps PyTorch's wrapper, whose text holds the worker's
traceback.
"""
from __future__ import annotations

import errno
import math
from dataclasses import dataclass
from typing import Iterator

import numpy as np
import torch
from torch.utils.data import Dataset, Sampler

from sc3d_train.data.batch_transfer import PackedBatch, RingBatch, SharedRing, pack, shm_full, unpack
from sc3d_train.data.batch_format import BINARY_KEYS, compact_tensors
from sc3d_data.io.shards import ShardError
from sc3d_train.data.dataset import DataError, ShardDataset


#: batches per loader task with workers: the DataLoader's per-task cost in the main process
#: (index and result queues, thread wake-ups: ~0.4 ms on a loaded 2-core machine) is paid once
#: per task; 4 brought the main process from 0.8 to 0.4 CPU-ms per batch (docs/benchmarks.md)
BATCHES_PER_TASK = 4
#: tasks each worker keeps ready (DataLoader ``prefetch_factor``): 2 tasks = 8 batches
TASKS_AHEAD = 2
#: errors of the data that name the file and the problem (``fit`` reports them in one line):
#: a worker sends them back as themselves (module doc)
DATA_ERRORS = (DataError, ShardError)


class LoaderWorkerDied(OSError):
    """A loader worker process that died outside Python (killed by a signal: the kernel's
    out-of-memory killer, ``kill -9``; a Bus error). PyTorch reports it as a RuntimeError raised
    by its SIGCHLD handler wherever the main process is (in the backward pass, a checkpoint's
    write), which ended ``fit`` in a traceback; an OSError is one line (:func:`worker_death`)."""


def worker_death(e: BaseException, then: str = "") -> LoaderWorkerDied | None:
    """``e`` as a :class:`LoaderWorkerDied` (its message followed by ``then``, e.g. the last good
    checkpoint) where it is PyTorch's report of a dead loader worker; None for any other error."""
    text = str(e)
    if not isinstance(e, RuntimeError) or not text.startswith("DataLoader worker (pid"):
        return None
    cause = ("/dev/shm full? give the machine more (docker run --shm-size)" if "Bus error" in text else
             "out of memory? (the kernel's OOM killer: see dmesg)")
    return LoaderWorkerDied(f"a loader worker process died ({text.split('. ')[0].strip().rstrip('.')}): {cause}; "
                            f"use fewer --workers (0: none){'; ' + then if then else ''}")


@dataclass
class WorkerError:
    """A :data:`DATA_ERRORS` exception that a loader worker met assembling a batch, sent in that
    batch's place (the exception pickled: its type and message); :class:`BatchLoader` raises
    ``error`` when the stream reaches it."""

    error: Exception


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
    (``drop_last``): batch ``k`` holds samples ``k*B .. k*B+B-1`` of the rank's stream, exactly
    the batches ``DataLoader(batch_size=B, sampler=views, drop_last=True)`` forms. Yielded in
    tasks of ``group`` consecutive batches, ``(k, [batch k, ..., batch k+group-1])``; ``k``
    (counted from this loader's start) places them in a :class:`~sc3d_train.data.batch_transfer.SharedRing`."""

    def __init__(self, views: ViewSampler, batch_size: int, group: int = 1):
        self.views, self.batch_size, self.group = views, batch_size, group

    def __iter__(self) -> Iterator[tuple[int, list[list[int]]]]:
        it = iter(self.views)
        k = 0
        while True:
            yield k, [[next(it) for _ in range(self.batch_size)] for _ in range(self.group)]
            k += self.group

    def __len__(self):
        return len(self.views) // (self.batch_size * self.group)


class _RingBatches(Dataset):
    """``dataset.compact_batch`` as a map-style dataset keyed by tasks ``(k, [indices, ...])``
    of :class:`BatchSampler`: in a loader worker, batch ``k + j`` of the task is packed into its
    slot of :attr:`ring` (:mod:`sc3d_train.data.batch_transfer`) and only its layout travels;
    in-process the batches are returned as they are. One worker assembles whole batches."""

    def __init__(self, dataset: ShardDataset):
        self.dataset = dataset
        self.ring: SharedRing | None = None  # set by BatchLoader before its workers start

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, key: tuple[int, list[list[int]]]) -> list:
        """A list of ``RingBatch`` (or ``PackedBatch`` where one did not fit), or in-process
        of ``(arrays, strings)``, one per batch of the task; in a worker, a batch that raised
        one of :data:`DATA_ERRORS` ends the list with its :class:`WorkerError`."""
        first, batches = key
        in_process = torch.utils.data.get_worker_info() is None  # nothing to send
        out = []
        for seq, indices in enumerate(batches, first):
            try:
                arrays, strings = self.dataset.compact_batch(indices)
            except DATA_ERRORS as e:
                if in_process:
                    raise
                out.append(WorkerError(e))  # the stream stops at this batch
                break
            out.append((arrays, strings) if in_process else self.ring.put(seq, arrays, strings, bits=BINARY_KEYS))
        return out

    def slot_bytes(self, batch_size: int) -> int:
        """Bytes of one packed batch of ``batch_size`` samples: ``batch_size`` times those of
        sample 0 (every array has the batch axis first; a bit-packed array of B samples needs at
        most B times the bytes of one). A batch whose arrays are not all binary where sample 0's
        are (then not bit-packed) does not fit and travels the usual way."""
        arrays, strings = self.dataset.compact_batch([0])
        return batch_size * pack(arrays, strings, bits=BINARY_KEYS).buffer.numel()


class BatchLoader(torch.utils.data.DataLoader):
    """A DataLoader of tasks of whole batches (:class:`BatchSampler`) whose iterator yields
    compact batches (:func:`~sc3d_train.data.batch_format.compact_tensors`: uint8 images, bool
    masks, uint8 voxels); the training step expands them on its device
    (:func:`~sc3d_train.data.batch_format.expand_batch`). With workers, each iteration makes a
    :class:`~sc3d_train.data.batch_transfer.SharedRing` of ``(prefetch_factor * num_workers + 1) *
    group`` slots (~0.8 MB each at batch 48, 64 px, 32^3) that its workers write batches into;
    a batch is copied out of its slot when it is yielded. The DataLoader sends a new task only
    when it hands out one and keeps at most ``prefetch_factor * num_workers`` ahead of it, so no
    worker writes into a slot of the task being yielded."""

    def __init__(self, *args, pin: bool = False, batch_bytes: int = 0, group: int = 1, **kwargs):
        super().__init__(*args, **kwargs)
        self.pin, self.batch_bytes, self.group = pin, batch_bytes, group

    def __iter__(self):
        ring = None
        if self.num_workers:
            ring = SharedRing(ring_slots(self.num_workers, self.prefetch_factor, self.group), self.batch_bytes)
            self.dataset.ring = ring  # the workers this iteration starts take this ring with them
        try:  # the workers start here; their queues' semaphores take pages of /dev/shm too
            tasks = super().__iter__()
        except OSError as e:
            if e.errno != errno.ENOSPC:
                raise
            raise shm_full("start its workers in /dev/shm", e) from e
        for task in tasks:
            for item in task:
                if isinstance(item, WorkerError):
                    raise item.error  # as --workers 0 raises it (module doc)
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
    ``workers=0``), :data:`BATCHES_PER_TASK` consecutive batches per worker task, written into
    shared memory made once per iteration (:class:`BatchLoader`), and yielded compact (uint8 images, bool masks, uint8
    voxels: :func:`~sc3d_train.data.batch_format.compact_tensors`); ``sc3d_train.data.batch_format.expand_batch``
    (called by the training step, on its device) makes the float training batch. Workers run
    one torch thread. ``pin_memory`` (CUDA) returns page-locked tensors. A private generator
    keeps the global torch RNG untouched."""
    group = BATCHES_PER_TASK if workers else 1
    sampler = BatchSampler(ViewSampler(dataset.num_objects, dataset.num_views, seed, rank,
                                       world_size, start), batch_size, group)
    batches = _RingBatches(dataset)
    return BatchLoader(
        batches, batch_size=None, sampler=sampler, num_workers=workers,
        collate_fn=_keep, pin=pin_memory, persistent_workers=False, group=group,
        batch_bytes=batches.slot_bytes(batch_size) if workers else 0,
        generator=torch.Generator().manual_seed(seed),
        worker_init_fn=_limit_worker_threads if workers else None,
        prefetch_factor=TASKS_AHEAD if workers else None)


def ring_slots(workers: int, tasks_ahead: int = TASKS_AHEAD, group: int = BATCHES_PER_TASK) -> int:
    """Slots of the ring of a :class:`BatchLoader` with ``workers`` workers, each ``tasks_ahead``
    tasks (``prefetch_factor``) of ``group`` batches ahead: one more task than the DataLoader
    keeps ahead, so no worker writes a slot being read (``SharedRing``); 0 without workers."""
    return (tasks_ahead * workers + 1) * group if workers else 0


def _keep(batch):
    return batch


def _limit_worker_threads(_worker_id: int) -> None:
    torch.set_num_threads(1)
