"""``fit`` on shards whose views are not a multiple of 32 px (``render --image-size 48``) was
refused as "image_size must be a multiple of 32 (5 stride-2 blocks), got 48", naming neither the
shards nor what to do (found by atk_spec). Real render of a bundled car, real ``fit``."""
from __future__ import annotations

from sc3d_cli.data import main as data_main
from sc3d_cli.train import main as train_main
from conftest import SAMPLE_MESHES, error_lines, run_cli
from test_faults import FAST


def test_fit_on_views_of_no_multiple_of_32_names_the_shards(tmp_path):
    shards = tmp_path / "shards48"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "car", "--out", shards, "--image-size", 48,
                        "--voxelize", *FAST])
    res = run_cli(train_main, ["fit", "--shards", shards, "--out", tmp_path / "run", "--tiny", "--steps", 2,
                               "--device", "cpu", "--no-progress"], expect_exit=1)
    assert error_lines(res.output) == [f"Error: {shards}: its views are 48x48 px; the model takes a multiple of 32 "
                                       "(5 stride-2 blocks): render them with --image-size 64 (or 32, 128)"]
    assert not (tmp_path / "run").exists()
