"""``sc3d-train``, round nine (an attack on the commands, 2026-11-27). O1: ``fit --out ''`` (an
unset ``$RUN``) trained into the current folder, and ``eval``, ``predict`` and ``claims`` wrote
there too. O2: an ``--out`` whose name is not valid UTF-8 failed in TensorBoard's writer naming no
file, after config.yaml, metrics.csv, tb/ and the lock were made. P1: ``predict`` replaced any
file of ``--out`` with a matching name (a shard folder's ``index.json``). E1: ``eval``'s default
folder took the evaluation of another checkpoint over the one it held. R1: ``eval`` said nothing
of shards rendered with other axes. R8: ``--resume`` stopped when config.yaml was deleted or cut
short, although every checkpoint holds the config. Real shards, real trainings, the real commands."""
from __future__ import annotations

import json
import os
import shutil

import pytest
import torch

from sc3d_cli.data import main as data_main
from sc3d_cli.train import main as train_main
from conftest import REPO, SAMPLE_MESHES, run_cli, error_lines
from sc3d_train.loop.checkpoint import load_checkpoint
from tests.test_train import TINY

FIT = ["--steps", 1, "--batch-size", 2, *TINY, "--val-every", 0, "--device", "cpu", "--no-progress"]


@pytest.mark.parametrize("option", ["--out", "--shards"])
def test_an_empty_folder_option_is_refused_and_nothing_is_written(sample_shards, tmp_path, monkeypatch, option):
    monkeypatch.chdir(tmp_path)
    paths = {"--shards": sample_shards, "--out": tmp_path / "run"}
    paths[option] = "  " if option == "--shards" else ""
    res = run_cli(train_main, ["fit", "--shards", paths["--shards"], "--out", paths["--out"], *FIT], expect_exit=2)
    assert f"Error: Invalid value for '{option}': is empty: give a folder (an unset variable?)" in res.output
    assert os.listdir(tmp_path) == []


def test_an_out_name_that_is_not_utf8_is_refused_before_anything_is_written(sample_shards, tmp_path):
    out = os.fsdecode(os.fsencode(str(tmp_path)) + b"/bad\xffout")  # the byte 0xff as Python holds it
    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", out, *FIT], expect_exit=1)
    errors = error_lines(res.output)
    assert errors == [f"Error: --out {tmp_path}/bad\\xffout: the name is not valid UTF-8 (byte 0xff), which "
                      "config.yaml and TensorBoard store as text; choose another name"], res.output
    assert os.listdir(tmp_path) == []


def test_predict_never_replaces_a_file_that_is_not_its_own(trained_run, sample_shards, tmp_path):
    """P1: an image named ``index.png`` predicted into a copy of a shard folder replaced its
    ``index.json`` with the prediction's JSON (the dataset then failed to open). Now refused in one
    line, the folder untouched; predicting the same image again into its own output folder still
    replaces its own five files."""
    shards = tmp_path / "shards"
    shutil.copytree(sample_shards, shards)
    image = tmp_path / "index.png"
    shutil.copyfile(REPO / "assets" / "sample_images" / "chair.png", image)
    before = (shards / "index.json").read_bytes()
    res = run_cli(train_main, ["predict", "--checkpoint", trained_run, image, "--out", shards, "--device", "cpu"],
                  expect_exit=1)
    errors = error_lines(res.output)
    assert errors == [f"Error: --out {shards}: index.json exists and is not a file of an earlier prediction (no "
                      "index.json of predict lists it), which this prediction would replace; choose another --out"]
    assert (shards / "index.json").read_bytes() == before and not (shards / "index.npz").exists()
    pred = tmp_path / "pred"
    for _ in range(2):
        run_cli(train_main, ["predict", "--checkpoint", trained_run, image, "--out", pred, "--device", "cpu"])
    assert sorted(p.name for p in pred.iterdir() if p.name != ".sc3d.lock") == [f"index.{k}" for k in ("binvox", "json", "npz", "obj", "png")]


def test_eval_never_replaces_another_evaluation_in_its_default_folder(trained_run, sample_shards, tmp_path):
    """E1: ``eval --checkpoint RUN`` then ``eval --checkpoint RUN/checkpoints/step_000180.pt`` wrote
    both into ``RUN/eval_test``; the evaluation of the final model was gone without a word. Now
    the second is refused in one line naming both checkpoints; evaluating the same checkpoint
    again replaces its own evaluation, and an explicit ``--out`` is free."""
    run = tmp_path / "run"
    shutil.copytree(trained_run, run)
    last, half = run / "checkpoints" / "last.pt", run / "checkpoints" / "step_000180.pt"
    common = ["--shards", sample_shards, "--device", "cpu", "--examples", 0, "--pose", "head"]
    for _ in range(2):
        run_cli(train_main, ["eval", "--checkpoint", run, "--pick", "last", *common])
    before = (run / "eval_test" / "metrics.json").read_text()
    assert json.loads(before)["checkpoint"] == str(last)
    res = run_cli(train_main, ["eval", "--checkpoint", half, *common], expect_exit=1)
    errors = error_lines(res.output)
    assert errors == [f"Error: {run / 'eval_test'}: holds the evaluation of checkpoint {last}, which this one "
                      f"(checkpoint {half}) would replace; give --out for this one (or remove that folder)"]
    assert (run / "eval_test" / "metrics.json").read_text() == before
    run_cli(train_main, ["eval", "--checkpoint", half, *common, "--out", tmp_path / "half"])
    assert json.loads((tmp_path / "half" / "metrics.json").read_text())["step"] == 180


