"""``sc3d-train``, round six: defects that earlier rounds noticed and left alone (T1) and that a
sixth attack on the commands found (T2-T6). T1: a CPU batch whose step does not fit in memory was
ended by Linux's out-of-memory killer with no message (``fit --batch-size 100000``); it is now
refused before training, in one line naming the largest batch that fits. Real shards, real tiny
training, no mocks."""
from __future__ import annotations

import json

import pytest
import torch

from sc3d_cli.train import main as train_main
from conftest import run_cli, error_lines
from tests.test_train import TINY, read_csv


def test_t1_live_tensor_bytes_counts_a_hand_derived_case():
    """The counter behind the memory check, on tensors of known size: two 1,000,000-byte
    tensors alive at once (peak 2,000,000), then one freed (live 1,000,000); a view adds nothing."""
    from sc3d_train.loop.memory_check import LiveTensorBytes

    with LiveTensorBytes() as memory:
        a = torch.ones(1000, 250)               # 1e6 bytes
        b = a + 1                                # another 1e6
        view = b[:10]                            # a view: the same storage
        del a
    assert memory.peak == 2_000_000 and memory.live == 1_000_000
    assert view.sum().item() == 10 * 250 * 2


def _needs_memory_figures():
    from sc3d_train.loop.memory_check import available_bytes

    free = available_bytes()
    if free is None or free < 2 * 2**30:
        pytest.skip(f"needs Linux's memory figures and 2 GiB available (available: {free})")


def test_t1_a_cpu_batch_that_cannot_fit_is_refused_in_one_line(sample_shards, tmp_path):
    """``--batch-size 10**7`` (terabytes a step) fails at once with one line naming the need, the
    memory available and a batch that fits; no checkpoint is written. The suggested batch is
    larger than the probing threshold and at most the memory available divided by the per-sample
    figure, which lies between 1 and 100 MiB for the tiny network (the peak resident memory of
    ``fit --tiny`` grew by about 10 MiB a sample from batch 32 to 256: ``memory_check``'s doc)."""
    import re

    from sc3d_train.loop.memory_check import PROBE_ABOVE

    _needs_memory_figures()
    out = tmp_path / "run"
    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", out, "--steps", 2, "--batch-size",
                               10**7, *TINY, "--device", "cpu"], expect_exit=1)
    lines = error_lines(res.output)
    assert len(lines) == 1, res.output
    m = re.fullmatch(r"Error: --batch-size 10000000 needs about ([\d.]+) GiB of memory a step on the CPU "
                     r"\(([\d.]+) MiB a sample, measured\), more than the [\d.]+ GiB a step may take \(80% of the "
                     r"([\d.]+) GiB available\); use --batch-size (\d+) or less", lines[0])
    assert m, lines[0]
    need, per_sample, free, fits = float(m[1]), float(m[2]), float(m[3]), int(m[4])
    assert 1 <= per_sample <= 100 and need >= 10**7 * (per_sample - 0.05) / 1024  # per_sample is rounded
    assert PROBE_ABOVE < fits <= free * 1024 / per_sample
    assert not (out / "checkpoints" / "last.pt").exists()


def test_t1_the_probe_changes_nothing_of_the_run(sample_shards, tmp_path, monkeypatch):
    """A batch above the probing threshold trains exactly as without the probe (it runs on a copy
    of the network with the RNG restored): the same losses and the same weights, bit for bit."""
    import sc3d_train.loop.memory_check as memory_check

    _needs_memory_figures()
    batch = memory_check.PROBE_ABOVE + 8

    def fit(out):
        run_cli(train_main, ["fit", "--shards", sample_shards, "--out", out, "--steps", 2, "--batch-size", batch,
                             *TINY, "--device", "cpu", "--val-every", 0])
        return read_csv(out / "metrics.csv"), torch.load(out / "checkpoints" / "last.pt", weights_only=False)

    probed = []
    real = memory_check.step_peak_bytes
    monkeypatch.setattr(memory_check, "step_peak_bytes", lambda t, n: probed.append(n) or real(t, n))
    csv_a, ckpt_a = fit(tmp_path / "probed")
    assert probed == list(memory_check.PROBE_SIZES)
    monkeypatch.setattr(memory_check, "PROBE_ABOVE", 10**9)
    csv_b, ckpt_b = fit(tmp_path / "unprobed")
    timing = {"samples_per_s", "data_wait", "gpu_util"}
    assert len(csv_a) == len(csv_b) == 2
    for ra, rb in zip(csv_a, csv_b):
        assert {k: v for k, v in ra.items() if k not in timing} == {k: v for k, v in rb.items() if k not in timing}
    for key, value in ckpt_a["model"].items():
        assert torch.equal(value, ckpt_b["model"][key]), key


