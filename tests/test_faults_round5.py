"""Hostile inputs, round five: one test per defect found by the fifth attack on ``sc3d-data``
(mesh content: D1, a glTF whose texture and buffer URIs are percent-encoded, as Blender writes a
file name with a space). Real renderer and HDF5; every fixture is built here. Expected values come
from the fixtures (the texture's own colour, the same file referenced without encoding), never
from the code under test."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST

RED = (200, 40, 40)


def _textured_box_gltf(folder: Path, name: str, image_uri: str, buffer_uri: str) -> None:
    """``folder/NAME.gltf``: a unit box whose every UV samples the texture ``image_uri``, its
    geometry in the external buffer ``buffer_uri`` (both URIs written into the JSON as given)."""
    import trimesh

    box = trimesh.creation.box((1, 1, 1))
    v, f = box.vertices.astype(np.float32), box.faces.astype(np.uint32)
    uv = np.full((len(v), 2), 0.5, np.float32)
    buf = v.tobytes() + f.tobytes() + uv.tobytes()
    (folder / "geo data.bin").write_bytes(buf)
    offsets = np.cumsum([0, v.nbytes, f.nbytes])
    (folder / f"{name}.gltf").write_text(json.dumps({
        "asset": {"version": "2.0"}, "buffers": [{"uri": buffer_uri, "byteLength": len(buf)}],
        "bufferViews": [{"buffer": 0, "byteOffset": int(o), "byteLength": a.nbytes}
                        for o, a in zip(offsets, (v, f, uv))],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(v), "type": "VEC3",
                       "min": v.min(0).tolist(), "max": v.max(0).tolist()},
                      {"bufferView": 1, "componentType": 5125, "count": f.size, "type": "SCALAR"},
                      {"bufferView": 2, "componentType": 5126, "count": len(v), "type": "VEC2"}],
        "images": [{"uri": image_uri}], "textures": [{"source": 0}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 2}, "indices": 1,
                                    "material": 0}]}],
        "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}], "scene": 0}))


# ----------------------------------------------------------------------------- D1
def test_d1_percent_encoded_gltf_uris_load_the_texture_and_buffer(tmp_path):
    """A glTF naming ``my%20tex.png`` and ``geo%20data.bin`` (glTF URIs are percent-encoded; the
    files are ``my tex.png`` and ``geo data.bin``). Before: the object failed ("texture image 0
    (my%20tex.png) not found"), and with ``--bad-texture fallback`` rendered untextured, grey
    where the texture is red. Now it renders exactly as the same glTF whose URIs are written
    unencoded: the texture's colour in every view."""
    chair = tmp_path / "m" / "chair"
    chair.mkdir(parents=True)
    Image.new("RGB", (16, 16), RED).save(chair / "my tex.png")
    _textured_box_gltf(chair, "encoded", "my%20tex.png", "geo%20data.bin")
    _textured_box_gltf(chair, "plain", "my tex.png", "geo data.bin")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    index = json.loads((out / "index.json").read_text())
    assert index["failures"] == [] and not index.get("warnings")
    objs = objects_by_id(out)
    enc, plain = objs[("03001627", "encoded")], objs[("03001627", "plain")]
    np.testing.assert_array_equal(enc["images"], plain["images"])
    np.testing.assert_array_equal(enc["masks"], plain["masks"])
    pixels = enc["images"][enc["masks"].astype(bool)].astype(float)
    assert (pixels[:, 0] > 2 * pixels[:, 1]).all() and (pixels[:, 0] > 2 * pixels[:, 2]).all()
