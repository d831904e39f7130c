"""The reference rows of ``claims`` (sc3d_train.evaluation.shape_baselines): the category mean
shape and the nearest training shape, checked on a hand-derived case and, on the real sample
shards, against a per-pair loop over the objects read through the training dataset."""
from __future__ import annotations

import numpy as np
import pytest

from sc3d_train.data.dataset import DataError, ShardDataset
from sc3d_train.evaluation.shape_baselines import baselines_of, iou_matrix, shape_baselines


def grids(*occupied: set[int]) -> np.ndarray:
    """``[N, 2, 2, 2]`` bool grids, grid i occupied at the flat indices ``occupied[i]``."""
    out = np.zeros((len(occupied), 8), dtype=bool)
    for i, cells in enumerate(occupied):
        out[i, list(cells)] = True
    return out.reshape(-1, 2, 2, 2)


def test_mean_and_nearest_shape_on_a_hand_derived_case():
    # category a: 5 training grids; cell frequencies 4/5, 2/5, 1/5, 2/5 -> prior at >= 0.4: {0, 1, 3}
    train = {"a": grids({0}, {0, 1}, {0, 1, 2}, {3}, {0, 3}), "b": grids(set(range(8)))}
    held_out = {"a": grids({0, 1}, {2, 3}), "b": grids({0}), "c": grids({5})}  # c: no training objects
    r = baselines_of(train, held_out)
    # a: mean shape {0,1,3}: IoU 2/3 and 1/4; nearest: {0,1} itself (1) and {3} for {2,3} (1/2)
    # b: the full grid against one cell: 1/8 for both rows; c is left out
    assert r["mean-shape"]["per_category"]["a"]["voxel_iou_0.4"] == pytest.approx((2 / 3 + 1 / 4) / 2)
    assert r["nearest-shape"]["per_category"]["a"]["voxel_iou_0.4"] == pytest.approx(3 / 4)
    assert r["mean-shape"]["per_category"]["b"]["voxel_iou_0.4"] == pytest.approx(1 / 8)
    assert set(r["mean-shape"]["per_category"]) == {"a", "b"}
    # no mean over a and b beside the runs' means over a, b and c: none, c named as left out
    assert r["mean-shape"]["mean"]["voxel_iou_0.4"] is None and r["mean-shape"]["left_out"] == ["c"]
    r = baselines_of(train, {k: held_out[k] for k in ("a", "b")})
    assert r["mean-shape"]["mean"]["voxel_iou_0.4"] == pytest.approx(7 / 24)
    assert r["nearest-shape"]["mean"]["voxel_iou_0.4"] == pytest.approx(7 / 16)
    # negative control: a prior thresholded with > instead of >= (cells at exactly 0.4 dropped)
    # would give {0} and IoU 1/2 for {0,1}; 0.5 as the threshold gives that
    strict = baselines_of(train, {"a": grids({0, 1})}, threshold=0.5)
    assert strict["mean-shape"]["per_category"]["a"]["voxel_iou_0.5"] == pytest.approx(1 / 2)
    with pytest.raises(DataError, match="no held-out category"):
        baselines_of(train, {"c": grids({5})})


def test_iou_matrix_of_empty_grids_is_one():
    m = iou_matrix(grids(set(), {1}), grids(set(), {1, 2}))
    assert m.tolist() == [[1.0, 0.0], [0.0, 0.5]]


def test_baselines_on_the_sample_shards_match_a_per_pair_loop(sample_shards):
    """Independent path: voxels read by the training dataset, IoU pair by pair in Python."""
    def voxels(split):
        d = ShardDataset(sample_shards, split=split)
        by_cat = {}
        for i, ref in enumerate(d.objects):
            by_cat.setdefault(ref.category, []).append(d.object_arrays(i)["voxels"].astype(bool))
        return by_cat

    def iou(a, b):
        return (a & b).sum() / (a | b).sum()

    train, test = voxels("train"), voxels("test")
    r = shape_baselines(sample_shards, sample_shards, "test")
    cats = [c for c in test if c in train]
    assert cats and set(r["nearest-shape"]["per_category"]) == set(cats)
    for c in cats:
        prior = np.mean(train[c], axis=0) >= 0.4
        assert r["mean-shape"]["per_category"][c]["voxel_iou_0.4"] == pytest.approx(
            np.mean([iou(v, prior) for v in test[c]]))
        assert r["nearest-shape"]["per_category"][c]["voxel_iou_0.4"] == pytest.approx(
            np.mean([max(iou(v, t) for t in train[c]) for v in test[c]]))
    with pytest.raises(DataError, match="'nope' is empty"):
        shape_baselines(sample_shards, sample_shards, "nope")
