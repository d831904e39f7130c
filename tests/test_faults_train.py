"""Hostile inputs to ``sc3d-train``, round three (and findings of round four that concern the
training side: F12 ``--resume --tiny``, F13 objects whose voxelization failed): one test per
finding F1-Fn (resume on shards that were rendered again, ...). Real shards, training and checkpoints; every fixture is built
here (the sample shards of ``conftest.py`` are rendered from the bundled meshes)."""
from __future__ import annotations

import json
import shutil

import h5py
import pytest
from PIL import Image

from sc3d_cli.data import main as data_main
from sc3d_cli.train import main as train_main
from conftest import SAMPLE_MESHES, run_cli, error_lines

TINY = ["--tiny", "--base-channels", "4", "--batch-size", "4", "--no-progress", "--val-every", "0"]


def one_line(output: str) -> str:
    """The single line of a failed command's output (fails when there is more, e.g. a traceback)."""
    lines = output.strip().splitlines()
    assert len(lines) == 1, output
    return lines[0]


# ----------------------------------------------------------------------------- F1
VIEWS = "elevations [30.0]; up +Y; front auto; normalize fit; shading matte-flat-headlight-v1"  # render's defaults


@pytest.mark.parametrize("render_again, changed", [
    (["--seed", "1"], "the objects of split 'train'"),
    (["--background", "0,0,0"], "background [255, 255, 255] -> [0, 0, 0]"),
    # round nine: other elevations or axes change every image at the same size and camera
    (["--elevations", "45"], f"view_setup {VIEWS!r} -> {VIEWS.replace('[30.0]', '[45.0]')!r}"),
    (["--up", "+Z", "--front", "-Y"], f"view_setup {VIEWS!r} -> {VIEWS.replace('up +Y; front auto', 'up +Z; front -Y')!r}"),
], ids=["seed", "background", "elevations", "axes"])
def test_f1_resume_refuses_shards_rendered_again_with_other_objects_or_camera(sample_shards, tmp_path,
                                                                             render_again, changed):
    """A run's shards rendered again in place (another split seed: other training objects;
    another background, camera or size) used to be resumed silently: the run continued on other
    data, config.yaml kept the old facts (which predict uses) and test objects could be trained
    on. ``--resume`` now refuses in one line naming the shards and what changed, and the
    run's checkpoint is left as it was."""
    shards, run = tmp_path / "shards", tmp_path / "run"
    shutil.copytree(sample_shards, shards)
    run_cli(train_main, ["fit", "--shards", shards, "--out", run, "--steps", 2, *TINY])
    before = (run / "checkpoints" / "last.pt").read_bytes()
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", shards, "--voxelize", "--overwrite",
                        "--workers", "2", "--no-progress", *render_again])
    res = run_cli(train_main, ["fit", "--out", run, "--resume", "--steps", 4, "--no-progress"], expect_exit=1)
    line = one_line(res.output)
    assert f"{shards}: the shards changed since run {run} started ({changed})" in line, line
    assert (run / "checkpoints" / "last.pt").read_bytes() == before
    assert not (run / "checkpoints" / "step_000004.pt").exists()


@pytest.fixture(scope="module")
def tiny_run(sample_shards, tmp_path_factory):
    """A 2-step run of the tiny network on the sample shards (its folder)."""
    run = tmp_path_factory.mktemp("tiny_run") / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, "--steps", 2, *TINY])
    return run


