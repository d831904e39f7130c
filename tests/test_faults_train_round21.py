"""Training-half defects of the twenty-first attack round, with the real trainer and evaluator on
the sample shards; expected outcomes are files left as they were and one-line refusals, checked
by reading the files back."""
from __future__ import annotations

import json
import os
from pathlib import Path

from sc3d_cli.train import main as train_main
from conftest import one_error, run_cli


def test_eval_out_replaces_no_file_of_someone_else(trained_run, sample_shards, tmp_path):
    """``eval --out DIR`` replaced ``DIR/metrics.json`` and ``DIR/predictions.png`` whatever they
    were (another experiment's results, a picture; ``--examples 0`` just deleted it), exit 0.
    Now a ``metrics.json`` that eval did not write, or a ``predictions.png`` without an
    evaluation's ``metrics.json`` beside it that eval did not draw, is refused in one line and left
    as it was; an earlier evaluation in the folder is replaced, also one cut short before its
    ``metrics.json`` (the controls)."""
    args = ["eval", "--checkpoint", trained_run, "--shards", sample_shards, "--examples", 0, "--device", "cpu"]
    foreign = tmp_path / "foreign_metrics"
    foreign.mkdir()
    (foreign / "metrics.json").write_text('{"my": "results of another experiment"}')
    picture = tmp_path / "foreign_picture"
    picture.mkdir()
    (picture / "predictions.png").write_bytes(b"my picture")
    for folder, name in ((foreign, "metrics.json"), (picture, "predictions.png")):
        before = (folder / name).read_bytes()
        error = one_error(run_cli(train_main, [*args, "--out", folder], expect_exit=1).output)
        assert f"--out {folder}: {name} exists and is not" in error and "choose another --out" in error, error
        assert (folder / name).read_bytes() == before and sorted(p.name for p in folder.iterdir()) == [name]
    ours = tmp_path / "ours"
    run_cli(train_main, [*args, "--out", ours])
    first = json.loads((ours / "metrics.json").read_text())
    run_cli(train_main, [*args, "--out", ours])  # its own evaluation: replaced
    assert json.loads((ours / "metrics.json").read_text())["checkpoint"] == first["checkpoint"]
    cut = tmp_path / "cut_short"  # an evaluation stopped between its picture and metrics.json (claims redoes it)
    run_cli(train_main, [*args[:-4], "--examples", 1, "--device", "cpu", "--out", cut])
    (cut / "metrics.json").unlink()
    run_cli(train_main, [*args[:-4], "--examples", 1, "--device", "cpu", "--out", cut])
    assert (cut / "metrics.json").is_file() and (cut / "predictions.png").is_file()


def test_eval_split_that_is_a_path_is_refused_before_any_folder_is_made(trained_run, sample_shards, tmp_path):
    """``eval --split ../../x`` named the default output folder ``RUN/eval_../../x``, made it (a
    folder outside the run) and then failed on a lock file path. A split is a name: refused in
    one line, nothing made."""
    split = f"../../../escape_{tmp_path.name}"
    made = Path(os.path.abspath(trained_run / f"eval_{split}"))  # the folder it made: beside the run's folder
    result = run_cli(train_main, ["eval", "--checkpoint", trained_run, "--shards", sample_shards, "--split", split,
                                  "--device", "cpu"], expect_exit=1)
    assert one_error(result.output) == (f"Error: --split {split!r}: a split is a name in the shards (train, val, "
                                        "test), not a path")
    assert made.parent == trained_run.parent and not made.exists()


