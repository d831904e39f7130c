"""A split file line that names no mesh (a typo, or a comment after an id: ``train chair/x  # the
white one``, whose ``#`` is part of the id) left that object out of ``render`` with exit 0 and no
word on the console: only ``index.json``'s ``skipped`` held it, where docs/data.md says such an id
"is reported line by line". ``render`` now prints one warning per such line (five, then a count);
categories the split files list beyond the meshes (``--categories`` taking a subset of the
official files) stay one quiet ``skipped`` entry each. Real renders of the bundled chairs."""
from __future__ import annotations

from click.testing import CliRunner

from sc3d_cli.data import main
from conftest import SAMPLE_MESHES
from test_faults import FAST, index_of


def _render(tmp_path, lines: list[str]):
    split = tmp_path / "split.txt"
    split.write_text("".join(line + "\n" for line in lines))
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["render", "--meshes", str(SAMPLE_MESHES), "--categories", "chair", "--out", str(out),
                                    "--split-file", str(split), *FAST], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    warnings = [line for line in res.output.splitlines() if line.startswith("warning:")]
    return split, out, warnings


def test_split_file_lines_that_name_no_mesh_are_printed(tmp_path):
    ghosts = [f"train chair/ghost_{i}" for i in range(5)]
    split, out, warnings = _render(tmp_path, ["train chair/chair2_blendswap  # the white one",
                                              "train chair/silla_blanca_blendswap", *ghosts])
    assert warnings[0] == (f"warning: {split}:1: split file names 'chair/chair2_blendswap  # the white one' (train), "
                           "which matches no mesh")
    assert warnings[1:5] == [f"warning: {split}:{n + 3}: split file names 'chair/ghost_{n}' (train), which matches no mesh"
                             for n in range(4)]
    assert warnings[5:] == ["warning: and 1 more problems of the split files, listed under skipped in index.json"]
    assert [o["model_id"] for o in index_of(out)["objects"]] == ["silla_blanca_blendswap"]
    assert sum("matches no mesh" in s["reason"] for s in index_of(out)["skipped"]) == 6  # every one still listed


def test_categories_the_split_file_lists_beyond_the_meshes_are_not_warned(tmp_path):
    """The control: an airplane id with ``--categories chair`` is a subset, not a mistake."""
    _, out, warnings = _render(tmp_path, ["train chair/silla_blanca_blendswap", "train airplane/some_plane"])
    assert warnings == []
    assert any("split files list 1 models of category" in s["reason"] for s in index_of(out)["skipped"])
