"""Draco-compressed glTF (``KHR_draco_mesh_compression``) renders: trimesh decodes it through
``DracoPy``, a dependency (such files were refused while it was not). A bitstream that does not
decode, or decodes to another vertex count than its accessor says, is refused in one line naming
the primitive (the loader alone read zeros and failed "zero surface area", blaming the mesh).

The Draco file of each test is written by trimesh's exporter (``extension_draco=True``, through
DracoPy's encoder) from the same mesh as its uncompressed twin, the reference."""
from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST, index_of
from test_gltf_primitives import _write_glb_document

pytest.importorskip("DracoPy")


def _sphere():
    """An icosphere with vertex colours from its positions (a look that shows any vertex moved)."""
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=2)
    mesh.visual.vertex_colors = np.c_[(mesh.vertices * 127 + 128).astype(np.uint8), np.full(len(mesh.vertices), 255)]
    return mesh


def _write(folder: Path) -> tuple[dict, bytes]:
    """``folder/plain.glb`` and ``folder/draco.glb`` of :func:`_sphere`; the Draco file's
    ``(document, BIN chunk)``."""
    import trimesh

    mesh = _sphere()
    mesh.export(folder / "plain.glb")
    data = trimesh.exchange.gltf.export_glb(trimesh.Scene(mesh), extension_draco=True)
    (folder / "draco.glb").write_bytes(data)
    n = struct.unpack("<I", data[12:16])[0]
    doc = json.loads(data[20:20 + n])
    return doc, data[20 + n + 8:]


def test_a_draco_glb_renders_as_its_uncompressed_twin(tmp_path):
    folder = tmp_path / "m" / "ball"
    folder.mkdir(parents=True)
    doc, _ = _write(folder)
    assert doc["extensionsRequired"] == ["KHR_draco_mesh_compression"]
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--voxelize", *FAST])
    index = index_of(out)
    assert index["failures"] == [] and index["warnings"] == []
    objects = {key[1]: obj for key, obj in objects_by_id(out).items()}
    plain, draco = objects["plain"], objects["draco"]
    np.testing.assert_array_equal(draco["masks"], plain["masks"])
    seen = plain["masks"] > 0
    # Draco stores positions in 14 bits and colours in 8: a step of colour at most, on a few pixels
    difference = np.abs(draco["images"].astype(int) - plain["images"].astype(int))[seen]
    assert difference.max() <= 8 and (difference > 2).mean() < 0.01
    voxels_a, voxels_b = plain["voxels"].astype(bool), draco["voxels"].astype(bool)
    assert (voxels_a & voxels_b).sum() / (voxels_a | voxels_b).sum() > 0.99


def test_draco_data_that_does_not_decode_is_refused_in_one_line(tmp_path):
    folder = tmp_path / "m" / "ball"
    folder.mkdir(parents=True)
    doc, binary = _write(folder)
    prim = doc["meshes"][0]["primitives"][0]
    view = doc["bufferViews"][prim["extensions"]["KHR_draco_mesh_compression"]["bufferView"]]
    start, length = view.get("byteOffset", 0), view["byteLength"]
    broken = bytearray(binary)
    broken[start:start + length] = bytes(length)  # the bitstream zeroed: not Draco
    _write_glb_document(folder / "zeroed.glb", doc, bytes(broken))
    miscounted = json.loads(json.dumps(doc))
    miscounted["accessors"][prim["attributes"]["POSITION"]]["count"] += 1
    _write_glb_document(folder / "miscounted.glb", miscounted, binary)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    reasons = {Path(f["source"]).name: f["reason"] for f in index_of(out)["failures"]}
    count = doc["accessors"][prim["attributes"]["POSITION"]]["count"]
    assert reasons["miscounted.glb"] == (f"{folder / 'miscounted.glb'}: mesh 0 primitive 0's Draco-compressed data "
                                         f"decodes to {count:,} vertices where its POSITION accessor says "
                                         f"{count + 1:,}; not read")
    zeroed = reasons["zeroed.glb"]
    assert zeroed.startswith(f"{folder / 'zeroed.glb'}: mesh 0 primitive 0's Draco-compressed data does not decode (")
    assert zeroed.endswith("); not read") and "\n" not in zeroed and "surface area" not in zeroed
    assert sorted(objects_by_id(out)) == [("ball", "draco"), ("ball", "plain")]


def test_a_skinned_draco_primitive_is_refused_saying_why(tmp_path):
    """Skins are posed from the accessors' data (io/gltf_skins.py); a Draco primitive's POSITION
    accessor has none (its data is in the bitstream), so the skin read zeros. Refused in one line."""
    folder = tmp_path / "m" / "ball"
    folder.mkdir(parents=True)
    doc, binary = _write(folder)
    n = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]["count"]
    binary += b"\0" * (-len(binary) % 4)
    joints, weights = np.zeros((n, 4), np.uint8), np.tile(np.float32([1, 0, 0, 0]), (n, 1))
    for data, ctype in ((joints, 5121), (weights, 5126)):
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": data.nbytes})
        doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "componentType": ctype, "count": n,
                                 "type": "VEC4"})
        binary += data.tobytes()
    doc["buffers"][0]["byteLength"] = len(binary)
    attributes = doc["meshes"][0]["primitives"][0]["attributes"]
    attributes["JOINTS_0"], attributes["WEIGHTS_0"] = len(doc["accessors"]) - 2, len(doc["accessors"]) - 1
    doc["nodes"][0]["skin"] = 0
    doc["nodes"].append({"name": "joint"})
    doc["skins"] = [{"joints": [len(doc["nodes"]) - 1]}]
    doc["scenes"][0]["nodes"].append(len(doc["nodes"]) - 1)
    (folder / "draco.glb").unlink()
    (folder / "plain.glb").unlink()
    _write_glb_document(folder / "skinned.glb", doc, binary)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST], expect_exit=1)
    (failure,) = index_of(out)["failures"]
    assert failure["reason"] == (f"{folder / 'skinned.glb'}: node 0's skin 0 cannot be applied: mesh 0 primitive 0 is "
                                 "Draco-compressed, and skins are applied to accessors' data (decompress the file "
                                 "first, e.g. with gltf-transform copy); not read")
