"""A render rerun over a dataset whose index does not record ``chunks`` (render before it had
``--chunks``: one object per chunk) took the option's default, ``view``: it kept the old shards,
wrote its new chunks one view per chunk and recorded ``"chunks": "view"``, so ``info`` named a
layout the kept shards do not have (exit 0). The layout now counts as what the shards hold
(``resume.shards_layout``). Real renderer, real HDF5."""
from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import h5py

from sc3d_cli.data import main as data_main
from conftest import SAMPLE_MESHES, one_error, run_cli

FAST = ["--views", "2", "--no-progress", "--workers", "1", "--objects-per-shard", "1"]


def _older_sc3d(out: Path, drop_last: bool) -> None:
    """``out`` as an sc3d that did not record ``chunks`` left it (index and shards' settings,
    checksums kept true); ``drop_last``: stopped before its last shard."""
    index = json.loads((out / "index.json").read_text())
    del index["settings"]["chunks"]
    for entry in index["shards"]:
        path = out / entry["file"]
        with h5py.File(path, "r+") as f:
            settings = json.loads(f.attrs["settings"])
            del settings["chunks"]
            f.attrs["settings"] = json.dumps(settings)
        entry["sha256"], entry["bytes"] = hashlib.sha256(path.read_bytes()).hexdigest(), path.stat().st_size
    if drop_last:
        last = index["shards"].pop()
        (out / last["file"]).unlink()
        index["objects"] = [o for o in index["objects"] if o["shard"] != last["file"]]
        index["complete"] = False
    (out / "index.json").write_text(json.dumps(index))


def _view_chunks(out: Path) -> set:
    """The view axis of the images' HDF5 chunks of every shard in ``out``."""
    return {h5py.File(p, "r")["images"].chunks[1] for p in sorted(out.glob("shard-*.h5"))}


def test_a_rerun_over_an_older_index_records_the_layout_its_shards_have(tmp_path):
    """Old shards one object per chunk: the default rerun is refused naming the layout they hold
    (it recorded ``view`` over them and wrote the rest per view); ``--chunks object`` resumes
    and records ``object``. Old shards one view per chunk resume with the default (control)."""
    meshes = tmp_path / "meshes"
    for name in ("car/jeep_psionic.glb", "chair/chair2_blendswap.glb"):
        (meshes / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(Path(SAMPLE_MESHES) / name, meshes / name)
    out = tmp_path / "old"
    run_cli(data_main, ["render", "--meshes", meshes, "--out", out, "--chunks", "object", *FAST])
    _older_sc3d(out, drop_last=True)
    error = one_error(run_cli(data_main, ["render", "--meshes", meshes, "--out", out, *FAST], expect_exit=1).output)
    assert "chunks differ" in error and "its shards hold one object per chunk" in error, error
    assert "chunks" not in json.loads((out / "index.json").read_text())["settings"]
    res = run_cli(data_main, ["render", "--meshes", meshes, "--out", out, "--chunks", "object", *FAST])
    assert "done 1, resumed 1" in res.output, res.output
    assert json.loads((out / "index.json").read_text())["settings"]["chunks"] == "object"
    assert _view_chunks(out) == {2}
    assert "chunks: object" in run_cli(data_main, ["info", out]).output

    views = tmp_path / "views"
    run_cli(data_main, ["render", "--meshes", meshes, "--out", views, *FAST])
    _older_sc3d(views, drop_last=False)
    assert "done 0, resumed 2" in run_cli(data_main, ["render", "--meshes", meshes, "--out", views, *FAST]).output
    assert json.loads((views / "index.json").read_text())["settings"]["chunks"] == "view"
    assert _view_chunks(views) == {1}


def test_merge_counts_an_older_part_as_the_layout_its_shards_have(tmp_path):
    """docs/data.md: a setting an older index does not record counts as its default, except
    ``chunks``, which counts as the layout its shards have, and ``merge`` compares its parts the
    same way. It took the default there: an older part (one object per chunk) merged with a new
    one (one view per chunk) without a word, into a dataset of two layouts (exit 0). Now that is
    refused as other settings; the part rendered again with ``--chunks object`` merges."""
    meshes = tmp_path / "meshes"
    for name in ("car/jeep_psionic.glb", "chair/chair2_blendswap.glb", "table/coffee_table_blendswap_ccby.glb"):
        (meshes / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(Path(SAMPLE_MESHES) / name, meshes / name)
    old, new, same = tmp_path / "p0", tmp_path / "p1", tmp_path / "p1_object"
    run_cli(data_main, ["render", "--meshes", meshes, "--out", old, "--chunks", "object", "--part", "0/2", *FAST])
    _older_sc3d(old, drop_last=False)
    run_cli(data_main, ["render", "--meshes", meshes, "--out", new, "--part", "1/2", *FAST])
    error = one_error(run_cli(data_main, ["merge", tmp_path / "m", old, new], expect_exit=1).output)
    assert "chunks differ" in error, error
    run_cli(data_main, ["render", "--meshes", meshes, "--out", same, "--chunks", "object", "--part", "1/2", *FAST])
    run_cli(data_main, ["merge", tmp_path / "m", old, same])
    assert _view_chunks(tmp_path / "m") == {2}
