"""Regressions of this session's fixes found in review (review29), each shown against what the
same input gave before the fix, derived by hand.

1. ``io.obj_keyword_case`` failed an OBJ whose ``VN``, ``L`` or ``P`` statement is written in
   another case than lower, saying its geometry would be drawn without it. Nothing drawn changes:
   the renderer shades by face normals and draws no points or lines, so the file renders exactly
   as the same file with those statements in lower case (it rendered so before the check, exit 0).
   Only ``V``, ``VT`` and ``F`` change what is drawn.
2. ``evaluated_data._same_path`` judged a relative path an earlier version recorded as the same
   file as any path given that ends with it. For the checkpoint that is sound (the default folder
   lies in the given checkpoint's run folder, so a path that ends with it names that file), but an
   earlier ``metrics.json`` recording ``--shards data/shards`` (relative to a folder no record
   names) then counted as the evaluation of every ``.../data/shards``: evaluating other shards
   into that default folder replaced it without a word (docs/training.md: "never given to the
   evaluation of ... other shards")."""
from __future__ import annotations

import json
import os

import pytest

from test_faults import CUBE_F, CUBE_V


def _cube(extra: str, normals: bool = False) -> bytes:
    lines = ["v %g %g %g" % tuple(p) for p in CUBE_V] + extra.splitlines()
    face = "f %d//1 %d//1 %d//1" if normals else "f %d %d %d"
    return ("\n".join(lines + [face % tuple(i + 1 for i in f) for f in CUBE_F]) + "\n").encode()


@pytest.mark.parametrize("extra, normals", [("VN 0 0 1", True), ("L 1 2", False), ("P 1", False)])
def test_an_upper_case_statement_that_draws_nothing_is_not_refused(extra, normals):
    from sc3d_data.io.obj_keyword_case import check_keyword_case

    assert check_keyword_case(_cube(extra, normals)) == []


@pytest.mark.parametrize("extra", ["V 0 0 2", "VT 0.5 0.5", "F 1 2 3"])
def test_an_upper_case_statement_that_draws_is_still_refused(extra):
    from sc3d_data.io.obj_keyword_case import check_keyword_case

    with pytest.raises(ValueError, match=f"{extra.split()[0]!r} statement"):
        check_keyword_case(_cube(extra))


def test_an_earlier_relative_shards_path_is_not_any_folder_of_that_name(tmp_path, monkeypatch):
    from sc3d_train.evaluation.evaluated_data import replaced_provenance

    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "last.pt").write_bytes(b"x")
    other = tmp_path / "project-b" / "data" / "shards"
    other.mkdir(parents=True)
    record = run / "eval_test" / "metrics.json"
    record.parent.mkdir()
    record.write_text(json.dumps({"checkpoint": "run/checkpoints/last.pt", "shards": "data/shards",
                                  "split": "test", "pose_from": "true"}))  # project-a's data/shards, as given
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    given = {"checkpoint": str(run / "checkpoints" / "last.pt"), "shards": str(other), "pose_from": "true"}
    assert replaced_provenance(record, given) == ("shards data/shards", f"shards {other}")
    # the same checkpoint named from another folder is still the same file (b3445a3)
    assert replaced_provenance(record, {"checkpoint": given["checkpoint"]}) is None
    assert os.getcwd() == str(tmp_path / "elsewhere")
