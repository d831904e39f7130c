"""The decoded objects a process keeps (``ShardDataset``'s cache when the whole split fits): each
field of every object in one array ``[num_objects, ...]``, so that a batch's views are gathered
with one fancy index per field (``images[objs, views]``) instead of a ``np.stack`` of 48
per-object arrays (0.17 against 0.45 ms a batch of 48 on the 2-core CPU box).

An array is allocated (``numpy.empty``, sized for the whole split) when the first object brings
its field, and memory is taken as objects are written into it: in pages of 2 MiB where the kernel
gives numpy transparent huge pages, so a store of a few objects scattered over the split holds up
to ~10x their bytes (a 2,000-object store with 100 objects put at random: 480 MiB for 46 MiB of
objects); a split is at most ``ShardDataset.cache_objects`` objects (2 GiB), and the pose
targets' search before training reads every object of it anyway. Objects are filled whole
(:meth:`ObjectStore.put`); :attr:`ObjectStore.filled` says which.
"""
from __future__ import annotations

from typing import Iterator

import numpy as np


class ObjectStore:
    """Fields ``name -> [num_objects, *field shape]`` (:attr:`arrays`) and which objects hold
    their values (:attr:`filled`, bool ``[num_objects]``). Every object of a store has the same
    fields, shapes and dtypes (one dataset's); a value of another dtype is cast on :meth:`put`."""

    def __init__(self, num_objects: int):
        self.num_objects = num_objects
        self.arrays: dict[str, np.ndarray] = {}
        self.filled = np.zeros(num_objects, dtype=bool)

    def __contains__(self, obj_i: int) -> bool:
        return bool(self.filled[obj_i])

    def __iter__(self) -> Iterator[int]:
        """The indices of the filled objects, ascending."""
        return iter(np.flatnonzero(self.filled).tolist())

    def __len__(self) -> int:
        return int(self.filled.sum())

    def put(self, obj_i: int, fields: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Store object ``obj_i``'s ``fields`` (name -> array); returns :meth:`get` of it."""
        for name, a in fields.items():
            if name not in self.arrays:
                self.arrays[name] = np.empty((self.num_objects,) + a.shape, dtype=a.dtype)
            self.arrays[name][obj_i] = a
        self.filled[obj_i] = True
        return self.get(obj_i)

    def get(self, obj_i: int) -> dict[str, np.ndarray]:
        """Object ``obj_i``'s fields as views of the store (writing into one writes the store)."""
        return {name: a[obj_i] for name, a in self.arrays.items()}
