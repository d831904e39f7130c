"""Training-half defects of the twenty-fifth attack: a run resumed on another shard layout of the
same objects trained in another order without a word, and ``--resume`` wrote the run's config over
a ``config.json`` that was a prediction's record. Real renderer, real HDF5, a real tiny model; the
expected values come from a second, uninterrupted or unmoved run, never from the code under test."""
from __future__ import annotations

import json
import shutil

import pytest
import torch

from sc3d_cli.data import main as data_main
from sc3d_cli.train import main as train_main
from conftest import SAMPLE_MESHES, run_cli

FAST = ["--views", "4", "--no-progress", "--workers", "1", "--voxelize"]
TINY_FIT = ["--tiny", "--batch-size", "4", "--val-every", "0", "--no-progress", "--device", "cpu"]


def _weights(run):
    from sc3d_train.loop.checkpoint import load_checkpoint

    return load_checkpoint(run / "checkpoints" / "last.pt")["model"]


@pytest.fixture(scope="module")
def one_and_merged(tmp_path_factory):
    """Two folders of the sample meshes (4 views, voxels): one render, and a merge of two
    ``--part`` renders (the same objects and splits, in two shards of another order)."""
    tmp_path = tmp_path_factory.mktemp("layouts")
    one, merged = tmp_path / "S", tmp_path / "SM"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", one, *FAST])
    parts = [tmp_path / f"p{i}" for i in range(2)]
    for i, part in enumerate(parts):
        run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", part, "--part", f"{i}/2", *FAST])
    run_cli(data_main, ["merge", merged, *parts])
    return one, merged


def _train_rows(shards) -> list[tuple[str, str]]:
    """``(category, model_id)`` of the training objects, in the shard files' order as h5py reads them."""
    import h5py

    rows = []
    for shard in json.loads((shards / "index.json").read_text())["shards"]:
        with h5py.File(shards / shard["file"], "r") as f:
            rows += [(c.decode(), m.decode()) for c, m, s in zip(f["category"][:], f["model_id"][:], f["split"][:])
                     if s.decode() == "train"]
    return rows


def test_a_run_resumed_on_a_merge_of_its_shards_continues_as_on_its_own(one_and_merged, tmp_path):
    """``fit --resume --shards COPY`` (docs/training.md: shards that moved) accepts a merge of two
    ``--part`` renders of the same objects (the check compares the sorted object names), but the
    run followed the shards' order of objects, which the merge changes: its resumed steps differed
    from those resumed on the run's own shards (total loss 6.8643 against 6.5285), exit 0. Runs
    now order their objects by category and model id, so both resumed runs must end with equal
    weights. The control: the two folders do hold the objects in different orders."""
    one, merged = one_and_merged
    assert _train_rows(one) != _train_rows(merged) and sorted(_train_rows(one)) == sorted(_train_rows(merged))
    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", one, "--out", run, "--steps", 2, *TINY_FIT])
    assert "object_order: category/model_id" in (run / "config.yaml").read_text()
    shutil.copytree(run, tmp_path / "moved")
    run_cli(train_main, ["fit", "--resume", "--out", run, "--steps", 4, "--no-progress"])
    run_cli(train_main, ["fit", "--resume", "--out", tmp_path / "moved", "--steps", 4, "--no-progress",
                         "--shards", merged])
    a, b = _weights(run), _weights(tmp_path / "moved")
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_a_run_of_an_earlier_version_keeps_the_shards_order(one_and_merged):
    """A run whose config predates ``object_order`` (None) trained in the shards' order: its
    datasets must keep that order, so that it resumes exactly; a new run's follow category and
    model id. Expected orders: the shards' rows as h5py reads them, and that list sorted."""
    from sc3d_train.loop.streams import phase_dataset
    from sc3d_train.settings.config import RunConfig

    merged = one_and_merged[1]
    rows = _train_rows(merged)
    assert rows != sorted(rows)  # the control: the merge holds its objects unsorted
    for order, expected in ((None, rows), ("category/model_id", sorted(rows))):
        cfg = RunConfig(shards=str(merged), out="unused", object_order=order)
        dataset = phase_dataset(cfg, "all")
        assert [(r.category, r.model_id) for r in dataset.objects] == expected, order
        dataset.close()


def test_resume_writes_the_config_it_restores_beside_a_prediction_named_config(tmp_path, sample_shards):
    """``predict --out RUN config.png`` writes ``RUN/config.json``, its record of the image. With
    ``config.yaml`` missing, ``--resume`` took that record for an earlier version's run config,
    said it "does not load" and wrote the run's YAML over it, exit 0: the record was lost. The
    record must be left as it was, the config restored from the checkpoint into ``config.yaml``;
    an earlier version's real ``config.json`` is still read (control)."""
    from PIL import Image

    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, "--steps", 2, *TINY_FIT])
    Image.new("RGB", (64, 64), "white").save(tmp_path / "config.png")
    run_cli(train_main, ["predict", "--checkpoint", run, "--out", run, tmp_path / "config.png", "--device", "cpu"])
    record = (run / "config.json").read_bytes()
    assert "azimuth_deg" in json.loads(record)
    (run / "config.yaml").unlink()
    res = run_cli(train_main, ["fit", "--resume", "--out", run, "--steps", 3, "--no-progress"])
    assert (run / "config.json").read_bytes() == record
    assert "config.yaml is missing" in res.output and "does not load" not in res.output, res.output
    assert "steps: 3" in (run / "config.yaml").read_text()