# ----------------------------------------------------------------------------- F2
def test_f2_a_bad_or_missing_device_is_one_line_naming_the_option(sample_shards, tiny_run, tmp_path):
    """``--device gpu7`` (or ``meta``) and ``--device cuda`` on a machine without CUDA used to end
    in a traceback (torch's "Invalid device string", "Torch not compiled with CUDA enabled") in
    fit, eval and predict; now one line naming ``--device``, before any output is written."""
    import torch

    image = tmp_path / "view.png"
    with h5py.File(next(sample_shards.glob("*.h5")), "r") as f:
        Image.fromarray(f["images"][0, 0]).save(image)
    commands = {"fit": ["fit", "--shards", sample_shards, "--out", tmp_path / "run", "--steps", 2, *TINY],
                "eval": ["eval", "--checkpoint", tiny_run, "--shards", sample_shards, "--out", tmp_path / "eval"],
                "predict": ["predict", "--checkpoint", tiny_run / "checkpoints" / "last.pt", image,
                            "--out", tmp_path / "pred"]}
    bad = {"gpu7": "--device 'gpu7': not a device; use auto", "meta": "--device 'meta': not a device"}
    if not torch.cuda.is_available():
        bad["cuda"] = "--device cuda: CUDA is not available here"
    for name, args in commands.items():
        for device, message in bad.items():
            res = run_cli(train_main, [*args, "--device", device], expect_exit=1)
            assert message in res.output.strip().splitlines()[-1], (name, res.output)
            # one line: fit's "training ..." line came first until round ten
            assert "Traceback" not in res.output and len(res.output.strip().splitlines()) == 1, res.output
        assert not any((tmp_path / d).exists() for d in ("run", "eval", "pred")), name


# ----------------------------------------------------------------------------- F3
@pytest.mark.parametrize("option, value, message", [
    ("--log-every", 0, "log_every (--log-every) must be >= 1, got 0"),
    ("--checkpoint-every", 0, "checkpoint_every (--checkpoint-every) must be >= 1, got 0"),
    ("--seed", -1, "seed (--seed) must be in [0, 2^63), got -1"),
    ("--seed", 10 ** 20, "seed (--seed) must be in [0, 2^63)"),
    ("--lr", "nan", "lr (--lr) must be a positive finite number, got nan"),
    ("--lr", -1, "lr (--lr) must be a positive finite number, got -1.0"),
    ("--lr-min-ratio", -1, "lr_min_ratio (--lr-min-ratio) must be in [0, 1]"),
    ("--workers", -3, "workers (--workers) must be >= 0, got -3"),
])
def test_f3_out_of_range_settings_are_refused_in_one_line_before_any_work(sample_shards, tmp_path, option,
                                                                          value, message):
    """Settings out of range used to reach the loop: ``--log-every 0`` and ``--checkpoint-every
    0`` ended in a traceback (``ZeroDivisionError``) after the data was read; ``--seed -1``,
    ``--lr nan`` and ``--workers -3`` in a message of numpy / torch naming no option;
    ``--lr-min-ratio -1`` trained with exit 0 while the cosine schedule drove the learning rate
    below zero (gradient ascent at the end). Now one line naming the option, no run folder."""
    run = tmp_path / "run"
    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, "--steps", 2, *TINY, option, value],
                  expect_exit=1)
    assert message in one_line(res.output), res.output
    assert not run.exists()


def test_f3_a_config_file_with_a_zero_ray_sample_count_is_refused_naming_the_file(sample_shards, tmp_path):
    """``loss_weights: {num_samples: 0}`` trained with exit 0 on empty rays (L_proj stuck at
    e - 1); ``search_mask_size: 0`` ended in a ``ZeroDivisionError`` traceback."""
    for key in ("num_samples", "search_mask_size"):
        config = tmp_path / f"{key}.yaml"
        config.write_text(f"shards: {sample_shards}\nout: {tmp_path / key}\nloss_weights: {{{key}: 0}}\n")
        res = run_cli(train_main, ["fit", "--config", config, *TINY, "--steps", 2], expect_exit=1)
        assert f"{config}: loss_weights: {key} must be >= 1, got 0" in one_line(res.output), res.output


