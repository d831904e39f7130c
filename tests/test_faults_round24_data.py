"""Data-half defects of the twenty-fourth round (items of the last left-alone list and the
twenty-fourth attack), each with the real loader, renderer and command; expected values come
from hand-built files and from bash itself, never from the code under test."""
from __future__ import annotations

import os
import re
import subprocess

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import FAST, index_of
from test_faults_round21_data import _vertex_coloured_obj


def test_obj_vertex_colours_that_are_not_numbers_are_refused_in_one_line(tmp_path):
    """``v x y z nan nan nan`` (trimesh's deliberately malformed ``models/nancolor.obj``) was cast
    to 0 by the loader: that corner and the faces around it drawn black, exit 0. Now the file is
    refused in one line naming it and the count, with or without a material; the same cube with
    finite colours (the control) renders, and so does every other object of the run."""
    meshes = tmp_path / "m" / "c"
    _vertex_coloured_obj(meshes / "finite", (1, 0, 0))
    for name, mtl in (("nan_plain", None), ("nan_material", "newmtl mat\nKd 1 1 1\n")):
        _vertex_coloured_obj(meshes / name, (1, 0, 0), mtl)
        obj = meshes / name / "m.obj"
        lines = obj.read_text().splitlines()
        first_v = next(i for i, line in enumerate(lines) if line.startswith("v "))
        lines[first_v] = " ".join(lines[first_v].split()[:4] + ["nan", "nan", "nan"])
        obj.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    index = index_of(out)
    assert [o["model_id"] for o in index["objects"]] == ["finite/m"]  # the mesh's path under its category
    reasons = {f["model_id"].split("/")[0]: f["reason"] for f in index["failures"]}
    assert sorted(reasons) == ["nan_material", "nan_plain"]
    for name, reason in reasons.items():
        assert reason == f"{meshes / name / 'm.obj'}: 1 vertex colours are not numbers (NaN/inf), which would be " \
                         "drawn black", reason


def _pasted(command_word: str) -> bytes:
    """What bash makes of ``command_word`` (one shell word, as printed in a message)."""
    return subprocess.run(["bash", "-c", f"printf %s {command_word}"], capture_output=True, check=True).stdout


def test_a_suggested_command_can_be_pasted_whatever_the_output_folder_is_named(tmp_path):
    """render's summary suggests ``sc3d-data info OUT`` when objects failed; OUT was printed as it
    is, so a folder named with a space split into two arguments when pasted and one with a newline
    split the line itself (and the summary's ``index:`` path with it). The suggested word must be
    read by bash (the reference) as the folder's exact name, and every line of the output must
    be one line."""
    meshes = tmp_path / "m" / "c"
    _vertex_coloured_obj(meshes / "good", (1, 0, 0))
    (meshes / "broken").mkdir()
    (meshes / "broken" / "m.obj").write_text("this is no mesh\n")
    for name in ("my out", "new\nline 'quoted'", "tab\tand \\ slash"):
        out = tmp_path / name
        res = run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
        suggestion = next(line for line in res.output.splitlines() if "listed with reasons by" in line)
        word = re.fullmatch(r".*`sc3d-data info (.+)`", suggestion).group(1)
        assert _pasted(word) == os.fsencode(str(out)), (name, suggestion)
        summary = next(line for line in res.output.splitlines() if line.startswith("done 1,"))
        assert summary.endswith("index.json"), (name, res.output)
        assert index_of(out)["objects"][0]["model_id"] == "good/m"
