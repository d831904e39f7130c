"""Shards rendered with ``--front F`` where ``auto`` gives every object that same F (the bundled
meshes: +Z) hold the very images, masks, voxels and cameras of an ``auto`` render, so ``eval``
notes no difference from the training data and ``fit --resume --shards`` takes them as the run's
data (before, both read the words "front auto" against "front +Z": a note in ``metrics.json``'s
``differs_from_training`` about identical data, and a refused resume). A front that does differ
is still noted. Found by atk_cross."""
from __future__ import annotations

import json

from sc3d_cli.train import main
from tests.conftest import SAMPLE_MESHES, run_cli

TINY = ["--tiny", "--base-channels", "4", "--no-progress", "--val-every", "0"]


def render(out, front: str) -> None:
    from sc3d_cli.data import main as data_main

    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", out, "--voxelize", "--front", front,
                        "--workers", "1", "--no-progress"])


def differences(run, shards, out) -> list:
    run_cli(main, ["eval", "--checkpoint", run, "--shards", shards, "--split", "test", "--out", out,
                   "--examples", "0", "--pose", "head"])
    return json.loads((out / "metrics.json").read_text())["differs_from_training"]


def test_an_explicit_front_equal_to_auto_is_the_same_data(sample_shards, tmp_path):
    run = tmp_path / "run"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", run, "--steps", "1", "--batch-size", "2", *TINY])
    plus_z, minus_z = tmp_path / "plus_z", tmp_path / "minus_z"
    render(plus_z, "+Z")
    render(minus_z, "-Z")
    assert differences(run, plus_z, tmp_path / "e1") == []
    assert any("front -Z" in d for d in differences(run, minus_z, tmp_path / "e2"))
    r = run_cli(main, ["fit", "--out", run, "--resume", "--steps", "2", "--shards", plus_z])
    assert "done: step 2" in r.output
