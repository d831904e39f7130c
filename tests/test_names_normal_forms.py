"""Names that look alike but are written in two Unicode normalisations: ``café`` typed in an editor
(NFC, ``é`` one code point) and a file named ``café`` on macOS or in a zip archive made there (NFD,
``e`` and a combining accent). sc3d compares names exactly (they are different names on Linux and
two such files are two objects); where a split file or ``--categories`` names one and the meshes
have the other, the message says so, instead of a bare "matches no mesh" beside a skipped mesh
whose name reads the same."""
from __future__ import annotations

import unicodedata
from types import SimpleNamespace

NFC, NFD = unicodedata.normalize("NFC", "café"), unicodedata.normalize("NFD", "café")


def _entries(*keys):
    return [SimpleNamespace(category=c, model_id=m) for c, m in keys]


def test_split_file_id_in_another_normalisation_is_named_as_such(tmp_path):
    from sc3d_data.formats.splits import assign_splits

    sp = tmp_path / "sp.txt"
    sp.write_text(f"train chair/{NFC}\ntest {NFC}\nval chair/plain\nval chair/nothing\n", encoding="utf-8")
    splits, _, problems = assign_splits(_entries(("03001627", NFD), ("03001627", "plain")), split_file=sp)
    assert splits == {("03001627", "plain"): "val"}  # exact names: nothing is matched across forms
    reasons = [p["reason"] for p in problems]
    assert len(reasons) == 3
    assert "another Unicode normalisation" in reasons[0] and ascii(f"03001627/{NFD}") in reasons[0]
    assert "another Unicode normalisation" in reasons[1] and ascii(NFD) in reasons[1]
    assert reasons[2].endswith("which matches no mesh")  # a plain typo: no note


def test_split_file_category_in_another_normalisation_is_not_summed_up_as_absent(tmp_path):
    """A category folder ``cafés`` (NFD) named ``cafés/x`` (NFC) in a split file was counted among
    the categories "not among the meshes" (no warning at all), its mesh skipped "not in any split"."""
    from sc3d_data.formats.splits import assign_splits

    sp = tmp_path / "sp.txt"
    sp.write_text(f"train {NFC}s/x\n", encoding="utf-8")
    _, _, problems = assign_splits(_entries((f"{NFD}s", "x")), split_file=sp)
    (problem,) = problems
    assert problem["source"] == f"{sp}:1" and "another Unicode normalisation" in problem["reason"]


def test_requested_category_in_another_normalisation_is_named_as_such(tmp_path):
    from sc3d_data.formats.discover import discover_meshes

    (tmp_path / NFD).mkdir()
    (tmp_path / NFD / "a.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "b.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    entries, problems = discover_meshes(tmp_path, categories=f"{NFC},other")
    assert [e.model_id for e in entries] == ["b"]
    (problem,) = problems
    assert "matches no mesh; the meshes have " + ascii(NFD) in problem["reason"]
