"""The fourth attack on ``sc3d-train`` (fit, eval, predict, claims as a user runs them): one
test per finding T1-Tn. Real shards (the bundled sample meshes rendered through the CLI), real
tiny training and checkpoints; no mocks."""
from __future__ import annotations

import shutil

import pytest

from sc3d_cli.train import main as train_main
from conftest import run_cli

TINY = ["--tiny", "--base-channels", "4", "--batch-size", "4", "--no-progress", "--val-every", "0"]


def one_line(output: str) -> str:
    """The single line of a failed command's output (fails when there is more, e.g. a traceback)."""
    lines = output.strip().splitlines()
    assert len(lines) == 1, output
    return lines[0]


def folder_bytes(folder):
    """``{relative path: bytes}`` of every file under ``folder`` (not the lock file of a command
    that wrote there: ``predict`` and ``eval`` lock their ``--out``)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != ".sc3d.lock"}


@pytest.fixture(scope="module")
def tiny_run(sample_shards, tmp_path_factory):
    """A 2-step run of the tiny network on the sample shards (its folder)."""
    run = tmp_path_factory.mktemp("tiny_run4") / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, "--steps", 2, *TINY])
    return run


# ----------------------------------------------------------------------------- T1
@pytest.mark.parametrize("option, message", [
    (["--steps", "0"], "steps (--steps) must be >= 1, got 0"),
    (["--steps", "4", "--log-every", "0"], "log_every (--log-every) must be >= 1, got 0"),
    (["--steps", "4", "--checkpoint-every", "0"], "checkpoint_every (--checkpoint-every) must be >= 1, got 0"),
    (["--steps", "4", "--workers", "-1"], "workers (--workers) must be >= 0, got -1"),
    (["--steps", "4", "--val-every", "-5"], "val_every (--val-every) must be >= 0, got -5"),
])
def test_t1_resume_checks_the_options_it_may_change_like_a_new_run(tiny_run, tmp_path, option, message):
    """``fit --resume`` set the options it may change (``--steps``, ``--log-every``,
    ``--checkpoint-every``, ``--workers``, ``--val-every``) on the saved config without the range
    checks a new run gets: ``--steps 0`` (or -3) exited 0 ("training ... for 0 steps"),
    ``--log-every 0`` and ``--checkpoint-every 0`` ended in a traceback (a full loss window, a
    modulo by zero), ``--workers -1`` in torch's DataLoader message naming no option, and
    ``--val-every -5`` trained with validation on. Now each is refused in one line naming the
    setting, before any step, and the run folder is left byte for byte as it was."""
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    before = folder_bytes(run)
    res = run_cli(train_main, ["fit", "--out", run, "--resume", "--no-progress", *option], expect_exit=1)
    assert message in one_line(res.output)
    assert folder_bytes(run) == before


# ----------------------------------------------------------------------------- T2
def test_t2_a_hand_written_config_without_shards_and_out_takes_them_from_the_command_line(sample_shards, tmp_path):
    """docs/config.md: a config file need not list every key, and ``--shards``/``--out`` replace
    the file's. A hand-written file holding only the settings to vary (``model.base_channels``,
    ``loss_weights.proj``) with ``--shards`` and ``--out`` given was refused all the same:
    ``missing RunConfig keys ['shards', 'out']`` (the file was validated alone, before the
    options were applied). Now the run trains with the file's settings and the given paths; a
    file and command line that together lack ``--out`` still name the missing key."""
    import yaml

    config = tmp_path / "vary.yaml"
    config.write_text("model:\n  base_channels: 4\nloss_weights:\n  proj: 0.0\n")
    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--config", config, "--shards", sample_shards, "--out", run, "--steps", 2,
                         "--batch-size", 4, "--no-progress", "--val-every", 0])
    saved = yaml.safe_load((run / "config.yaml").read_text())
    assert saved["model"]["base_channels"] == 4 and saved["loss_weights"]["proj"] == 0.0
    assert saved["shards"] == str(sample_shards.resolve()) and saved["steps"] == 2
    assert (run / "checkpoints" / "last.pt").is_file()
    res = run_cli(train_main, ["fit", "--config", config, "--shards", sample_shards, "--steps", 2], expect_exit=1)
    assert f"{config}: missing RunConfig keys ['out']" in one_line(res.output)


# ----------------------------------------------------------------------------- T3
def test_t3_predict_never_writes_its_picture_over_an_input_image(sample_shards, tiny_run, tmp_path):
    """``predict imgs/view.png --out imgs`` (predictions beside the images) wrote its picture
    ``NAME.png`` over the input: ``imgs/view.png`` became the 675x252 plot, the user's image was
    gone, exit 0. So did ``imgs/view.jpg imgs/view.png`` (the .jpg's picture is ``view.png``).
    Now both are refused in one line naming ``--out`` and the input, before anything is written;
    the folder keeps its bytes, and the same images predict into another ``--out``."""
    import h5py
    from PIL import Image

    imgs = tmp_path / "imgs"
    imgs.mkdir()
    with h5py.File(next(sample_shards.glob("*.h5")), "r") as f:
        Image.fromarray(f["images"][0, 0]).save(imgs / "view.png")
        Image.fromarray(f["images"][0, 5]).save(imgs / "view.jpg")
    before = folder_bytes(imgs)
    checkpoint = tiny_run / "checkpoints" / "last.pt"
    for images in ([imgs / "view.png"], [imgs / "view.jpg", imgs / "view.png"]):
        res = run_cli(train_main, ["predict", "--checkpoint", checkpoint, *images, "--out", imgs], expect_exit=1)
        assert (f"--out {imgs}: its view.png (the prediction's .png) would overwrite the input image "
                f"{imgs / 'view.png'}; choose another --out") in one_line(res.output)
        assert folder_bytes(imgs) == before
    run_cli(train_main, ["predict", "--checkpoint", checkpoint, imgs / "view.jpg", imgs / "view.png",
                         "--out", tmp_path / "pred"])
    assert sorted(p.name for p in (tmp_path / "pred").glob("*.png")) == ["view.png", "view_.png"]
    assert folder_bytes(imgs) == before


# ----------------------------------------------------------------------------- T4
@pytest.mark.parametrize("weights, message", [
    ("  w3d: -1\n", "loss_weights: w3d must be a finite weight >= 0, got -1.0"),
    ("  wsc: .nan\n", "loss_weights: wsc must be a finite weight >= 0, got nan"),
    ("  pos_weight: 0\n", "loss_weights: pos_weight must be a finite weight > 0, got 0.0"),
])
def test_t4_a_config_file_with_a_negative_or_nan_loss_weight_is_refused_naming_the_key(sample_shards, tmp_path,
                                                                                   weights, message):
    """A hand-edited config with ``loss_weights.w3d: -1`` trained with exit 0 a network that
    ascends its 3D loss (the total fell to 3.26 from 6.79 while L_3D stayed), ``pos_weight: 0``
    one that ignores every occupied voxel, and ``wsc: .nan`` ran to "loss is nan at step 0",
    naming no key, after writing config.yaml. Now each is refused in one line naming the file
    and the key, and no run folder is made."""
    config = tmp_path / "weights.yaml"
    config.write_text("loss_weights:\n" + weights)
    run = tmp_path / "run"
    res = run_cli(train_main, ["fit", "--config", config, "--shards", sample_shards, "--out", run, "--steps", 2,
                               *TINY], expect_exit=1)
    assert f"{config}: {message}" in one_line(res.output)
    assert not run.exists()


# ----------------------------------------------------------------------------- T5
def test_t5_claims_refuses_to_evaluate_on_objects_its_runs_train_on(sample_shards, tmp_path):
    """``claims --eval-split train`` (same shards), or ``--eval-shards`` rendered with another split
    seed (``render --seed 1``: another test split, which holds objects of the first render's
    train split), trained every run and wrote the paper's tables from objects the runs had
    trained on, exit 0: figures labelled held-out that were not. Now the study is refused
    before any training in one line naming the shards and the number of shared objects (counted
    here from the two index.json files), and no study folder is made."""
    import json

    from sc3d_cli.data import main as data_main
    from sc3d_train.data.dataset import DataError
    from sc3d_train.evaluation.claims import ClaimsPreset, run_all
    from conftest import SAMPLE_MESHES

    other = tmp_path / "shards-seed1"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", other, "--voxelize", "--workers", "2",
                        "--seed", "1", "--no-progress"])

    def objects(shards, split):
        index = json.loads((shards / "index.json").read_text())
        return {(o["category"], o["model_id"]) for o in index["objects"] if o["split"] == split}

    shared = objects(sample_shards, "train") & objects(other, "test")
    assert shared and not objects(sample_shards, "train") & objects(sample_shards, "test")
    preset = ClaimsPreset(steps=2, batch_size=4, lr=1e-3, tiny=True, extra={"val_every": 0, "base_channels": 4})
    out = tmp_path / "study"
    for eval_shards, split, count in ((sample_shards, "train", len(objects(sample_shards, "train"))),
                                      (other, "test", len(shared))):
        with pytest.raises(DataError) as e:
            run_all(sample_shards, eval_shards, out, preset, eval_split=split, device="cpu", runs=["sup-3tube"],
                    echo=lambda _: None)
        assert (f"{eval_shards}: {count} object(s) of split {split!r} are 'train' objects of {sample_shards} "
                f"that the runs train on") in str(e.value)
        assert not out.exists()
        res = run_cli(train_main, ["claims", "--train-shards", sample_shards, "--eval-shards", eval_shards,
                                   "--eval-split", split, "--out", out, "--runs", "sup-3tube"], expect_exit=1)
        assert "claims evaluates on objects never trained on" in one_line(res.output)
        assert not out.exists()
    from sc3d_train.evaluation.claims import check_held_out

    check_held_out(sample_shards, sample_shards, "test", "train")  # the default study: held out


# ----------------------------------------------------------------------------- T6
@pytest.mark.parametrize("weights", ["int", "one weight an int"])
def test_t6_a_checkpoint_whose_model_is_no_state_dict_is_refused_in_one_line(sample_shards, tiny_run, tmp_path,
                                                                              weights):
    """A ``.pt`` that loads under ``weights_only`` and holds a valid ``config`` but a ``model``
    that is no state dict of tensors (another program's file, a hand-made one) ended ``eval`` and
    ``predict`` in a traceback (``TypeError: argument of type 'int' is not iterable``,
    ``AttributeError: 'int' object has no attribute 'shape'``). Now one line naming the file,
    nothing written."""
    import torch

    from sc3d_train.loop.checkpoint import load_checkpoint

    real = load_checkpoint(tiny_run / "checkpoints" / "last.pt")
    model = 5 if weights == "int" else {**real["model"], next(iter(real["model"])): 5}
    crafted = tmp_path / "crafted.pt"
    torch.save({"model": model, "config": real["config"]}, crafted)
    image = tmp_path / "view.png"
    with h5py_file(sample_shards) as f:
        from PIL import Image

        Image.fromarray(f["images"][0, 0]).save(image)
    for args in (["eval", "--checkpoint", crafted, "--shards", sample_shards, "--out", tmp_path / "ev"],
                 ["predict", "--checkpoint", crafted, image, "--out", tmp_path / "pred"]):
        res = run_cli(train_main, args, expect_exit=1)
        assert f"{crafted}: not an sc3d-train checkpoint" in one_line(res.output)
    assert not (tmp_path / "ev").exists() and not (tmp_path / "pred").exists()


def h5py_file(shards):
    """The first shard file of ``shards``, open for reading."""
    import h5py

    return h5py.File(next(shards.glob("*.h5")), "r")
