"""Defects of the data half found by the twelfth attack on the commands (2026-11-28), each test
failing without its fix: glTF attributes stored as (normalized) integers, which trimesh reads
unscaled; triangles of no area (a part hidden by a node of scale 0, a collapsed triangle) that set
the normalisation and left a stray voxel; a symlinked flat ``--meshes`` folder named by its
target; an 8-digit model folder turned as a ShapeNet model; an object rendered with a missing
material or texture file never rendered again once the file is there. Real files, the real loader,
renderer and commands."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST, index_of
from test_gltf_primitives import _cube, _gltf_doc, _write_glb_document


# ----------------------------------------------------------------------------- quantized glTF
def _red_green_png() -> str:
    """A data URI of an 8 x 16 PNG whose left half is red and right half green."""
    import base64
    import io

    from PIL import Image

    texture = np.zeros((8, 16, 3), np.uint8)
    texture[:, :8], texture[:, 8:] = (255, 0, 0), (0, 255, 0)
    png = io.BytesIO()
    Image.fromarray(texture).save(png, format="PNG")
    return "data:image/png;base64," + base64.b64encode(png.getvalue()).decode()


def _quantized_cube(path: Path, positions: str = "float", uv: str | None = None, edit=None) -> None:
    """The unit cube (corners at +-0.5) as GLB ``path``: POSITION as float32 (``"float"``),
    normalized shorts (``"normalized"``: +-16384 / 32767) or plain shorts (``"short"``: +-1, so
    the cube spans [-1, 1]); with ``uv`` a TEXCOORD_0 at (0.25, 0.5) for every corner, as float32
    (``"float"``) or normalized unsigned shorts (``"normalized"``: 16384, 32768 of 65535), mapping a red and green texture
    (:func:`_red_green_png`: the point is in the red half)."""
    v, idx = _cube()
    doc, buf = _gltf_doc([(v, idx, 4)])
    position = doc["accessors"][0]
    if positions != "float":
        data = (np.sign(v) * (16384 if positions == "normalized" else 1)).astype(np.int16)
        data = np.concatenate([data, np.zeros((len(v), 1), np.int16)], axis=1)  # 4-byte aligned elements
        view = {"buffer": 0, "byteOffset": len(buf), "byteLength": data.nbytes, "byteStride": 8}
        buf += data.tobytes()
        doc["bufferViews"].append(view)
        position.update(bufferView=len(doc["bufferViews"]) - 1, componentType=5122,
                        min=data[:, :3].min(0).tolist(), max=data[:, :3].max(0).tolist())
        if positions == "normalized":
            position["normalized"] = True
        doc["extensionsUsed"] = doc["extensionsRequired"] = ["KHR_mesh_quantization"]
    if uv is not None:
        data = np.tile(np.float32([0.25, 0.5]) if uv == "float" else np.uint16([16384, 32768]), (len(v), 1))
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(buf), "byteLength": data.nbytes})
        buf += data.tobytes()
        doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "count": len(v), "type": "VEC2",
                                 "componentType": 5126 if uv == "float" else 5123,
                                 **({"normalized": True} if uv == "normalized" else {})})
        doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = len(doc["accessors"]) - 1
        doc["meshes"][0]["primitives"][0]["material"] = 0
        doc.update(materials=[{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
                   textures=[{"source": 0}], images=[{"uri": _red_green_png()}])
    doc["buffers"] = [{"byteLength": len(buf)}]
    if edit is not None:
        edit(doc)
    _write_glb_document(path, doc, buf)


def test_trimesh_reads_quantized_attributes_unscaled(tmp_path):
    """Why quantized attributes are converted (tests/test_gltf_dequantize.py; they were refused):
    the loader itself reads a normalized-short cube 32767 times too large and normalized texture
    coordinates as raw integers; plain shorts it reads right."""
    import trimesh

    for positions, half in (("normalized", 16384), ("short", 1)):
        _quantized_cube(tmp_path / f"{positions}.glb", positions)
        mesh = trimesh.load(tmp_path / f"{positions}.glb", force="mesh")
        np.testing.assert_array_equal(mesh.bounds, [[-half] * 3, [half] * 3])
    _quantized_cube(tmp_path / "uv.glb", uv="normalized")
    uv = trimesh.load(tmp_path / "uv.glb", force="mesh").visual.uv
    assert uv[:, 0].max() > 1  # 16384, not 0.25


def test_integer_texture_coordinates_the_loader_does_not_use_pass(tmp_path):
    """Normalized-short texture coordinates as TEXCOORD_1 (a lightmap set: the loader reads only
    TEXCOORD_0), or as TEXCOORD_0 of a material without a texture (nothing is placed with them),
    change nothing the loader draws: not refused. Before this rule was narrowed, both were."""
    from sc3d_data.io.gltf_check import gltf_refusal

    def second_set(doc):
        attributes = doc["meshes"][0]["primitives"][0]["attributes"]
        attributes["TEXCOORD_1"] = attributes.pop("TEXCOORD_0")

    def untextured(doc):
        doc["materials"] = [{"pbrMetallicRoughness": {"baseColorFactor": [0, 0, 1, 1]}}]
        doc.pop("textures"), doc.pop("images")

    for name, edit in (("second.glb", second_set), ("untextured.glb", untextured)):
        _quantized_cube(tmp_path / name, uv="normalized", edit=edit)
        assert gltf_refusal(tmp_path / name) is None, name


# ----------------------------------------------------------------------------- triangles of no area
SAMPLE = Path(__file__).resolve().parents[1] / "assets" / "sample_meshes"


def _dataset_arrays(out: Path) -> dict:
    """``{model_id: {"masks", "voxels", "to_canonical": array}}`` of the one-category dataset
    ``out`` (not the images: their shading may differ by the normals the loader computes)."""
    return {mid: {k: np.asarray(v) for k, v in o.items() if k in ("masks", "voxels", "to_canonical")}
            for (_, mid), o in objects_by_id(out).items()}


def test_triangles_of_no_area_neither_move_the_normalisation_nor_leave_voxels(tmp_path):
    """A bundled chair as GLB with a part hidden by a node of scale 0 far off the chair (how
    exporters hide parts), and as PLY with two collapsed triangles, one far off the chair and one
    inside its bounding box away from its surface: each is normalised, masked and voxelized
    exactly as the same chair without them. Before: the hidden point set the bounding box (the chair shrank into
    a corner of the frame) and left a voxel that no view's mask holds."""
    import trimesh

    chair = trimesh.load(SAMPLE / "chair" / "chair2_blendswap.glb", force="scene")
    lo, hi = chair.bounds
    plain, hidden = tmp_path / "plain" / "chair", tmp_path / "hidden" / "chair"
    for folder in (plain, hidden):
        folder.mkdir(parents=True)
    chair.export(plain / "a.glb")
    mesh = chair.to_mesh()  # every part, node transforms baked in
    mesh.export(plain / "b.ply")
    far = hi + 2 * (hi - lo)
    box = trimesh.creation.box((1, 1, 1))
    with_hidden = chair.copy()
    with_hidden.add_geometry(box, node_name="hidden", transform=trimesh.transformations.translation_matrix(far)
                             @ np.diag([0.0, 0.0, 0.0, 1.0]))
    with_hidden.export(hidden / "a.glb")
    inside = lo + np.array([0.5, 0.95, 0.05]) * (hi - lo)  # high above the seat, at the back: empty space
    n = len(mesh.vertices)
    collapsed = trimesh.Trimesh(np.concatenate([mesh.vertices, [far] * 3, [inside] * 3]),
                                np.concatenate([mesh.faces, [[n, n + 1, n + 2], [n + 3, n + 4, n + 5]]]),
                                process=False)
    collapsed.export(hidden / "b.ply")
    for name in ("plain", "hidden"):
        run_cli(data_main, ["render", "--meshes", tmp_path / name, "--out", tmp_path / f"{name}-out", "--voxelize",
                            *FAST])
        assert not index_of(tmp_path / f"{name}-out")["failures"]
    want, got = _dataset_arrays(tmp_path / "plain-out"), _dataset_arrays(tmp_path / "hidden-out")
    assert sorted(got) == ["a", "b"]
    for mid in got:
        for key in want[mid]:
            np.testing.assert_array_equal(got[mid][key], want[mid][key], err_msg=f"{mid} {key}")


