"""Hostile inputs to `sc3d-train`, round seven: checkpoints that are no checkpoint, a torch too
old to load one safely, shards a render left incomplete. Real CLI, real HDF5, real tiny runs;
expected outcomes are stated by hand."""
from __future__ import annotations

import json
import shutil

import pytest

from sc3d_cli.train import main as train_main
from conftest import run_cli

QUICK = ["--tiny", "--steps", "2", "--batch-size", "2", "--val-every", "0", "--no-progress"]


def one_line(output: str) -> str:
    return " ".join(output.split())


@pytest.fixture(scope="module")
def tiny_run(sample_shards, tmp_path_factory):
    out = tmp_path_factory.mktemp("r7") / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", out, *QUICK])
    return out


@pytest.mark.parametrize("name", ["config.yaml", "curves.png"])
def test_r7_a_file_that_is_no_checkpoint_is_called_so(sample_shards, tiny_run, tmp_path, name):
    """The run's own config.yaml or curves picture given as --checkpoint: 'not a checkpoint file',
    not the crafted-file refusal that a zip of foreign Python objects gets."""
    res = run_cli(train_main, ["eval", "--checkpoint", tiny_run / name, "--shards", sample_shards,
                               "--out", tmp_path / "ev"], expect_exit=1)
    text = one_line(res.output)
    assert f"{tiny_run / name}: not a checkpoint file" in text and "crafted" not in text
    assert "Traceback" not in res.output


@pytest.mark.parametrize("version, safe", [("2.13.0+cpu", True), ("2.6.0", True), ("2.6.0a0+git1234", True),
                                           ("3.0.1", True), ("2.5.1+cu121", False), ("2.4.0", False),
                                           ("1.13.1", False)])
def test_r7_torch_before_2_6_is_not_trusted_with_a_checkpoint(version, safe):
    """CVE-2025-32434: weights_only loading ran code in torch 2.5.1 and earlier."""
    from sc3d_train.loop.checkpoint import torch_is_safe

    assert torch_is_safe(version) is safe


def test_r7_an_old_torch_refuses_to_load_in_one_line(tiny_run, monkeypatch):
    import torch

    from sc3d_train.loop.checkpoint import CheckpointError, load_checkpoint

    monkeypatch.setattr(torch, "__version__", "2.5.1")
    with pytest.raises(CheckpointError, match=r"torch 2\.5\.1 is older than 2\.6.*CVE-2025-32434"):
        load_checkpoint(tiny_run / "checkpoints" / "last.pt")


def _incomplete_copy(shards, dest):
    """A copy of ``shards`` whose index says a render was cut short (what an interrupted render
    leaves: ``complete: false``)."""
    shutil.copytree(shards, dest)
    index = json.loads((dest / "index.json").read_text())
    index["complete"] = False
    (dest / "index.json").write_text(json.dumps(index))
    return dest


def test_r7_fit_and_claims_refuse_shards_a_render_left_incomplete(sample_shards, tmp_path):
    """Training on part of a dataset, silently, then being unable to resume once the render is
    finished, cost the run; now fit and claims refuse before anything, naming the rerun. Control:
    the complete shards train."""
    part = _incomplete_copy(sample_shards, tmp_path / "part")
    res = run_cli(train_main, ["fit", "--shards", part, "--out", tmp_path / "run", *QUICK], expect_exit=1)
    text = one_line(res.output)
    assert f"{part}: incomplete" in text and "same render command" in text
    assert not (tmp_path / "run").exists()
    res = run_cli(train_main, ["claims", "--train-shards", part, "--eval-shards", sample_shards,
                               "--out", tmp_path / "cl"], expect_exit=1)
    assert f"{part}: incomplete" in one_line(res.output)
    res = run_cli(train_main, ["claims", "--train-shards", sample_shards, "--eval-shards", part,
                               "--out", tmp_path / "cl2"], expect_exit=1)
    assert f"{part}: incomplete" in one_line(res.output)


def test_r7_eval_of_incomplete_shards_says_so(sample_shards, tiny_run, tmp_path):
    part = _incomplete_copy(sample_shards, tmp_path / "part")
    res = run_cli(train_main, ["eval", "--checkpoint", tiny_run, "--shards", part, "--split", "train",
                               "--pose", "head", "--out", tmp_path / "ev"])
    assert "incomplete" in one_line(res.output)
    assert json.loads((tmp_path / "ev" / "metrics.json").read_text())["shards_complete"] is False
    run_cli(train_main, ["eval", "--checkpoint", tiny_run, "--shards", sample_shards, "--split", "train",
                         "--pose", "head", "--out", tmp_path / "ev2"])
    assert json.loads((tmp_path / "ev2" / "metrics.json").read_text())["shards_complete"] is True
