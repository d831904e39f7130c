"""A hand-edited ``index.json`` whose object ``row`` is not a row of its shard: row 99 in a shard
of 11 objects made ``sc3d-data preview`` end in an h5py ``IndexError`` traceback; row -1 made it
exit 0 drawing the shard's last object under the first object's name; ``info --verify`` and
``check`` passed both, and ``fit`` / ``eval`` (which read the shards' own rows) used the index
without a word. Now every reader of the index refuses it in the one line docs/data.md promises,
and a render rerun renders that shard again. Expected messages written by hand."""
from __future__ import annotations

import json
import shutil

import pytest

from sc3d_cli.data import main as data_main
from sc3d_data.io.shard_reader import ShardReader
from sc3d_data.io.shards import ShardError
from conftest import SAMPLE_MESHES, one_error, run_cli

FIRST = "02691156/b767_lowpoly_fgai"
CASES = {"past_the_end": (99, f"{FIRST} has row 99 in shard-00000.h5, which holds 11 objects (rows 0 to 10)"),
         "negative": (-1, f"{FIRST} has row -1 in shard-00000.h5, which holds 11 objects (rows 0 to 10)"),
         "float": (1.0, f"{FIRST} has row 1.0 in shard-00000.h5, not an integer"),
         "taken": (1, f"{FIRST} and 02691156/c182_fgai both have row 1 in shard-00000.h5")}


def _edited(sample_shards, tmp_path, row, count=True):
    out = tmp_path / "edited"
    shutil.copytree(sample_shards, out)
    index = json.loads((out / "index.json").read_text())
    assert index["objects"][0]["model_id"] == FIRST.split("/")[1] and index["objects"][1]["row"] == 1
    index["objects"][0]["row"] = row
    if not count:
        del index["shards"][0]["objects"]
    (out / "index.json").write_text(json.dumps(index))
    return out


@pytest.mark.parametrize("case", list(CASES))
def test_readers_refuse_an_object_row_outside_its_shard(sample_shards, tmp_path, case):
    row, problem = CASES[case]
    out = _edited(sample_shards, tmp_path, row)
    want = f"Error: {out / 'index.json'}: malformed: {problem} (hand-edited?); render or merge it again"
    for args in (["preview", out, "--out", tmp_path / "p.png"], ["info", out, "--verify"],
                 ["check", out, "--no-progress"]):
        assert one_error(run_cli(data_main, args, expect_exit=1).output) == want, args
    assert not (tmp_path / "p.png").exists()
    with pytest.raises(ShardError, match="malformed: "):  # the reader of fit and eval
        ShardReader(out)


@pytest.mark.parametrize("row", [99, -1])
def test_preview_checks_the_row_where_the_index_gives_no_count(sample_shards, tmp_path, row):
    """Without the file's object count in ``shards`` the index cannot be judged alone: preview
    checks the row when it opens the shard."""
    out = _edited(sample_shards, tmp_path, row, count=False)
    res = run_cli(data_main, ["preview", out, "--out", tmp_path / "p.png"], expect_exit=1)
    assert one_error(res.output) == (f"Error: {out / 'index.json'}: malformed: {FIRST} has row {row} in "
                                     "shard-00000.h5, which holds 11 objects (hand-edited?)")


def test_a_render_rerun_renders_the_shard_again(sample_shards, tmp_path):
    out = _edited(sample_shards, tmp_path, -1)
    res = run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", out, "--voxelize", "--no-progress",
                                "--workers", "1"])
    assert f"{CASES['negative'][1]}; rendering its objects again" in res.output
    assert json.loads((out / "index.json").read_text())["objects"][0]["row"] == 0
    run_cli(data_main, ["preview", out, "--out", tmp_path / "p.png"])
