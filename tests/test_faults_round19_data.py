"""Data-half defects of the nineteenth round (items of the left-alone list and the nineteenth
attack), each with the real loader, renderer and command; expected values come from the file
formats' specifications (glTF 2.0, the MTL format) and from hand-built fixtures, never from the
code under test."""
from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST, index_of
from test_gltf_accessors import CUBE
from test_gltf_primitives import _gltf_doc


def _coloured_cube(path: Path, colors: np.ndarray, component_type: int, material: dict | None) -> None:
    """The cube as .gltf with every corner's ``COLOR_0`` = ``colors`` (one row, repeated; stored
    with glTF ``component_type``, normalised where an integer type) and ``material`` on its primitive."""
    doc, buf = _gltf_doc(CUBE)
    data = np.tile(colors, (8, 1)).tobytes()
    doc["bufferViews"].append({"buffer": 0, "byteOffset": len(buf), "byteLength": len(data)})
    accessor = {"bufferView": len(doc["bufferViews"]) - 1, "componentType": component_type, "count": 8,
                "type": "VEC3" if len(colors) == 3 else "VEC4"}
    doc["accessors"].append(accessor | ({"normalized": True} if component_type != 5126 else {}))
    buf += data + b"\0" * (-len(data) % 4)
    prim = doc["meshes"][0]["primitives"][0]
    prim["attributes"]["COLOR_0"] = len(doc["accessors"]) - 1
    if material is not None:
        doc["materials"], prim["material"] = [material], 0
    doc["buffers"] = [{"byteLength": len(buf),
                       "uri": "data:application/octet-stream;base64," + base64.b64encode(buf).decode()}]
    path.write_text(json.dumps(doc))


def test_vertex_colours_of_a_glTF_primitive_with_a_material_are_drawn(tmp_path):
    """glTF 2.0 (3.9.2): a primitive's base colour is ``baseColorFactor`` x texture x ``COLOR_0``.
    The reference is the same red cube without a material, drawn through the loader's plain
    vertex colours: a white material with red ``COLOR_0`` (floats, or normalised bytes with
    alpha) must draw the same pixels, and a blue material with red ``COLOR_0`` must draw black
    (red x blue = 0). Before, trimesh's loader kept the material and the colours were dropped:
    white and blue cubes, exit 0."""
    folder = tmp_path / "m" / "box"
    folder.mkdir(parents=True)
    red, white, blue = np.float32([1, 0, 0]), [1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 1.0, 1.0]
    _coloured_cube(folder / "plain.gltf", red, 5126, None)
    _coloured_cube(folder / "white_float.gltf", red, 5126,
                   {"pbrMetallicRoughness": {"baseColorFactor": white, "metallicFactor": 0}})
    _coloured_cube(folder / "white_bytes.gltf", np.uint8([255, 0, 0, 255]), 5121,
                   {"pbrMetallicRoughness": {"baseColorFactor": white, "metallicFactor": 0}})
    _coloured_cube(folder / "blue_float.gltf", red, 5126,
                   {"pbrMetallicRoughness": {"baseColorFactor": blue, "metallicFactor": 0}})
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == []
    objects = {name[1]: obj for name, obj in objects_by_id(out).items()}
    plain = objects["plain"]
    pixels = plain["images"][plain["masks"] > 0].astype(int)
    assert (pixels[:, 0] > 100).all() and (pixels[:, 1:] < 10).all()  # the reference is red
    for name in ("white_float", "white_bytes"):
        np.testing.assert_array_equal(objects[name]["masks"], plain["masks"])
        np.testing.assert_array_equal(objects[name]["images"], plain["images"], err_msg=name)
    blue_red = objects["blue_float"]
    assert (blue_red["images"][blue_red["masks"] > 0] < 10).all()
