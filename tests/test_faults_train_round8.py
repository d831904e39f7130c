"""``sc3d-train``, round eight. C1: ``claims`` took evaluation shards of another image size (or
voxel resolution) than its training shards, trained every run, and only then failed in ``eval``;
now they are refused before any training, in one line naming both folders and the difference.
P1: ``predict`` with a checkpoint of NaN weights wrote ``NAME.binvox`` and ``NAME.npz`` and then
crashed in marching cubes with a traceback, and ``eval`` reported nan / 0.000 without a word; both
now refuse such a checkpoint at load in one line, and both refuse predictions that are not finite
(finite weights that overflow) before writing anything. P2: ``predict --threshold 1`` crashed the same way when a
probability saturated at exactly 1.0. Real shards, real tiny trainings, no mocks."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from sc3d_cli.data import main as data_main
from sc3d_cli.train import main as train_main
from conftest import REPO, SAMPLE_MESHES, run_cli, error_lines
from tests.test_train import TINY

CHAIR = REPO / "assets" / "sample_images" / "chair.png"


def _render(out, *extra):
    """The bundled sample meshes rendered and voxelized like ``sample_shards`` but for ``extra``."""
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", out, "--voxelize", "--no-progress",
                        "--workers", 1, *extra])
    return out


@pytest.fixture(scope="module")
def shards_32px(tmp_path_factory):
    """The sample meshes at 32x32 images (``sample_shards``: 64x64), 32^3 voxels, the same split."""
    return _render(tmp_path_factory.mktemp("shards_32px") / "shards", "--image-size", 32)


def _tiny_preset():
    from sc3d_train.evaluation.claims import ClaimsPreset

    return ClaimsPreset(steps=2, batch_size=2, lr=1e-3, tiny=True, extra={"val_every": 0, "base_channels": 4})


# ----------------------------------------------------------------------------- C1
def test_c1_claims_refuses_eval_shards_of_another_image_size_before_training(sample_shards, shards_32px, tmp_path):
    """``run_all`` trained the run on the 64x64 sample shards, then ``eval`` refused the 32x32
    evaluation shards ("the model expects 64x64"): the training was lost. Now the line names both
    folders and both sizes (64 and 32: the sizes the two folders were rendered at) and no run
    folder is made."""
    from sc3d_train.data.dataset import DataError
    from sc3d_train.evaluation.claims import run_all

    out = tmp_path / "claims"
    with pytest.raises(DataError) as e:
        run_all(sample_shards, shards_32px, out, preset=_tiny_preset(), runs=["sup-3tube"], device="cpu",
                echo=lambda line: None)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{shards_32px}: images are 32x32 but the runs train on 64x64"), msg
    assert f"--train-shards {sample_shards}" in msg and "--image-size 64" in msg, msg
    assert not (out / "runs").exists()


def test_c1_claims_refuses_eval_shards_of_another_voxel_resolution_before_training(sample_shards, tmp_path):
    """The same for voxels: ``eval`` refuses 16^3 ground truth for a checkpoint predicting the
    32^3 grids of the training shards; and both differences at once are named in the one line.
    Shards alike in both (the training shards themselves) pass."""
    from sc3d_train.data.dataset import DataError
    from sc3d_train.evaluation.claims import run_all

    vox16 = _render(tmp_path / "vox16", "--voxel-resolution", 16)
    out = tmp_path / "claims"
    with pytest.raises(DataError) as e:
        run_all(sample_shards, vox16, out, preset=_tiny_preset(), runs=["sup-3tube"], device="cpu",
                echo=lambda line: None)
    msg = str(e.value)
    assert msg.startswith(f"{vox16}: voxels are 16^3 but the runs predict 32^3"), msg
    assert "images are" not in msg and f"--train-shards {sample_shards}" in msg, msg
    assert not (out / "runs").exists()

    from sc3d_train.evaluation.claims import check_evaluable

    both = _render(tmp_path / "both", "--voxel-resolution", 16, "--image-size", 32)
    with pytest.raises(DataError, match=r"images are 32x32 but the runs train on 64x64; voxels are 16\^3 but "
                                        r"the runs predict 32\^3"):
        check_evaluable(sample_shards, both)
    check_evaluable(sample_shards, sample_shards)  # alike: nothing to refuse


def test_c1_claims_command_prints_one_error_line_and_trains_nothing(sample_shards, shards_32px, tmp_path,
                                                                  monkeypatch):
    """``sc3d-train claims`` with 32x32 evaluation shards: exit 1, one ``Error:`` line naming both
    folders, no run started (``steps of``) and no study folder left. The cpu preset's budget is
    made tiny here so that a regression costs seconds, not a 700-step training."""
    from sc3d_train.evaluation import claims

    monkeypatch.setitem(claims.PRESETS, "cpu", _tiny_preset())
    out = tmp_path / "claims"
    res = run_cli(train_main, ["claims", "--train-shards", sample_shards, "--eval-shards", shards_32px, "--out", out,
                               "--runs", "sup-3tube", "--device", "cpu"], expect_exit=1)
    errors = error_lines(res.output)
    assert len(errors) == 1, res.output
    assert f"{shards_32px}: images are 32x32 but the runs train on 64x64" in errors[0], res.output
    assert str(sample_shards) in errors[0] and "Traceback" not in res.output, res.output
    assert "steps of" not in res.output and not (out / "runs").exists(), res.output


# ----------------------------------------------------------------------------- P1
@pytest.fixture(scope="module")
def tiny_run(sample_shards, tmp_path_factory):
    """A 2-step tiny supervised run on the sample shards (``checkpoints/last.pt``)."""
    run = tmp_path_factory.mktemp("tiny_run") / "run"
    run_cli(train_main, ["fit", "--shards", sample_shards, "--out", run, "--steps", 2, "--batch-size", 2, *TINY,
                         "--val-every", 0, "--device", "cpu"])
    return run


def _altered(run, path, value):
    """``run``'s last.pt with its first weight tensor (the encoder's first convolution) set to
    ``value`` everywhere, saved as ``path``."""
    from sc3d_train.loop.checkpoint import load_checkpoint

    ckpt = dict(load_checkpoint(run / "checkpoints" / "last.pt"))
    weights = dict(ckpt["model"])
    first = next(iter(weights))
    weights[first] = torch.full_like(weights[first], value)
    ckpt["model"] = weights
    torch.save(ckpt, path)
    return path


def test_p1_predict_refuses_nan_weights_in_one_line_and_writes_nothing(tiny_run, tmp_path):
    """Before: ``chair.binvox`` and ``chair.npz`` written, then ``RuntimeError: No surface found at
    the given iso value.`` with a traceback. Now one line names the checkpoint and says its weights
    are not finite; no output folder is made."""
    nan = _altered(tiny_run, tmp_path / "nan.pt", float("nan"))
    out = tmp_path / "pred"
    res = run_cli(train_main, ["predict", "--checkpoint", nan, CHAIR, "--out", out, "--device", "cpu"], expect_exit=1)
    errors = error_lines(res.output)
    assert len(errors) == 1 and f"{nan}: its weights are not finite" in errors[0], res.output
    assert "Traceback" not in res.output and not out.exists(), res.output


def test_p1_eval_refuses_nan_weights_in_one_line(tiny_run, sample_shards, tmp_path):
    """Before: ``eval`` of the NaN checkpoint exited 0 with IoU 0.000 and nan pose errors and wrote
    metrics.json. Now the same one line as ``predict``, and no metrics.json."""
    nan = _altered(tiny_run, tmp_path / "nan.pt", float("nan"))
    out = tmp_path / "eval"
    res = run_cli(train_main, ["eval", "--checkpoint", nan, "--shards", sample_shards, "--split", "test",
                               "--out", out, "--device", "cpu", "--examples", 0], expect_exit=1)
    errors = error_lines(res.output)
    assert len(errors) == 1 and f"{nan}: its weights are not finite" in errors[0], res.output
    assert not (out / "metrics.json").exists()


def test_p1_predict_refuses_a_prediction_that_is_not_finite_before_writing(tiny_run, tmp_path):
    """Finite weights can still give a NaN prediction: the first convolution's weights at 3e38
    (finite in float32) overflow to inf on a white pixel (27 x 3e38 > 3.4e38), and inf - inf in the
    next layers is NaN. Two images: nothing of either is written; the line names the image."""
    huge = _altered(tiny_run, tmp_path / "huge.pt", 3e38)
    out = tmp_path / "pred"
    res = run_cli(train_main, ["predict", "--checkpoint", huge, CHAIR, CHAIR, "--out", out, "--device", "cpu"],
                  expect_exit=1)
    errors = error_lines(res.output)
    assert len(errors) == 1 and f"{huge}: its prediction for {CHAIR} is not finite" in errors[0], res.output
    assert "Traceback" not in res.output and not out.exists(), res.output


def test_p1_eval_refuses_predictions_that_are_not_finite_and_writes_nothing(tiny_run, sample_shards, tmp_path):
    """The checkpoint of the test above (finite weights, NaN predictions on white pixels). Before:
    ``eval`` exited 0 and wrote metrics.json with IoU 0.000 and nan pose errors. Now one line names
    the checkpoint, how many of the split's images overflow and the first of them; nothing written."""
    huge = _altered(tiny_run, tmp_path / "huge.pt", 3e38)
    out = tmp_path / "eval"
    res = run_cli(train_main, ["eval", "--checkpoint", huge, "--shards", sample_shards, "--split", "test",
                               "--out", out, "--device", "cpu", "--examples", 0], expect_exit=1)
    errors = error_lines(res.output)
    assert len(errors) == 1 and f"{huge}: its predictions are not finite" in errors[0], res.output
    # the test split of the sample shards is one object (24 views), and every view has white pixels
    assert "for 24 of 24 images (first: " in errors[0], errors[0]
    assert "Traceback" not in res.output and not out.exists(), res.output