# ----------------------------------------------------------------------------- F4
def test_f4_semi_pretraining_default_follows_the_steps_given_on_the_command_line(sample_shards, tmp_path):
    """A config file with ``mode: semi`` and no ``pretrain_steps`` had its default (steps // 2)
    taken from the file's steps (or the default 2000) before ``--steps`` replaced them: ``--steps
    4`` was refused with "pretrain steps 1000 not in [0, steps=4]" (a number the user never
    wrote) and ``--steps 40`` on a file of 20 pretrained 10 steps, not 20. The default now
    follows the run's own steps, as on the command line."""
    config = tmp_path / "semi.yaml"
    config.write_text(f"shards: {sample_shards}\nout: {tmp_path / 'run'}\nmode: semi\nlabeled_fraction: 0.5\n")
    run_cli(train_main, ["fit", "--config", config, *TINY, "--steps", 4])
    assert "pretrain_steps: 2\n" in (tmp_path / "run" / "config.yaml").read_text()
    config.write_text(config.read_text().replace("/run\n", "/run2\n") + "steps: 20\n")
    run_cli(train_main, ["fit", "--config", config, *TINY, "--steps", 6])
    assert "pretrain_steps: 3\n" in (tmp_path / "run2" / "config.yaml").read_text()


# ----------------------------------------------------------------------------- F5
def test_f5_claims_never_reports_runs_of_other_settings_or_an_evaluation_of_another_split(sample_shards, tmp_path):
    """``claims`` read back every (run, seed) whose ``eval/metrics.json`` existed, whatever it held:
    a rerun into the same ``--out`` with another preset reported the old runs under the new
    preset's settings, and one with another ``--eval-split`` or ``--eval-shards`` reported the old
    split's figures as the new one's, exit 0. Now an evaluation of another split or shards is
    redone, and a run trained with other settings is refused in one line naming its folder."""
    from sc3d_train.evaluation.claims import ClaimsPreset, run_all
    from sc3d_train.loop.checkpoint import CheckpointError

    preset = ClaimsPreset(steps=2, batch_size=4, lr=1e-3, tiny=True, extra={"val_every": 0, "base_channels": 4})
    out, metrics = tmp_path / "claims", tmp_path / "claims" / "runs" / "sup-3tube" / "seed-0" / "eval" / "metrics.json"
    lines = []
    run_all(sample_shards, sample_shards, out, preset, eval_split="test", device="cpu", runs=["sup-3tube"],
            echo=lines.append)
    assert json.loads(metrics.read_text())["split"] == "test"
    run_all(sample_shards, sample_shards, out, preset, eval_split="val", device="cpu", runs=["sup-3tube"],
            echo=lines.append)
    assert json.loads(metrics.read_text())["split"] == "val"
    assert json.loads((out / "claims.json").read_text())["meta"]["eval_split"] == "val"
    other = ClaimsPreset(steps=2, batch_size=4, lr=5e-4, tiny=True, extra={"val_every": 0, "base_channels": 4})
    with pytest.raises(CheckpointError) as e:
        run_all(sample_shards, sample_shards, out, other, eval_split="val", device="cpu", runs=["sup-3tube"],
                echo=lines.append)
    assert f"{out / 'runs' / 'sup-3tube' / 'seed-0'}: cannot change on --resume: --lr 0.0005 (run has 0.001)" in str(e.value)
    assert "give another --out" in str(e.value) and "\n" not in str(e.value)


# ----------------------------------------------------------------------------- F6
@pytest.mark.parametrize("threshold", ["nan", "-1", "1.5"])
def test_f6_predict_refuses_a_threshold_that_is_no_probability_before_writing(sample_shards, tiny_run, tmp_path,
                                                                                threshold):
    """``predict --threshold nan`` ended in a traceback from marching cubes ("No surface found"),
    ``-1`` in scikit-image's "Surface level must be within volume data range" naming no option
    (after the output folder was made); now one line naming ``--threshold``, nothing written."""
    image = tmp_path / "view.png"
    with h5py.File(next(sample_shards.glob("*.h5")), "r") as f:
        Image.fromarray(f["images"][0, 0]).save(image)
    res = run_cli(train_main, ["predict", "--checkpoint", tiny_run / "checkpoints" / "last.pt", image,
                               "--out", tmp_path / "pred", "--threshold", threshold], expect_exit=1)
    assert "--threshold must be an occupancy probability in [0, 1]" in one_line(res.output)
    assert not (tmp_path / "pred").exists()