def test_t1_the_probe_runs_the_step_of_a_true_pose_masks_run(sample_shards, tmp_path):
    """The ablation ``mode: true-pose-masks`` (config file only) reads the true pose, which the
    supervised batch drops: the probe builds its batch as the loop does, so a CPU batch above the
    threshold trains instead of ending in ``KeyError: 'azimuth'``."""
    import sc3d_train.loop.memory_check as memory_check

    _needs_memory_figures()
    config = tmp_path / "ablation.yaml"
    config.write_text(f"shards: {sample_shards}\nmode: true-pose-masks\n")
    run_cli(train_main, ["fit", "--config", config, "--out", tmp_path / "run", "--steps", 1, "--batch-size",
                         memory_check.PROBE_ABOVE + 8, *TINY, "--val-every", 0, "--device", "cpu"])
    assert (tmp_path / "run" / "checkpoints" / "last.pt").is_file()


# ----------------------------------------------------------------------------- T2
def test_t2_a_run_that_diverges_leaves_no_best_checkpoint_of_nan_weights(sample_shards, tmp_path):
    """Validation ran whenever ``--val-every`` was due, but the loss was checked only at log and
    checkpoint steps: ``--lr 1e6 --log-every 5 --val-every 2`` diverged at step 1, the
    validation of step 2 kept ``best.pt`` of NaN weights, and ``eval RUN`` used them by default.
    Now the loss is checked before every validation: the run stops at step 2 with the divergence
    message and no ``best.pt`` exists."""
    out = tmp_path / "run"
    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", out, "--steps", 10, "--batch-size", 4,
                               "--tiny", "--no-progress", "--lr", 1e6, "--log-every", 5, "--checkpoint-every", 5,
                               "--val-every", 2, "--val-min-objects", 1, "--device", "cpu"], expect_exit=1)
    assert "Error: loss is nan at step" in res.output and "last good checkpoint: none" in res.output, res.output
    assert not (out / "checkpoints" / "best.pt").exists()


# ----------------------------------------------------------------------------- T3
def test_t3_claims_refuses_evaluation_data_it_cannot_use_before_training(sample_shards, tmp_path):
    """``claims`` checked only that the evaluation objects were not trained on, and opened the
    evaluation split after training the first run: an ``--eval-split`` that names no objects, or
    evaluation shards without voxels, cost a whole training run before the error. Now both are
    refused first, in one line, and no run folder is made."""
    import shutil

    import h5py

    novox = tmp_path / "novox"
    shutil.copytree(sample_shards, novox)
    for shard in novox.glob("*.h5"):
        with h5py.File(shard, "a") as f:
            del f["voxels"]
    for eval_shards, split, expected in ((sample_shards, "nonexist", f"{sample_shards}: split 'nonexist' is empty"),
                                         (novox, "test", "shard has no 'voxels' dataset")):
        out = tmp_path / f"claims-{split}"
        res = run_cli(train_main, ["claims", "--train-shards", sample_shards, "--eval-shards", eval_shards,
                                   "--out", out, "--device", "cpu", "--eval-split", split], expect_exit=1)
        errors = error_lines(res.output)
        assert len(errors) == 1 and expected in errors[0], res.output
        assert "steps of" not in res.output and not out.exists()


# ----------------------------------------------------------------------------- T4
def test_t4_resume_from_weights_only_is_one_line(sample_shards, tmp_path):
    """``best.pt`` copied over ``last.pt`` (weights and config, no optimiser, RNG or data position)
    made ``fit --resume`` end in ``KeyError: 'optimizer'``; now one line names the file and what
    it lacks."""
    out = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", out, "--steps", 1, "--batch-size", 4, *TINY,
                         "--val-every", 1, "--val-min-objects", 1, "--device", "cpu"])
    ckpts = out / "checkpoints"
    (ckpts / "last.pt").write_bytes((ckpts / "best.pt").read_bytes())
    for p in ckpts.glob("step_*.pt"):
        p.unlink()
    res = run_cli(train_main, ["fit", "--out", out, "--resume", "--steps", 3, "--no-progress"], expect_exit=1)
    errors = error_lines(res.output)
    assert len(errors) == 1 and f"{ckpts / 'last.pt'}: holds no optimizer, rng, data_position" in errors[0], res.output
    assert "Traceback" not in res.output


