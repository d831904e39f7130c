"""``sc3d-train predict`` on images from the wild (the images attack): defects found by feeding it
the files a researcher has at hand; expected values are derived by hand, never from the code
under test."""
from __future__ import annotations

import json

import numpy as np
from PIL import Image

from sc3d_cli.train import main as train_main
from conftest import run_cli
from test_faults_train import tiny_run  # noqa: F401 - a fixture


def test_an_rgb_png_with_a_transparent_colour_is_composited_like_a_cut_out(tmp_path):
    """A cut-out PNG whose transparent pixels share one colour is stored by PNG optimisers
    (optipng, oxipng, PIL's ``transparency=``) as RGB plus a tRNS colour key, not as RGBA; viewers
    show those pixels transparent. ``predict`` took RGB "as is", so the model saw the key colour
    (black here) as the background instead of the training background. By hand: a grey square
    (128) on black, black marked transparent, on the background (10, 200, 30) must read as the
    square on that background; the same pixels without the key (the control) stay black."""
    from sc3d_train.evaluation.predict import load_image

    pixels = np.zeros((64, 64, 3), dtype=np.uint8)
    pixels[16:48, 16:48] = 128
    Image.fromarray(pixels).save(tmp_path / "keyed.png", transparency=(0, 0, 0))
    Image.fromarray(pixels).save(tmp_path / "opaque.png")
    assert Image.open(tmp_path / "keyed.png").mode == "RGB"  # the file is RGB + tRNS, not RGBA
    background = [10, 200, 30]
    expected = np.empty((64, 64, 3), dtype=np.float32)
    expected[:] = np.array(background, dtype=np.float32) / 255.0
    expected[16:48, 16:48] = 128 / 255.0
    np.testing.assert_allclose(load_image(tmp_path / "keyed.png", 64, background), expected, atol=1e-6)
    np.testing.assert_allclose(load_image(tmp_path / "opaque.png", 64, background), pixels / 255.0, atol=1e-6)


def test_another_image_of_the_same_name_does_not_replace_a_prediction(sample_shards, tiny_run, tmp_path,
                                                                       monkeypatch):
    """Camera files restart their names per folder (``day1/IMG_0001.jpg``, ``day2/IMG_0001.jpg``):
    predicting ``day2``'s into the folder that holds ``day1``'s predictions replaced them without a
    word (exit 0), although within one call the second image gets ``IMG_0001_``. Now refused in
    one line naming the record and the image it holds, with day1's files untouched; the same image
    again, by another path (relative, from another folder), still replaces its own prediction."""
    import h5py

    with h5py.File(next(sample_shards.glob("*.h5")), "r") as f:
        views = [Image.fromarray(f["images"][i, 3]) for i in (0, 1)]
    (tmp_path / "day1").mkdir()
    (tmp_path / "day2").mkdir()
    views[0].save(tmp_path / "day1" / "IMG_0001.png")
    views[1].save(tmp_path / "day2" / "IMG_0001.png")
    ckpt, out = tiny_run / "checkpoints" / "last.pt", tmp_path / "pred"
    run_cli(train_main, ["predict", "--checkpoint", ckpt, tmp_path / "day1" / "IMG_0001.png", "--out", out])
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    res = run_cli(train_main, ["predict", "--checkpoint", ckpt, tmp_path / "day2" / "IMG_0001.png", "--out", out],
                  expect_exit=1)
    assert res.output.count("\n") == 1, res.output
    assert "IMG_0001.json" in res.output and f"{tmp_path}/day1/IMG_0001.png" in res.output, res.output
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    monkeypatch.chdir(tmp_path / "day1")  # the same image by a relative path: its own prediction, replaced
    run_cli(train_main, ["predict", "--checkpoint", ckpt, "IMG_0001.png", "--out", out])
    assert json.loads((out / "IMG_0001.json").read_text())["image"] == "IMG_0001.png"


def test_a_prediction_of_an_earlier_version_is_not_replaced_by_another_image(sample_shards, tiny_run, tmp_path):
    """Upgrade attack: ``NAME.json`` of a version before ``image_realpath`` records the image as
    given (``image``). Predicting ``day2/IMG_0001.png`` into a folder holding such a record of
    ``day1/IMG_0001.png`` replaced it without a word (exit 0), the refusal above applying only to
    folders written by this version. A record whose ``image`` is absolute names its file and is
    judged by it (refused, files untouched); the same image again replaces its own prediction; a
    relative one, relative to a folder no record names, is not judged (control)."""
    import h5py

    with h5py.File(next(sample_shards.glob("*.h5")), "r") as f:
        views = [Image.fromarray(f["images"][i, 3]) for i in (0, 1)]
    for day, view in zip(("day1", "day2"), views):
        (tmp_path / day).mkdir()
        view.save(tmp_path / day / "IMG_0001.png")
    ckpt, out = tiny_run / "checkpoints" / "last.pt", tmp_path / "pred"
    predict = ["predict", "--checkpoint", ckpt, "--out", out]

    def make_earlier(image: str) -> None:  # the record as an earlier version wrote it
        record = json.loads((out / "IMG_0001.json").read_text())
        del record["image_realpath"]
        record["image"] = image
        (out / "IMG_0001.json").write_text(json.dumps(record))

    run_cli(train_main, [*predict, tmp_path / "day1" / "IMG_0001.png"])
    make_earlier(str(tmp_path / "day1" / "IMG_0001.png"))
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    res = run_cli(train_main, [*predict, tmp_path / "day2" / "IMG_0001.png"], expect_exit=1)
    assert res.output.count("\n") == 1 and f"{tmp_path}/day1/IMG_0001.png" in res.output, res.output
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    run_cli(train_main, [*predict, tmp_path / "day1" / "IMG_0001.png"])  # its own image: replaced
    make_earlier("IMG_0001.png")
    run_cli(train_main, [*predict, tmp_path / "day2" / "IMG_0001.png"])  # relative: not judged


def test_a_relative_checkpoint_of_an_earlier_version_is_the_same_checkpoint_from_another_folder(
        tiny_run, tmp_path, monkeypatch):
    """Upgrade attack: an earlier version recorded ``checkpoint`` in ``RUN/predictions/NAME.json``
    as given (``run/checkpoints/last.pt``, relative to the folder it ran in). Predicting the same
    image with the same checkpoint from another folder was refused ('holds the prediction of
    checkpoint run/checkpoints/last.pt, which this one (checkpoint /abs/run/...) would replace'):
    the relative path was resolved against today's folder. It names the same file where the
    checkpoint given ends with it; another checkpoint is still refused (control)."""
    import shutil

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    shutil.copy(run / "checkpoints" / "last.pt", run / "checkpoints" / "step_000001.pt")
    image = tmp_path / "view.png"
    Image.fromarray(np.full((64, 64, 3), 200, dtype=np.uint8)).save(image)
    run_cli(train_main, ["predict", "--checkpoint", run / "checkpoints" / "last.pt", image, "--device", "cpu"])
    record = run / "predictions" / "view.json"
    record.write_text(json.dumps({**json.loads(record.read_text()), "checkpoint": "run/checkpoints/last.pt"}))
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    run_cli(train_main, ["predict", "--checkpoint", run / "checkpoints" / "last.pt", image, "--device", "cpu"])
    record.write_text(json.dumps({**json.loads(record.read_text()), "checkpoint": "run/checkpoints/last.pt"}))
    res = run_cli(train_main, ["predict", "--checkpoint", run / "checkpoints" / "step_000001.pt", image,
                               "--device", "cpu"], expect_exit=1)
    assert "holds the prediction of checkpoint run/checkpoints/last.pt" in res.output, res.output
