"""The fifth attack on ``sc3d-train`` (fit, eval, claims as a user runs them, in areas the earlier
rounds did not reach): one test per finding T1-Tn. Real shards (the bundled sample meshes
rendered through the CLI), real tiny training, evaluation and checkpoints; no mocks."""
from __future__ import annotations

import json
import shutil

import pytest
from conftest import error_lines


# ----------------------------------------------------------------------------- T1
def test_t1_claims_redoes_an_evaluation_that_was_cut_short(sample_shards, tmp_path):
    """``evaluate`` wrote ``metrics.json`` first (not atomically) and ``predictions.png`` after it,
    and ``claims`` took any ``eval/metrics.json`` for a finished evaluation. An evaluation whose
    picture could not be written (a full disk; here a folder where the file must go) left
    ``metrics.json`` behind, so the rerun read it back and the study never got the picture; a
    ``metrics.json`` cut short by a kill mid-write made every rerun fail on a JSON error naming no
    file. Now ``metrics.json`` is written last and atomically, and the rerun evaluates again
    whatever was cut short: the figures equal those of the uninterrupted evaluation, byte for
    byte."""
    from sc3d_train.evaluation.claims import ClaimsPreset, run_all

    preset = ClaimsPreset(steps=2, batch_size=4, lr=1e-3, tiny=True, extra={"val_every": 0, "base_channels": 4})
    out = tmp_path / "claims"
    evald = out / "runs" / "sup-3tube" / "seed-0" / "eval"

    def study(echo=None):
        run_all(sample_shards, sample_shards, out, preset, eval_split="test", device="cpu", runs=["sup-3tube"],
                echo=echo or (lambda _: None))

    study()
    whole = (evald / "metrics.json").read_bytes()  # the uninterrupted evaluation

    shutil.rmtree(evald)
    (evald / "predictions.png").mkdir(parents=True)  # the picture's write fails
    with pytest.raises(OSError):
        study()
    assert not (evald / "metrics.json").exists()
    (evald / "predictions.png").rmdir()
    lines = []
    study(lines.append)
    assert not any("done before" in ln for ln in lines), lines
    assert (evald / "predictions.png").is_file() and (evald / "metrics.json").read_bytes() == whole

    (evald / "metrics.json").write_bytes(whole[: len(whole) // 2])  # what a kill mid-write leaves
    study()
    assert (evald / "metrics.json").read_bytes() == whole
    assert json.loads((out / "claims.json").read_text())["meta"]["eval_split"] == "test"


# ----------------------------------------------------------------------------- T2
def test_t2_resume_drops_a_best_checkpoint_of_steps_it_trains_again(sample_shards, tmp_path):
    """``best.pt`` is written at each validation, the checkpoint only every ``--checkpoint-every``
    steps, so a run stopped between them (killed, or its checkpoint write failed on a full disk)
    has a ``best.pt`` of a later step than ``last.pt``. ``--resume`` kept it as the best to beat:
    resumed with ``--steps 6`` (a cosine schedule, so other weights from the resumed step on), the
    6-step run reported and kept ``best.pt`` of step 8, weights of no step of it, and ``eval RUN``
    evaluated those. Now that ``best.pt`` is removed and the best chosen again from the resumed
    step: ``best.pt`` holds the weights of a step of the resumed run (equal to that step's
    checkpoint, written with ``--checkpoint-every 1``), the step ``validation.csv`` marks best.
    An exact resume (same ``--steps``) still ends with the uninterrupted run's ``best.pt``; one
    with validation turned off (``--val-every 0``) keeps no ``best.pt`` (follow-up: before, the
    step-8 file stayed there too)."""
    import csv

    import torch

    from sc3d_cli.train import main as train_main
    from conftest import run_cli

    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, "--steps", 8, "--tiny", "--base-channels", 4,
                         "--batch-size", 4, "--no-progress", "--val-every", 1, "--val-min-objects", 1,
                         "--checkpoint-every", 4, "--lr", 0.01, "--select-by", "iou"])
    whole_best = torch.load(run / "checkpoints" / "best.pt", weights_only=False)
    assert whole_best["step"] > 4  # the precondition: a best after the checkpoint resumed from
    noval = tmp_path / "noval"  # resumed with validation off (--val-every may change on resume)
    shutil.copytree(run, noval)
    (noval / "checkpoints" / "step_000008.pt").unlink()
    shutil.copyfile(noval / "checkpoints" / "step_000004.pt", noval / "checkpoints" / "last.pt")
    run_cli(train_main, ["fit", "--out", noval, "--resume", "--steps", 6, "--val-every", 0, "--no-progress"])
    assert not (noval / "checkpoints" / "best.pt").exists()  # eval then reads last.pt, of this run
    for name, steps in (("short", 6), ("exact", 8)):
        again = tmp_path / name
        shutil.copytree(run, again)
        (again / "checkpoints" / "step_000008.pt").unlink()  # as a failed or killed checkpoint at step 8 leaves
        shutil.copyfile(again / "checkpoints" / "step_000004.pt", again / "checkpoints" / "last.pt")
        res = run_cli(train_main, ["fit", "--out", again, "--resume", "--steps", steps, "--checkpoint-every", 1,
                                   "--no-progress"])
        best = torch.load(again / "checkpoints" / "best.pt", weights_only=False)
        with open(again / "validation.csv", newline="") as f:
            marked = [int(r["step"]) for r in csv.DictReader(f) if r["best"] == "1"]
        assert best["step"] <= steps and marked[-1] == best["step"], (best["step"], marked)
        assert f"best on 'val' (iou): step {best['step']}," in res.output
        that_step = torch.load(again / "checkpoints" / f"step_{best['step']:06d}.pt", weights_only=False)
        for k, v in that_step["model"].items():
            assert torch.equal(best["model"][k], v), k
        if name == "exact":
            assert best["step"] == whole_best["step"]
            for k, v in whole_best["model"].items():
                assert torch.equal(best["model"][k], v), k


