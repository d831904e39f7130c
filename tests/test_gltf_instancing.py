"""A glTF node that draws its mesh through ``EXT_mesh_gpu_instancing`` (Blender's "GPU
Instances", gltfpack ``-mi``) is drawn once per instance, at the node's transform times the
instance's translation x rotation x scale (such files were refused: the loader draws the mesh
once). References: the same instances written by hand as plain child nodes with those TRS."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST, index_of
from test_gltf_accessors import CUBE
from test_gltf_primitives import _gltf_doc

TRANSLATIONS = np.float32([[0, 0, 0], [2, 0, 0], [0, 0, -3]])
#: quarter turns about y and z, as glTF quaternions (x, y, z, w)
ROTATIONS = np.float32([[0, 0, 0, 1], [0, np.sqrt(0.5), 0, np.sqrt(0.5)], [0, 0, np.sqrt(0.5), np.sqrt(0.5)]])
SCALES = np.float32([[1, 1, 1], [1, 2, 1], [0.5, 0.5, 3]])


def _document(instanced: bool, rotations_as_shorts: bool = False, edit=None) -> tuple[dict, bytes]:
    """The cube drawn by node 0 (moved by (0, 1, 0) itself) three times: through instancing, or
    (``instanced`` False) by three child nodes with the same translation, rotation and scale."""
    doc, buf = _gltf_doc(CUBE)
    doc["nodes"][0]["translation"] = [0, 1, 0]
    if not instanced:
        del doc["nodes"][0]["mesh"]
        doc["nodes"][0]["children"] = [1, 2, 3]
        doc["nodes"] += [{"mesh": 0, "translation": t.tolist(), "rotation": r.tolist(), "scale": s.tolist()}
                         for t, r, s in zip(TRANSLATIONS, ROTATIONS, SCALES)]
        return doc, buf
    rotations = np.rint(ROTATIONS * 32767).astype(np.int16) if rotations_as_shorts else ROTATIONS
    attributes = {}
    for role, data in (("TRANSLATION", TRANSLATIONS), ("ROTATION", rotations), ("SCALE", SCALES)):
        buf += b"\0" * (-len(buf) % 4)
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(buf), "byteLength": data.nbytes})
        doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "count": len(data),
                                 "componentType": 5122 if data.dtype == np.int16 else 5126,
                                 "type": "VEC4" if role == "ROTATION" else "VEC3",
                                 **({"normalized": True} if data.dtype == np.int16 else {})})
        attributes[role] = len(doc["accessors"]) - 1
        buf += data.tobytes()
    doc["nodes"][0]["extensions"] = {"EXT_mesh_gpu_instancing": {"attributes": attributes}}
    doc["extensionsUsed"] = ["EXT_mesh_gpu_instancing"] + ["KHR_mesh_quantization"] * rotations_as_shorts
    if edit is not None:
        edit(doc)
    return doc, buf


def _write(path: Path, doc: dict, buf: bytes) -> None:
    import base64

    doc["buffers"] = [{"byteLength": len(buf), "uri": "data:application/octet-stream;base64,"
                       + base64.b64encode(buf).decode()}]
    path.write_text(json.dumps(doc))


def test_instances_are_drawn_as_the_plain_nodes_they_stand_for(tmp_path):
    folder = tmp_path / "m" / "c"
    folder.mkdir(parents=True)
    _write(folder / "plain.gltf", *_document(instanced=False))
    _write(folder / "instanced.gltf", *_document(instanced=True))
    _write(folder / "instanced_shorts.gltf", *_document(instanced=True, rotations_as_shorts=True))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--voxelize", *FAST])
    assert index_of(out)["failures"] == [] and index_of(out)["warnings"] == []
    objects = {key[1]: obj for key, obj in objects_by_id(out).items()}
    for name in ("instanced", "instanced_shorts"):
        for field in ("masks", "voxels", "images"):
            if name == "instanced_shorts" and field == "images":
                continue  # sqrt(0.5) in 16 bits turns the faces by ~1e-5 rad: their shading may differ by a step
            np.testing.assert_array_equal(objects[name][field], objects["plain"][field], err_msg=f"{name} {field}")
    assert objects["plain"]["voxels"].sum() < 0.5 * 32 ** 3  # three cubes apart, not one block


def test_instances_that_cannot_be_read_are_refused_naming_the_node(tmp_path):
    def fewer_scales(doc):
        doc["accessors"][-1]["count"] = 2

    def skinned(doc):
        doc["nodes"][0]["skin"] = 0
        doc["nodes"].append({})
        doc["skins"] = [{"joints": [1]}]

    folder = tmp_path / "m" / "c"
    folder.mkdir(parents=True)
    _write(folder / "fewer.gltf", *_document(instanced=True, edit=fewer_scales))
    _write(folder / "skinned.gltf", *_document(instanced=True, edit=skinned))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST], expect_exit=1)
    reasons = {Path(f["source"]).stem: f["reason"].split(": ", 1)[1] for f in index_of(out)["failures"]}
    assert reasons["fewer"] == ("node 0's EXT_mesh_gpu_instancing cannot be applied: its attributes hold different "
                                "numbers of instances (2, 3); not read")
    assert ("node 0's EXT_mesh_gpu_instancing cannot be applied: it is also skinned, which EXT_mesh_gpu_instancing "
            "does not define") in reasons["skinned"]


def test_a_glb_binary_chunk_is_read_once_by_the_judges_and_the_loader(tmp_path, monkeypatch):
    """A GLB drawing instances (with quantized rotations) is judged by a judge that reads its data
    (instancing; those of skins, quantized and Draco attributes read it too), its embedded images
    are looked for, and its document is copied for the loader: each read the ``BIN`` chunk again
    (three reads of one file). It must be read once (a spy
    counts ``read_gltf(binary=True)`` in every module that reads it), and the GLB must still load the
    triangles of its ``.gltf`` twin (three cubes: 36)."""
    import sc3d_data.io.gltf_check as gltf_check
    import sc3d_data.io.gltf_loader_doc as gltf_loader_doc
    import sc3d_data.io.materials as materials
    from sc3d_data.io.meshes import load_mesh
    from test_gltf_primitives import _write_glb_document

    doc, buf = _document(instanced=True, rotations_as_shorts=True)
    buf += b"\0" * (-len(buf) % 4)
    doc["buffers"] = [{"byteLength": len(buf)}]
    _write_glb_document(tmp_path / "instanced.glb", doc, buf)
    _write(tmp_path / "twin.gltf", *_document(instanced=True, rotations_as_shorts=True))
    reads, real = [], gltf_check.read_gltf

    def counted(path, binary=False):
        reads.append(binary)
        return real(path, binary)

    for module in (gltf_check, gltf_loader_doc, materials):
        monkeypatch.setattr(module, "read_gltf", counted, raising=False)
    glb_faces = load_mesh(tmp_path / "instanced.glb")[2]
    assert reads.count(True) == 1, reads
    assert len(glb_faces) == len(load_mesh(tmp_path / "twin.gltf")[2]) == 36
