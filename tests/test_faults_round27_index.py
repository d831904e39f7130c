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
    warnings = [line for line in run_cli(data_main, [*RENDER, "--out", out]).output.splitlines()
                if line.startswith("warning: ")]
    assert len(set(warnings)) == len(warnings), warnings  # a shard listed twice was warned of twice
    assert_same_dataset(out, rendered)
    assert run_cli(data_main, ["info", out, "--verify"]).exit_code == 0
    index = json.loads((out / "index.json").read_text())
    assert [s["file"] for s in index["shards"]] == [f"shard-{c:05d}.h5" for c in range(4)]
    assert len(index["objects"]) == 11


def _parts(tmp_path):
    """Two parts of the sample meshes (2 views), the second's first shard damaged in place: 8
    bytes of an image chunk flipped, the size kept (bit rot, a bad copy)."""
    from test_faults_round8_data import flip_bytes_in_a_chunk

    parts = [tmp_path / f"p{i}" for i in range(2)]
    for i, p in enumerate(parts):
        run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", p, "--part", f"{i}/2", "--views", "2",
                            "--no-progress", "--workers", "1", "--objects-per-shard", "3"])
    return parts, flip_bytes_in_a_chunk


def test_merge_refuses_a_part_shard_whose_bytes_changed(tmp_path):
    """``merge`` checked a part's shards by size only: one with flipped bytes was merged, exit 0,
    and ``info --verify`` of OUT then said to rerun the merge, which linked the same damaged
    file again, exit 0, for ever. It must refuse naming the part's file, before writing an
    index, and also when the damage appears after a merge (a hard link shares the bytes)."""
    (p0, p1), flip = _parts(tmp_path)
    out = tmp_path / "m"
    run_cli(data_main, ["merge", out, p0, p1])
    flip(p1 / "shard-00000.h5")  # OUT's linked copy is the same file: damaged too
    want = (f"Error: {p1 / 'shard-00000.h5'}: SHA-256 differs from the index (corrupted or modified); rerun that "
            "part (it re-renders the shard), then merge")
    assert one_error(run_cli(data_main, ["merge", out, p0, p1], expect_exit=1).output) == want
    assert one_error(run_cli(data_main, ["merge", tmp_path / "m2", p0, p1], expect_exit=1).output) == want
    assert not (tmp_path / "m2" / "index.json").exists()
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", p1, "--part", "1/2", "--views", "2",
                        "--no-progress", "--workers", "1", "--objects-per-shard", "3"])  # repairs the part
    run_cli(data_main, ["merge", out, p0, p1])
    assert run_cli(data_main, ["info", out, "--verify"]).exit_code == 0


def test_a_failed_slurm_part_is_reported_with_its_reason(tmp_path):
    """A part of ``--executor slurm`` that failed (here: its folder locked by another writer, as
    after a stopped submitting process whose array still runs) was reported as
    ``part 0/2 (job N):   - .../N_0_log.out``: the last line of submitit's message, a log path
    whose file does not hold the error. The line must carry the part's own error and the log
    that holds its trace (``_log.err``)."""
    import re

    pytest.importorskip("submitit")
    from sc3d_data.io.outlock import exclusive_lock

    out, part = tmp_path / "out", tmp_path / "out" / "parts" / "part-000-of-002"
    part.mkdir(parents=True)
    with exclusive_lock(part, "a test"):
        res = run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "chair", "--out", out, "--executor", "slurm",
                                  "--slurm-cluster", "local", "--slurm-parts", "2", "--slurm-cpus-per-task", "1",
                                  *FAST], expect_exit=1)
    line = one_error(res.output)
    want = (rf"Error: part 0/2 \(job \d+\): {re.escape(str(part))}: another process \(PID \d+: a test\) is writing "
            rf"to this folder; wait for it to finish or use another --out \(log: \S+_0_log\.err\) -- rerun the same "
            r"command \(finished parts are kept\)")
    assert re.fullmatch(want, line), line
