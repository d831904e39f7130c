"""Defects of the training half noticed by the thirteenth attack and found by the fourteenth
(2026-11-28), each test failing without its fix. Real runs of the tiny model on the bundled
sample meshes."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time

import pytest
import yaml

from sc3d_cli.train import main
from sc3d_train.loop.checkpoint import load_checkpoint
from tests.conftest import run_cli
from tests.test_train import TINY
from conftest import REPO, error_lines


# ----------------------------------------------------------------------------- --resume --amp off
def test_resume_accepts_precision_settings_that_are_the_runs_own_on_this_device(sample_shards, tmp_path):
    """A run started with the defaults (``amp: auto``, ``channels_last: auto``) on the CPU trains
    in fp32 and NCHW; ``--resume --amp off --channels-last off`` asks for exactly that and was
    refused as a change. The control: ``--amp bf16`` would change the precision and stays refused."""
    out = tmp_path / "run"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", out, "--steps", 2, "--batch-size", 4, *TINY,
                   "--val-every", 0, "--device", "cpu", "--no-progress"])
    run_cli(main, ["fit", "--out", out, "--resume", "--steps", 3, "--amp", "off", "--channels-last", "off",
                   "--device", "cpu", "--no-progress"])
    saved = yaml.safe_load((out / "config.yaml").read_text())
    assert (saved["amp"], saved["channels_last"], saved["steps"]) == ("auto", "auto", 3)
    res = run_cli(main, ["fit", "--out", out, "--resume", "--steps", 4, "--amp", "bf16", "--device", "cpu",
                         "--no-progress"], expect_exit=1)
    assert error_lines(res.output) == [f"Error: {out}: cannot change on --resume: --amp 'bf16' (run has 'auto')"]


# ----------------------------------------------------------------------------- D1: best.pt before the first checkpoint
#: the ``sc3d-train`` console script as a child runs it (``python -c``), with Python's Ctrl-C handler
#: whatever this process inherited (a suite started in the background by a shell, ``nohup ... &``,
#: ignores SIGINT, and a child then ignored the test's Ctrl-C and trained on) and an ``atexit`` hook
#: that writes the file ``SC3D_TEST_FINALISED`` names: whether the interpreter was finalised
CONSOLE_SCRIPT = ("import atexit, os, signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
                  "atexit.register(lambda: open(os.environ['SC3D_TEST_FINALISED'], 'w').close()); "
                  "import sc3d_cli.train as t; t.console_main()")


def test_the_console_script_is_finalised_as_usual_when_not_interrupted(tmp_path):
    """The control of the Ctrl-C test below: an ``sc3d-train`` that ends otherwise (here
    ``--version``, and a refusal) exits through Python's finalisation (its atexit hook runs)."""
    for args, code in ((["--version"], 0), (["fit", "--out", str(tmp_path / "none"), "--resume"], 1)):
        finalised = tmp_path / f"finalised-{code}"
        r = subprocess.run([sys.executable, "-c", CONSOLE_SCRIPT, *args], cwd=REPO, capture_output=True, text=True,
                           timeout=120, env=dict(os.environ, PYTHONPATH=str(REPO), SC3D_TEST_FINALISED=str(finalised)))
        assert r.returncode == code and finalised.exists(), r.stdout + r.stderr


@pytest.mark.parametrize("stop,status", [(signal.SIGINT, 1), (signal.SIGTERM, 128 + signal.SIGTERM)],
                         ids=["ctrl_c", "sigterm"])
