"""Camera options that cannot show the object are refused before any work, in one line naming the
option. Before: ``--fov 179.9`` and ``--distance 1e6`` were accepted and then every object failed
with "silhouette is empty ... outlier vertex", blaming its mesh; ``--elevations 450`` rendered the
views of 90 degrees while the shards recorded 450 and ``check`` passed; a memory refusal caused by
``--views 5000`` named every option but ``--views``. The real command and ``RenderConfig``."""
from __future__ import annotations

import pytest

from sc3d_cli.data import main as data_main
from conftest import SAMPLE_MESHES, run_cli, error_lines


@pytest.mark.parametrize("options, line", [
    (["--fov", "179.9"], "Error: --fov 179.9 with --distance 2.0 and --image-size 64: the object (at most 1 unit) "
                         "would span 0.014 pixels; every silhouette would be empty"),
    (["--distance", "1e6"], "Error: --fov 49.13 with --distance 1000000.0 and --image-size 64: the object (at most "
                            "1 unit) would span 7e-05 pixels; every silhouette would be empty"),
    (["--elevations", "30,450"], "Error: --elevations 30.0,450.0: must lie between -90 and 90 degrees (past the "
                                 "pole the camera sees the object upside down)"),
    (["--elevations", "-90.5"], "Error: --elevations -90.5: must lie between -90 and 90 degrees (past the pole "
                                "the camera sees the object upside down)"),
    (["--elevations", "30,15,30.0"], "Error: --elevations 30.0,15.0,30.0: lists an elevation twice; each elevation "
                                     "gives its own views"),
    (["--views", "5000", "--objects-per-shard", "100000"], "Error: --views 5000 x 1 elevation(s) / --image-size 64 / "
                                                           "--voxel-resolution 32 / --objects-per-shard 100000 / "
                                                           "--workers 1: would need about"),
], ids=["fov", "distance", "elevation-450", "elevation-below-pole", "elevation-twice", "views-memory"])
def test_options_that_cannot_render_are_refused_before_any_work(tmp_path, options, line):
    out = tmp_path / "out"
    res = run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "car", "--out", out, "--workers", 1,
                              "--no-progress", *options], expect_exit=1)
    errors = error_lines(res.output)
    assert len(errors) == 1 and errors[0].startswith(line), res.output
    assert not (out / "index.json").exists()


def test_the_smallest_object_is_one_pixel_by_hand():
    """At a 90 degree field of view the focal length is (64 / 2) / tan(45) = 32 pixels, so the
    object's 1 unit spans 32 / distance pixels: distance 32 is 1 pixel (accepted), 33 is 0.97
    (refused); the poles themselves (+-90) are views like any other."""
    from sc3d_data.pipeline.jobs.render_checks import object_pixels
    from sc3d_data.pipeline.jobs.render_job import RenderConfig

    assert object_pixels(90.0, 32.0, 64) == pytest.approx(1.0)
    RenderConfig(out="unused", fov_deg=90.0, distance=32.0, elevations=(-90.0, 0.0, 90.0)).validate()
    with pytest.raises(ValueError, match="would span 0.97 pixels"):
        RenderConfig(out="unused", fov_deg=90.0, distance=33.0).validate()