# ----------------------------------------------------------------------------- F7
def test_f7_a_new_run_is_refused_beside_checkpoints_of_another_run(sample_shards, tmp_path):
    """A folder whose run lost its ``last.pt`` (deleted, or its write failed on a full disk) took
    a new ``fit`` with exit 0, leaving the old run's ``step_*.pt`` and ``best.pt`` beside the new
    config: ``eval RUN`` then evaluated the old run's ``best.pt`` as the new run's, and ``--resume``
    picked the old, newer ``step_*.pt`` and was refused. Now the new run is refused in one line
    naming the files, and the folder is left as it was."""
    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, "--steps", 4, *TINY, "--seed", 5,
                         "--val-every", 2, "--val-min-objects", 1])
    (run / "checkpoints" / "last.pt").unlink()
    config = (run / "config.yaml").read_text()
    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, "--steps", 2, *TINY, "--seed", 1],
                  expect_exit=1)
    assert (f"{run}: already holds checkpoints of a run (best.pt, step_000004.pt) but no last.pt; "
            f"use --resume to continue it") in one_line(res.output)
    assert (run / "config.yaml").read_text() == config
    assert sorted(f.name for f in (run / "checkpoints").iterdir()) == ["best.pt", "step_000004.pt"]


# ----------------------------------------------------------------------------- F8
def test_f8_a_failed_first_checkpoint_says_to_start_again_not_to_resume(sample_shards, tmp_path):
    """When the first checkpoint of a run cannot be written, no checkpoint of the run exists,
    so the hint "rerun with --resume" (what a later failure rightly says) led to "checkpoint not
    found". The message now says to start the run again, and the same command then works. The
    write fails for real: a file stands where the ``checkpoints`` folder must go."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "checkpoints").write_text("not a folder")
    args = ["fit", "--shards", sample_shards, "--out", run, "--steps", 2, *TINY]
    res = run_cli(train_main, args, expect_exit=1)
    errors = error_lines(res.output)  # after the run's start line
    assert len(errors) == 1 and res.output.rstrip().endswith(errors[0]), res.output
    line = errors[0]
    assert f"{run / 'checkpoints' / 'step_000002.pt'}: cannot write checkpoint" in line
    assert "start the run again (the same command" in line and "rerun with --resume" not in line
    assert "checkpoint not found" in run_cli(train_main, ["fit", "--out", run, "--resume"], expect_exit=1).output
    (run / "checkpoints").unlink()
    run_cli(train_main, args)
    assert (run / "checkpoints" / "last.pt").is_file()


# ----------------------------------------------------------------------------- F9
def test_f9_a_second_claims_into_the_same_study_folder_is_refused_in_one_line(sample_shards, tmp_path):
    """``claims`` trains through ``fit``'s library call, which takes no lock, so two studies into
    one ``--out`` trained the same run folders at once (one run's checkpoints over the other's).
    ``claims`` now holds the study folder's write lock; a second one is refused in one line naming
    the holder before any work, and the folder is left as it was."""
    from sc3d_data.io.outlock import LOCK_NAME, exclusive_lock

    out = tmp_path / "study"
    with exclusive_lock(out, "sc3d-train claims", create=True):
        res = run_cli(train_main, ["claims", "--train-shards", sample_shards, "--eval-shards", sample_shards,
                                   "--out", out, "--runs", "sup-3tube"], expect_exit=1)
        assert f"{out}: another process (PID" in one_line(res.output)
        assert "sc3d-train claims) is writing to this folder" in res.output
        assert [p.name for p in out.iterdir()] == [LOCK_NAME]


# ----------------------------------------------------------------------------- F10
def test_f10_predict_turns_an_image_by_its_exif_orientation_and_refuses_an_animated_one(sample_shards, tiny_run,
                                                                                        tmp_path):
    """A camera stores a turned photo as unturned pixels plus an EXIF orientation tag; predict
    read the raw pixels, so its input was not the image the user sees. Now the tag is applied:
    a view stored upside down with orientation 3 ("rotate 180") predicts exactly what the upright
    view predicts, and differs from the raw upside-down pixels (negative control). An animated
    image used its first frame silently; it is now refused in one line."""
    import numpy as np

    with h5py.File(next(sample_shards.glob("*.h5")), "r") as f:
        view = Image.fromarray(f["images"][0, 5])
    upright, tagged, raw = tmp_path / "upright.png", tmp_path / "tagged.png", tmp_path / "raw.png"
    view.save(upright)
    exif = Image.Exif()
    exif[0x0112] = 3  # Orientation: rotate 180
    view.rotate(180).save(tagged, exif=exif)
    view.rotate(180).save(raw)
    ckpt = tiny_run / "checkpoints" / "last.pt"
    run_cli(train_main, ["predict", "--checkpoint", ckpt, upright, tagged, raw, "--out", tmp_path / "pred"])
    probs = {p: np.load(tmp_path / "pred" / f"{p}.npz")["probabilities"] for p in ("upright", "tagged", "raw")}
    np.testing.assert_array_equal(probs["tagged"], probs["upright"])
    assert not np.array_equal(probs["raw"], probs["upright"])

    gif = tmp_path / "turning.gif"
    view.save(gif, save_all=True, append_images=[view.rotate(90)], duration=100, loop=0)
    res = run_cli(train_main, ["predict", "--checkpoint", ckpt, gif, "--out", tmp_path / "pred_gif"], expect_exit=1)
    assert f"{gif}: an animated image of 2 frames; give one frame as a still image" in one_line(res.output)


# ----------------------------------------------------------------------------- F11
def test_f11_eval_notes_shards_that_differ_from_the_training_data(sample_shards, tiny_run, tmp_path):
    """``eval`` of a checkpoint on shards rendered with another background and at an elevation its
    pose grid does not hold (10-50 deg) printed figures like any other, with nothing to say
    that they measure a domain shift (and a pose error with a floor). Now one note names each
    difference and ``metrics.json`` keeps them; on shards like the training data there is none
    (negative control)."""
    meshes = tmp_path / "meshes"
    shutil.copytree(SAMPLE_MESHES / "chair", meshes / "chair")
    other = tmp_path / "black"
    run_cli(data_main, ["render", "--meshes", meshes, "--out", other, "--voxelize", "--background", "0,0,0",
                        "--elevations", "70", "--split", "random:0,0,1", "--no-progress"])
    ckpt = tiny_run / "checkpoints" / "last.pt"
    res = run_cli(train_main, ["eval", "--checkpoint", ckpt, "--shards", other, "--out", tmp_path / "e1"])
    notes = [ln for ln in res.output.splitlines() if ln.startswith("note:")]
    # the re-rendered chairs are the run's own: F14's note counts those it trained on
    trained = sum(1 for o in json.loads((sample_shards / "index.json").read_text())["objects"]
                  if o["split"] == "train" and o["category"] == "03001627")  # chair
    assert len(notes) == 3 and notes[2].startswith(f"note: {trained} of the 4 evaluated objects"), res.output
    assert "background [0, 0, 0] (trained on [255, 255, 255])" in notes[0] and "elevation" not in notes[0]
    assert "elevations [70.0] deg of these shards lie outside the checkpoint's pose grid [10, 50]" in notes[1]
    saved = json.loads((tmp_path / "e1" / "metrics.json").read_text())
    assert len(saved["differs_from_training"]) == 1 and saved["differs_from_training"][0].startswith("background")
    assert saved["outside_pose_grid"] == [70.0]

    res = run_cli(train_main, ["eval", "--checkpoint", ckpt, "--shards", sample_shards, "--out", tmp_path / "e2"])
    assert "note:" not in res.output
    assert json.loads((tmp_path / "e2" / "metrics.json").read_text())["differs_from_training"] == []


# ----------------------------------------------------------------------------- F12
def test_f12_resume_with_tiny_refuses_a_run_of_another_model(sample_shards, tiny_run, tmp_path):
    """``fit --resume --tiny`` used to ignore ``--tiny``: a run of another network went on at its
    own width while the command asked for the tiny one. ``--tiny`` on ``--resume`` is now held to
    the run's model like any model option: refused in one line naming the fields that differ
    (the tiny preset's ``shape_dim`` 32, ``pose_dim`` 8; hand-copied from ``TINY_MODEL``), and
    accepted where the run is tiny (negative control: ``tiny_run`` is ``--tiny --base-channels 4``)."""
    run = tmp_path / "small"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, "--steps", 2, "--base-channels", 4,
                         "--shape-dim", 16, "--pose-dim", 4, "--batch-size", 4, "--no-progress", "--val-every", 0])
    before = (run / "checkpoints" / "last.pt").read_bytes()
    res = run_cli(train_main, ["fit", "--out", run, "--resume", "--tiny", "--base-channels", 4, "--steps", 3,
                               "--no-progress"], expect_exit=1)
    line = one_line(res.output)
    assert "cannot change on --resume: --pose-dim 8 (from --tiny) (run has 4), --shape-dim 32 (from --tiny) (run has 16)" in line, line
    assert (run / "checkpoints" / "last.pt").read_bytes() == before

    copy = tmp_path / "tiny"
    shutil.copytree(tiny_run, copy)
    ok = run_cli(train_main, ["fit", "--out", copy, "--resume", "--tiny", "--base-channels", 4, "--steps", 3,
                              "--no-progress"])
    assert "step 3" in ok.output


# ----------------------------------------------------------------------------- F13
def test_f13_objects_whose_voxelization_failed_are_left_out_of_training_and_evaluation(tmp_path):
    """``sc3d-data voxelize SHARDS`` gives a mesh it cannot voxelize (here: moved away) an empty
    grid, so its shard stays rectangular, and records a ``"stage": "voxelize"`` failure. The
    training side never read those failures: the object was trained and evaluated on with an
    empty grid as its ground truth. Now every split leaves it out, and one note line on stderr
    names it (once, though a run builds several datasets). Expected values come from the
    fixture (which mesh was moved) and from the shard itself (its row holds an all-empty grid)."""
    import h5py
    import numpy as np
    from test_faults import CUBE_F, CUBE_V, FAST, obj_text
    from sc3d_train.data.dataset import ShardDataset, scan_objects

    meshes, shards = tmp_path / "m", tmp_path / "s"
    (meshes / "chair").mkdir(parents=True)
    for name in "abcdefgh":
        (meshes / "chair" / f"{name}.obj").write_text(obj_text(CUBE_V, CUBE_F))
    run_cli(data_main, ["render", "--meshes", meshes, "--out", shards, *FAST])
    index = json.loads((shards / "index.json").read_text())
    split_of = {o["model_id"]: o["split"] for o in index["objects"]}
    gone = next(i for i in sorted(split_of) if split_of[i] == "train")
    (meshes / "chair" / f"{gone}.obj").rename(tmp_path / "gone.obj")
    run_cli(data_main, ["voxelize", shards, "--no-progress"])
    (fail,) = json.loads((shards / "index.json").read_text())["failures"]
    with h5py.File(shards / fail["shard"]) as f:
        assert f["model_id"][fail["row"]].decode() == gone and not np.any(f["voxels"][fail["row"]])

    res = run_cli(train_main, ["fit", "--shards", shards, "--out", tmp_path / "run", "--steps", 2, *TINY])
    note = [line for line in res.output.splitlines() if line.startswith("note:")]
    assert note == [f"note: {shards}: 1 object(s) left out, their voxelization failed and their grid is an "
                    f"empty placeholder (index.json failures): 03001627/{gone}"], res.output

    refs, info = scan_objects(shards)
    assert sorted(r.model_id for r in refs) == sorted(set(split_of) - {gone})
    assert info["left_out"] == [f"03001627/{gone}"]  # chair: ShapeNet synset 03001627
    train = ShardDataset(shards, "train", mask_size=16)
    assert gone not in {r.model_id for r in train.objects}
    assert len(train.objects) == sum(1 for i, s in split_of.items() if s == "train" and i != gone)


# ----------------------------------------------------------------------------- F14
def test_f14_eval_on_the_training_objects_says_the_figures_are_not_held_out(sample_shards, tiny_run, tmp_path):
    """``eval --split train`` (a legitimate check of the training fit) printed its figures like
    any held-out ones. It now adds one note line counting the evaluated objects the checkpoint
    was trained on, and ``metrics.json`` keeps the count (``trained_on``); on the test split
    there is none (negative control). Expected counts come from the shards' ``index.json``."""
    objects = json.loads((sample_shards / "index.json").read_text())["objects"]
    n_train = sum(1 for o in objects if o["split"] == "train")
    res = run_cli(train_main, ["eval", "--checkpoint", tiny_run, "--shards", sample_shards, "--split", "train",
                               "--out", tmp_path / "train", "--pose", "head", "--device", "cpu"])
    assert (f"note: {n_train} of the {n_train} evaluated objects are objects the checkpoint was trained on: "
            f"these figures are not of held-out objects") in res.output
    assert json.loads((tmp_path / "train" / "metrics.json").read_text())["trained_on"] == n_train
    res = run_cli(train_main, ["eval", "--checkpoint", tiny_run, "--shards", sample_shards, "--split", "test",
                               "--out", tmp_path / "test", "--pose", "head", "--device", "cpu"])
    assert "trained on" not in res.output
    assert json.loads((tmp_path / "test" / "metrics.json").read_text())["trained_on"] == 0


# ----------------------------------------------------------------------------- F15
def test_f15_predict_takes_a_run_folder_like_eval(sample_shards, tiny_run, tmp_path):
    """``eval --checkpoint RUN_DIR`` took a run folder, ``predict --checkpoint RUN_DIR`` refused it
    (click: "is a directory"). ``predict`` now takes one too, with the same ``--pick``: the run's
    ``checkpoints/best.pt``, or ``last.pt`` where it kept none (``tiny_run`` validates never).
    Expected: the same probabilities as ``--checkpoint RUN_DIR/checkpoints/last.pt`` (the path
    written by hand), written beside the run in ``RUN_DIR/predictions`` (the file's default)."""
    import numpy as np

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    image = tmp_path / "view.png"
    with h5py.File(sorted(sample_shards.glob("shard-*.h5"))[0]) as f:
        Image.fromarray(f["images"][0, 0]).save(image)
    run_cli(train_main, ["predict", "--checkpoint", run, image, "--device", "cpu"])
    run_cli(train_main, ["predict", "--checkpoint", run / "checkpoints" / "last.pt", image, "--device", "cpu",
                         "--out", tmp_path / "file"])
    folder = np.load(run / "predictions" / "view.npz")["probabilities"]
    assert np.array_equal(folder, np.load(tmp_path / "file" / "view.npz")["probabilities"])
    res = run_cli(train_main, ["predict", "--checkpoint", run, image, "--pick", "nope"], expect_exit=2)
    assert "--pick" in res.output