# ----------------------------------------------------------------------------- T5
def test_t5_a_checkpoint_given_as_config_is_named(sample_shards, tmp_path):
    """``fit --config RUN/checkpoints/last.pt`` printed only ``'utf-8' codec can't decode byte
    0x80 ...``, naming neither the file nor what it is; now the line names the file and says a
    checkpoint is resumed with ``--resume``."""
    out = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", out, "--steps", 1, "--batch-size", 4, *TINY,
                         "--val-every", 0, "--device", "cpu"])
    ckpt = out / "checkpoints" / "last.pt"
    res = run_cli(train_main, ["fit", "--config", ckpt, "--out", tmp_path / "other"], expect_exit=1)
    assert f"Error: {ckpt}: not a YAML config file (not UTF-8 text" in res.output, res.output
    assert "--resume" in res.output


# ----------------------------------------------------------------------------- T6
def test_t6_eval_knows_training_objects_after_the_shards_moved(sample_shards, tmp_path):
    """``eval`` found the objects a checkpoint trained on by reading the run's shards; once they
    had moved (trained on a scratch copy, evaluated on a local one) it counted 0 and printed no
    note, so training-set figures read as held-out. Now a copy whose split holds the run's
    objects (``objects_sha256``) stands in for them: ``--split train`` gets the note (all 8
    train objects of the sample shards), ``--split test`` counts 0; shards split otherwise say
    that it is unknown (``trained_on`` null)."""
    import shutil

    from sc3d_cli.data import main as data_main
    from conftest import SAMPLE_MESHES

    first = tmp_path / "scratch"
    shutil.copytree(sample_shards, first)
    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", first, "--out", run, "--steps", 1, "--batch-size", 4, *TINY,
                         "--val-every", 0, "--device", "cpu"])
    moved = tmp_path / "local"
    first.rename(moved)
    train_objects = sum(1 for o in json.loads((moved / "index.json").read_text())["objects"] if o["split"] == "train")

    def evaluate(shards, split):
        res = run_cli(train_main, ["eval", "--checkpoint", run, "--shards", shards, "--split", split, "--pose", "head",
                                   "--device", "cpu", "--out", tmp_path / f"eval-{shards.name}-{split}"])
        return res.output, json.loads((tmp_path / f"eval-{shards.name}-{split}" / "metrics.json").read_text())

    output, metrics = evaluate(moved, "train")
    assert metrics["trained_on"] == train_objects > 0
    assert f"note: {train_objects} of the {train_objects} evaluated objects are objects the checkpoint was trained on" \
        in output
    output, metrics = evaluate(moved, "test")
    assert metrics["trained_on"] == 0 and "note:" not in output
    other = tmp_path / "other"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", other, "--voxelize", "--seed", 3, "--no-progress"])
    output, metrics = evaluate(other, "train")
    assert metrics["trained_on"] is None and "whether evaluated objects were trained on is unknown" in output