def test_a_run_stopped_by_ctrl_c_before_its_first_checkpoint_can_be_started_again(sample_shards, tmp_path, stop, status):
    """Validation every 2 steps, checkpoints every 1000: Ctrl-C once ``best.pt`` exists left a
    run that said 'nothing to resume (start the run again)', whose ``--resume`` said 'start it
    again without --resume' and whose start again was refused ('holds checkpoints ... (best.pt)
    but no last.pt; use --resume'). Now the same command starts it again and drops that
    ``best.pt`` (its weights are of the run being replaced). A SIGTERM (``docker stop``, a
    scheduler's preemption) is the same stop, ending with status 143: it ended ``fit`` without a word."""
    out = tmp_path / "run"
    args = ["fit", "--shards", sample_shards, "--out", out, "--batch-size", 2, *TINY, "--checkpoint-every", 1000,
            "--val-every", 2, "--val-min-objects", 1]
    finalised = tmp_path / "finalised"
    first = subprocess.Popen([sys.executable, "-c", CONSOLE_SCRIPT, *map(str, args), "--steps", "1000"], cwd=REPO,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                             env=dict(os.environ, PYTHONPATH=str(REPO), SC3D_TEST_FINALISED=str(finalised)))
    try:
        deadline = time.monotonic() + 240
        while not (out / "checkpoints" / "best.pt").is_file():
            assert first.poll() is None and time.monotonic() < deadline, first.stdout.read() if first.poll() else "timeout"
            time.sleep(0.1)
        first.send_signal(stop)
        printed = first.communicate(timeout=120)[0]
    finally:
        first.kill()
    assert "interrupted before the first checkpoint: nothing to resume (start the run again)" in printed, printed
    # the console script left at once, without Python's finalisation, which could spin forever after
    # an interrupt (cli/interrupted_exit.py): its atexit hook did not run; its last line was printed
    assert first.returncode == status and printed.rstrip().endswith("Aborted!") and not finalised.exists(), printed
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["best.pt"]
    res = run_cli(main, [*args, "--steps", 3, "--seed", 5])  # started again, with another seed
    assert "removed best.pt of step" in res.output and "stopped before its first checkpoint" in res.output
    assert load_checkpoint(out / "checkpoints" / "last.pt")["config"]["seed"] == 5
    assert load_checkpoint(out / "checkpoints" / "best.pt")["config"]["seed"] == 5


@pytest.mark.parametrize("schedule", [["--checkpoint-every", 1000], ["--checkpoint-every", 4, "--log-every", 2]],
                         ids=["end_before_first_checkpoint", "end_at_first_checkpoint"])
def test_a_best_pt_kept_from_a_finished_run_still_refuses_a_new_run(sample_shards, tmp_path, schedule):
    """The control: a finished 4-step run (its end is its checkpoint, at step 4 < 1000) whose
    ``last.pt`` and step files were deleted keeps its ``best.pt``: a new run there is refused.
    Also where its first checkpoint is its end (``--checkpoint-every 4``), whose log reaches step 4
    like a run stopped while writing that checkpoint (``test_faults_train_round27``): it validated
    step 4 after writing it."""
    out = tmp_path / "run"
    args = ["fit", "--shards", sample_shards, "--out", out, "--batch-size", 2, *TINY, *schedule,
            "--val-every", 2, "--val-min-objects", 1, "--steps", 4]
    run_cli(main, args)
    for p in (out / "checkpoints").glob("*.pt"):
        if p.name != "best.pt":
            p.unlink()
    res = run_cli(main, args, expect_exit=1)
    assert "already holds checkpoints of a run (best.pt) but no last.pt" in res.output
    assert (out / "checkpoints" / "best.pt").is_file()


# ----------------------------------------------------------------------------- D2: resumed with validation off
def test_a_run_resumed_with_validation_off_keeps_no_best_pt_of_its_validated_steps(sample_shards, tmp_path):
    """``--resume --steps 8 --val-every 0`` of a 4-step run validated every 2 steps kept
    ``best.pt`` of step 2 or 4, and ``eval RUN`` read it as the 8-step run's without a word.
    Now the resume removes it (one line) and eval reads ``last.pt`` of step 8."""
    out = tmp_path / "run"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", out, "--batch-size", 2, *TINY, "--steps", 4,
                   "--val-every", 2, "--val-min-objects", 1])
    assert (out / "checkpoints" / "best.pt").is_file()
    res = run_cli(main, ["fit", "--out", out, "--resume", "--steps", 8, "--val-every", 0, "--no-progress"])
    assert "removed best.pt of step" in res.output and "validation is off from here" in res.output
    assert not (out / "checkpoints" / "best.pt").exists()
    res = run_cli(main, ["eval", "--checkpoint", out, "--shards", sample_shards, "--split", "test", "--out",
                         tmp_path / "ev", "--device", "cpu"])
    assert "last.pt" in res.output and "step 8" in res.output, res.output


