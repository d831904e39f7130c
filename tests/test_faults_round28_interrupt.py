"""Defects found by the twenty-eighth attack on interruptions (2026-12-07): a run stopped between
two of the files one step writes, then resumed. Each test fails without its fix; real runs of the
tiny model on the bundled sample meshes. The stop is reproduced without a kill: a folder at a
temporary name makes that write fail, or the file a kill would not have written is cut back."""
from __future__ import annotations

import csv

from sc3d_cli.train import main
from sc3d_train.loop.checkpoint import load_checkpoint
from tests.conftest import run_cli
from tests.test_train import TINY


def test_a_finished_resume_from_a_newer_step_file_brings_last_pt_up_to_it(sample_shards, tmp_path):
    """A run stopped after its last step's ``step_XXXXXX.pt`` and before the ``last.pt`` copy (a
    kill, a full disk) is resumed from the step file ('resuming from step_000004.pt: last.pt is
    older'), which finishes it: 'nothing to train', exit 0, and ``last.pt`` stayed the older
    step. ``eval RUN`` (no best.pt: validation off), ``eval --pick last``, ``predict`` and
    ``claims --pick last`` then read the weights of step 2 as the finished run's. Now the resume
    makes ``last.pt`` the copy of the step file it continues from."""
    out = tmp_path / "run"
    args = ["fit", "--shards", sample_shards, "--out", out, "--batch-size", 2, *TINY, "--checkpoint-every", 2,
            "--val-every", 0]
    run_cli(main, [*args, "--steps", 2])
    blocker = out / "checkpoints" / "last.pt.tmp"
    blocker.mkdir()
    res = run_cli(main, [*args, "--steps", 4, "--resume"], expect_exit=1)
    assert "last.pt: cannot write checkpoint" in res.output and "step_000004.pt is complete" in res.output
    blocker.rmdir()
    res = run_cli(main, ["fit", "--out", out, "--resume", "--steps", 4, "--no-progress"])
    assert "resuming from" in res.output and "step_000004.pt" in res.output
    assert load_checkpoint(out / "checkpoints" / "last.pt")["step"] == 4
    assert not (out / "checkpoints" / "last.pt.tmp").exists()


def test_a_validation_revalidated_on_resume_keeps_its_best_mark(sample_shards, tmp_path):
    """A step saves its checkpoint, validates, writes ``best.pt``, then appends its row to
    ``validation.csv``; a run stopped between the last two (a kill, Ctrl-C) is validated again on
    ``--resume``, and the kept ``best.pt`` of that very step was the best to beat: the same
    score is no improvement, so the row said ``best`` 0 and no row of ``validation.csv`` named the
    ``best.pt`` the run kept (``curves.png`` drew no best.pt line, or an earlier step's). Now the
    row of the step ``best.pt`` holds says 1."""
    out = tmp_path / "run"
    args = ["fit", "--shards", sample_shards, "--out", out, "--batch-size", 2, *TINY, "--steps", 2,
            "--checkpoint-every", 2, "--val-every", 2, "--val-min-objects", 1]
    run_cli(main, args)
    val = out / "validation.csv"
    assert [r["best"] for r in csv.DictReader(val.open())] == ["1"]
    val.write_text(val.read_text().splitlines(keepends=True)[0])  # what a kill before the row leaves
    assert load_checkpoint(out / "checkpoints" / "best.pt")["step"] == 2
    res = run_cli(main, ["fit", "--out", out, "--resume", "--no-progress"])
    assert "validated that step" in res.output
    assert [(r["step"], r["best"]) for r in csv.DictReader(val.open())] == [("2", "1")]
    assert load_checkpoint(out / "checkpoints" / "best.pt")["step"] == 2
