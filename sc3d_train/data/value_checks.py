"""Checks of the values a split is trained and evaluated with that the shard layout check
(``sc3d_data.io.shard_layout``, metadata only) cannot see. Cameras and poses (read once per
split by ``ShardDataset._read_cameras``): a NaN or infinity in ``K``, ``R``, ``t``, ``distance``,
``azimuth`` or ``elevation`` of one view (a hand edit, a bad import, a disk that returned wrong
bytes behind an unchanged checksum) would be trained on, or scored by ``eval``, without a word,
as the layout check reads no values. They are small (~2.3 KB per object), so checking them
all costs nothing next to reading them. Voxels (per batch, ``ShardDataset.compact_batch``): a grid
holding other values than 0 and 1 (the layout allows any integer dtype) was a BCE target of 7 or
200 with one process and 1 where workers bit-pack it; a max over the batch's grids (~1.5 MB of
bytes at batch 48 and 32^3) costs ~0.1 ms.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np


def nonfinite_camera(path: Path, whole: dict[str, np.ndarray], rows: np.ndarray,
                     model_ids: list[str]) -> str | None:
    """One line naming shard ``path``, the dataset, row, object and view of the first value of
    ``whole`` (``[N, V, ...]`` arrays as stored) at ``rows`` (of objects ``model_ids``) that
    is not finite; None when all are."""
    for name, array in whole.items():
        if array.dtype.kind != "f":
            continue
        used = array[rows]
        bad = ~np.isfinite(used.reshape(used.shape[0], used.shape[1], -1)).all(axis=2)
        if bad.any():
            i, view = (int(x) for x in np.argwhere(bad)[0])
            return (f"{path}: '{name}' of row {int(rows[i])} (object {model_ids[i]}), view {view} holds "
                    f"{used[i, view].ravel()[~np.isfinite(used[i, view].ravel())][0]}, not a finite number "
                    "(a damaged or hand-edited shard); see `sc3d-data info --verify`")
    return None


def nonbinary_voxels(voxels: np.ndarray, where) -> str | None:
    """One line naming the sample of the first grid of ``voxels`` ``[B, G, G, G]`` that holds
    a value other than 0 or 1 (``where(i)``: the shard, row and object of batch sample ``i``),
    or None when all are 0/1."""
    if voxels.dtype == bool or voxels.size == 0 or (voxels.max() <= 1 and voxels.min() >= 0):
        return None
    flat = voxels.reshape(len(voxels), -1)
    i = int(np.flatnonzero(((flat > 1) | (flat < 0)).any(axis=1))[0])
    value = flat[i][(flat[i] > 1) | (flat[i] < 0)][0]
    return (f"{where(i)}: 'voxels' holds {value}, not 0 or 1 (a damaged or hand-edited shard); "
            "see `sc3d-data info --verify`")


def nonfinite_summary(summaries) -> str | None:
    """One line naming the shard whose first view's ``K`` or whose ``distance`` values (the
    dataset ``info`` that ``fit`` copies into the run's config and ``eval`` compares with) are
    not finite, or None: without it a NaN there failed as "intrinsics must be a 3x3 list of
    finite numbers", naming no file."""
    for sm in summaries:
        for name, values in (("K", np.asarray(sm.K)), ("distance", np.asarray(sm.distances))):
            if not np.isfinite(values).all():
                return (f"{sm.path}: '{name}' holds {values[~np.isfinite(values)].ravel()[0]}, not a finite number "
                        "(a damaged or hand-edited shard); see `sc3d-data info --verify`")
    return None
