"""An index whose ``part`` or ``counts`` record is hand-edited or damaged (not an object, a key
removed, a count written as a string). ``info`` indexes into both and ``merge`` into ``part``:
each crashed with a traceback (``AttributeError: 'int' object has no attribute 'get'``,
``KeyError: 'count'``, ``TypeError: '>' not supported ...``) where every other malformed key of
the index is refused in one line naming the file and the key (``io.index_check``). Real
renderer, real files; expected messages written by hand."""
from __future__ import annotations

import json
import shutil

import pytest

from sc3d_cli.data import main as data_main
from conftest import SAMPLE_MESHES, one_error, run_cli
from test_faults import FAST

RENDER = ["render", "--meshes", SAMPLE_MESHES, *FAST]

EDITS = [  # (edit of the parsed index, the phrase the one error line must hold)
    (lambda ix: ix.update(part=5), "malformed: part is 5, not an object"),
    (lambda ix: ix["part"].pop("count"), "malformed: part.count is missing, not an integer"),
    (lambda ix: ix["part"].update(count="2"), "malformed: part.count is '2', not an integer"),
    (lambda ix: ix["part"].pop("assigned"), "malformed: part.assigned is missing, not an integer"),
    (lambda ix: ix.update(counts="x"), "malformed: counts is 'x', not an object"),
    (lambda ix: ix["counts"].update(by_category={"03001627": 5}),
     "malformed: counts.by_category.03001627 is 5, not an object of integers"),
    (lambda ix: ix["counts"].update(by_split={"train": "a"}), "malformed: counts.by_split is"),
]


@pytest.fixture(scope="module")
def parts(tmp_path_factory):
    root = tmp_path_factory.mktemp("parts")
    for i in (0, 1):
        run_cli(data_main, [*RENDER, "--out", root / f"p{i}", "--part", f"{i}/2"])
    return root


@pytest.mark.parametrize("edit,phrase", EDITS)
def test_info_and_merge_refuse_a_malformed_part_or_counts_record_in_one_line(parts, tmp_path, edit, phrase):
    edited = tmp_path / "p0"
    shutil.copytree(parts / "p0", edited)
    index = json.loads((edited / "index.json").read_text())
    edit(index)
    (edited / "index.json").write_text(json.dumps(index))
    for args in (["info", edited], ["merge", tmp_path / "merged", edited, parts / "p1"]):
        res = run_cli(data_main, args, expect_exit=1)
        line = one_error(res.output)
        assert f"{edited / 'index.json'}: " in line and phrase in line, line
    assert not (tmp_path / "merged" / "index.json").exists()
    run_cli(data_main, ["merge", tmp_path / "good", parts / "p0", parts / "p1"])  # the parts themselves merge