def test_a_config_file_is_checked_with_the_options_that_override_it(sample_shards, tmp_path):
    """Later wins (docs/config.md): a ``--config`` file's settings with the options that override
    them. The file was checked alone first, so a file of ``split: val`` with ``--val-every 0``
    (what its own error advised) or ``--val-split train``, one of ``val_split: train`` with
    ``--split val``, and one of ``mode: semi, pretrain_steps: 2500`` with ``--steps 3000`` were
    refused, though the same settings as options were accepted. Each must resolve to what the
    options say; the file alone is still refused, naming it."""
    import pytest

    from sc3d_train.loop.resolve import resolve_config

    cases = [("split: val\n", {"val_every": 0}), ("split: val\n", {"val_split": "train"}),
             ("val_split: train\n", {"split": "val"}), ("mode: semi\npretrain_steps: 2500\n", {"steps": 3000})]
    for n, (text, options) in enumerate(cases):
        config = tmp_path / f"c{n}.yaml"
        config.write_text(text)
        cfg = resolve_config({"shards": str(sample_shards), "out": str(tmp_path / f"run{n}"), **options},
                             {"tiny": True}, config_file=config)
        assert all(getattr(cfg, k) == v for k, v in options.items()), (text, options)
        if "pretrain_steps" in text:
            assert cfg.mode == "semi" and cfg.pretrain_steps == 2500
        with pytest.raises(ValueError, match=str(config)):  # the file alone: its settings contradict each other
            resolve_config({"shards": str(sample_shards), "out": str(tmp_path / f"alone{n}")}, {"tiny": True},
                           config_file=config)


def test_a_resumed_run_with_a_damaged_log_cell_finishes(trained_run, tmp_path):
    """A log cell that is no number (a hand-edited ``validation.csv``, an empty ``samples_per_s``
    in ``metrics.csv``) stopped a resumed run with "could not convert string to float: 'oops'",
    naming no file: at its start (the resumed step's validation row, re-sent to TensorBoard), or
    after training every step, while drawing ``curves.png`` (exit 1). The run must finish (exit 0)
    with its curves drawn, the damaged points left out."""
    import csv
    import shutil

    run = tmp_path / "run"
    shutil.copytree(trained_run, run)
    steps = _last_step(run)
    for name, key, value in (("validation.csv", "val_iou", "oops"), ("metrics.csv", "samples_per_s", "")):
        with open(run / name, newline="") as f:
            rows = list(csv.DictReader(f))
        rows[0][key] = rows[-1][key] = value  # an earlier row and the resumed step's
        with open(run / name, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    (run / "curves.png").unlink()
    run_cli(train_main, ["fit", "--out", run, "--resume", "--steps", steps + 2, "--no-progress"])
    assert (run / "curves.png").stat().st_size > 0


def _last_step(run) -> int:
    """The step of ``run``'s ``last.pt``, from its ``metrics.csv``'s last row (0-based step + 1)."""
    import csv

    with open(run / "metrics.csv", newline="") as f:
        return int(list(csv.DictReader(f))[-1]["step"]) + 1


def test_a_semi_config_file_with_other_steps_or_another_mode_trains(sample_shards, tmp_path):
    """Two uses of a semi run's own ``config.yaml`` (``steps: 5000, pretrain_steps: 2500``, the
    default half) that the check of a file with its options must not refuse: ``fit --config
    FILE --steps 2`` with the run folder named by the file (no ``--out``: the command reads it
    from the file), whose pretraining follows the new steps (1, docs/config.md), and, with
    ``pretrain_steps: 2400`` (chosen, not the default), ``--labeled-only --steps 2``, whose mode
    does not read the file's pretraining (it was checked against the 2 steps, and refused)."""
    for n, (pretrain, extra) in enumerate(((2500, []), (2400, ["--labeled-only"]))):
        config = tmp_path / f"semi{n}.yaml"
        config.write_text(f"shards: {sample_shards}\nout: {tmp_path / f'run{n}'}\nmode: semi\nsteps: 5000\n"
                          f"pretrain_steps: {pretrain}\nval_every: 0\n")
        run_cli(train_main, ["fit", "--config", config, "--steps", 2, *extra, "--tiny", "--base-channels", 4,
                             "--batch-size", 4, "--no-progress"])
        saved = (tmp_path / f"run{n}" / "config.yaml").read_text()
        assert "steps: 2\n" in saved and ("pretrain_steps: 1\n" in saved if not extra else "labeled-only" in saved)
