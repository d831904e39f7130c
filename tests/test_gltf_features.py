"""glTF features trimesh ignores. Required extensions it cannot decode (Draco without DracoPy,
meshopt) and base colour textures read through ``texCoord`` 1 are refused in one line; a
``KHR_texture_transform`` is applied after loading (its material named in the loader's copy of
the document where it has no name of its own, as gltfpack writes them). Before: a Draco GLB printed two stderr lines naming no file and then
failed as "zero surface area", blaming the mesh; a texture meant for TEXCOORD_1, or moved by a
transform, was drawn from TEXCOORD_0 unmoved (the wrong half of the image), with no warning. Real
files built here (the cube writers of test_gltf_primitives), the real loader, renderer and command."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST, index_of
from test_gltf_accessors import CUBE, _edit_gltf
from test_gltf_primitives import _write_glb, _write_glb_document

NO_DRACOPY = importlib.util.find_spec("DracoPy") is None


def _textured(doc: dict, **texture_info) -> dict:
    """``doc`` with material 0 on its primitive, whose base colour texture is ``{"index": 0,
    **texture_info}`` (texture 0 of image 0, a file that these checks never open)."""
    doc.update(materials=[{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0, **texture_info}}}],
               textures=[{"source": 0}], images=[{"uri": "never-read.png"}])
    doc["meshes"][0]["primitives"][0]["material"] = 0
    return doc


def _refusal(tmp_path: Path, edit) -> str | None:
    from sc3d_data.io.gltf_check import gltf_refusal

    path = tmp_path / "cube.gltf"
    _edit_gltf(path, edit)
    return gltf_refusal(path)


@pytest.mark.parametrize("edit, problem", [
    (lambda d: _textured(d, texCoord=1),  # the cube has TEXCOORD_0 alone
     "material 0's base colour texture reads TEXCOORD_1, which a primitive of mesh 0 has not"),
    (lambda d: _textured(d, extensions={"KHR_texture_transform": {"texCoord": 1}}),
     "material 0's base colour texture reads TEXCOORD_1, which a primitive of mesh 0 has not"),
    (lambda d: (_textured(d, texCoord=1), d["meshes"][0]["primitives"][0].update(extensions={
        "KHR_draco_mesh_compression": {"bufferView": 0, "attributes": {"POSITION": 0, "TEXCOORD_1": 1}}}),
        d["meshes"][0]["primitives"][0]["attributes"].update(TEXCOORD_1=0)),
     "material 0's base colour texture reads TEXCOORD_1 of a Draco-compressed primitive of mesh 0, but the "
     "loader maps every texture with TEXCOORD_0"),
    (lambda d: d.update(extensionsRequired=["EXT_meshopt_compression"]),
     "it requires EXT_meshopt_compression (meshoptimizer compression), which the loader cannot decode"),
], ids=["texCoord-1", "transform-texCoord", "texCoord-1-draco", "meshopt"])
def test_ignored_features_are_named(tmp_path, edit, problem):
    refusal = _refusal(tmp_path, edit)  # the Draco case's empty bitstream is named after it
    assert refusal.startswith(f"{tmp_path / 'cube.gltf'}: {problem}") and refusal.endswith("; not read"), refusal


def _drawn_untextured_copy(doc: dict) -> None:
    """The scene draws, in place of mesh 0, a copy of it without material (a document whose
    scene draws no mesh at all is refused for that: tests/test_faults_round25_data.py)."""
    prim = {k: v for k, v in doc["meshes"][0]["primitives"][0].items() if k != "material"}
    doc["meshes"].append({"primitives": [prim]})
    doc["nodes"].append({"mesh": len(doc["meshes"]) - 1})
    doc["scenes"][0]["nodes"] = [len(doc["nodes"]) - 1]


@pytest.mark.parametrize("edit", [
    lambda d: _textured(d, texCoord=0),
    lambda d: _textured(d, extensions={"KHR_texture_transform": {"offset": [0, 0], "scale": [1, 1], "rotation": 0}}),
    lambda d: (_textured(d, extensions={"KHR_texture_transform": {"offset": [0.5, 0]}}),  # applied after loading
               d["materials"][0].update(name="fabric")),
    lambda d: _textured(d, extensions={"KHR_texture_transform": {"offset": [0.5, 0]}}),  # named for the loader
    lambda d: (_textured(d, extensions={"KHR_texture_transform": {"offset": [0.5, 0]}}),
               d["materials"].append({"name": "same"}), d["materials"][0].update(name="same")),
    lambda d: d.update(extensionsRequired=["KHR_mesh_quantization"]),  # the loader reads quantized data
    lambda d: (_textured(d, texCoord=1), _drawn_untextured_copy(d)),  # the textured mesh is not drawn
], ids=["texCoord-0", "identity-transform", "named-transform", "unnamed-transform", "name-shared-transform",
        "quantization", "not-drawn"])
def test_what_the_loader_reads_as_written_passes(tmp_path, edit):
    assert _refusal(tmp_path, edit) is None


@pytest.mark.skipif(not NO_DRACOPY, reason="DracoPy is installed: trimesh decodes Draco")
def test_a_draco_glb_fails_in_one_line_naming_the_extension_and_a_good_cube_renders(tmp_path, capfd):
    """A GLB whose primitive is Draco-compressed (accessors without bufferView, as Draco files
    have them; the bitstream is 64 zero bytes, never read) beside a good cube."""
    folder = tmp_path / "m" / "box"
    folder.mkdir(parents=True)
    _write_glb(folder / "good.glb", CUBE)
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "extensionsUsed": ["KHR_draco_mesh_compression"], "extensionsRequired": ["KHR_draco_mesh_compression"],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "extensions": {
               "KHR_draco_mesh_compression": {"bufferView": 0, "attributes": {"POSITION": 0}}}}]}],
           "accessors": [{"componentType": 5126, "count": 8, "type": "VEC3", "min": [-.5] * 3, "max": [.5] * 3},
                         {"componentType": 5125, "count": 36, "type": "SCALAR"}],
           "bufferViews": [{"buffer": 0, "byteLength": 64}], "buffers": [{"byteLength": 64}]}
    _write_glb_document(folder / "draco.glb", doc, bytes(64))
    out = tmp_path / "out"
    result = run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    (failure,) = index_of(out)["failures"]
    assert failure["reason"] == (f"{folder / 'draco.glb'}: it requires KHR_draco_mesh_compression (Draco mesh "
                                 "compression), which the loader cannot decode; not read")
    captured = capfd.readouterr()
    for text in (result.output, captured.out, captured.err):
        assert "DracoPy" not in text and "placeholder" not in text and "zero surface area" not in text, text
    assert list(objects_by_id(out)) == [("box", "good")]


# ----------------------------------------------------------------------------- KHR_texture_transform applied
def test_the_transform_matrix_is_the_extensions():
    """Offset (0.5, 0), scale (2, 1), rotation 90 degrees on the texture point (0.25, 0.25), by
    hand in the extension's order (scale, then rotate by [[cos, sin], [-sin, cos]], then offset):
    (0.5, 0.25) -> (0.25, -0.5) -> (0.75, -0.5)."""
    import numpy as np

    from sc3d_data.io.gltf_features import transform_matrix

    m = transform_matrix({"offset": [0.5, 0], "scale": [2, 1], "rotation": np.pi / 2})
    np.testing.assert_allclose(m @ [0.25, 0.25, 1], [0.75, -0.5, 1], atol=1e-12)


def _half_red_half_green_cube(path: Path, material: dict, u0: float = 0.25, u1: float | None = None) -> None:
    """The cube as .gltf, every corner's TEXCOORD_0 at (``u0``, 0.5) (by default the middle of
    the left half) of an 8 x 16 texture whose left half is red and right half green (a data URI
    PNG); with ``u1``, a TEXCOORD_1 at (``u1``, 0.5)."""
    import base64
    import io

    import numpy as np
    from PIL import Image

    from test_gltf_primitives import _gltf_doc

    doc, buf = _gltf_doc(CUBE)
    for k, u in enumerate((u0, u1)):
        if u is None:
            continue
        uv = np.tile(np.float32([u, 0.5]), (8, 1)).tobytes()
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(buf), "byteLength": len(uv)})
        doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "componentType": 5126, "count": 8,
                                 "type": "VEC2"})
        buf += uv
        doc["meshes"][0]["primitives"][0]["attributes"][f"TEXCOORD_{k}"] = len(doc["accessors"]) - 1
    doc["meshes"][0]["primitives"][0]["material"] = 0
    texture = np.zeros((8, 16, 3), np.uint8)
    texture[:, :8], texture[:, 8:] = (255, 0, 0), (0, 255, 0)
    png = io.BytesIO()
    Image.fromarray(texture).save(png, format="PNG")
    doc.update(buffers=[{"byteLength": len(buf), "uri": "data:application/octet-stream;base64,"
                         + base64.b64encode(buf).decode()}],
               images=[{"uri": "data:image/png;base64," + base64.b64encode(png.getvalue()).decode()}],
               textures=[{"source": 0}], materials=[material])
    path.write_text(json.dumps(doc))


def _cube_colours(out: Path) -> dict[str, str]:
    """``{model id: "red", "green" or "mixed"}``: the colour of every rendered pixel of each object."""
    colour = {}
    for name, obj in objects_by_id(out).items():
        pixels = obj["images"][obj["masks"] > 0].astype(int)
        colour[name[1]] = "red" if (pixels[:, 0] > pixels[:, 1] + 50).all() else \
            "green" if (pixels[:, 1] > pixels[:, 0] + 50).all() else "mixed"
    return colour


def test_a_texture_transform_moves_the_texture_as_the_file_says(tmp_path):
    """The same cube: without a transform it is red (its texture point is in the red half); with
    the offset (0.5, 0) it is green (before: red, the transform ignored), whether its material has
    a name of its own, none (as gltfpack writes them; before: refused), or one another material
    has too (before: refused). The other material of that name, drawn by a second cube without a
    transform, stays red (a transform applied by a shared name would move it as well)."""
    folder = tmp_path / "m" / "box"
    folder.mkdir(parents=True)
    texture = {"index": 0}
    moved = {"baseColorTexture": {**texture, "extensions": {"KHR_texture_transform": {"offset": [0.5, 0]}}},
             "metallicFactor": 0}
    _half_red_half_green_cube(folder / "plain.gltf", {"name": "plain", "pbrMetallicRoughness": {
        "baseColorTexture": texture, "metallicFactor": 0}})
    _half_red_half_green_cube(folder / "moved.gltf", {"name": "moved", "pbrMetallicRoughness": moved})
    _half_red_half_green_cube(folder / "unnamed.gltf", {"pbrMetallicRoughness": moved})
    for name, drawn in (("shared_moved", 0), ("shared_plain", 1)):
        def shared(doc, drawn=drawn):
            doc["materials"] = [{"name": "same", "pbrMetallicRoughness": moved},
                                {"name": "same", "pbrMetallicRoughness": {"baseColorTexture": texture,
                                                                          "metallicFactor": 0}}]
            doc["meshes"].append({"primitives": [{**doc["meshes"][0]["primitives"][0], "material": 1}]})
            doc["nodes"].append({"mesh": 1})
            doc["scenes"][0]["nodes"] = [drawn]  # node 0 draws the moved material, node 1 the other
        _half_red_half_green_cube(folder / f"{name}.gltf", {})
        doc = json.loads((folder / f"{name}.gltf").read_text())
        shared(doc)
        (folder / f"{name}.gltf").write_text(json.dumps(doc))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == []
    assert _cube_colours(out) == {"plain": "red", "moved": "green", "unnamed": "green", "shared_moved": "green",
                      "shared_plain": "red"}


def test_a_texture_read_through_texcoord_1_is_drawn_with_that_set(tmp_path):
    """A base colour texture reading TEXCOORD_1 (its ``texCoord``, or its transform's, which
    overrides it: Khronos' KhrTextureTransformWithFallback) was refused; the loader maps every
    texture with TEXCOORD_0. Each cube is green only where the set the file names is read, moved
    as its transform says: TEXCOORD_0 lies in the red half, and so does TEXCOORD_1 before the
    transform's scale (2, 1) moves it (any other reading is red)."""
    folder = tmp_path / "m" / "box"
    folder.mkdir(parents=True)
    texture = {"index": 0}
    _half_red_half_green_cube(folder / "set1.gltf", {"pbrMetallicRoughness": {
        "baseColorTexture": {**texture, "texCoord": 1}, "metallicFactor": 0}}, u0=0.125, u1=0.75)
    _half_red_half_green_cube(folder / "set1_by_transform.gltf", {"pbrMetallicRoughness": {
        "baseColorTexture": {**texture, "extensions": {"KHR_texture_transform": {"texCoord": 1, "scale": [2, 1]}}},
        "metallicFactor": 0}}, u0=0.125, u1=0.375)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == [] and index_of(out)["warnings"] == []
    assert _cube_colours(out) == {"set1": "green", "set1_by_transform": "green"}


def test_a_sparse_set_read_as_texcoord_0_is_named_by_its_own_name(tmp_path):
    """A texture read through TEXCOORD_1 is given to the loader as TEXCOORD_0; a sparse TEXCOORD_1,
    which the loader would not apply, was refused as "(TEXCOORD_0 of mesh 0) is sparse": the line
    must name the set the file names."""
    def sparse_set1(doc):
        _textured(doc, texCoord=1)
        doc["accessors"].append({"componentType": 5126, "count": 8, "type": "VEC2", "sparse": {
            "count": 1, "indices": {"bufferView": 0, "componentType": 5125}, "values": {"bufferView": 0}}})
        doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_1"] = len(doc["accessors"]) - 1

    refusal = _refusal(tmp_path, sparse_set1)
    a = json.loads((tmp_path / "cube.gltf").read_text())["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_1"]
    assert refusal == (f"{tmp_path / 'cube.gltf'}: accessor {a} (TEXCOORD_1 of mesh 0) is sparse, which the loader "
                       "does not apply; not read"), refusal