def test_the_area_kernel_finds_exactly_the_triangles_of_no_area():
    """By hand: a right triangle (area 1/2), a sliver with its corners on one line, a triangle
    whose three corners are one point, and one whose two corners name the same vertex."""
    from sc3d_data.geometry.triangle_area import triangles_with_area

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 2, 2], [3, 3, 3], [5, 5, 5]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [3, 4, 5], [5, 5, 5], [0, 1, 1]], dtype=np.int64)
    assert triangles_with_area(v, faces).tolist() == [True, False, False, False]


# ----------------------------------------------------------------------------- names of folders
def test_a_symlinked_flat_folder_is_named_as_given_not_by_its_target(tmp_path):
    """``--meshes a/chair``, where ``a/chair`` is a link to ``store/export_v3``: the meshes are
    chairs (synset 03001627), as when the same link is a category folder under ``--meshes a``.
    Before: category ``export_v3``, the link target's name."""
    store = tmp_path / "store" / "export_v3"
    store.mkdir(parents=True)
    (store / "box.glb").write_bytes((SAMPLE / "chair" / "chair2_blendswap.glb").read_bytes())
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "chair").symlink_to(store, target_is_directory=True)
    for meshes, out in ((tmp_path / "a" / "chair", tmp_path / "flat"), (tmp_path / "a", tmp_path / "tree")):
        run_cli(data_main, ["render", "--meshes", meshes, "--out", out, *FAST])
        assert list(objects_by_id(out)) == [("03001627", "box")], meshes


