"""Quantized glTF (``KHR_mesh_quantization``; gltfpack, gltf-transform ``quantize``) is read as
the numbers it means: positions stored as normalized integers and texture coordinates stored as
integers are given to the loader as floats (``sc3d_data.io.gltf_dequantize``). Such files were
refused (the loader read the integers unscaled: a part 32767 times too large, a texture drawn
thousands of times off). A sparse accessor is not converted, and is refused as before.

References are the same files written with float32 attributes whose values are the integers
divided by the type's largest value by hand, as glTF 2.0 defines ``normalized``."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST, index_of
from test_faults_round12_data import _quantized_cube
from test_gltf_primitives import _cube, _gltf_doc, _write_glb_document

#: cube B of the two-part file: x from -1 to -0.5, y and z +-0.5, as normalized shorts
CUBE_B_SHORTS = np.array([[x, y, z] for x in (-32767, -16384) for y in (-16384, 16384) for z in (-16384, 16384)],
                         np.int16)
CUBE_B_FACES = np.uint32([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                          [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]).ravel()


def _two_parts(path: Path, quantized: bool) -> None:
    """A GLB of two cubes as two primitives of one mesh: A (floats, x from 0.5 to 1.5) and B
    (:data:`CUBE_B_SHORTS`), B stored as normalized shorts (``quantized``) or as the floats they
    mean (by hand: / 32767)."""
    v_a, idx_a = _cube()
    b_floats = (CUBE_B_SHORTS / 32767.0).astype(np.float32)
    doc, buf = _gltf_doc([(v_a + np.float32([1, 0, 0]), idx_a, 4), (b_floats, CUBE_B_FACES, 4)])
    if quantized:
        data = np.concatenate([CUBE_B_SHORTS, np.zeros((8, 1), np.int16)], axis=1)  # 4-byte aligned elements
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(buf), "byteLength": data.nbytes, "byteStride": 8})
        buf += data.tobytes()
        position = doc["accessors"][doc["meshes"][0]["primitives"][1]["attributes"]["POSITION"]]
        position.update(bufferView=len(doc["bufferViews"]) - 1, componentType=5122, normalized=True,
                        min=CUBE_B_SHORTS.min(0).tolist(), max=CUBE_B_SHORTS.max(0).tolist())
        doc["extensionsUsed"] = doc["extensionsRequired"] = ["KHR_mesh_quantization"]
    doc["buffers"] = [{"byteLength": len(buf)}]
    _write_glb_document(path, doc, buf)


def _sparse_uv(doc: dict) -> None:
    """Make the cube's TEXCOORD_0 accessor sparse (one corner substituted from the same view)."""
    uv = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"]]
    uv["sparse"] = {"count": 1, "indices": {"bufferView": 0, "componentType": 5125},
                    "values": {"bufferView": uv["bufferView"]}}


def test_quantized_positions_and_texture_coordinates_draw_as_the_floats_they_mean(tmp_path):
    folder = tmp_path / "m" / "box"
    folder.mkdir(parents=True)
    _two_parts(folder / "two_float.glb", quantized=False)
    _two_parts(folder / "two_quantized.glb", quantized=True)
    _quantized_cube(folder / "uv_float.glb", uv="float")
    _quantized_cube(folder / "uv_quantized.glb", uv="normalized")  # 16384, 32768 of 65535: (0.25, 0.5)
    _quantized_cube(folder / "uv_sparse.glb", uv="normalized", edit=_sparse_uv)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--voxelize", *FAST])
    reasons = {Path(f["source"]).name: f["reason"] for f in index_of(out)["failures"]}
    assert reasons == {"uv_sparse.glb": f"{folder / 'uv_sparse.glb'}: accessor 2 (TEXCOORD_0 of mesh 0) is sparse, "
                                        "which the loader does not apply; not read"}
    objects = {key[1]: obj for key, obj in objects_by_id(out).items()}
    for name in ("two", "uv"):
        ref, quantized = objects[f"{name}_float"], objects[f"{name}_quantized"]
        for field in ("images", "masks", "voxels"):
            np.testing.assert_array_equal(quantized[field], ref[field], err_msg=f"{name} {field}")
    # the references themselves: cube B is beside cube A (the two-part masks are wider than tall
    # in the side views), and the texture point is in the red half
    red, green = np.asarray(objects["uv_float"]["images"])[np.asarray(objects["uv_float"]["masks"]) > 0][:, :2].mean(0)
    assert red > 2 * green
    assert objects["two_float"]["voxels"].sum() < 0.75 * 32 ** 3  # two cubes with a gap, not one block


def test_the_loader_itself_reads_the_two_part_file_unscaled(tmp_path):
    """Why the conversion: trimesh alone reads cube B 32767 times too large."""
    import trimesh

    _two_parts(tmp_path / "q.glb", quantized=True)
    bounds = trimesh.load(tmp_path / "q.glb", force="mesh").bounds
    assert bounds[0][0] == -32767 and bounds[1][0] == 1.5


