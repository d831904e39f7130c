"""Hostile inputs to `sc3d-train fit`, round eight: a new run into a folder that holds the user's
own files named like the ones a run writes. Real CLI, real tiny runs; expected outcomes are
stated by hand."""
from __future__ import annotations

import shutil

from conftest import run_cli, error_lines

QUICK = ["--tiny", "--steps", "2", "--batch-size", "2", "--val-every", "0", "--no-progress"]


def test_a_new_run_never_overwrites_files_that_are_not_of_a_run(sample_shards, tmp_path):
    """A new ``fit`` into a folder without checkpoints replaced whatever ``config.yaml``,
    ``metrics.csv`` and ``curves.png`` it held (``--out .`` in a project folder: the user's own
    config gone). It now refuses in one line naming them, and leaves them as they were; the
    leftovers of a run stopped before its first checkpoint (its own config.yaml) are still
    replaced by rerunning its command."""
    from sc3d_cli.train import main as train_main

    mine = tmp_path / "project"
    mine.mkdir()
    files = {"config.yaml": "my: precious\n", "metrics.csv": "a,b\n1,2\n", "curves.png": "not a picture\n"}
    for name, text in files.items():
        (mine / name).write_text(text)
    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", mine, *QUICK], expect_exit=1)
    errors = error_lines(res.output)
    assert errors == [f"Error: {mine}: holds config.yaml, metrics.csv, curves.png, not from an sc3d-train run, "
                      "which a new run would overwrite; choose another --out (or move them)"], res.output
    assert {name: (mine / name).read_text() for name in files} == files
    (mine / "config.yaml").unlink()  # a metrics.csv alone is the user's too
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", mine, *QUICK], expect_exit=1)
    assert (mine / "metrics.csv").read_text() == files["metrics.csv"]

    stopped = tmp_path / "stopped"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", stopped, *QUICK])
    shutil.rmtree(stopped / "checkpoints")  # as if killed before its first checkpoint
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", stopped, *QUICK])
    assert (stopped / "checkpoints" / "last.pt").is_file()


def test_resume_of_a_run_stopped_before_its_first_checkpoint_says_to_start_it_again(sample_shards, tmp_path):
    """``fit --resume`` of a run killed before its first checkpoint said only "checkpoints/last.pt:
    checkpoint not found"; it now says what to do, and doing it works."""
    from sc3d_cli.train import main as train_main

    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, *QUICK])
    shutil.rmtree(run / "checkpoints")  # as if killed before its first checkpoint
    res = run_cli(train_main, ["fit", "--out", run, "--resume", "--no-progress"], expect_exit=1)
    assert "the run stopped before its first checkpoint: start it again without --resume" in res.output
    run_cli(train_main, ["fit", "--config", run / "config.yaml", "--out", run, "--no-progress"])
    assert (run / "checkpoints" / "last.pt").is_file()
