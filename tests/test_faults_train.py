"""Hostile inputs to ``sc3d-train``, round three: one test per finding F1-Fn (resume on shards
that were rendered again, ...). Real shards, training and checkpoints; every fixture is built
here (the sample shards of ``conftest.py`` are rendered from the bundled meshes)."""
from __future__ import annotations

import shutil

import h5py
import pytest
from PIL import Image

from sc3d_cli.data import main as data_main
from sc3d_cli.train import main as train_main
from conftest import SAMPLE_MESHES, run_cli

TINY = ["--tiny", "--base-channels", "4", "--batch-size", "4", "--no-progress", "--val-every", "0"]


def one_line(output: str) -> str:
    """The single line of a failed command's output (fails when there is more, e.g. a traceback)."""
    lines = output.strip().splitlines()
    assert len(lines) == 1, output
    return lines[0]


# ----------------------------------------------------------------------------- F1
@pytest.mark.parametrize("render_again, changed", [(["--seed", "1"], "the objects of split 'train'"),
                                                   (["--background", "0,0,0"], "background [255, 255, 255] -> [0, 0, 0]")])
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
        bad["cuda"] = "--device cuda:0: CUDA is not available here"
    for name, args in commands.items():
        for device, message in bad.items():
            res = run_cli(train_main, [*args, "--device", device], expect_exit=1)
            assert message in res.output.strip().splitlines()[-1], (name, res.output)
            assert "Traceback" not in res.output and len(res.output.strip().splitlines()) <= 2, res.output
        assert not any((tmp_path / d).exists() for d in ("run", "eval", "pred")), name