# ----------------------------------------------------------------------------- the twenty-sixth attack
def test_the_config_of_an_extended_run_repeats_it(one_and_merged, tmp_path):
    """``fit --resume --steps 6`` of a 4-step cosine run trains steps 4-5 on a 6-step plan, but its
    ``config.yaml`` said only ``steps: 6``, so ``fit --config RUN/config.yaml`` (docs/config.md:
    "repeats run/ exactly") trained one 6-step schedule: other learning rates at steps 1-3, other
    weights, exit 0. The config now records where the plan changed; the repeat must end with
    the extended run's weights, also for a run extended from an earlier checkpoint (step 2 of a
    4-step plan: the plan changed at step 2, not at 4). With another ``--steps`` the repeat says
    it follows one schedule."""
    shards = one_and_merged[0]
    fit = [*TINY_FIT, "--checkpoint-every", 2]
    for name, cut in (("whole", None), ("cut", 2)):
        run = tmp_path / name
        run_cli(train_main, ["fit", "--shards", shards, "--out", run, "--steps", 4, *fit])
        if cut:  # the run as a crash at step 3 leaves it: its newest checkpoint is step 2's
            for stale in ("last.pt", "step_000004.pt"):
                (run / "checkpoints" / stale).unlink()
        run_cli(train_main, ["fit", "--resume", "--out", run, "--steps", 6, "--no-progress"])
        assert f"steps_before: [[{cut or 4}, 4]]" in (run / "config.yaml").read_text()
        again = tmp_path / f"{name}_again"
        run_cli(train_main, ["fit", "--config", run / "config.yaml", "--out", again, "--no-progress"])
        a, b = _weights(run), _weights(again)
        assert all(torch.equal(a[k], b[k]) for k in a), name
    res = run_cli(train_main, ["fit", "--config", tmp_path / "whole" / "config.yaml", "--out", tmp_path / "three",
                               "--steps", 3, "--no-progress"])
    assert "with --steps 3 this run follows one schedule of 3 steps" in res.output
    assert "steps_before: null" in (tmp_path / "three" / "config.yaml").read_text()


def test_a_hand_written_pretrain_steps_without_steps_is_kept(sample_shards, tmp_path):
    """A config file with ``pretrain_steps: 1000`` and no ``steps``, run with ``--steps 4``, trained
    with ``pretrain_steps: 2``: the file's missing ``steps`` was taken as the default 2000, of which
    1000 is the half a run's own config records for a default. The file's value must be kept
    (here refused, as the same file with ``steps: 3000`` is); a file without ``pretrain_steps``
    still pretrains half the run's steps (control)."""
    for name, extra in (("hand.yaml", "pretrain_steps: 1000\n"), ("none.yaml", "")):
        (tmp_path / name).write_text("mode: semi\nlabeled_fraction: 0.5\nval_every: 0\n" + extra)
    res = run_cli(train_main, ["fit", "--config", tmp_path / "hand.yaml", "--shards", sample_shards, "--out",
                               tmp_path / "hand", "--steps", 4, *TINY_FIT], expect_exit=1)
    assert "hand.yaml: pretrain_steps (--pretrain-steps) 1000 not in [0, steps=4]" in res.output, res.output
    run_cli(train_main, ["fit", "--config", tmp_path / "none.yaml", "--shards", sample_shards, "--out",
                         tmp_path / "none", "--steps", 4, *TINY_FIT])
    assert "pretrain_steps: 2" in (tmp_path / "none" / "config.yaml").read_text()


def test_the_config_of_a_run_of_an_earlier_version_repeats_it_in_its_order(one_and_merged, tmp_path):
    """A run started before ``object_order`` existed trained in its shards' order; repeated with
    ``fit --config RUN/config.yaml`` it was trained in category/model_id order (other weights, on
    merged shards), although docs/config.md promises the same weights. Its repeat must keep the
    shards' order: equal weights to a run of that order; a hand-written config (no
    ``objects_sha256``) gets the new order. A bad ``object_order`` is refused naming the file, and
    a ``steps_before`` in a file run without ``--steps`` raised a KeyError."""
    import yaml

    from sc3d_train.loop.resolve import resolve_config

    merged = one_and_merged[1]
    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", merged, "--out", run, "--steps", 2, *TINY_FIT])
    config = yaml.safe_load((run / "config.yaml").read_text())
    old = {k: v for k, v in config.items() if k != "object_order"}  # as an earlier version wrote it
    (tmp_path / "old.yaml").write_text(yaml.safe_dump(old))
    (tmp_path / "shards_order.yaml").write_text(yaml.safe_dump({**config, "object_order": "shards"}))
    for name in ("old", "shards_order"):
        run_cli(train_main, ["fit", "--config", tmp_path / f"{name}.yaml", "--out", tmp_path / f"{name}_again",
                             "--no-progress"])
    assert "object_order: shards" in (tmp_path / "old_again" / "config.yaml").read_text()
    a, b = _weights(tmp_path / "old_again"), _weights(tmp_path / "shards_order_again")
    assert all(torch.equal(a[k], b[k]) for k in a)
    (tmp_path / "hand.yaml").write_text("batch_size: 4\nsteps_before: [[2, 4]]\n")
    cfg = resolve_config({"shards": str(merged), "out": str(tmp_path / "hand")}, config_file=tmp_path / "hand.yaml")
    assert cfg.object_order == "category/model_id" and cfg.steps_before == [[2, 4]]
    (tmp_path / "bad.yaml").write_text("object_order: sorted\n")
    res = run_cli(train_main, ["fit", "--config", tmp_path / "bad.yaml", "--shards", merged, "--out", tmp_path / "bad",
                               "--steps", 2, *TINY_FIT], expect_exit=1)
    assert "bad.yaml: object_order must be one of category/model_id, shards (or null), got 'sorted'" in res.output, \
        res.output
