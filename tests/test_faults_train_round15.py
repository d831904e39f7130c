"""Defects of the training half left by the fifteenth attack (2026-11-28), each test failing without
its fix. Real checkpoints of a real (tiny) run, real files."""
from __future__ import annotations

import shutil

import h5py
from PIL import Image

from sc3d_cli.train import main as train_main
from conftest import one_error, run_cli
from test_faults_train import tiny_run  # noqa: F401 - the fixture (a 2-step run)


def _files(folder):
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file() and p.name != ".sc3d.lock"}


def test_predict_never_gives_its_default_folder_to_another_checkpoint(sample_shards, tiny_run, tmp_path):  # noqa: F811
    """``predict --checkpoint RUN/checkpoints/last.pt view.png`` then the same image with another
    checkpoint file (or ``--pose``) replaced ``RUN/predictions/view.*`` without a word, as ``eval``'s
    default folder no longer does. Now refused in one line naming both, nothing written; the same
    checkpoint again, another image, or an explicit ``--out`` still predict (controls)."""
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    other = run / "checkpoints" / "step_000001.pt"
    shutil.copy(run / "checkpoints" / "last.pt", other)
    image = tmp_path / "view.png"
    with h5py.File(sorted(sample_shards.glob("shard-*.h5"))[0]) as f:
        Image.fromarray(f["images"][0, 0]).save(image)
    last = ["predict", "--checkpoint", run / "checkpoints" / "last.pt", "--device", "cpu"]
    run_cli(train_main, [*last, image])
    before = _files(run / "predictions")

    res = run_cli(train_main, ["predict", "--checkpoint", other, image, "--device", "cpu"], expect_exit=1)
    error = one_error(res.output)
    assert "view.json holds the prediction of checkpoint" in error and "last.pt" in error and "--out" in error, error
    res = run_cli(train_main, [*last, image, "--pose", "head"], expect_exit=1)
    assert "--pose search" in one_error(res.output)
    assert _files(run / "predictions") == before

    run_cli(train_main, [*last, image])  # the same checkpoint replaces its own prediction
    second = tmp_path / "second.png"
    shutil.copy(image, second)
    run_cli(train_main, ["predict", "--checkpoint", other, second, "--device", "cpu"])  # another image's name
    run_cli(train_main, ["predict", "--checkpoint", other, image, "--device", "cpu", "--out", run / "predictions"])


def test_a_semi_run_that_never_leaves_its_pretraining_is_warned_of(sample_shards, tmp_path):
    """``fit --semi --pretrain-steps 3 --steps 3`` trained labelled-only from start to end without a
    word (no step of the unlabelled phase). One warning line now says so; a semi run that does
    reach its unlabelled phase gets none (control)."""
    from test_faults_train import TINY

    semi = ["fit", "--shards", sample_shards, "--semi", *TINY]
    res = run_cli(train_main, [*semi, "--out", tmp_path / "a", "--steps", "3", "--pretrain-steps", "3"])
    warned = [ln for ln in res.output.splitlines() if "never reaches its phase on unlabelled images" in ln]
    assert len(warned) == 1 and warned[0].startswith("warning: --pretrain-steps 3 >= --steps 3"), res.output
    res = run_cli(train_main, [*semi, "--out", tmp_path / "b", "--steps", "3", "--pretrain-steps", "2"])
    assert "never reaches" not in res.output


def _val_rows(run) -> dict[str, list[str]]:
    lines = (run / "validation.csv").read_text().splitlines()[1:]
    return {ln.split(",")[0]: ln.split(",")[1:5] for ln in lines}  # step -> the four figures


def test_a_validation_cut_short_by_ctrl_c_is_done_on_resume(sample_shards, tmp_path, monkeypatch):
    """A step saves its checkpoint, then validates. A Ctrl-C in that validation left the step's
    checkpoint and no validation of it; ``--resume`` went on from there (or, at the last step,
    said "nothing to train"), so that step never became a candidate for ``best.pt``. Now the
    resumed run validates it first. Expected: the rows of an uninterrupted run, figure for figure
    (an exact resume holds the same weights)."""
    from sc3d_train.loop.validation import Validator

    args = ["fit", "--shards", sample_shards, "--batch-size", 2, "--tiny", "--base-channels", "4", "--no-progress",
            "--checkpoint-every", 2, "--val-every", 2, "--val-min-objects", 1, "--steps", 4]
    whole = tmp_path / "whole"
    run_cli(train_main, [*args, "--out", whole])
    assert list(_val_rows(whole)) == ["2", "4"]
    original = Validator.run
    for stop_at in (2, 4):
        def interrupted(self, model, done):
            if done == stop_at:
                raise KeyboardInterrupt
            return original(self, model, done)

        run = tmp_path / f"stopped_at_{stop_at}"
        with monkeypatch.context() as m:
            m.setattr(Validator, "run", interrupted)
            res = run_cli(train_main, [*args, "--out", run], expect_exit=None)
        assert res.exit_code != 0 and stop_at not in map(int, _val_rows(run)), res.output
        res = run_cli(train_main, [*args, "--out", run, "--resume"])
        assert _val_rows(run) == _val_rows(whole), res.output
        if stop_at == 4:
            assert "validated that step" in res.output, res.output
    res = run_cli(train_main, [*args, "--out", run, "--resume"])  # control: nothing owed, nothing done
    assert "nothing to train" in res.output and "validated" not in res.output
