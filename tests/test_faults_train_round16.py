"""Defects of the training half found by the sixteenth attack on the commands (2026-11-28), each
test failing without its fix. Real (tiny) runs, real checkpoint files, real YAML."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import torch
from PIL import Image

from sc3d_cli.train import main as train_main
from conftest import one_error, run_cli
from test_faults_train import TINY, tiny_run  # noqa: F401 - the fixture (a 2-step run)


def test_ctrl_c_between_the_step_file_and_last_pt_names_the_step_file(sample_shards, tmp_path, monkeypatch):
    """A Ctrl-C after ``step_000002.pt`` was written but before it was copied to ``last.pt`` said
    "interrupted before the first checkpoint: nothing to resume (start the run again)"; starting
    again is then refused (the folder holds a step file) while ``--resume`` works. The line now
    names the step file and says to resume, which then continues from it."""
    from sc3d_train.loop import checkpoint

    real = checkpoint.shutil.copyfile
    for stop_at in (2, 4):  # the first checkpoint (no last.pt yet), and a later one (last.pt of step 2)
        def stopped_before_last(src, dst):
            if f"step_{stop_at:06d}" in str(src):
                raise KeyboardInterrupt
            return real(src, dst)

        out = tmp_path / f"run{stop_at}"
        args = ["fit", "--shards", sample_shards, "--out", out, "--steps", 6, "--checkpoint-every", 2, *TINY]
        with monkeypatch.context() as m:
            m.setattr(checkpoint.shutil, "copyfile", stopped_before_last)
            res = run_cli(train_main, args, expect_exit=None)
        assert res.exit_code != 0, res.output
        step_file = out / "checkpoints" / f"step_{stop_at:06d}.pt"
        assert f"last good checkpoint: {step_file} (resume with --resume)" in res.output, res.output
        res = run_cli(train_main, [*args, "--resume"])
        assert "resuming from" in res.output and f"(step {stop_at})" in res.output, res.output


@pytest.mark.parametrize("text, key", [("1: 2\n", "'1'"), ("model: {true: 4}\n", "'model.True'")])
def test_a_config_key_that_is_no_string_is_refused_in_one_line(sample_shards, tmp_path, text, key):
    """A ``--config`` file with a key YAML reads as a number or a boolean (``1: 2``, ``model:
    {true: 4}``) ended in a traceback (``TypeError: can only concatenate str (not "int") to str``)
    or a line that meant nothing; one line now names the file and the key."""
    config = tmp_path / "c.yaml"
    config.write_text(f"shards: {sample_shards}\nout: {tmp_path / 'run'}\n" + text)
    error = one_error(run_cli(train_main, ["fit", "--config", config], expect_exit=1).output)
    assert "c.yaml" in error and f"keys [{key}]" in error, error


def test_a_checkpoint_naming_a_huge_network_is_refused_before_it_is_built(tiny_run, tmp_path):  # noqa: F811
    """A 2-step checkpoint whose stored config was edited to ``base_channels: 1000000`` made
    ``eval`` and ``predict`` build that network before comparing it with the file's weights:
    "DefaultCPUAllocator: can't allocate memory: you tried to allocate 36000000000000 bytes"
    (a smaller number would really take tens of GB). The shapes are now compared first, on the
    meta device, and the file is refused in one line."""
    ckpt = torch.load(tiny_run / "checkpoints" / "last.pt", weights_only=False)
    ckpt["config"]["model"]["base_channels"] = 1000000
    huge = tmp_path / "huge.pt"
    torch.save(ckpt, huge)
    image = tmp_path / "view.png"
    Image.new("RGB", (64, 64), (200, 30, 30)).save(image)
    error = one_error(run_cli(train_main, ["predict", "--checkpoint", huge, image, "--out", tmp_path / "p"],
                              expect_exit=1).output)
    assert "weights do not match the model config stored in it" in error and "shape differs" in error, error
    shutil.copy(tiny_run / "checkpoints" / "last.pt", tmp_path / "fine.pt")  # control: the same file unedited
    run_cli(train_main, ["predict", "--checkpoint", tmp_path / "fine.pt", image, "--out", tmp_path / "q"])


def test_the_same_checkpoint_named_from_another_folder_keeps_its_default_folders(sample_shards, tiny_run, tmp_path,  # noqa: F811
                                                                              monkeypatch):
    """``predict`` and ``eval`` recorded the checkpoint (and shards) as typed; their default
    folder's check resolved that against the current folder, so the same checkpoint named from
    another folder (``run/checkpoints/last.pt``, then ``checkpoints/last.pt`` inside ``run``) was
    refused as "the prediction of another checkpoint". They record absolute paths now."""
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    image = tmp_path / "view.png"
    Image.new("RGB", (64, 64), (200, 30, 30)).save(image)
    monkeypatch.chdir(tmp_path)
    run_cli(train_main, ["predict", "--checkpoint", "run/checkpoints/last.pt", "view.png"])
    run_cli(train_main, ["eval", "--checkpoint", "run/checkpoints/last.pt", "--shards", sample_shards, "--examples", 0])
    monkeypatch.chdir(run)
    run_cli(train_main, ["predict", "--checkpoint", "checkpoints/last.pt", "../view.png"])
    run_cli(train_main, ["eval", "--checkpoint", "checkpoints/last.pt", "--shards", sample_shards, "--examples", 0])


def test_an_image_given_twice_is_predicted_once(tiny_run, tmp_path, monkeypatch):  # noqa: F811
    """``predict imA/x.png imA/x.png ./imA/x.png`` wrote three identical predictions, ``x.*``,
    ``x_.*`` and ``x__.*``. One file is predicted once, under its first path; another file of
    the same name still gets its own (``x_``: control)."""
    monkeypatch.chdir(tmp_path)
    for folder in ("imA", "imB"):
        Path(folder).mkdir()
        Image.new("RGB", (64, 64), (200, 30, 30)).save(f"{folder}/x.png")
    res = run_cli(train_main, ["predict", "--checkpoint", tiny_run, "imA/x.png", "imA/x.png", "./imA/x.png",
                               "imB/x.png", "--out", "p"])
    assert sorted(p.name for p in Path("p").glob("*.json")) == ["x.json", "x_.json"], res.output
    assert [ln.split(":")[0] for ln in res.output.splitlines() if "voxels ->" in ln] == ["imA/x.png", "imB/x.png"]
