"""OBJ and STL text whose statements are laid out in ways the loader does not read, found by
feeding real files of public repositories to ``render``: Williams College's
``CornellBox-Original.obj`` (a tab after ``v`` on half its vertex lines) and numpy-stl's
``mac.stl`` (lines ended by CR alone). Expected values come from the same geometry written in the
plain layout (``KEYWORD VALUE``, LF), never from the code under test."""
from __future__ import annotations

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST, index_of

#: two boxes written object by object with relative indices, half the vertex lines with a tab
#: after ``v`` (as CornellBox-Original.obj writes them), as a file written in the plain layout
_BOXES = "\n".join(
    [f"o box{b}\n" + "\n".join(f"v {x + 3 * b} {y} {z * (1 + b)}" for x in (0, 1) for y in (0, 1) for z in (0, 1))
     + "\nf -8 -7 -5 -6\nf -4 -3 -1 -2\nf -8 -4 -3 -7\nf -6 -5 -1 -2\nf -8 -6 -2 -4\nf -7 -3 -1 -5"
     for b in (0, 1)]) + "\n"


def _tabbed(text: str) -> str:
    """``text`` with a tab after the keyword of every other vertex line (CornellBox-Original.obj)."""
    lines = text.split("\n")
    return "\n".join("v\t" + line[2:] if line.startswith("v ") and n % 2 else line for n, line in enumerate(lines))


def _render(tmp_path, files: dict[str, bytes]) -> dict:
    """``{stem: arrays}`` of ``render --voxelize`` of ``files`` (name -> bytes) in one category;
    asserts nothing failed."""
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    for name, data in files.items():
        (meshes / name).write_bytes(data)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--voxelize", *FAST])
    assert index_of(out)["failures"] == []
    return {name[1]: obj for name, obj in objects_by_id(out).items()}


def _assert_same(objects: dict, reference: str) -> None:
    for name, obj in objects.items():
        for array in ("images", "masks", "voxels"):
            np.testing.assert_array_equal(obj[array], objects[reference][array], err_msg=f"{name} {array}")


def test_obj_statements_with_tabs_indentation_or_cr_lines_are_read_as_written(tmp_path):
    """A tab after ``v`` (Williams College's CornellBox-Original.obj), indented statements, lines
    ended by CR alone, and a face continued by ``\\`` in a CRLF file with relative indices: the
    loader dropped the tabbed or indented statements ("cannot parse ... IndexError", or no
    triangles), read a CR-only file as no triangles, and drew the continued CRLF face on other
    vertices (exit 0). Each now renders as the same boxes written plainly."""
    plain = _BOXES
    continued = plain.replace("f -8 -7 -5 -6\n", "f -8 -7 \\\n-5 -6\n").replace("\n", "\r\n")
    objects = _render(tmp_path, {
        "plain.obj": plain.encode(),
        "tabbed.obj": _tabbed(plain).encode(),
        "indented.obj": "\n".join("  " + line for line in plain.split("\n")).encode(),
        "cr_only.obj": plain.replace("\n", "\r").encode(),
        "continued_crlf.obj": continued.encode(),
    })
    assert len(objects) == 5
    _assert_same(objects, "plain")


def test_obj_with_index_zero_on_cr_only_lines_is_refused(tmp_path):
    """A face naming index 0 in a file whose lines end with CR alone is refused naming its line,
    as in a file of LF lines (read as LF lines, it would draw vertex 0 as the last vertex)."""
    from sc3d_data.io.obj_loader_text import check_obj_indices

    import pytest

    with pytest.raises(ValueError, match="line 4 .*names index 0"):
        check_obj_indices(b"v 0 0 0\rv 1 0 0\rv 0 1 0\rf 0 1 2\r")


def test_ascii_stl_with_cr_only_lines_is_read(tmp_path):
    """numpy-stl's ``mac.stl`` layout: an ASCII STL whose lines end with CR alone was refused as
    "does not end with an `endsolid` line: cut short?" (it does end with one), and the loader could
    not parse it either. It renders as its LF twin; one really cut short is still refused."""
    facets = "".join(f"facet normal 0 0 1\n outer loop\n  vertex {a}\n  vertex {b}\n  vertex {c}\n endloop\nendfacet\n"
                      for a, b, c in (("0 0 0", "1 0 0", "0 1 0"), ("0 0 0", "0 1 0", "0 0 1"),
                                      ("0 0 0", "0 0 1", "1 0 0"), ("1 0 0", "0 0 1", "0 1 0")))
    lf = f"solid Moon.stl\n{facets}endsolid Moon.stl\n"
    objects = _render(tmp_path, {"lf.stl": lf.encode(), "mac.stl": lf.replace("\n", "\r").encode(),
                                 "dos.stl": lf.replace("\n", "\r\n").encode()})
    assert len(objects) == 3
    _assert_same(objects, "lf")

    from sc3d_data.io.stl_check import loader_stl_bytes

    import pytest

    cut = tmp_path / "cut.stl"
    cut.write_bytes(lf.replace("\n", "\r").encode()[:-40])
    with pytest.raises(ValueError, match="cut short"):
        loader_stl_bytes(cut)
