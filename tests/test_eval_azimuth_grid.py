"""Views whose azimuths lie between the pose grid's (``render --views 7``: every 51.43 deg, where the
grid of the pose head has one every 15 deg). The self-consistent pose ``eval`` reports by default is a
grid azimuth and the head's targets are grid poses, so such views have an azimuth error of 2-6 deg
however good the model (3.7 deg on average over the 7): ``eval`` printed its pose errors as if that
floor were the model's error, without a word, where elevations outside the grid get a note. Now it
notes the floor and ``metrics.json`` records it (``azimuth_grid_floor``). Found by fix_small."""
from __future__ import annotations

import json
import shutil

import pytest

from conftest import REPO, run_cli
from sc3d_train.paper.pose import PoseGrid


@pytest.mark.parametrize("azimuths, floor", [([0.0, 15.0, 345.0, 360.0], 0.0),
                                             ([360 / 7 * k for k in range(7)], 3.67), ([7.5], 7.5)])
def test_the_azimuth_floor_is_the_mean_distance_to_the_grid(azimuths, floor):
    assert PoseGrid().azimuth_floor(azimuths) == pytest.approx(floor, abs=0.01)


def test_eval_notes_the_floor_of_views_between_the_grid_azimuths(tmp_path):
    from sc3d_cli.data import main as data_main
    from sc3d_cli.train import main as train_main

    meshes = tmp_path / "meshes" / "car"
    meshes.mkdir(parents=True)
    shutil.copy(REPO / "assets" / "sample_meshes" / "car" / "jeep_psionic.glb", meshes)
    shards = tmp_path / "shards"
    run_cli(data_main, ["render", "--meshes", tmp_path / "meshes", "--out", shards, "--voxelize", "--views", "7",
                        "--no-progress", "--workers", "1", "--split", "random:1,0,0"])
    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", shards, "--out", run, "--steps", "1", "--batch-size", "2", "--tiny",
                         "--base-channels", "4", "--no-progress", "--val-every", "0"])
    res = run_cli(train_main, ["eval", "--checkpoint", run, "--shards", shards, "--split", "train",
                               "--out", tmp_path / "ev", "--examples", "0"])
    assert ("note: the views' azimuths lie between the checkpoint's pose grid azimuths (every 15 deg): "
            "their azimuth error is at least 3.7 deg on average however good the model") in res.output, res.output
    assert json.loads((tmp_path / "ev" / "metrics.json").read_text())["azimuth_grid_floor"] == pytest.approx(3.67, abs=0.01)
