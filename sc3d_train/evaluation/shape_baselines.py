"""Two reference rows for held-out voxel IoU that read no image (Tatarchenko et al., "What Do
Single-view 3D Reconstruction Networks Learn?", CVPR 2019): how much of a model's IoU a shape
prior alone explains, and how far retrieving a training shape could go.

- **mean shape**: every held-out object of category ``c`` is predicted as the occupancy
  frequency of ``c``'s training objects, ``mean_i voxels_i [G,G,G]`` in [0, 1], thresholded like
  a model's probabilities (``>= threshold``). A model at this row has learnt its categories'
  average, not the object in the image.
- **nearest training shape (oracle)**: each held-out object is matched to the training object of
  its category with the highest IoU *to its own ground truth*. No method that outputs a training
  shape can beat it; it reads the answer, so it is a bound, not a method.

Both are computed per object and averaged per category, then over categories, as
:func:`sc3d_train.paper.metrics.summarize` averages a model's per-image IoU (every view of an
object gets the same prediction here). Voxels are compared in the frame the shards store them
in (SPEC: canonical object frame), the frame the model's voxels are scored in.
"""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from sc3d_data.io.shard_reader import ShardReader
from sc3d_train.data.dataset import DataError, scan_objects

#: rows of ``a`` per matrix product in :func:`iou_matrix` (bounds its float32 copies' memory)
_CHUNK = 256


def read_voxels(shard_dir: Path, split: str) -> dict[str, np.ndarray]:
    """``{category: voxels [N, G, G, G] bool}`` of the objects of ``split`` in ``shard_dir``
    (reads the ``voxels`` dataset only)."""
    refs, info = scan_objects(shard_dir)
    if info["files_without_voxels"]:
        raise DataError(f"{info['files_without_voxels'][0]}: shard has no 'voxels' dataset")
    reader = ShardReader(shard_dir)
    by_category: dict[str, list[np.ndarray]] = defaultdict(list)
    for r in refs:
        if r.split == split:
            by_category[r.category].append(reader.read(Path(r.shard), r.row, ("voxels",))["voxels"] > 0)
    if not by_category:
        raise DataError(f"{shard_dir}: split {split!r} is empty")
    return {c: np.stack(v) for c, v in sorted(by_category.items())}


def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of every pair of boolean grids: ``a [N, ...]``, ``b [M, ...]`` -> ``[N, M]``
    (1 where both are empty)."""
    fa = a.reshape(len(a), -1).astype(np.float32)
    fb = b.reshape(len(b), -1).astype(np.float32)
    inter = np.concatenate([fa[i:i + _CHUNK] @ fb.T for i in range(0, len(fa), _CHUNK)]) if len(fa) else \
        np.zeros((0, len(fb)), np.float32)
    union = fa.sum(1)[:, None] + fb.sum(1)[None, :] - inter
    return np.where(union > 0, inter / np.maximum(union, 1), 1.0)


def _summary(per_category: dict[str, float], key: str, left_out: list[str]) -> dict:
    """The blocks of an evaluation (``per_category``, ``mean``) holding one figure ``key``; the
    mean is None (no figure) where categories are ``left_out``: a mean over fewer categories
    than the runs' would stand in the same column as theirs, not comparable."""
    return {"per_category": {c: {key: v} for c, v in per_category.items()},
            "mean": {key: None if left_out else float(np.mean(list(per_category.values())))},
            "left_out": left_out}


def baselines_of(train: dict[str, np.ndarray], held_out: dict[str, np.ndarray],
                 threshold: float = 0.4) -> dict[str, dict]:
    """``{"mean-shape": blocks, "nearest-shape": blocks}`` from ``{category: voxels [N,G,G,G]
    bool}`` of the training and held-out objects: each in the shape of an evaluation's
    ``per_category`` / ``mean`` blocks with ``voxel_iou_{threshold}``, over the held-out
    categories that have training objects (a category without them has no prior: left out, listed
    in ``left_out``, and then the blocks have no mean)."""
    key = f"voxel_iou_{threshold}"
    mean_shape, nearest = {}, {}
    for c, targets in held_out.items():
        if c not in train or not len(train[c]):
            continue
        prior = train[c].mean(axis=0) >= threshold
        mean_shape[c] = float(iou_matrix(targets, prior[None])[:, 0].mean())
        nearest[c] = float(iou_matrix(targets, train[c]).max(axis=1).mean())
    if not mean_shape:
        raise DataError("no held-out category has training objects")
    left_out = sorted(c for c in held_out if c not in mean_shape)
    return {"mean-shape": _summary(mean_shape, key, left_out), "nearest-shape": _summary(nearest, key, left_out)}


def shape_baselines(train_shards: Path, eval_shards: Path, eval_split: str = "test",
                    train_split: str = "train", threshold: float = 0.4) -> dict[str, dict]:
    """:func:`baselines_of` the ``train_split`` objects of ``train_shards`` and the
    ``eval_split`` objects of ``eval_shards`` (a ``DataError`` names the folder and split)."""
    train = read_voxels(Path(train_shards), train_split)  # its errors name the folder already
    held_out = read_voxels(Path(eval_shards), eval_split)
    try:
        return baselines_of(train, held_out, threshold)
    except DataError as e:
        raise DataError(f"{eval_shards} ({eval_split}) against {train_shards} ({train_split}): {e}") from e
