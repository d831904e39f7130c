"""Defects of the training half found by the twenty-seventh attack (2026-11-29), each test
failing without its fix. Real runs of the tiny model on the bundled sample meshes."""
from __future__ import annotations

from sc3d_cli.train import main
from sc3d_train.loop.checkpoint import load_checkpoint
from tests.conftest import run_cli
from tests.test_train import TINY


# ----------------------------------------------------------------------------- A1: the first checkpoint's write
def test_a_run_whose_first_checkpoint_write_failed_after_a_best_pt_can_be_started_again(sample_shards, tmp_path):
    """Validation before the first checkpoint (the defaults: every 100 steps, checkpoints every
    500) leaves ``best.pt``; when the first checkpoint's write then fails (a full disk, a kill or
    Ctrl-C inside the write), fit said 'start the run again (the same command ...)', the same
    command was refused ('already holds checkpoints of a run (best.pt) but no last.pt; use
    --resume') and ``--resume`` said 'start it again without --resume': no command continued the
    run. The step of the failed checkpoint was logged before it (a log comes before the step's
    checkpoint), which the early-stop test took for a run gone past its first checkpoint. Now the
    same command starts the run again. The write fails for real: a folder stands at the
    checkpoint's temporary name."""
    out = tmp_path / "run"
    args = ["fit", "--shards", sample_shards, "--out", out, "--batch-size", 2, *TINY, "--steps", 6,
            "--checkpoint-every", 4, "--val-every", 2, "--val-min-objects", 1, "--log-every", 2]
    blocker = out / "checkpoints" / "step_000004.pt.tmp"
    blocker.mkdir(parents=True)
    res = run_cli(main, args, expect_exit=1)
    assert "step_000004.pt: cannot write checkpoint" in res.output and "start the run again" in res.output
    assert sorted(p.name for p in (out / "checkpoints").glob("*.pt")) == ["best.pt"]
    assert "start it again without --resume" in run_cli(main, ["fit", "--out", out, "--resume"], expect_exit=1).output
    blocker.rmdir()
    res = run_cli(main, [*args, "--seed", 3])  # what the first error said to do: the same command
    assert "removed best.pt of step" in res.output
    assert load_checkpoint(out / "checkpoints" / "last.pt")["step"] == 6
    assert load_checkpoint(out / "checkpoints" / "best.pt")["config"]["seed"] == 3


# ----------------------------------------------------------------------------- A2: TensorBoard of a run started again
def tb_steps(run_dir) -> dict:
    """{tag: [step, ...]} as TensorBoard reads ``run_dir/tb`` (every event file, its purges applied)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    ea = EventAccumulator(str(run_dir / "tb"), size_guidance={"scalars": 0})
    ea.Reload()
    return {tag: [e.step for e in ea.Scalars(tag)] for tag in ea.Tags()["scalars"]}


def test_a_run_started_again_shows_each_step_once_in_tensorboard(sample_shards, tmp_path):
    """A run stopped before its first checkpoint is started again by its own command, which
    rewrites ``metrics.csv``; its TensorBoard folder kept the stopped run's event file beside the
    new one, so every step the stopped run had logged showed twice (``train/total`` at steps
    0, 1, 2, 3, 0, 1, 2, 3), with the stopped run's values among the new run's. Now a new run
    starts ``tb/`` empty, as it starts ``metrics.csv``."""
    out = tmp_path / "run"
    args = ["fit", "--shards", sample_shards, "--out", out, "--batch-size", 2, *TINY, "--steps", 4,
            "--checkpoint-every", 4, "--val-every", 0, "--log-every", 1]
    blocker = out / "checkpoints" / "step_000004.pt.tmp"
    blocker.mkdir(parents=True)
    run_cli(main, [*args, "--seed", 7], expect_exit=1)  # stopped at its first checkpoint
    assert tb_steps(out)["train/total"] == [0, 1, 2, 3]
    blocker.rmdir()
    run_cli(main, args)
    steps = tb_steps(out)
    assert steps["train/total"] == [0, 1, 2, 3] and steps["train/lr"] == [0, 1, 2, 3], steps
    assert len(list((out / "tb").iterdir())) == 1


# ----------------------------------------------------------------------------- A3: claims with another preset
def test_claims_with_other_settings_is_refused_before_it_trains_a_run(sample_shards, tmp_path):
    """A study rerun into its folder with other settings (``--preset paper`` after ``cpu``, with
    ``--runs`` naming a run not yet trained) said 'also in the report, finished before: ...' of
    the earlier runs, trained its new runs with the other settings (20000 steps each at the paper
    preset), and only then, reaching an earlier run, was refused; the folder was left holding runs
    of two settings, so that the first study's own rerun was refused in turn. Now the runs it
    would reuse are checked first: refused before anything is trained, the folder unchanged."""
    import pytest

    from sc3d_train.evaluation.claims import ClaimsPreset, run_all
    from sc3d_train.loop.checkpoint import CheckpointError

    out = tmp_path / "study"
    first = ClaimsPreset(steps=2, batch_size=4, lr=1e-3, tiny=True, extra={"base_channels": 4, "val_every": 0})
    run_all(sample_shards, sample_shards, out, first, "test", "cpu", runs=["ray"], echo=lambda line: None)
    other = ClaimsPreset(steps=2, batch_size=4, lr=2e-4, tiny=True, extra={"base_channels": 4, "val_every": 0})
    with pytest.raises(CheckpointError) as e:
        run_all(sample_shards, sample_shards, out, other, "test", "cpu", runs=["ray-proj"], echo=lambda line: None)
    assert f"{out / 'runs' / 'ray' / 'seed-0'}: cannot change on --resume: --lr" in str(e.value)
    assert "give another --out" in str(e.value)
    assert not (out / "runs" / "ray-proj").exists()
