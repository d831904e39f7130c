"""Defects of the training half found by the twelfth attack on the commands (2026-11-28), each
test failing without its fix: the claims reference rows' Mean over fewer categories than the
runs'; a run's own ``config.yaml`` rerun with another ``--steps`` keeping its old pretraining;
``--resume`` of a semi run below its pretraining answering with a number the user never wrote;
``--resume`` on shards whose validation split changed; validation rows of steps trained again
kept with ``--val-every 0``; a huge ``--log-every`` allocating its loss window up front;
``claims --runs ""`` training every run; eval's note sending the user to the split it evaluates.
Real runs of the tiny model on the bundled sample meshes."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sc3d_cli.data import main as data_main
from sc3d_cli.train import main
from tests.conftest import SAMPLE_MESHES, run_cli
from tests.test_train import TINY, interrupt_at, read_csv


# ----------------------------------------------------------------------------- claims' reference rows
def test_reference_rows_have_no_mean_when_a_category_has_no_training_objects():
    """Held-out categories a and b, training objects of a only (by hand: a's training grid
    equals its held-out one, IoU 1): the references keep a's 1.0, leave b out, and have no Mean
    (the runs' Mean is over a and b); the report says so. Before: Mean 1.0, over a alone."""
    from sc3d_train.evaluation.claims_report import format_report
    from sc3d_train.evaluation.shape_baselines import baselines_of

    grid = np.zeros((1, 4, 4, 4), bool)
    grid[0, 1:3, 1:3, 1:3] = True
    refs = baselines_of({"a": grid}, {"a": grid, "b": grid})
    for block in refs.values():
        assert block["per_category"] == {"a": {"voxel_iou_0.4": 1.0}}
        assert block["mean"] == {"voxel_iou_0.4": None} and block["left_out"] == ["b"]
    run = {"per_category": {"a": {"voxel_iou_0.4": 0.5}, "b": {"voxel_iou_0.4": 0.3}}, "mean": {"voxel_iou_0.4": 0.4},
           "overall": {}}
    report = format_report({"sup-3tube": run, **refs})
    assert "| *reference:* category mean shape (no image) | 100.0 | - | - |" in report
    assert "The reference rows have no figure for b" in report and "over all 2 categories" in report
    assert baselines_of({"a": grid, "b": grid}, {"a": grid, "b": grid})["mean-shape"]["mean"] == {"voxel_iou_0.4": 1.0}


# ----------------------------------------------------------------------------- pretraining and --steps
def test_a_runs_own_config_with_another_steps_pretrains_half_of_them(sample_shards, tmp_path):
    """A semi run's ``config.yaml`` (20 steps: it records pretrain_steps 10, the default's value)
    rerun with ``--steps 100`` pretrains 50, as ``--semi --steps 100`` does, and with ``--steps
    8`` 4 (before: 10 of 100, and 8 refused for a pretraining of 10 never written); a
    ``pretrain_steps`` the user chose (3) is kept."""
    from sc3d_train.loop.resolve import resolve_config

    run = resolve_config({"shards": str(sample_shards), "out": str(tmp_path / "a"), "mode": "semi", "steps": 20}, {})
    assert run.pretrain_steps == 10
    run.save(tmp_path / "run.yaml")
    for steps, want in ((100, 50), (8, 4), (20, 10)):
        cfg = resolve_config({"out": str(tmp_path / "b"), "steps": steps}, {}, config_file=tmp_path / "run.yaml")
        assert cfg.pretrain_steps == want, steps
    run.pretrain_steps = 3
    run.save(tmp_path / "chosen.yaml")
    cfg = resolve_config({"out": str(tmp_path / "c"), "steps": 100}, {}, config_file=tmp_path / "chosen.yaml")
    assert cfg.pretrain_steps == 3


def test_resume_of_a_semi_run_below_its_pretraining_says_so(sample_shards, tmp_path):
    """A 4-step semi run (2 steps of pretraining) resumed with ``--steps 1``: one line saying
    that --steps ends inside its pretraining, which --resume cannot shorten. Before: "pretrain
    steps 2 not in [0, steps=1]"."""
    run = tmp_path / "semi"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", run, "--semi", "--steps", "4", "--batch-size", "4",
                   *TINY, "--val-every", "0"])
    result = run_cli(main, ["fit", "--out", run, "--resume", "--steps", "1"], expect_exit=1)
    assert (f"{run}: --steps 1 ends inside this semi run's pretraining (2 steps), which --resume cannot shorten"
            in result.output), result.output
    assert "not in [0, steps=1]" not in result.output


# ----------------------------------------------------------------------------- the validation split on resume
TRAIN = ["b767_lowpoly_fgai", "c182_fgai", "centrair101_glider_fgai", "f16_lowpoly_fgai", "jeep_psionic",
         "peugeot_308cc_scopia", "chair2_blendswap"]