def test_eval_notes_shards_rendered_with_other_axes(trained_run, tmp_path):
    """R1's eval side: shards of the same chairs rendered with other up and front axes were
    evaluated without a note (``differs_from_training`` empty); now the note names both setups.
    (``--resume`` on such shards is refused: ``test_faults_train.py::test_f1...[axes]``.)"""
    meshes, shards = tmp_path / "meshes", tmp_path / "turned"
    shutil.copytree(SAMPLE_MESHES / "chair", meshes / "chair")
    run_cli(data_main, ["render", "--meshes", meshes, "--out", shards, "--voxelize", "--up", "+Z", "--front", "-Y",
                        "--split", "random:0,0,1", "--no-progress", "--workers", 1])
    res = run_cli(train_main, ["eval", "--checkpoint", trained_run, "--shards", shards, "--out", tmp_path / "e",
                               "--device", "cpu", "--examples", 0, "--pose", "head"])
    setup = "normalize fit; shading matte-flat-headlight-v1"
    expected = f"views of up +Z; front -Y; {setup} (trained on up +Y; front auto; {setup})"
    assert any(ln.startswith("note:") and expected in ln for ln in res.output.splitlines()), res.output
    assert json.loads((tmp_path / "e" / "metrics.json").read_text())["differs_from_training"] == [expected]


@pytest.mark.parametrize("command", ["eval", "predict", "claims"])
def test_the_other_commands_refuse_an_empty_out_too(trained_run, sample_shards, tmp_path, monkeypatch, command):
    """``eval --out ''`` and ``predict --out ''`` wrote into the current folder like ``fit``'s, and
    ``claims --out ''`` started its study there."""
    monkeypatch.chdir(tmp_path)
    args = {"eval": ["eval", "--checkpoint", trained_run, "--shards", sample_shards],
            "predict": ["predict", "--checkpoint", trained_run, REPO / "assets" / "sample_images" / "chair.png"],
            "claims": ["claims", "--train-shards", sample_shards, "--eval-shards", sample_shards]}[command]
    res = run_cli(train_main, [*args, "--out", "", "--device", "cpu"], expect_exit=2)
    assert "Error: Invalid value for '--out': is empty: give a folder (an unset variable?)" in res.output
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("damage", ["deleted", "cut short"])
def test_resume_reads_a_lost_config_from_the_checkpoint_and_goes_on_exactly(sample_shards, tmp_path, damage):
    """R8: with config.yaml deleted or cut short, ``--resume`` stopped ("nothing to resume (no
    config.yaml)", or a YAML error that did not say the file was cut) although every checkpoint
    holds the run's config. Now the config is read from the newest checkpoint and written back,
    and the run goes on to the same weights as the uninterrupted run (a 4-step run taken back to
    its step-2 checkpoint); a folder in config.yaml's place, and a run with no checkpoint, are
    refused in one line."""
    whole, run = tmp_path / "whole", tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--batch-size", 2, *TINY, "--val-every", 0, "--device",
                         "cpu", "--checkpoint-every", 2, "--out", whole, "--steps", 4])
    shutil.copytree(whole, run)
    (run / "checkpoints" / "step_000004.pt").unlink()
    shutil.copyfile(run / "checkpoints" / "step_000002.pt", run / "checkpoints" / "last.pt")  # as it was at step 2
    config = run / "config.yaml"
    text = config.read_text()
    config.unlink()
    if damage == "cut short":  # three characters into the line at the middle: a key cut short, which no YAML parses
        config.write_text(text[:text.index("\n", len(text) // 2) + 4])
    res = run_cli(train_main, ["fit", "--out", run, "--resume", "--steps", 4, "--device", "cpu", "--no-progress"])
    assert (f"note: {config} {'is missing' if damage == 'deleted' else 'does not load ('}" in res.output
            and f"the run's config is read from {run / 'checkpoints' / 'last.pt'} and written back" in res.output), \
        res.output
    a, b = (load_checkpoint(r / "checkpoints" / "last.pt")["model"] for r in (whole, run))
    assert all(torch.equal(a[k], b[k]) for k in a)
    # the resumed run's config.yaml loads again, and is the original but for `out` (this copy's folder)
    assert config.read_text() == text.replace(str(whole), str(run))

    config.unlink()
    config.mkdir()
    res = run_cli(train_main, ["fit", "--out", run, "--resume", "--steps", 6, "--no-progress"], expect_exit=1)
    assert f"Error: {config}: is not a file; move it away, and --resume reads the run's config" in res.output
    config.rmdir()
    shutil.rmtree(run / "checkpoints")
    res = run_cli(train_main, ["fit", "--out", run, "--resume", "--steps", 6, "--no-progress"], expect_exit=1)
    assert f"Error: {run}: nothing to resume (no config.yaml and no checkpoint)" in res.output
