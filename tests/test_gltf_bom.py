"""A glTF/GLB whose JSON starts with a UTF-8 byte order mark (found rendering glTF-Validator's
``test/base/data/json/bom.gltf``; Windows tools such as .NET's ``Encoding.UTF8`` write one).
sc3d's checks read it (``json.loads`` of bytes skips the mark), then trimesh's loader, which decodes
to text first, failed: "cannot parse mesh file (FileNotFoundError: model.gltf: not found)", naming
a file that does not exist. three.js reads such files (``TextDecoder`` drops the mark). The loader
is now given the document without it, and the object renders as the same file without one."""
from __future__ import annotations

import json
import struct

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import FAST, index_of
from test_faults_round19_data import _objects
from test_gltf_accessors import CUBE
from test_gltf_primitives import _write_gltf

BOM = b"\xef\xbb\xbf"


def _glb_with_bom(path, doc: dict, buf: bytes) -> None:
    """``path`` as a GLB whose JSON chunk starts with ``BOM`` (padded with spaces to 4 bytes)."""
    text = BOM + json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(buf), b"BIN\0") + buf
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)


def test_a_byte_order_mark_before_the_json_is_read_past(tmp_path):
    """``bom.gltf`` and ``bom.glb`` render, with no failure or warning, as ``plain.gltf``."""
    from test_gltf_primitives import _gltf_doc

    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    _write_gltf(meshes / "plain.gltf", CUBE)
    (meshes / "bom.gltf").write_bytes(BOM + (meshes / "plain.gltf").read_bytes())
    doc, buf = _gltf_doc(CUBE)
    _glb_with_bom(meshes / "bom_glb.glb", {**doc, "buffers": [{"byteLength": len(buf)}]}, buf)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--voxelize", *FAST])
    assert index_of(out)["failures"] == [] and index_of(out)["warnings"] == []
    objects = _objects(out)
    for name in ("bom", "bom_glb"):
        for field in ("images", "masks", "voxels"):
            np.testing.assert_array_equal(objects[name][field], objects["plain"][field], err_msg=f"{name} {field}")