# ----------------------------------------------------------------------------- D3: --compile-backend
def test_every_option_the_resume_help_names_is_an_option_of_fit(sample_shards, tmp_path):
    """``--resume``'s help said ``--compile-backend`` may change, and fit had no such option
    ('No such option'); it is now one (a compiled run that misbehaves is resumed with
    ``--compile-backend aot_eager``, as config.md advises)."""
    from click.testing import CliRunner

    help_text = CliRunner().invoke(main, ["fit", "--help"]).output
    resume_help = " ".join(help_text[re.search(r"^\s+--resume ", help_text, re.MULTILINE).start():].split())
    named = re.findall(r"--[a-z-]+", resume_help.split("may change")[0])
    options = {o for line in help_text.splitlines() if line.lstrip().startswith("--")
               for o in re.findall(r"--[a-z-]+", line.split("  ")[1] if line.startswith("  ") else line)}
    assert "--compile-backend" in named and set(named) <= options, set(named) - options
    out = tmp_path / "run"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", out, "--batch-size", 2, *TINY, "--steps", 1,
                   "--val-every", 0, "--device", "cpu"])
    run_cli(main, ["fit", "--out", out, "--resume", "--steps", 2, "--compile-backend", "aot_eager", "--no-progress"])
    assert yaml.safe_load((out / "config.yaml").read_text())["compile_backend"] == "aot_eager"


# ----------------------------------------------------------------------------- D4: a semi run's config, labelled-only
def test_a_semi_runs_own_config_trains_the_labelled_only_comparison(sample_shards, tmp_path):
    """The paper's comparison from one config: a semi run's ``config.yaml`` (its
    ``pretrain_steps`` recorded as half its steps, ``semi_batch_size`` and ``semi_lr`` given)
    with ``--labeled-only`` was refused ('pretrain_steps: 2 (read by semi runs): not read by a
    labeled-only run'). The switch is the user's: the file's semi-only settings go back to their
    defaults (config.yaml records none of them), its shared ``labeled_fraction`` stays."""
    semi, labelled = tmp_path / "semi", tmp_path / "labelled"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", semi, "--batch-size", 4, *TINY, "--steps", 4,
                   "--val-every", 0, "--semi", "--labeled-fraction", 0.5, "--semi-batch-size", 4,
                   "--semi-lr", 5e-4])
    run_cli(main, ["fit", "--config", semi / "config.yaml", "--labeled-only", "--out", labelled])
    saved = yaml.safe_load((labelled / "config.yaml").read_text())
    assert saved["mode"] == "labeled-only" and saved["labeled_fraction"] == 0.5
    assert (saved["pretrain_steps"], saved["semi_batch_size"], saved["semi_lr"]) == (None, None, None)


def test_the_semi_shares_out_of_range_name_their_option(sample_shards, tmp_path):
    """'labeled fraction must be in (0, 1]' named neither the option nor the config key."""
    for option, message in (("--labeled-fraction", "labeled_fraction (--labeled-fraction) must be in (0, 1], got 1.5"),
                            ("--semi-labeled-share", "semi_labeled_share (--semi-labeled-share) must be in [0, 1), "
                                                     "got 1.5")):
        res = run_cli(main, ["fit", "--shards", sample_shards, "--out", tmp_path / "run", *TINY, "--steps", 2,
                             "--semi", option, 1.5], expect_exit=None)
        assert res.exit_code != 0 and error_lines(res.output) == [f"Error: {message}"], res.output


def test_a_config_key_given_twice_is_refused(sample_shards, tmp_path):
    """``steps: 4`` and, below, ``steps: 6`` trained 6 steps without a word (yaml keeps the last)."""
    config = tmp_path / "run.yaml"
    config.write_text(f"shards: {sample_shards}\nsteps: 4\nbatch_size: 4\nsteps: 6\n")
    res = run_cli(main, ["fit", "--config", config, "--out", tmp_path / "run", *TINY], expect_exit=1)
    assert error_lines(res.output) == [f"Error: {config}: not valid YAML at line 4 (key 'steps' given twice)"]
    model = tmp_path / "model.yaml"  # nested mappings too; a key in two mappings is no repeat
    model.write_text(f"shards: {sample_shards}\nsteps: 1\nmodel:\n  shape_dim: 8\n  shape_dim: 16\n")
    res = run_cli(main, ["fit", "--config", model, "--out", tmp_path / "run", *TINY], expect_exit=1)
    assert "at line 5 (key 'shape_dim' given twice)" in res.output
    merged = tmp_path / "merged.yaml"  # a YAML merge key repeats nothing (the review's control)
    merged.write_text(f"shards: {sample_shards}\nsteps: 1\nbatch_size: 2\nmodel: &m\n  shape_dim: 8\n"
                      f"loss_weights:\n  <<: {{}}\n  ray: 1.0\n")
    run_cli(main, ["fit", "--config", merged, "--out", tmp_path / "merged", *TINY, "--val-every", 0])


