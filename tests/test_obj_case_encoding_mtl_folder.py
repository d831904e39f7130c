"""Three OBJ/MTL edge cases that drew a wrong picture, each rendered with the real renderer and
compared with a reference written independently (the same cube written the plain way):

1. OBJ keywords in another case (``MTLLIB``, ``USEMTL``, ``V``): trimesh, Blender and
   tinyobjloader do not read them, and neither does sc3d (``io.obj_keyword_case``), but it says
   so: a warning naming the file and the keyword (the object renders as the same cube without
   material statements), a failure naming the line for a geometry statement. Before, ``USEMTL``
   drew the default grey without a word, ``V`` failed "empty mesh". MTL keywords in another
   case (``NEWMTL``, ``KD``, ``MAP_KD``) are read, as trimesh reads them.
2. A Latin-1 ``.mtl`` naming ``caf\\xe9.png`` where the file on disk is ``café.png`` in UTF-8, and
   the reverse: the texture is drawn (``io.stand_ins.respelled``), with a warning. Before, the
   object failed "texture ... not found" (the loader itself would have read it). Where both files
   lie there, the one of the bytes written is drawn (before, the UTF-8 one, without a word).
3. ``mtllib mats/m.mtl`` naming ``map_Kd t.png``: the texture is ``mats/t.png``, beside the
   ``.mtl``, as Blender's importer (``mtl_dir_path``) and sc3d's own checks read it. Before, the
   loader read ``t.png`` beside the OBJ: a different texture drawn without a word where one lies
   there, a failure where none does.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import CUBE_F, CUBE_V, FAST, index_of

RED, BLUE, GREEN = (255, 0, 0), (0, 0, 255), (0, 255, 0)


def _obj_text(mtllib: str | None = "mtllib m.mtl", usemtl: str | None = "usemtl mat", v: str = "v") -> str:
    """A unit cube, every corner's texture coordinate (0.5, 0.5), with the given statements."""
    lines = [s for s in (mtllib, usemtl) if s is not None] + [f"{v} %g %g %g" % tuple(p) for p in CUBE_V]
    return "\n".join(lines + ["vt 0.5 0.5"] + ["f %d/1 %d/1 %d/1" % tuple(np.add(f, 1)) for f in CUBE_F]) + "\n"


def _png(path: bytes | Path, rgb) -> None:
    """A 4 x 4 PNG of one colour at ``path`` (bytes: a name that need not be UTF-8)."""
    path = os.fsencode(path)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "wb") as f:
        Image.fromarray(np.full((4, 4, 3), rgb, np.uint8)).save(f, format="PNG")