def test_an_eight_digit_model_folder_is_neither_a_shapenet_model_nor_turned_as_one(tmp_path):
    """``SYNSET/12345678/model.obj`` is read as a plain mesh (model id ``12345678/model``, as
    before) and so keeps sc3d's front (+Z: no turn), while ``SYNSET/abcdef01/model.obj`` is a
    ShapeNet v1 model turned from its +X front. Before: the 8-digit one was turned as well."""
    import trimesh

    for model in ("12345678", "abcdef01"):
        (tmp_path / "m" / "02691156" / model).mkdir(parents=True)
        trimesh.creation.box((2, 1, 0.5)).export(tmp_path / "m" / "02691156" / model / "model.obj")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    objects = objects_by_id(out)
    assert sorted(objects) == [("02691156", "12345678/model"), ("02691156", "abcdef01")]
    plain = np.asarray(objects[("02691156", "12345678/model")]["to_canonical"])
    np.testing.assert_allclose(plain[:3, :3], 0.5 * np.eye(3), atol=1e-12)  # longest side 2 -> 1, no turn
    turned = np.asarray(objects[("02691156", "abcdef01")]["to_canonical"])
    np.testing.assert_allclose(turned[:3, :3] @ [1, 0, 0], [0, 0, 0.5], atol=1e-12)  # +X front -> +Z