def test_p1_thresholds_zero_and_one_still_predict(tiny_run, tmp_path):
    """The guard refuses only what is not finite: ``--threshold 0`` (every probability >= 0: all
    32^3 = 32768 voxels) and ``--threshold 1`` still write all five files."""
    import json

    for threshold in (0, 1):
        out = tmp_path / f"t{threshold}"
        run_cli(train_main, ["predict", "--checkpoint", tiny_run, CHAIR, "--out", out, "--device", "cpu",
                             "--threshold", threshold])
        assert sorted(p.suffix for p in out.iterdir() if p.name != ".sc3d.lock") == [".binvox", ".json", ".npz", ".obj",
                                                                                  ".png"]
        info = json.loads((out / "chair.json").read_text())
        if threshold == 0:
            assert info["occupied_voxels"] == 32 ** 3


# ----------------------------------------------------------------------------- P2
def test_p2_mesh_of_probabilities_saturated_at_the_threshold():
    """A 3x3x3 block of probability exactly 1.0 (sigmoid saturates in float32 for logits above
    ~17) in an 8^3 grid of zeros, meshed at threshold 1: marching cubes found no surface at the
    grid's maximum and ``predict --threshold 1`` crashed. Now the surface passes through the
    centres of the block's outer voxels (indices 2 and 4), i.e. -0.5 + 2.5/8 = -0.1875 and
    -0.5 + 4.5/8 = 0.0625 on each axis. All-zero probabilities give an empty mesh (at threshold
    0 every voxel is occupied, zeros too, as the .binvox says: the whole cube,
    ``tests/test_predict_threshold_zero.py``)."""
    from sc3d_train.evaluation.predict import voxel_mesh

    probs = np.zeros((8, 8, 8), dtype=np.float32)
    probs[2:5, 2:5, 2:5] = 1.0
    verts, faces = voxel_mesh(probs, 1.0)
    assert len(faces) > 0
    np.testing.assert_allclose(verts.min(axis=0), [-0.1875] * 3, atol=1e-5)
    np.testing.assert_allclose(verts.max(axis=0), [0.0625] * 3, atol=1e-5)
    verts, faces = voxel_mesh(np.zeros((8, 8, 8), dtype=np.float32), 0.5)
    assert verts.shape == (0, 3) and faces.shape == (0, 3)


def test_a_checkpoint_whose_config_has_ragged_intrinsics_is_named_in_one_line(tiny_run, tmp_path):
    """A checkpoint whose stored config held ``intrinsics: [[1, 2], [3]]`` failed ``predict`` with
    numpy's "setting an array element with a sequence" and no file name; it is now refused as a
    config this version does not read, naming the file."""
    from sc3d_train.loop.checkpoint import load_checkpoint

    ckpt = dict(load_checkpoint(tiny_run / "checkpoints" / "last.pt"))
    ckpt["config"] = {**ckpt["config"], "intrinsics": [[1, 2], [3]]}
    bad = tmp_path / "K.pt"
    torch.save(ckpt, bad)
    res = run_cli(train_main, ["predict", "--checkpoint", bad, CHAIR, "--out", tmp_path / "pred", "--device", "cpu"],
                  expect_exit=1)
    errors = error_lines(res.output)
    assert len(errors) == 1 and f"{bad}: its config is not one this version reads" in errors[0], res.output
    assert "intrinsics must be a 3x3 list of finite numbers" in errors[0]
