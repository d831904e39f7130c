"""An index whose ``shards`` and ``objects`` lists disagree (hand-edited: a shard listed twice,
an object listed twice or removed, a shard entry removed). Every reader trusted the lists: a
shard listed twice was trained and evaluated twice (eval's test views doubled) with exit 0 and
``info --verify`` / ``check`` passed; a render rerun kept the duplicate. Real renderer, real
files; expected messages written by hand."""
from __future__ import annotations

import json
import shutil

import pytest

from sc3d_cli.data import main as data_main
from sc3d_data.io.shard_reader import ShardReader
from sc3d_data.io.shards import ShardError
from conftest import SAMPLE_MESHES, assert_same_dataset, one_error, run_cli
from test_faults import FAST

RENDER = ["render", "--meshes", SAMPLE_MESHES, "--objects-per-shard", "3", "--voxelize", *FAST]


def _shard_listed_twice(index):
    index["shards"].append(dict(index["shards"][0]))
    return "shard-00000.h5 is listed twice in shards"


def _object_listed_twice(index):
    index["objects"].append(dict(index["objects"][0]))
    o = index["objects"][0]
    return f"{o['category']}/{o['model_id']} is listed twice in objects"


def _object_removed(index):
    index["objects"] = [o for o in index["objects"] if o["shard"] != "shard-00001.h5" or o["row"] != 0]
    return "shards says shard-00001.h5 holds 3 objects, objects name it 2 times"


def _shard_entry_removed(index):
    index["shards"] = index["shards"][1:]
    return "objects name shard-00000.h5, which shards does not list"


EDITS = [_shard_listed_twice, _object_listed_twice, _object_removed, _shard_entry_removed]


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    out = tmp_path_factory.mktemp("r27") / "clean"
    run_cli(data_main, [*RENDER, "--out", out])
    return out


def _edited(rendered, tmp_path, edit):
    out = tmp_path / "edited"
    shutil.copytree(rendered, out)
    index = json.loads((out / "index.json").read_text())
    problem = edit(index)
    (out / "index.json").write_text(json.dumps(index))
    return out, problem


@pytest.mark.parametrize("edit", EDITS, ids=lambda f: f.__name__.strip("_"))
def test_readers_refuse_an_index_whose_lists_disagree(rendered, tmp_path, edit):
    """``info``, ``info --verify``, ``check`` and the reader of training and eval refuse in one line
    naming index.json and the disagreement (a shard listed twice passed all of them)."""
    out, problem = _edited(rendered, tmp_path, edit)
    want = f"Error: {out / 'index.json'}: malformed: {problem} (hand-edited?); render or merge it again"
    for args in (["info", out], ["info", out, "--verify"], ["check", out, "--no-progress"]):
        assert one_error(run_cli(data_main, args, expect_exit=1).output) == want, args
    with pytest.raises(ShardError, match="malformed: "):
        ShardReader(out)


@pytest.mark.parametrize("edit", EDITS, ids=lambda f: f.__name__.strip("_"))
def test_a_render_rerun_makes_the_disagreeing_shards_again(rendered, tmp_path, edit):
    """A rerun of the render renders the chunks of the files the lists disagree on and leaves the
    dataset one clean render makes (a shard listed twice stayed listed twice, exit 0)."""
    out, _ = _edited(rendered, tmp_path, edit)
    run_cli(data_main, [*RENDER, "--out", out])
    assert_same_dataset(out, rendered)
    assert run_cli(data_main, ["info", out, "--verify"]).exit_code == 0
    index = json.loads((out / "index.json").read_text())
    assert [s["file"] for s in index["shards"]] == [f"shard-{c:05d}.h5" for c in range(4)]
    assert len(index["objects"]) == 11
