"""``--semi-batch-size``: the mixed phase of ``semi`` takes that many images a step (labelled and
unlabelled together), so the unlabelled images can be added to a whole labelled batch instead of
taking half of it. Expected sizes are derived by hand from the options."""
from __future__ import annotations

import pytest
import torch

from sc3d_cli.train import main
from tests.conftest import run_cli
from tests.test_train import TINY, read_csv


def mixed_step_images(sample_shards, **options) -> dict:
    """Images per phase of the first mixed step of a semi run (batch 4, labelled share 0.5, no
    pretraining) through the real loader: ``{"supervised": n, "unsupervised": n}``."""
    from sc3d_train.loop.metrics_log import DataWaitClock
    from sc3d_train.loop.resolve import resolve_config
    from sc3d_train.loop.streams import phase_loaders
    from sc3d_train.loop.trainer import device_batches, prepare

    cfg = resolve_config({"shards": str(sample_shards), "out": "unused", "batch_size": 4, "mode": "semi",
                          "labeled_fraction": 0.5, "pretrain_steps": 0, "device": "cpu",
                          "model": {"base_channels": 4}, **options}, {"tiny": True})
    t = prepare(cfg)
    batches = {p: next(it) for p, it in device_batches(t, phase_loaders(t, 0), DataWaitClock()).items()}
    return {p: b["images"].shape[0] for p, b in batches.items()}


def test_the_mixed_step_takes_semi_batch_size_images(sample_shards):
    # batch 4, share 0.5: 2 labelled + 2 unlabelled; with a mixed batch of 8: 4 + 4 (the labelled
    # half is then as large as the pretraining's whole batch); of 6 at share 0.5: 3 + 3
    assert mixed_step_images(sample_shards) == {"supervised": 2, "unsupervised": 2}
    assert mixed_step_images(sample_shards, semi_batch_size=8) == {"supervised": 4, "unsupervised": 4}
    assert mixed_step_images(sample_shards, semi_batch_size=6) == {"supervised": 3, "unsupervised": 3}


def test_mixed_batch_per_rank_and_the_images_a_step_counts():
    from sc3d_train.loop.schedule import mixed_batch, step_samples
    from sc3d_train.settings.config import RunConfig

    def cfg(**kw):
        return RunConfig(shards="s", out="o", mode="semi", batch_size=32, steps=10, pretrain_steps=4, **kw)

    assert mixed_batch(cfg(), 16) == 16                       # unset: the rank's share of --batch-size
    assert mixed_batch(cfg(semi_batch_size=64), 32) == 64      # one rank
    assert mixed_batch(cfg(semi_batch_size=64), 16) == 32      # two ranks: 64 / 2
    with pytest.raises(ValueError, match="semi batch size 63 is not divisible by 2 ranks"):
        mixed_batch(cfg(semi_batch_size=63), 16)
    # pretraining steps 0-3 count --batch-size, mixed steps 4-9 --semi-batch-size
    assert [step_samples(cfg(semi_batch_size=64), s) for s in (0, 3, 4, 9)] == [32, 32, 64, 64]
    assert [step_samples(cfg(), s) for s in (0, 9)] == [32, 32]


def test_bad_semi_batch_sizes_are_refused_in_one_line(sample_shards, tmp_path):
    base = ["fit", "--shards", sample_shards, "--out", tmp_path / "run", "--steps", "2", "--batch-size", "4", *TINY]
    r = run_cli(main, base + ["--semi-batch-size", "8"], expect_exit=1)
    assert "--semi-batch-size (read by semi runs)" in r.output
    r = run_cli(main, base + ["--labeled-only", "--semi-batch-size", "8"], expect_exit=1)
    assert "not read by a labeled-only run" in r.output and "reads it (--semi) or leave it out" in r.output
    r = run_cli(main, base + ["--semi", "--semi-batch-size", "1"], expect_exit=1)
    assert "semi_batch_size (--semi-batch-size) must be at least 2" in r.output
    r = run_cli(main, base + ["--semi", "--semi-batch-size", str(2 ** 24 + 1)], expect_exit=1)
    assert f"semi_batch_size (--semi-batch-size) must be at most {2 ** 24}" in r.output
    r = run_cli(main, base + ["--batch-size", "0"], expect_exit=1)
    assert "batch_size (--batch-size) must be >= 1, got 0" in r.output
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_a_semi_run_with_a_larger_mixed_batch_resumes_where_its_streams_stopped(sample_shards, tmp_path):
    """3 steps: 1 of pretraining (4 labelled images), 2 mixed of 4 labelled + 4 unlabelled
    (``--semi-batch-size 8``); the checkpoint's data position counts those images per stream,
    and a resume from step 2 logs the same losses as the run without a stop."""
    from tests.test_train import interrupt_at

    args = ["--shards", sample_shards, "--batch-size", "4", *TINY, "--semi", "--labeled-fraction", "0.5",
            "--pretrain-steps", "1", "--semi-batch-size", "8", "--checkpoint-every", "2", "--seed", "2"]
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    run_cli(main, ["fit", "--out", whole, "--steps", "3", *args])
    ckpt = torch.load(whole / "checkpoints" / "last.pt", weights_only=False)
    assert ckpt["data_position"] == {"phase": "unsupervised", "phase_start": 1, "samples_per_rank": 8,
                                     "labeled_samples_per_rank": 8}
    interrupt_at(whole, parts, 2)
    run_cli(main, ["fit", "--out", parts, "--steps", "3", "--resume", "--no-progress"])
    a, b = read_csv(whole / "metrics.csv"), read_csv(parts / "metrics.csv")
    assert [r["phase"] for r in a] == ["supervised", "unsupervised", "unsupervised"] and len(b) == 3
    for ra, rb in zip(a, b):
        assert (ra["total"], ra["u_lsc"]) == (rb["total"], rb["u_lsc"]), ra["step"]
