"""fit's validation split and best.pt: figures equal eval's on the same objects, best.pt is the
best row, validation neither trains on nor disturbs anything, resume keeps the best, and eval
reads best.pt from a run folder unless told --pick last."""
from __future__ import annotations

import csv

import pytest
import torch

from sc3d_cli.train import main
from tests.conftest import run_cli

TINY = ["--tiny", "--base-channels", "4", "--batch-size", "4", "--lr", "1e-3", "--lr-schedule", "constant",
        "--no-progress", "--device", "cpu"]


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_validation_picks_best_and_leaves_training_alone(sample_shards, tmp_path):
    from sc3d_train.loop.checkpoint import load_checkpoint
    from sc3d_train.data.dataset import ShardDataset
    from sc3d_train.evaluation.evaluate import evaluate
    from sc3d_train.loop.validation import view_indices

    assert view_indices(2, 24, 4) == [0, 6, 12, 18, 24, 30, 36, 42]
    val = tmp_path / "val"  # validated every step, interrupted after 4 steps and resumed to 8
    run_cli(main, ["fit", "--shards", sample_shards, "--out", val, "--steps", 4, *TINY, "--val-every", 1,
                   "--val-views", 24, "--val-min-objects", 1, "--checkpoint-every", 4, "--log-every", 1])
    first_best = load_checkpoint(val / "checkpoints" / "best.pt")["validation"]
    run_cli(main, ["fit", "--out", val, "--steps", 8, "--resume", "--no-progress"])
    plain = tmp_path / "plain"  # no validation at all
    run_cli(main, ["fit", "--shards", sample_shards, "--out", plain, "--steps", 8, *TINY, "--val-every", 0,
                   "--checkpoint-every", 8, "--log-every", 1])
    assert not (plain / "checkpoints" / "best.pt").exists() and not (plain / "validation.csv").exists()
    # the trajectory does not depend on validation (its RNG draws are undone), across the resume too
    assert [r["total"] for r in read_csv(val / "metrics.csv")] == [r["total"] for r in read_csv(plain / "metrics.csv")]

    rows = read_csv(val / "validation.csv")
    assert [int(r["step"]) for r in rows] == list(range(1, 9))
    scores = [float(r["val_score"]) for r in rows]
    assert scores == pytest.approx([float(r["val_iou"]) + float(r["val_rot_acc30"]) for r in rows], abs=2e-6)
    best_step = 1 + scores.index(max(scores))  # the first of equal maxima
    best = load_checkpoint(val / "checkpoints" / "best.pt")
    assert best["step"] == best_step == best["validation"]["step"]
    assert [int(r["best"]) for r in rows] == [int(s > max(scores[:i], default=-1)) for i, s in enumerate(scores)]
    assert best["validation"]["val_score"] >= first_best["val_score"]  # resume kept the best to beat

    # the validation objects are the val split, disjoint from the objects trained on
    trained = {o.model_id for o in ShardDataset(sample_shards, "train").objects}
    validated = {o.model_id for o in ShardDataset(sample_shards, "val").objects}
    assert validated and not trained & validated

    # eval of the run folder reads best.pt; its figures on all 24 views of the val objects are the
    # validation row of that step (eval's own loader, not validation's batches)
    res = evaluate(val, sample_shards, "val", tmp_path / "ev", "cpu", examples=0)
    assert res["checkpoint"].endswith("best.pt") and res["step"] == best_step
    row = rows[best_step - 1]
    assert res["mean"]["voxel_iou_0.4"] == pytest.approx(float(row["val_iou"]), abs=1e-5)
    assert res["mean"]["pose_rotation_acc30"] == pytest.approx(float(row["val_rot_acc30"]), abs=1e-5)
    assert res["mean"]["pose_rotation_median"] == pytest.approx(float(row["val_rot_median"]), abs=1e-4)
    last = run_cli(main, ["eval", "--checkpoint", val, "--shards", sample_shards, "--split", "val", "--pick", "last",
                          "--examples", 0, "--device", "cpu", "--out", tmp_path / "ev_last"])
    assert "last.pt (step 8)" in last.output
    weights = [load_checkpoint(val / "checkpoints" / f)["model"] for f in ("best.pt", "last.pt")]
    assert best_step == 8 or any(not torch.equal(weights[0][k], weights[1][k]) for k in weights[0])
    assert (val / "curves.png").stat().st_size > 10_000
    resumed = run_cli(main, ["fit", "--out", val, "--steps", 9, "--resume", "--no-progress"])
    assert "best on 'val' (iou+pose): step " in resumed.output


def test_too_few_val_objects_log_figures_but_keep_no_best(sample_shards, tmp_path):
    """The sample shards hold 2 val objects (< the default --val-min-objects 5): fit still writes
    the validation rows, marks none best, keeps no best.pt, says so, and eval of the run folder
    reads last.pt."""
    from sc3d_train.data.dataset import ShardDataset

    assert ShardDataset(sample_shards, "val").num_objects == 2
    run = tmp_path / "run"
    out = run_cli(main, ["fit", "--shards", sample_shards, "--out", run, "--steps", 2, *TINY, "--val-every", 1,
                         "--checkpoint-every", 2])
    assert "only 2 'val' object(s)" in out.output and "no best.pt (eval reads last.pt)" in out.output
    assert "best on" not in out.output
    rows = read_csv(run / "validation.csv")
    assert [int(r["step"]) for r in rows] == [1, 2] and all(r["best"] == "0" for r in rows)
    assert not (run / "checkpoints" / "best.pt").exists()
    ev = run_cli(main, ["eval", "--checkpoint", run, "--shards", sample_shards, "--split", "val", "--examples", 0,
                        "--device", "cpu", "--out", tmp_path / "ev"])
    assert "last.pt (step 2)" in ev.output


def test_validation_refuses_the_training_and_test_splits(sample_shards, tmp_path):
    for split in ("train", "test"):
        r = run_cli(main, ["fit", "--shards", sample_shards, "--out", tmp_path / split, "--steps", 1, *TINY,
                           "--val-split", split], expect_exit=1)
        assert "never trained on" in r.output and "--val-every 0" in r.output


def test_semi_keeps_best_from_its_mixed_phase_only(sample_shards, tmp_path):
    """A semi run validates during pretraining (rows logged) but best.pt comes from the mixed
    phase: with 4 pretraining steps of 6, validated every step, rows 1-4 are never best (the
    first row would be best under any rule that looks at scores alone) and best.pt's step is 5 or 6."""
    from sc3d_train.loop.checkpoint import load_checkpoint

    run = tmp_path / "semi"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", run, "--steps", 6, *TINY, "--semi", "--pretrain-steps", 4,
                   "--labeled-fraction", 0.5, "--val-every", 1, "--val-min-objects", 1, "--checkpoint-every", 6])
    rows = read_csv(run / "validation.csv")
    assert [int(r["step"]) for r in rows] == list(range(1, 7))
    assert [r["best"] for r in rows[:4]] == ["0"] * 4 and rows[4]["best"] == "1"
    scores = [float(r["val_score"]) for r in rows[4:]]
    best = load_checkpoint(run / "checkpoints" / "best.pt")
    assert best["step"] == 5 + scores.index(max(scores))
