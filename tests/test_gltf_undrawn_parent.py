"""A glTF node whose other parent lies outside the drawn scene (found rendering bevy's
``assets/models``: Kenney's ``craft_speederD.gltf``, ``cakeBirthday.glb``, ``tile.glb``, written by
UniGLTF with a ``tmpParent`` node that no scene lists). sc3d refused them as "a root of the scene
and a child of node 0, where glTF allows one parent", though node 0 is never drawn, so every reader
(trimesh, three.js, Blender) draws the child once, as sc3d does. Only drawn parents count now."""
from __future__ import annotations

import json

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import FAST, index_of
from test_faults_round19_data import _objects
from test_gltf_accessors import CUBE
from test_gltf_primitives import _gltf_doc


def _write(meshes, name: str, doc: dict) -> None:
    """``meshes/name.gltf`` holding ``doc``."""
    (meshes / f"{name}.gltf").write_text(json.dumps(doc))


def test_a_parent_outside_the_scene_does_not_refuse_its_child(tmp_path):
    """``tmp_parent``: scene ``[1]``, undrawn node 0 lists node 1 as its child; ``undrawn_second``:
    a drawn child of node 0 that undrawn node 2 also lists. Both render as their references, a
    plain one-node scene and a plain parent and child; two drawn parents are still refused."""
    doc, buf = _gltf_doc(CUBE)
    doc["buffers"] = [{"byteLength": len(buf), "uri": "cube.bin"}]
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    (meshes / "cube.bin").write_bytes(buf)
    _write(meshes, "tmp_parent", {**doc, "nodes": [{"children": [1]}, {"mesh": 0}], "scenes": [{"nodes": [1]}]})
    _write(meshes, "plain", {**doc, "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]})
    _write(meshes, "undrawn_second", {**doc, "nodes": [{"children": [1]}, {"mesh": 0}, {"children": [1]}],
                                      "scenes": [{"nodes": [0]}]})
    _write(meshes, "two_drawn", {**doc, "nodes": [{"children": [1]}, {"mesh": 0}, {"children": [1]}],
                                 "scenes": [{"nodes": [0, 2]}]})
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--voxelize", *FAST])
    assert [f["reason"].split(": ", 1)[1] for f in index_of(out)["failures"]] == [
        "node 1 is a child of nodes 0, 2, where glTF allows one parent; the loader would draw it once; not read"]
    objects = _objects(out)
    assert sorted(objects) == ["plain", "tmp_parent", "undrawn_second"]
    for name in ("tmp_parent", "undrawn_second"):
        for field in ("images", "masks", "voxels"):
            np.testing.assert_array_equal(objects[name][field], objects["plain"][field], err_msg=f"{name} {field}")