# ----------------------------------------------------------------------------- T3
def test_t3_resume_with_another_number_of_ranks_says_so(sample_shards, tmp_path):
    """A run trained under ``torchrun --nproc_per_node 2`` and resumed without torchrun (1 rank)
    was refused with ``data position {... 'samples_per_rank': 4} != {... 8}``: the per-rank batch
    differs, and the data position was compared before the number of ranks, so the message that
    names the cause (``saved with 2 ranks, now 1``) was never reached. Now the rank count is
    checked first and the line says how many ranks to resume with; the run folder is left as it
    was."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from sc3d_cli.train import main as train_main
    from conftest import run_cli

    script = Path(sys.executable).parent / "sc3d-train"
    if not script.is_file():
        pytest.skip(f"{script} not installed")
    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2", str(script),
           "fit", "--shards", str(sample_shards), "--out", str(run), "--steps", "2", "--device", "cpu", "--tiny",
           "--base-channels", "4", "--batch-size", "4", "--no-progress", "--val-every", "0"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    def files():  # the lock file records the PID of its last holder: not the run's
        return {p: p.read_bytes() for p in sorted(run.rglob("*")) if p.is_file() and p.name != ".sc3d.lock"}

    before = files()
    res = run_cli(train_main, ["fit", "--out", run, "--resume", "--steps", 4, "--device", "cpu", "--no-progress"],
                  expect_exit=1)
    line = error_lines(res.output)
    assert len(line) == 1 and res.output.rstrip().endswith(line[0]), res.output
    assert f"{run / 'checkpoints' / 'last.pt'}: saved with 2 ranks, now 1; resume with 2" in line[0]
    assert files() == before
    # on 3 ranks, which do not split its batch of 4, the line named the batch ("batch size 4 is not
    # divisible by 3 ranks") and not the ranks to resume with
    three = [*cmd[:5], "3", str(script), "fit", "--out", str(run), "--resume", "--steps", "4", "--device", "cpu",
             "--no-progress"]
    r = subprocess.run(three, capture_output=True, text=True, timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert r.returncode != 0
    assert f"Error: {run / 'checkpoints' / 'last.pt'}: saved with 2 ranks, now 3; resume with 2" in r.stderr, r.stderr[-3000:]
    assert files() == before


# ----------------------------------------------------------------------------- T4
def test_t4_tensorboard_keeps_the_validation_of_the_resumed_step(sample_shards, tmp_path):
    """A resumed run's TensorBoard writer purges the events from the resumed step on (the
    interrupted run logged them after its checkpoint); but the validation at that step ran before
    the checkpoint, is kept in ``validation.csv`` and is not run again, so ``tb/`` lost it:
    ``val/*`` of a 4-step run resumed at step 2 held step 4 alone. Now the resumed step's row is
    logged again: ``val/*`` and ``train/*`` hold the uninterrupted run's steps and values."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from sc3d_cli.train import main as train_main
    from conftest import run_cli

    def scalars(run):
        ea = EventAccumulator(str(run / "tb"))
        ea.Reload()
        return {tag: [(e.step, round(e.value, 5)) for e in ea.Scalars(tag)] for tag in ea.Tags()["scalars"]}

    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, "--steps", 4, "--tiny", "--base-channels", 4,
                         "--batch-size", 4, "--no-progress", "--log-every", 1, "--val-every", 2,
                         "--val-min-objects", 1, "--checkpoint-every", 2])
    whole = scalars(run)
    assert [s for s, _ in whole["val/iou"]] == [2, 4]
    again = tmp_path / "again"
    shutil.copytree(run, again)
    (again / "checkpoints" / "step_000004.pt").unlink()  # as a run stopped after step 2's checkpoint leaves
    shutil.copyfile(again / "checkpoints" / "step_000002.pt", again / "checkpoints" / "last.pt")
    run_cli(train_main, ["fit", "--out", again, "--resume", "--no-progress"])
    resumed = scalars(again)
    assert {t: [s for s, _ in v] for t, v in resumed.items()} == {t: [s for s, _ in v] for t, v in whole.items()}
    for tag in ("val/iou", "val/rot_median", "val/rot_acc30", "val/score", "train/total", "train/l3d"):
        assert [v for _, v in resumed[tag]] == pytest.approx([v for _, v in whole[tag]], abs=1e-5), tag


# ----------------------------------------------------------------------------- T5
def test_t5_claims_resumes_a_run_cut_short_near_where_it_stopped(sample_shards, tmp_path):
    """``claims`` says a rerun resumes a half-trained run, but it trained every run with
    ``checkpoint_every = steps``: no checkpoint before the last step, so a run stopped before it
    (killed, or its checkpoint write failed on a full disk) was trained again from step 0 (a cpu
    preset run: minutes lost per run). Here the write of the last step's checkpoint fails for
    real (a folder stands where its temporary file goes). Now a claims run checkpoints every tenth of its
    steps, and the rerun resumes from step 7 of 8: its weights and figures equal an uninterrupted
    study's; the finished run keeps ``last.pt`` and drops the intermediate ``step_*.pt``."""
    import torch

    from sc3d_train.evaluation.claims import ClaimsPreset, run_all
    from sc3d_train.loop.checkpoint import CheckpointError

    preset = ClaimsPreset(steps=8, batch_size=4, lr=1e-3, tiny=True, extra={"val_every": 0, "base_channels": 4})

    def study(out, echo=None):
        return run_all(sample_shards, sample_shards, out, preset, eval_split="test", device="cpu",
                       runs=["sup-3tube"], echo=echo or (lambda _: None))

    whole = tmp_path / "whole"
    study(whole)
    out = tmp_path / "cut"
    ckpts = out / "runs" / "sup-3tube" / "seed-0" / "checkpoints"
    (ckpts / "step_000008.pt.tmp" / "obstacle").mkdir(parents=True)  # the last checkpoint cannot be written
    with pytest.raises(CheckpointError):
        study(out)
    shutil.rmtree(ckpts / "step_000008.pt.tmp")
    lines = []
    study(out, lines.append)
    assert "sup-3tube seed 0: supervised, 8 steps of 4 (resuming at step 7)" in lines  # step 8 could not be written
    assert sorted(p.name for p in ckpts.iterdir()) == ["last.pt", "step_000008.pt"]
    a, b = (torch.load(d / "runs" / "sup-3tube" / "seed-0" / "checkpoints" / "last.pt", weights_only=False)
            for d in (whole, out))
    assert a["step"] == b["step"] == 8
    for k, v in a["model"].items():
        assert torch.equal(v, b["model"][k]), k
    ma, mb = (json.loads((d / "runs" / "sup-3tube" / "seed-0" / "eval" / "metrics.json").read_text())
              for d in (whole, out))
    assert ma["mean"] == mb["mean"] and ma["per_category"] == mb["per_category"]


# ----------------------------------------------------------------------------- T6
def test_t6_resume_drops_a_log_row_that_a_crash_cut_short(sample_shards, tmp_path):
    """A crash (power loss, a full disk) while ``fit`` appends a row to ``metrics.csv`` or
    ``validation.csv`` leaves the row cut short, with no line end: ``11,supervised,...`` cut to
    ``1``. ``--resume`` read it back as a row of step 1 (before the resumed step 10, so kept):
    ``metrics.csv`` held step 1 twice, one row empty, and drawing ``curves.png`` at the next
    checkpoint failed (``could not convert string to float: ''``, exit 1). Now the cut row is
    dropped: the logs hold each step once with the uninterrupted run's values, exit 0."""
    import csv

    from sc3d_cli.train import main as train_main
    from conftest import run_cli

    def rows(path):
        with open(path, newline="") as f:
            return list(csv.DictReader(f))

    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, "--steps", 12, "--tiny", "--base-channels", 4,
                         "--batch-size", 4, "--no-progress", "--log-every", 1, "--checkpoint-every", 10,
                         "--val-every", 4, "--val-min-objects", 1])
    again = tmp_path / "again"
    shutil.copytree(run, again)
    (again / "checkpoints" / "step_000012.pt").unlink()  # stopped after the checkpoint at step 10
    shutil.copyfile(again / "checkpoints" / "step_000010.pt", again / "checkpoints" / "last.pt")
    for name in ("metrics.csv", "validation.csv"):
        data = (again / name).read_bytes().rstrip(b"\r\n")
        (again / name).write_bytes(data[: data.rindex(b"\n") + 2])  # the last row cut after its first byte
    assert (again / "metrics.csv").read_bytes().endswith(b"\n1") and (again / "validation.csv").read_bytes().endswith(b"\n1")
    run_cli(train_main, ["fit", "--out", again, "--resume", "--no-progress"])
    for name, columns in (("metrics.csv", ("step", "phase", "total", "l3d", "kl")),
                          ("validation.csv", ("step", "val_iou", "val_rot_median", "best"))):
        got, want = rows(again / name), rows(run / name)
        assert [int(r["step"]) for r in got] == [int(r["step"]) for r in want], name
        for g, w in zip(got, want):
            for c in columns:
                if c in ("step", "phase", "best"):
                    assert g[c] == w[c], (name, c)
                else:
                    assert float(g[c]) == pytest.approx(float(w[c]), abs=1e-4), (name, c)
    assert (again / "curves.png").stat().st_size > 0


# ----------------------------------------------------------------------------- T7
@pytest.mark.parametrize("option, message", [
    (["--batch-size", "0"], "batch_size (--batch-size) must be >= 1, got 0"),
    (["--batch-size", "-3"], "batch_size (--batch-size) must be >= 1, got -3"),
    (["--examples", "-1"], "examples (--examples) must be >= 0, got -1"),
])
def test_t7_eval_refuses_a_batch_size_or_example_count_out_of_range(sample_shards, tmp_path, option, message):
    """``eval --batch-size 0`` (or -3) ended in torch's DataLoader message ("batch_size should be
    a positive integer value"), naming no option, and ``--examples -1`` exited 0 with a
    predictions.png of no example. Now each is refused in one line naming the option, before the
    checkpoint is read, and no output folder is made."""
    from sc3d_cli.train import main as train_main
    from conftest import run_cli

    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, "--steps", 1, "--tiny", "--base-channels", 4,
                         "--batch-size", 4, "--no-progress", "--val-every", 0])
    res = run_cli(train_main, ["eval", "--checkpoint", run, "--shards", sample_shards, "--out", tmp_path / "ev",
                               "--device", "cpu", *option], expect_exit=1)
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], res.output
    assert not (tmp_path / "ev").exists()
