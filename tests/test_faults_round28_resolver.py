"""Companion files read in place of those a mesh names (round 28): what is warned about,
fingerprinted and checked is the file the loader draws. A material file, texture or glTF file
whose name reaches no file is read under its bare name beside the file that names it
(``io.stand_ins``), as the renderer's resolver always did; the judges said "not found" and
fingerprinted the missing name. And an OBJ whose lines end with CR alone, which the loader reads
since b9c3af0, had its ``mtllib`` and ``usemtl`` statements misread by the project's own readers.
Real renders of hand-built files; expected values written by hand."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import FAST, index_of
from test_faults_round19_data import _looks, _textured_obj
from test_faults_round5 import _textured_box_gltf


def _warnings(out: Path) -> list[str]:
    """The warnings of dataset ``out``, each without the mesh's path before it."""
    return sorted(w["warning"].split(": ", 1)[1] for w in index_of(out).get("warnings", []))


def _colour(out: Path) -> tuple[int, int, int]:
    """The median colour of the masked pixels of the one object of dataset ``out``."""
    from conftest import objects_by_id

    (obj,) = objects_by_id(out).values()
    return tuple(int(c) for c in np.median(obj["images"][obj["masks"] > 0], axis=0))


def test_a_material_file_named_by_a_path_from_the_repository_root_is_read_beside_the_obj(tmp_path):
    """chellmuth/pathed's ``CornellBox-Original.obj`` says ``mtllib scenes/CornellBox-Original.mtl``
    with the ``.mtl`` beside it. The loader reads that ``.mtl`` (red walls), so the index must say
    so (before: "material file scenes/m.mtl not found; rendered with the default material"), and
    fingerprint it: the file edited (green), a resume renders the object again (before: the
    missing name was fingerprinted, the edit went unnoticed and the shard kept red)."""
    folder = tmp_path / "m" / "c" / "box"
    _textured_obj(folder, b"newmtl mat\nKd 1 0 0\n")
    (folder / "t.png").unlink()
    obj = folder / "m.obj"
    obj.write_text(obj.read_text().replace("mtllib m.mtl", "mtllib scenes/m.mtl"))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert _warnings(out) == ["material file scenes/m.mtl not found; m.mtl beside the OBJ is read in its place"]
    assert _looks(out) == {"box": "red"}
    materials = index_of(out)["objects"][0]["source_file"]["materials"]
    assert sorted(materials) == ["m.mtl", "scenes/m.mtl"]
    assert materials["scenes/m.mtl"] is None and materials["m.mtl"]["bytes"] == len(b"newmtl mat\nKd 1 0 0\n")
    (folder / "m.mtl").write_bytes(b"newmtl mat\nKd 0 1 0\n")
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    r, g, b = _colour(out)
    assert g > 100 and r < 10 and b < 10


def test_a_texture_under_a_missing_folder_is_drawn_from_beside_the_mtl_and_checked(tmp_path):
    """``map_Kd textures/t.png`` with ``t.png`` beside the MTL: the loader draws ``t.png`` (as
    Blender's importer does), so the object renders, textured, with a warning naming both files;
    before it failed "texture textures/t.png (from m.mtl) not found" (with ``--bad-texture
    fallback``: "rendered with material colours", over a textured object). And the material
    file read beside the OBJ in place of ``scenes/m.mtl`` has its texture checked: a ``t.png``
    that is no image fails the object naming it (before: not checked, drawn untextured, exit 0)."""
    meshes = tmp_path / "m" / "c"
    _textured_obj(meshes / "tex", b"newmtl mat\nKd 1 1 1\nmap_Kd textures/t.png\n")
    _textured_obj(meshes / "bad", b"newmtl mat\nKd 1 1 1\nmap_Kd t.png\n")
    (meshes / "bad" / "t.png").write_bytes(b"not an image")
    obj = meshes / "bad" / "m.obj"
    obj.write_text(obj.read_text().replace("mtllib m.mtl", "mtllib scenes/m.mtl"))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert _warnings(out) == ["texture textures/t.png (from m.mtl) not found; t.png beside m.mtl is read in its place"]
    assert _looks(out) == {"tex": "red"}
    (failure,) = index_of(out)["failures"]
    assert Path(failure["source"]).parent.name == "bad"
    assert failure["reason"].split(": ", 1)[1] == ("texture t.png (from m.mtl) unreadable (not an image format Pillow "
                                                    "reads) (use --bad-texture fallback to render with material colours)")
    materials = index_of(out)["objects"][0]["source_file"]["materials"]
    assert sorted(materials) == ["m.mtl", "t.png", "textures/t.png"] and materials["textures/t.png"] is None


def test_a_gltf_image_and_buffer_under_a_missing_folder_are_read_beside_the_gltf(tmp_path):
    """A glTF naming ``textures/red.png`` and ``data/geo%20data.bin`` with both files beside it:
    the loader reads them there, so the object renders red with a warning for the texture
    (before: failed "texture image 0 (textures/red.png) not found", though the loader drew it),
    and both files drawn are fingerprinted beside the missing names."""
    from PIL import Image

    folder = tmp_path / "m" / "c"
    folder.mkdir(parents=True)
    _textured_box_gltf(folder, "box", "textures/red.png", "data/geo%20data.bin")
    Image.new("RGB", (4, 4), (255, 0, 0)).save(folder / "red.png")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == []
    assert _warnings(out) == ["texture image 0 (textures/red.png) not found; red.png beside the glTF is read in "
                              "its place"]
    assert _looks(out) == {"box": "red"}
    materials = index_of(out)["objects"][0]["source_file"]["materials"]
    assert sorted(materials) == ["data/geo data.bin", "geo data.bin", "red.png", "textures/red.png"]
    assert materials["textures/red.png"] is None and materials["red.png"] is not None


def test_mtllib_and_usemtl_of_an_obj_whose_lines_end_with_cr_alone_are_read(tmp_path):
    """An OBJ saved with classic Mac OS line ends (CR alone), which the loader reads since
    b9c3af0, with ``mtllib\\tm.mtl`` (a tab) and ``usemtl other``, a material ``m.mtl`` does not
    define. The project's statement readers took the whole file for one ``mtllib`` line: a
    "material file ... not found" warning for every word of it, and none for ``other``. Now the
    one warning is the undefined material's, and ``m.mtl`` is fingerprinted."""
    folder = tmp_path / "m" / "c" / "box"
    _textured_obj(folder, b"newmtl mat\nKd 1 0 0\n", usemtl="other")
    (folder / "t.png").unlink()
    obj = folder / "m.obj"
    obj.write_bytes(obj.read_bytes().replace(b"mtllib m.mtl", b"mtllib\tm.mtl").replace(b"\n", b"\r"))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert _warnings(out) == ["usemtl names other, which its material files do not define; those faces are drawn "
                              "with the default material"]
    assert list(index_of(out)["objects"][0]["source_file"]["materials"]) == ["m.mtl"]
    assert json.loads(json.dumps(_looks(out))) == {"box": "grey"}
