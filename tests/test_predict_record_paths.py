"""``predict --out REL`` with a relative ``--out``: each ``NAME.json`` listed its files under
``files`` as paths relative to the folder predict ran in (``rel_out/chair.obj``), while its
``image_realpath`` and ``checkpoint`` are absolute: a reader opening the record from any other
folder could not find them. Now they are absolute (docs/training.md); a record of an earlier
version, with such relative paths, is still read as listing the files of those names beside it."""
from __future__ import annotations

import json
from pathlib import Path

from sc3d_cli.train import main
from tests.conftest import REPO, run_cli

TINY = ["--tiny", "--base-channels", "4", "--no-progress", "--val-every", "0"]
IMAGE = REPO / "assets" / "sample_images" / "chair.png"


def test_relative_out_records_files_a_reader_elsewhere_finds(sample_shards, tmp_path, monkeypatch):
    run = tmp_path / "run"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", run, "--steps", "1", "--batch-size", "2", *TINY])
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path)
    args = ["predict", "--checkpoint", run, IMAGE, "--out", "rel_out", "--pose", "head"]
    run_cli(main, args)
    monkeypatch.chdir(tmp_path / "elsewhere")
    record = json.loads((tmp_path / "rel_out" / "chair.json").read_text())
    assert sorted(record["files"]) == ["binvox", "json", "npz", "obj", "png"]
    assert all(Path(p).is_file() for p in record["files"].values()), record["files"]

    # an earlier version's record (paths relative to where it ran) still lists its files: predicting
    # again into that folder, from elsewhere, replaces them instead of refusing them as foreign
    record["files"] = {k: f"rel_out/chair.{k}" for k in record["files"]}
    (tmp_path / "rel_out" / "chair.json").write_text(json.dumps(record))
    run_cli(main, [*args[:-3], tmp_path / "rel_out", "--pose", "head"])