def _case(meshes: Path, name: str, obj: str, mtl: bytes | None = None, mtl_name: str = "m.mtl",
          textures: dict[bytes, tuple] = {}) -> None:  # noqa: B006 - read only
    folder = meshes / name
    folder.mkdir(parents=True)
    (folder / "m.obj").write_text(obj)
    if mtl is not None:
        (folder / mtl_name).parent.mkdir(parents=True, exist_ok=True)
        (folder / mtl_name).write_bytes(mtl)
    for texture, rgb in textures.items():
        _png(os.fsencode(folder) + b"/" + texture, rgb)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """``(images by case, warnings by case, failures by case)`` of one render of every case."""
    root = tmp_path_factory.mktemp("obj_edges")
    meshes = root / "m" / "c"
    red = b"newmtl mat\nKd 1 0 0\n"
    textured = b"newmtl mat\nKd 1 1 1\nmap_Kd t.png\n"
    # 1: keyword case
    _case(meshes, "ref_default", _obj_text(None, None))
    _case(meshes, "upper_mtllib", _obj_text("MTLLIB m.mtl"), red)
    _case(meshes, "upper_usemtl", _obj_text(usemtl="USEMTL mat"), red)
    _case(meshes, "upper_v", _obj_text(v="V"), red)
    _case(meshes, "ref_red", _obj_text(), red)
    _case(meshes, "upper_mtl_keys", _obj_text(), b"NEWMTL mat\nKD 1 0 0\n")
    _case(meshes, "ref_texture", _obj_text(), textured, textures={b"t.png": BLUE})
    _case(meshes, "upper_map_kd", _obj_text(), b"newmtl mat\nKd 1 1 1\nMAP_KD t.png\n", textures={b"t.png": BLUE})
    # 2: encodings of a texture's name
    _case(meshes, "latin1_mtl_utf8_file", _obj_text(), b"newmtl mat\nKd 1 1 1\nmap_Kd caf\xe9.png\n",
          textures={"café.png".encode(): BLUE})
    _case(meshes, "utf8_mtl_latin1_file", _obj_text(), "newmtl mat\nKd 1 1 1\nmap_Kd café.png\n".encode(),
          textures={b"caf\xe9.png": BLUE})
    _case(meshes, "latin1_mtl_both_files", _obj_text(), b"newmtl mat\nKd 1 1 1\nmap_Kd caf\xe9.png\n",
          textures={b"caf\xe9.png": BLUE, "café.png".encode(): GREEN})  # the bytes as written are drawn
    # 3: a material file in a subfolder, its texture beside it (and another beside the OBJ)
    _case(meshes, "mtl_in_subfolder", _obj_text("mtllib mats/m.mtl"), textured, "mats/m.mtl",
          textures={b"mats/t.png": BLUE, b"t.png": GREEN})
    _case(meshes, "mtl_in_subfolder_alone", _obj_text("mtllib mats/m.mtl"), textured, "mats/m.mtl",
          textures={b"mats/t.png": BLUE})
    out = root / "out"
    run_cli(data_main, ["render", "--meshes", root / "m", "--out", out, *FAST])
    index = index_of(out)
    images = {key[1].split("/")[0]: obj["images"] for key, obj in objects_by_id(out).items()}
    warnings = {Path(w["source"]).parent.name: w["warning"] for w in index["warnings"]}
    failures = {Path(f["source"]).parent.name: f["reason"] for f in index["failures"]}
    return images, warnings, failures


def test_obj_keywords_in_another_case_are_warned_of_or_refused(rendered):
    images, warnings, failures = rendered
    for name, keyword in (("upper_mtllib", "MTLLIB"), ("upper_usemtl", "USEMTL")):
        np.testing.assert_array_equal(images[name], images["ref_default"], err_msg=name)  # as OBJ readers read it
        assert f"{Path('c', name, 'm.obj')}: {keyword} (line " in warnings.get(name, "") \
            and "not read" in warnings[name], warnings.get(name)  # one line naming the file and the keyword
    assert "upper_v" not in images and "line 3 ('V 0 0 0')" in failures["upper_v"] and "'v'" in failures["upper_v"]
    assert not np.array_equal(images["ref_red"], images["ref_default"])  # the reference does show the material
    np.testing.assert_array_equal(images["upper_mtl_keys"], images["ref_red"])  # MTL keywords: any case
    np.testing.assert_array_equal(images["upper_map_kd"], images["ref_texture"])
    assert not {"upper_mtl_keys", "upper_map_kd", "ref_red", "ref_texture", "ref_default"} & set(warnings)


def test_a_texture_name_in_the_other_encoding_than_the_file_on_disk_is_drawn(rendered):
    images, warnings, failures = rendered
    for name in ("latin1_mtl_utf8_file", "utf8_mtl_latin1_file"):
        assert name not in failures, failures.get(name)
        np.testing.assert_array_equal(images[name], images["ref_texture"], err_msg=name)
        assert "is read in its place" in warnings[name]
    np.testing.assert_array_equal(images["latin1_mtl_both_files"], images["ref_texture"])  # blue, not green
    assert "latin1_mtl_both_files" not in warnings


def test_a_texture_of_a_material_file_in_a_subfolder_is_read_beside_that_file(rendered):
    images, warnings, failures = rendered
    for name in ("mtl_in_subfolder", "mtl_in_subfolder_alone"):
        assert name not in failures, failures.get(name)
        np.testing.assert_array_equal(images[name], images["ref_texture"], err_msg=name)  # blue, not green
        assert name not in warnings