def test_a_ctrl_c_in_the_first_checkpoint_write_leaves_a_run_that_starts_again(sample_shards, tmp_path,
                                                                               monkeypatch):
    """Found by the review of the fix above: a step that both validates and saves wrote
    ``best.pt`` first, so a Ctrl-C in the first checkpoint's write (validation every 2 steps,
    checkpoints every 2: the defaults 100 and 500 line up the same way) left ``best.pt`` of
    the first checkpoint's step and no ``last.pt``: the same dead end. The step now saves, then
    validates: the interrupted run leaves no checkpoint at all and starts again."""
    from sc3d_train.loop import trainer

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    out = tmp_path / "run"
    args = ["fit", "--shards", sample_shards, "--out", out, "--batch-size", 2, *TINY, "--checkpoint-every", 2,
            "--val-every", 2, "--val-min-objects", 1, "--steps", 4]
    with monkeypatch.context() as m:
        m.setattr(trainer, "save", interrupted)
        res = run_cli(main, args, expect_exit=None)
    assert res.exit_code != 0 and "nothing to resume (start the run again)" in res.output, res.output
    run_cli(main, args)
    assert load_checkpoint(out / "checkpoints" / "last.pt")["step"] == 4


def test_the_final_curves_picture_is_drawn_after_the_last_validation(sample_shards, tmp_path):
    """The fifteenth attack: with the step saving before it validates, ``curves.png`` (drawn
    with the checkpoint) missed the run's last validation and could mark an earlier ``best.pt``
    step than the one kept. The picture is now drawn after the step's validation."""
    out = tmp_path / "run"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", out, "--batch-size", 2, *TINY, "--steps", 4,
                   "--checkpoint-every", 2, "--val-every", 2, "--val-min-objects", 1])
    rows = (out / "validation.csv").read_text().splitlines()
    assert [r.split(",")[0] for r in rows[1:]] == ["2", "4"]
    assert (out / "curves.png").stat().st_mtime_ns >= (out / "validation.csv").stat().st_mtime_ns


def test_eval_with_no_examples_writes_no_blank_picture(sample_shards, tmp_path):
    """The fifteenth attack: ``eval --examples 0`` wrote an all-white predictions.png and said so."""
    out = tmp_path / "run"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", out, "--batch-size", 2, *TINY, "--steps", 1,
                   "--val-every", 0])
    res = run_cli(main, ["eval", "--checkpoint", out, "--shards", sample_shards, "--out", tmp_path / "ev",
                         "--examples", 0, "--device", "cpu"])
    assert "(--examples 0: no picture)" in res.output and not (tmp_path / "ev" / "predictions.png").exists()
    assert (tmp_path / "ev" / "metrics.json").is_file()


def test_a_claims_rerun_of_some_runs_keeps_the_studys_other_finished_runs(sample_shards, tmp_path):
    """The fifteenth attack: the study ``--runs sup-3tube,ray`` then a rerun ``--runs ray`` (as
    training.md shows: the full study, then a subset) rewrote claims.md/json/png with ray alone;
    sup-3tube's finished row was gone without a word. A run not finished for every seed (here all
    the others) stays out."""
    from sc3d_train.evaluation.claims import ClaimsPreset, run_all

    preset = ClaimsPreset(steps=2, batch_size=4, lr=1e-3, tiny=True, extra={"val_min_objects": 1})
    out = tmp_path / "claims"
    run_all(sample_shards, sample_shards, out, preset, eval_split="test", device="cpu", runs=["sup-3tube", "ray"],
            echo=lambda line: None)
    lines = []
    results = run_all(sample_shards, sample_shards, out, preset, eval_split="test", device="cpu", runs=["ray"],
                      echo=lines.append)
    assert {"sup-3tube", "ray"} <= set(results) and "semi" not in results
    assert f"also in the report, finished before in {out}: sup-3tube" in lines
    assert "Ours (Sup), 3 tubes" in (out / "claims.md").read_text()
    assert set(json.loads((out / "claims.json").read_text())["results"]) == set(results)