# ----------------------------------------------------------------------------- T7
def test_t7_resume_follows_shards_that_moved_and_only_the_same_data(sample_shards, tmp_path):
    """A run whose shard folder had moved could not be resumed: ``--shards NEW`` was refused as a
    change and the checkpoint's config named the old folder. Now ``--resume --shards NEW``
    continues exactly (the losses of the resumed steps equal the uninterrupted run's, bit for bit
    on the CPU) when NEW holds the run's data, and is refused naming the change when it holds
    other training objects; without ``--shards`` the error says how to resume."""
    import shutil

    import h5py

    from tests.test_train import interrupt_at

    scratch = tmp_path / "scratch"
    shutil.copytree(sample_shards, scratch)
    args = ["--batch-size", "4", *TINY, "--checkpoint-every", "3", "--seed", "5", "--val-every", 0, "--device", "cpu"]
    whole, part = tmp_path / "whole", tmp_path / "part"
    run_cli(train_main, ["fit", "--shards", scratch, "--out", whole, "--steps", "6", *args])
    interrupt_at(whole, part, 3)
    moved = tmp_path / "local"
    scratch.rename(moved)
    res = run_cli(train_main, ["fit", "--out", part, "--resume", "--no-progress"], expect_exit=1)
    assert f"Error: {scratch}: the shard folder of run {part} does not exist; if it moved, resume with --shards" \
        in res.output, res.output

    other = tmp_path / "other"   # the same objects, but one of the training objects moved to val
    shutil.copytree(moved, other)
    with h5py.File(sorted(other.glob("*.h5"))[0], "a") as f:
        splits = [s.decode() if isinstance(s, bytes) else s for s in f["split"][:]]
        f["split"][splits.index("train")] = "val"
    res = run_cli(train_main, ["fit", "--out", part, "--resume", "--shards", other, "--no-progress"], expect_exit=1)
    assert f"Error: {other}: the shards changed since run {part} started (the objects of split 'train')" in res.output

    run_cli(train_main, ["fit", "--out", part, "--resume", "--shards", moved, "--no-progress"])
    a, b = read_csv(whole / "metrics.csv"), read_csv(part / "metrics.csv")
    for key in ("total", "l3d", "l2d", "lsc", "pose"):
        assert [r[key] for r in a[3:]] == [r[key] for r in b[3:]], key
    assert f"shards: {moved}" in (part / "config.yaml").read_text()


# ----------------------------------------------------------------------------- T8
@pytest.mark.parametrize("flags, expected", [
    (["--labeled-fraction", "0.1", "--pretrain-steps", "1"],
     "Error: --labeled-fraction (read by semi and labeled-only runs), --pretrain-steps (read by semi runs): not "
     "read by a supervised run"),
    (["--labeled-only", "--semi-lr", "0.1"], "Error: --semi-lr (read by semi runs): not read by a labeled-only run"),
    (["--mask-size", "100000"], "Error: model: mask_size (--mask-size) must be at most the image size 64 (or the default 48), got 100000"),
])
def test_t8_options_the_run_would_ignore_or_cannot_use_are_refused(sample_shards, tmp_path, flags, expected):
    """``--labeled-fraction 0.1`` without ``--semi`` trained on every object while ``config.yaml``
    recorded 0.1; ``--mask-size 100000`` ended in a 37 GiB allocation traceback. Both are one
    line now, before any work. Control: the same semi options with ``--semi`` train."""
    out = tmp_path / "run"
    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", out, "--steps", 2, "--batch-size", 4, *TINY,
                               "--val-every", 0, "--device", "cpu", *flags], expect_exit=None)
    assert res.exit_code != 0 and expected in res.output, res.output
    assert not (out / "checkpoints").exists()


def test_t8_control_semi_options_with_semi_train(sample_shards, tmp_path):
    out = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", out, "--steps", 2, "--batch-size", 4, *TINY,
                         "--val-every", 0, "--device", "cpu", "--semi", "--labeled-fraction", "0.5",
                         "--pretrain-steps", "1"])
    assert (out / "labeled_objects.txt").is_file() and "labeled_fraction: 0.5" in (out / "config.yaml").read_text()


# ----------------------------------------------------------------------------- T9
def test_t9_an_interrupt_after_a_checkpoint_names_that_checkpoint(sample_shards, tmp_path, monkeypatch):
    """Ctrl-C while ``curves.png`` was redrawn, right after a checkpoint was written, reported the
    checkpoint before it as the last good one (the loop had not noted the new one yet). Now the
    message names the ``last.pt`` on disk: the checkpoint of step 2 here. The interrupt is raised
    where Ctrl-C landed in the attack: in the curves' redraw after the checkpoint."""
    import sc3d_train.loop.metrics_log as metrics_log

    def ctrl_c(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(metrics_log, "plot_curves", ctrl_c)
    out = tmp_path / "run"
    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", out, "--steps", 4, "--batch-size", 4, *TINY,
                               "--checkpoint-every", 2, "--val-every", 0, "--device", "cpu"], expect_exit=None)
    assert res.exit_code != 0
    assert f"interrupted; last good checkpoint: {out / 'checkpoints' / 'last.pt'} (resume with --resume)" in res.output
    assert torch.load(out / "checkpoints" / "last.pt", weights_only=False)["step"] == 2
