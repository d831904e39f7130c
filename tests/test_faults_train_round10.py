"""Hostile inputs, round ten (the training commands): a nearly black background read as white, a
``--config`` file's relative shards, a ``predict`` stopped half-way, a ``semi`` run pretrained and
then extended, the Ctrl-C advice, ``eval``'s trained-on count of a labelled-only run, the
validation options' message. Real shards, real training, real checkpoints; expected values come
from the inputs (the render's options, the files fit wrote), not from the code under test."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import pytest
import torch
from PIL import Image

from sc3d_cli.data import main as data_main
from sc3d_cli.train import main as train_main
from conftest import SAMPLE_MESHES, run_cli

SHORT = ["--tiny", "--batch-size", "4", "--no-progress"]


def test_a_nearly_black_background_is_not_read_as_white(tmp_path):
    """``render --background 1,1,1`` records ``[1, 1, 1]`` (0..255); training read every colour
    with channels <= 1 as fractions and took the background for white ``[255, 255, 255]``: predict
    pasted cut-outs on white and eval saw no difference from white shards. Only a colour written
    as fractions (floats) is scaled."""
    from sc3d_train.data.dataset import background_of
    from sc3d_train.loop.resolve import shard_facts

    assert background_of({"settings": {"background": [1, 1, 1]}}) == [1, 1, 1]
    assert background_of({"settings": {"background": [0, 0, 1]}}) == [0, 0, 1]
    assert background_of({"settings": {"background": [0.5, 0.5, 1.0]}}) == [128, 128, 255]
    assert background_of({"settings": {"background": [255, 255, 255]}}) == [255, 255, 255]
    dark = tmp_path / "dark"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "table", "--out", dark, "--background", "1,1,1",
                        "--views", "4", "--voxelize", "--no-progress", "--workers", "1"])
    split = json.loads((dark / "index.json").read_text())["objects"][0]["split"]
    assert shard_facts(dark, split, "val")["background"] == [1, 1, 1]


def test_relative_shards_in_a_config_file_are_recorded_absolute(sample_shards, tmp_path, monkeypatch):
    """``shards: shards`` in a ``--config`` file stayed relative in the run's ``config.yaml``: the
    run then resumed, and repeated with ``--config RUN/config.yaml``, only from the folder it was
    started in. Now it is read from the current folder, as ``--shards`` is, and recorded absolute."""
    project = tmp_path / "project"
    project.mkdir()
    shutil.copytree(sample_shards, project / "shards")
    (project / "c.yaml").write_text("shards: shards\nsteps: 1\nval_every: 0\n")
    monkeypatch.chdir(project)
    run_cli(train_main, ["fit", "--config", "c.yaml", "--out", "run", *SHORT])
    recorded = [ln for ln in (project / "run" / "config.yaml").read_text().splitlines() if ln.startswith("shards:")]
    assert recorded == [f"shards: {(project / 'shards').resolve()}"], recorded
    monkeypatch.chdir(tmp_path)
    res = run_cli(train_main, ["fit", "--out", project / "run", "--resume", "--steps", "2", "--no-progress"])
    assert "Error" not in res.output and (project / "run" / "checkpoints" / "step_000002.pt").is_file()


def test_predict_stopped_half_way_can_be_run_again(trained_run, sample_shards, tmp_path, monkeypatch):
    """An image's files were written ``.binvox``, ``.npz``, ``.obj``, ``.png``, then the ``.json``
    that lists them: a Ctrl-C in between left files no listing named, and the same command was then
    refused ("not a file of an earlier prediction"). Now the listing comes first (written whole),
    so the rerun replaces the half-written files. The Ctrl-C is injected where the picture is drawn."""
    import sc3d_train.evaluation.predict as predict_module

    with h5py.File(next(sample_shards.glob("shard-*.h5")), "r") as f:
        Image.fromarray(f["images"][0, 3]).save(tmp_path / "view.png")
    out = tmp_path / "pred"
    args = ["predict", "--checkpoint", trained_run, tmp_path / "view.png", "--out", out, "--pose", "head"]

    def interrupted(*_a, **_k):
        raise KeyboardInterrupt

    monkeypatch.setattr(predict_module, "plot_prediction", interrupted)
    assert "Aborted!" in run_cli(train_main, args, expect_exit=1).output  # click's answer to Ctrl-C
    assert (out / "view.binvox").is_file() and not (out / "view.png").exists()
    monkeypatch.undo()
    res = run_cli(train_main, args)
    listing = json.loads((out / "view.json").read_text())
    assert sorted(Path(p).name for p in listing["files"].values()) == sorted(p.name for p in out.iterdir() if p.name != ".sc3d.lock"), res.output


def test_a_semi_run_extended_on_resume_keeps_no_pretraining_best(sample_shards, tmp_path):
    """A ``semi`` run trained to the end of its pretraining (``--steps`` = ``--pretrain-steps``)
    keeps a pretraining ``best.pt``; extended with ``--resume --steps``, that checkpoint stayed
    ``best.pt`` unless a mixed-phase one scored higher, and ``eval`` reported labelled-only weights
    as the semi run. Now the extended run's ``best.pt`` comes from its mixed phase, as one run
    with the whole schedule gives."""
    out = tmp_path / "run"
    common = ["--val-every", "2", "--val-min-objects", "1", "--checkpoint-every", "2"]
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", out, "--semi", "--labeled-fraction", "0.5",
                         "--pretrain-steps", "4", "--steps", "4", *common, *SHORT])
    assert torch.load(out / "checkpoints" / "best.pt", weights_only=True)["step"] <= 4  # pretraining's own
    run_cli(train_main, ["fit", "--out", out, "--resume", "--steps", "8", "--no-progress"])
    best = out / "checkpoints" / "best.pt"
    assert best.is_file() and torch.load(best, weights_only=True)["step"] in (6, 8)


def test_ctrl_c_advice_names_how_the_command_resumes(tmp_path):
    """``fit`` said "resume with --resume" under ``claims`` (which has no ``--resume``: it resumes
    by running it again), and also when there was no checkpoint to resume from."""
    from sc3d_train.loop.checkpoint_resume import interrupted_line

    run = tmp_path / "run"
    assert interrupted_line(run, "resume with --resume") == \
        "interrupted before the first checkpoint: nothing to resume (start the run again)"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "last.pt").write_bytes(b"")
    assert interrupted_line(run, "run the same claims command again to resume") == \
        f"interrupted; last good checkpoint: {run / 'checkpoints' / 'last.pt'} (run the same claims command again to resume)"
    source = (Path(__file__).parents[1] / "sc3d_train" / "evaluation" / "claims.py").read_text()
    assert 'resume_hint="run the same claims command again to resume"' in source


def test_eval_counts_only_the_labelled_objects_of_a_labelled_only_run(sample_shards, tmp_path):
    """A ``--labeled-only`` run reads only its labelled objects (``labeled_objects.txt``), but
    ``eval --split train`` counted every training object as trained on."""
    out = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", out, "--labeled-only", "--labeled-fraction", "0.15",
                         "--steps", "1", "--val-every", "0", *SHORT])
    labelled = set((out / "labeled_objects.txt").read_text().split())
    train = {f"{o['category']}/{o['model_id']}" for o in json.loads((sample_shards / "index.json").read_text())["objects"]
             if o["split"] == "train"}
    assert labelled < train
    run_cli(train_main, ["eval", "--checkpoint", out, "--shards", sample_shards, "--split", "train", "--out",
                         tmp_path / "ev", "--pose", "head"])
    assert json.loads((tmp_path / "ev" / "metrics.json").read_text())["trained_on"] == len(labelled)


@pytest.mark.parametrize("option, value, least", [("val-views", "0", 1), ("val-min-objects", "0", 1),
                                                   ("val-every", "-1", 0)])
def test_each_validation_option_is_named_in_its_error(sample_shards, tmp_path, option, value, least):
    """``--val-views 0``, ``--val-min-objects 0`` and ``--val-every -1`` gave one message that named
    none of them; each is now named with its value, as the other options are."""
    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", tmp_path / "run", "--steps", "2",
                               f"--{option}", value, *SHORT], expect_exit=1)
    key = option.replace("-", "_")
    assert f"Error: {key} (--{option}) must be >= {least}, got {value}" in res.output, res.output


def test_the_resume_options_are_listed_where_users_read_them():
    """``--resume`` accepts ``--val-every`` (and more) that ``fit --help``, config.md and
    training.md left out; each now names every setting a resume may change
    (``RESUMABLE_FIELDS``, the list the code enforces)."""
    from click.testing import CliRunner

    from sc3d_train.settings.config import RESUMABLE_FIELDS

    docs = Path(__file__).parents[1] / "docs"
    config_md = " ".join((docs / "config.md").read_text().split())
    training_md = " ".join((docs / "training.md").read_text().split())
    help_text = " ".join(CliRunner().invoke(train_main, ["fit", "--help"]).output.split())
    config_list = config_md[config_md.index("`--resume` continues a run"):][:400]
    training_list = training_md[training_md.index("`--resume` may change only"):][:400]
    resume_help = help_text[help_text.index("--resume Continue"):][:500]
    for field in RESUMABLE_FIELDS:
        option = "--" + field.replace("_", "-")
        assert f"`{field}`" in config_list, field
        assert f"`{option}`" in training_list, option
        assert option in resume_help, option
