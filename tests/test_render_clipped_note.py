"""`render` says when views are clipped (the mask touches the image border): a `--fov` given in
radians (`--fov 0.8575` for 49.13 deg) makes every mask the whole image, and the render ended
with exit 0 and its usual summary; `check` passes such data (voxels and masks agree) and `fit`
trains on it. Only `info` counted the clipped views."""
from __future__ import annotations

from sc3d_cli.data import main as data_main
from conftest import SAMPLE_MESHES, run_cli


def test_a_render_whose_views_are_clipped_says_so_and_one_that_fits_does_not(tmp_path):
    common = ["render", "--meshes", SAMPLE_MESHES / "table", "--views", "2", "--workers", "1", "--no-progress"]
    res = run_cli(data_main, [*common, "--out", tmp_path / "rad", "--fov", "0.8575"])
    lines = [line for line in res.output.splitlines() if "clipped" in line]
    assert len(lines) == 1 and lines[0].startswith("warning: 2 of 2 views (1 of 1 objects) are clipped"), res.output
    assert "--fov is in degrees" in lines[0]
    res = run_cli(data_main, [*common, "--out", tmp_path / "deg"])
    assert "clipped" not in res.output, res.output