# ----------------------------------------------------------------------------- companion files on a rerun
def _textured_quad(folder: Path, colour: tuple[int, int, int]) -> None:
    """``folder/t/a.obj``: a unit quad mapping the whole of ``folder/t/tex.png`` (4 x 4 pixels of
    ``colour``) through material file ``a.mtl``, which is not written here."""
    from PIL import Image

    (folder / "t").mkdir(parents=True, exist_ok=True)
    Image.new("RGB", (4, 4), colour).save(folder / "t" / "tex.png")
    (folder / "t" / "a.obj").write_text("mtllib a.mtl\nv -.5 -.5 0\nv .5 -.5 0\nv .5 .5 0\nv -.5 .5 0\n"
                                        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl m\nf 1/1 2/2 3/3 4/4\n")


def _object_colour(out: Path) -> np.ndarray:
    (obj,) = objects_by_id(out).values()
    return np.asarray(obj["images"])[np.asarray(obj["masks"]) > 0].mean(0)


def test_a_rerun_renders_again_an_object_whose_material_file_appeared_or_texture_changed(tmp_path):
    """An OBJ whose ``a.mtl`` is missing renders grey with a warning; the user puts ``a.mtl`` in
    place and reruns the same command: the object is rendered again with its red texture and the
    warning is gone. Then the texture is replaced by a green one: rendered again, green. A rerun
    with nothing changed renders nothing again. Before: the rerun resumed, the object stayed grey
    and ``info`` still printed the old warning; a replaced texture was never noticed."""
    meshes, out = tmp_path / "m", tmp_path / "out"
    _textured_quad(meshes, (255, 0, 0))
    render = ["render", "--meshes", meshes, "--out", out, *FAST]
    run_cli(data_main, render)
    (warning,) = index_of(out)["warnings"]
    assert "a.mtl not found" in warning["warning"]
    grey = _object_colour(out)
    assert abs(grey[0] - grey[1]) < 10
    (meshes / "t" / "a.mtl").write_text("newmtl m\nKd 1 1 1\nmap_Kd tex.png\n")
    result = run_cli(data_main, render)
    assert "a.mtl was missing and is there now" in result.output
    assert index_of(out)["warnings"] == []
    red = _object_colour(out)
    assert red[0] > 100 > 30 > red[1]
    _textured_quad(meshes, (0, 255, 0))  # the texture replaced (the OBJ rewritten the same)
    result = run_cli(data_main, render)
    assert "tex.png: " in result.output
    green = _object_colour(out)
    assert green[1] > 100 > 30 > green[0]
    result = run_cli(data_main, render)
    assert "rendering its chunk again" not in result.output


def test_statement_values_reads_the_obj_statements_a_line_regex_reads():
    """``statement_values`` (found with str.find, then matched per line) against the multi-line
    regex it replaced, by hand: CRLF endings, leading blanks, a comment, a keyword inside another
    word or at the end of the text, a statement without a value, a name with spaces."""
    import re

    from sc3d_data.io.obj_statements import statement_values

    text = ("# mtllib not.mtl\r\nmtllib a.mtl\r\n  mtllib  b c.mtl  \nusemtl mtllib\nxmtllib d.mtl\nmtllib\n"
            "v 0 0 0\nmtllib e.mtl")
    assert statement_values(text, "mtllib") == ["a.mtl", "b c.mtl", "e.mtl"]
    assert re.findall(r"^[ \t]*mtllib[ \t]+(.+?)\s*$", text, flags=re.M) == ["a.mtl", "b c.mtl", "e.mtl"]


def test_a_rerun_never_opens_a_companion_file_an_edited_index_names_outside_the_dataset(tmp_path):
    """An index edited to record ``../../outside.txt`` (a file beside the dataset folder) as a
    companion file of its object: the rerun neither reads it nor renders again when it changes.
    Without the check, the rerun hashed a file outside --meshes and rendered the chunk again."""
    from sc3d_data.io.source_fingerprint import fingerprint

    meshes, out = tmp_path / "m", tmp_path / "out"
    _textured_quad(meshes, (255, 0, 0))
    (meshes / "t" / "a.mtl").write_text("newmtl m\nKd 1 1 1\nmap_Kd tex.png\n")
    outside = tmp_path / "outside.txt"
    outside.write_text("before")
    render = ["render", "--meshes", meshes, "--out", out, *FAST]
    run_cli(data_main, render)
    index = index_of(out)
    index["objects"][0]["source_file"]["materials"]["../../outside.txt"] = fingerprint(outside)
    (out / "index.json").write_text(json.dumps(index))
    outside.write_text("after, longer")
    result = run_cli(data_main, render)
    assert "rendering its chunk again" not in result.output and "resumed 1" in result.output


def test_a_rerun_renders_again_a_gltf_whose_buffer_file_changed(tmp_path):
    """A .gltf whose geometry lies in ``cube.bin`` beside it: the buffer rewritten (the cube
    stretched 3 times along y) renders the chunk again. Before: only images were fingerprinted,
    and the rerun kept the old views and voxels."""
    from test_gltf_primitives import _gltf_doc

    folder = tmp_path / "m" / "box"
    folder.mkdir(parents=True)
    v, idx = _cube()

    doc, buf = _gltf_doc([(v, idx, 4)])
    doc["buffers"] = [{"byteLength": len(buf), "uri": "cube.bin"}]
    (folder / "cube.bin").write_bytes(buf)
    (folder / "cube.gltf").write_text(json.dumps(doc))
    render = ["render", "--meshes", tmp_path / "m", "--out", tmp_path / "out", *FAST]
    run_cli(data_main, render)
    assert list(index_of(tmp_path / "out")["objects"][0]["source_file"]["materials"]) == ["cube.bin"]
    (folder / "cube.bin").write_bytes(_gltf_doc([(v * np.float32([1, 3, 1]), idx, 4)])[1])  # the .gltf unchanged
    result = run_cli(data_main, render)
    assert "cube.bin: same size, other content" in result.output and "rendering its chunk again" in result.output


def test_a_companion_file_replaced_by_a_fifo_is_a_change_never_opened(tmp_path):
    """``source_change`` of a FIFO where a file was recorded: a change, said without opening it
    (hashing it would wait for a writer forever)."""
    import os

    from sc3d_data.io.source_fingerprint import fingerprint, source_change

    file = tmp_path / "a.mtl"
    file.write_text("")
    recorded = fingerprint(file)
    file.unlink()
    os.mkfifo(file)
    assert source_change(file, recorded) == "no longer a regular file"