@pytest.fixture(scope="module")
def two_validation_splits(tmp_path_factory) -> tuple[Path, Path]:
    """The sample meshes rendered twice with the same training objects: in A two chairs are
    validation objects and a chair and the table test objects, in B the other way round."""
    from sc3d_data.formats.shapenet import resolve_category

    root = tmp_path_factory.mktemp("two_val")
    category = {p.stem: resolve_category(p.parent.name) for p in Path(SAMPLE_MESHES).glob("*/*.glb")}
    chairs, others = ["dining_chair_katorlegaz", "rattan_armchair_scopia"], ["silla_blanca_blendswap",
                                                                             "coffee_table_blendswap_ccby"]
    out = []
    for name, val, test in (("A", chairs, others), ("B", others, chairs)):
        lines = [f"{split} {category[m]}/{m}" for split, ms in (("train", TRAIN), ("val", val), ("test", test))
                 for m in ms]
        (root / f"{name}.txt").write_text("\n".join(lines) + "\n")
        run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", root / name, "--voxelize", "--views", "4",
                            "--no-progress", "--workers", "2", "--split-file", root / f"{name}.txt"])
        out.append(root / name)
    return out[0], out[1]


def test_resume_refuses_shards_whose_validation_objects_changed(two_validation_splits, tmp_path):
    """A run validating on A's split resumed on B (same training objects, other validation
    objects) is refused in one line naming the validation split; with ``--val-every 0`` (no
    validation from there) it goes on. Before: accepted, and best.pt was chosen by comparing
    scores measured on other objects."""
    a, b = two_validation_splits
    run = tmp_path / "run"
    run_cli(main, ["fit", "--shards", a, "--out", run, "--steps", "2", "--batch-size", "4", *TINY,
                   "--checkpoint-every", "1", "--val-every", "1", "--val-views", "1", "--val-min-objects", "1"])
    result = run_cli(main, ["fit", "--out", run, "--resume", "--shards", b, "--steps", "3"], expect_exit=1)
    assert f"{b}: the shards changed since run {run} started (the objects of split 'val')" in result.output
    run_cli(main, ["fit", "--out", run, "--resume", "--shards", b, "--steps", "3", "--val-every", "0"])
    assert [r["step"] for r in read_csv(run / "metrics.csv")] == ["0", "1", "2"]


def test_eval_note_on_the_test_split_does_not_send_the_user_to_the_test_split(two_validation_splits, tmp_path):
    """best.pt chosen on A's validation chairs, evaluated on B's test split (those chairs): the
    note says the figures are optimistic and does not advise evaluating on --split test.
    Before: "...; evaluate on --split test or with --pick last"."""
    a, b = two_validation_splits
    run = tmp_path / "run"
    run_cli(main, ["fit", "--shards", a, "--out", run, "--steps", "2", "--batch-size", "4", *TINY,
                   "--checkpoint-every", "1", "--val-every", "1", "--val-views", "1", "--val-min-objects", "1"])
    result = run_cli(main, ["eval", "--checkpoint", run, "--shards", b, "--split", "test", "--examples", "0",
                            "--out", tmp_path / "eval"])
    assert "these figures are optimistic; evaluate on objects it was not chosen on, or with --pick last" \
        in result.output, result.output
    assert "evaluate on --split test" not in result.output


# ----------------------------------------------------------------------------- validation rows, loss window, claims
def test_resume_with_validation_off_drops_the_rows_of_steps_trained_again(sample_shards, tmp_path):
    """A 4-step run validated at steps 2 and 4, resumed from step 2 with ``--val-every 0``: its
    validation.csv keeps step 2's row only (step 4's was of weights the resumed run replaced).
    Before: the row of step 4 stayed."""
    run, parts = tmp_path / "run", tmp_path / "parts"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", run, "--steps", "4", "--batch-size", "4", *TINY,
                   "--checkpoint-every", "2", "--val-every", "2", "--val-views", "1", "--val-min-objects", "1"])
    assert [r["step"] for r in read_csv(run / "validation.csv")] == ["2", "4"]
    interrupt_at(run, parts, 2)
    run_cli(main, ["fit", "--out", parts, "--resume", "--steps", "4", "--val-every", "0"])
    assert [r["step"] for r in read_csv(parts / "validation.csv")] == ["2"]


def test_a_huge_log_every_costs_no_memory(sample_shards, tmp_path):
    """``--log-every 10**11`` ("log at the end only") on a 2-step run trains and logs the last
    step. Before: the loss window was allocated for 10**11 steps (400 GB) and the run died with
    a traceback."""
    out = tmp_path / "run"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", out, "--steps", "2", "--batch-size", "4",
                   "--tiny", "--base-channels", "4", "--no-progress", "--log-every", str(10**11), "--val-every", "0"])
    assert [r["step"] for r in read_csv(out / "metrics.csv")] == ["1"]


def test_claims_refuses_an_empty_runs_value(sample_shards, tmp_path):
    """``claims --runs ""`` (an unset variable) is refused in one line, nothing created. Before:
    every run of the study was trained (hours on a CPU)."""
    from sc3d_cli.train import main as train_main

    result = run_cli(train_main, ["claims", "--train-shards", sample_shards, "--eval-shards", sample_shards,
                                  "--out", tmp_path / "study", "--runs", ""], expect_exit=2)
    assert "--runs '' names no run" in result.output
    assert not (tmp_path / "study").exists()
