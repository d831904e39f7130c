"""``fit --config RUN/config.yaml`` on shards that no longer hold the data RUN was trained on
(re-rendered in place at another camera distance, say) trains on them, as docs/config.md allows,
but says so in one ``note:`` line: the run is no repeat of RUN (docs/config.md: "run-again/
repeats run/ exactly"), and before, nothing told the two apart. Found by atk_cross."""
from __future__ import annotations

import shutil

from sc3d_cli.train import main
from tests.conftest import SAMPLE_MESHES, run_cli

TINY = ["--tiny", "--base-channels", "4", "--no-progress", "--val-every", "0"]


def test_fit_config_on_changed_shards_notes_the_change(sample_shards, tmp_path):
    from sc3d_cli.data import main as data_main

    shards = tmp_path / "shards"
    shutil.copytree(sample_shards, shards)
    run = tmp_path / "run"
    run_cli(main, ["fit", "--shards", shards, "--out", run, "--steps", "1", "--batch-size", "2", *TINY])
    same = run_cli(main, ["fit", "--config", run / "config.yaml", "--out", tmp_path / "same"])
    assert "note:" not in same.output  # the same data: a true repeat, no note

    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", shards, "--voxelize", "--distance", "3",
                        "--overwrite", "--workers", "1", "--no-progress"])
    again = run_cli(main, ["fit", "--config", run / "config.yaml", "--out", tmp_path / "again"])
    notes = [ln for ln in again.output.splitlines() if ln.startswith("note:")]
    assert len(notes) == 1, again.output
    assert str(shards) in notes[0] and "camera_distance 2.0 -> 3.0" in notes[0] and "repeat" in notes[0], notes[0]
