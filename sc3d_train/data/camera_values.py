"""Checks of the camera and pose values a split is trained and evaluated with (read once per
split by ``ShardDataset._read_cameras``): a NaN or infinity in ``K``, ``R``, ``t``, ``distance``,
``azimuth`` or ``elevation`` of one view (a hand edit, a bad import, a disk that returned wrong
bytes behind an unchanged checksum) would be trained on, or scored by ``eval``, without a word,
since the shard layout check (``sc3d_data.io.shard_layout``) reads metadata only. The values
are small (~2.3 KB per object), so checking them all costs nothing next to reading them.
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