def _gltfpack_style_cube(path: Path, quantized: bool) -> None:
    """The unit cube with a texture of 256 rows of random colours, as gltfpack writes it
    (``quantized``: POSITION as unsigned shorts 0 / 16383 dequantized by its node's scale and
    translation, TEXCOORD_0 as plain unsigned shorts (1024, 2054) dequantized by a
    ``KHR_texture_transform`` scale of 1 / 4095, NORMAL as normalized bytes) or as the floats
    these mean, by hand (corners at +-0.5, every TEXCOORD_0 at (1024 / 4095, 2054 / 4095)). The
    loader alone reads the shorts' v as 1 - 2054 wrapped in 16 bits, which the transform then
    makes 0.0039 off: one row of this texture (rows of 1 / 256)."""
    import base64
    import io

    from PIL import Image

    png = io.BytesIO()
    Image.fromarray(np.random.default_rng(3).integers(0, 256, (256, 2, 3)).astype(np.uint8)).save(png, format="PNG")
    image = "data:image/png;base64," + base64.b64encode(png.getvalue()).decode()
    v, idx = _cube()
    if quantized:
        q = np.rint((v + 0.5) * 16383).astype(np.uint16)
        q = np.concatenate([q, np.zeros((len(v), 1), np.uint16)], axis=1)  # 4-byte aligned elements
        positions, uv = q, np.tile(np.uint16([1024, 2054]), (len(v), 1))
        normals = np.concatenate([np.rint(v / np.linalg.norm(v, axis=1, keepdims=True) * 127).astype(np.int8),
                                  np.zeros((len(v), 1), np.int8)], axis=1)
    else:
        positions, uv, normals = v, np.tile(np.float32([1024 / 4095, 2054 / 4095]), (len(v), 1)), None
    doc, buf = _gltf_doc([(v, idx, 4)])
    prim = doc["meshes"][0]["primitives"][0]

    def add(data: np.ndarray, role: str, kind: str, stride: int | None = None, **extra) -> None:
        nonlocal buf
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(buf), "byteLength": data.nbytes,
                                   **({"byteStride": stride} if stride else {})})
        buf += data.tobytes() + b"\0" * (-data.nbytes % 4)
        ctype = {np.float32: 5126, np.uint16: 5123, np.int8: 5120}[data.dtype.type]
        doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "componentType": ctype,
                                 "count": len(data), "type": kind, **extra})
        prim["attributes"][role] = len(doc["accessors"]) - 1

    texture = {"index": 0}
    if quantized:
        add(positions, "POSITION", "VEC3", 8, min=[0, 0, 0], max=[16383] * 3)
        add(normals, "NORMAL", "VEC3", 4, normalized=True)
        doc["extensionsUsed"] = ["KHR_mesh_quantization", "KHR_texture_transform"]
        doc["extensionsRequired"] = ["KHR_mesh_quantization"]
        doc["nodes"][0].update(scale=[1 / 16383] * 3, translation=[-0.5] * 3)
        texture["extensions"] = {"KHR_texture_transform": {"offset": [0, 0], "scale": [1 / 4095, 1 / 4095]}}
    add(uv, "TEXCOORD_0", "VEC2")
    prim["material"] = 0
    doc.update(materials=[{"name": "packed", "pbrMetallicRoughness": {"baseColorTexture": texture,
                                                                       "metallicFactor": 0}}],
               textures=[{"source": 0}], images=[{"uri": image}], buffers=[{"byteLength": len(buf)}])
    _write_glb_document(path, doc, buf)


def test_a_cube_as_gltfpack_writes_it_draws_as_its_float_twin(tmp_path):
    """gltfpack's layout (the Khronos sample assets' ``glTF-Quantized`` variants, e.g. Avocado):
    positions dequantized by the node transform, texture coordinates by a texture transform."""
    folder = tmp_path / "m" / "box"
    folder.mkdir(parents=True)
    _gltfpack_style_cube(folder / "float.glb", quantized=False)
    _gltfpack_style_cube(folder / "packed.glb", quantized=True)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--voxelize", *FAST])
    assert index_of(out)["failures"] == []
    objects = {key[1]: obj for key, obj in objects_by_id(out).items()}
    for field in ("images", "masks", "voxels"):
        np.testing.assert_array_equal(objects["packed"][field], objects["float"][field], err_msg=field)


def test_the_attributes_of_a_draco_primitive_are_left_to_its_bitstream():
    """A Draco primitive's accessors carry no data (its bitstream does, decoded by the loader):
    one declared as normalized shorts is not converted (it would be read as zeros)."""
    from sc3d_data.io.gltf_dequantize import quantized_accessors

    prim = {"attributes": {"POSITION": 0, "TEXCOORD_0": 1}}
    doc = {"accessors": [{"componentType": 5122, "normalized": True, "count": 8, "type": "VEC3"},
                         {"componentType": 5123, "normalized": True, "count": 8, "type": "VEC2"}],
           "meshes": [{"primitives": [prim]}]}
    assert quantized_accessors(doc) == {0: "POSITION of mesh 0", 1: "TEXCOORD_0 of mesh 0"}
    prim["extensions"] = {"KHR_draco_mesh_compression": {"bufferView": 0, "attributes": {"POSITION": 0}}}
    assert quantized_accessors(doc) == {}
    # malformed documents (the loader reports them) are no error here
    for bad in ({"accessors": {}, "meshes": [{"primitives": [prim]}]}, {"meshes": {}}, {"meshes": [1, {"primitives": 3}]},
                {"meshes": [{"primitives": [{"attributes": 5, "extensions": 7}]}]}):
        assert quantized_accessors(bad) == {}
