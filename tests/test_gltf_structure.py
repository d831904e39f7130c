"""A glTF document whose structure names what it does not hold (found running glTF-Validator's 372
test files through ``render``: ``buffer_view/valid.gltf`` failed "cannot parse mesh file (KeyError:
'accessors')", ``node/unresolved_child_node.gltf`` and ``scenes`` problems "IndexError: list index
out of range", ``node/infinite_transform.gltf`` printed NumPy's "RuntimeWarning: invalid value
encountered in dot" naming no file). Each is refused in one line naming the file and the cause
(``sc3d_data.io.gltf_structure``); the expected lines are written by hand."""
from __future__ import annotations

import base64
import copy
import json
import warnings

import numpy as np
import pytest

from sc3d_cli.data import main as data_main
from sc3d_data.io.meshes import MeshError, load_mesh
from conftest import run_cli
from test_faults import FAST, index_of
from test_faults_round19_data import _objects
from test_gltf_accessors import CUBE
from test_gltf_primitives import _gltf_doc

#: the one-cube document's mesh (a second copy of it makes a file of two meshes)
_MESH = _gltf_doc(CUBE)[0]["meshes"][0]
#: (name, change to a one-cube document of 1 mesh, 1 node, 1 scene, the refusal after the file name)
REFUSED = [
    ("no_meshes", {"meshes": None, "accessors": None, "nodes": None, "scenes": None},
     "it holds no mesh (the document has no meshes), so there is nothing to draw; not read"),
    ("empty_meshes", {"meshes": [], "nodes": [{}]},
     "it holds no mesh (its meshes list is empty), so there is nothing to draw; not read"),
    ("child_past", {"nodes": [{"mesh": 0, "children": [7]}, {}, {}]},
     "node 0 names child 7, but the file has 3 nodes; not read"),
    ("child_negative", {"nodes": [{"mesh": 0, "children": [-1]}, {}]},
     "node 0 names child -1, but the file has 2 nodes; not read"),
    ("root_past", {"scenes": [{"nodes": [0, 4]}]}, "scene 0 names node 4, but the file has 1 node; not read"),
    ("scene_past", {"scene": 3}, "it names scene 3 to draw, but the file has 1 scene; not read"),
    ("mesh_past", {"nodes": [{"mesh": 0}, {"mesh": 2}], "scenes": [{"nodes": [0, 1]}]},
     "node 1 names mesh 2, but the file has 1 mesh; not read"),
    ("mesh_past_of_two", {"meshes": [_MESH, _MESH], "nodes": [{"mesh": 0}, {"mesh": 5}], "scenes": [{"nodes": [0, 1]}]},
     "node 1 names mesh 5, but the file has 2 meshes; not read"),
    ("children_no_list", {"nodes": [{"mesh": 0, "children": 1}, {}]}, "node 0's children is 1, not a list; not read"),
    ("node_no_object", {"nodes": [{"mesh": 0}, "x"], "scenes": [{"nodes": [0, 1]}]},
     'node 1 is "x", not an object; not read'),
    ("materials_no_objects", {"materials": ["material", None]},
     'materials 0, 1 are "material", ..., not objects; not read'),
    ("infinite_translation", {"nodes": [{"children": [1], "translation": [1e309, 0, 0]}, {"mesh": 0}]},
     "node 0's translation holds a number that is not finite (JSON reads numbers past 1.8e308 as infinity), "
     "so the mesh(es) it moves would be drawn nowhere; not read"),
    # failed 'empty mesh (no triangles)' and "cannot parse mesh file (KeyError: 'primitives')" (found by fix_small)
    ("no_primitives", {"meshes": [{"primitives": []}]},
     "mesh 0 has no primitives (its primitives list is empty), so there is nothing to draw; not read"),
    ("no_primitives_key", {"meshes": [_MESH, {}]}, "mesh 1 has no primitives list; not read"),
    # failed "cannot parse mesh file (FileNotFoundError: data:application/octet-stream;base64: not found)", or
    # "(Error: Invalid base64-encoded string: ...)", or "data:image/png;base64 named by the mesh or its materials
    # was not loaded (not found)" (found by fix_small)
    ("buffer_uri_no_comma", {"buffers": [{"byteLength": 240, "uri": "data:application/octet-stream;base64"}]},
     "buffer 0 has a malformed data URI (no 'base64,' before its data: glTF embeds data as base64); not read"),
    ("buffer_uri_not_base64", {"buffers": [{"byteLength": 240, "uri": "data:application/octet-stream;base64,AAA@"}]},
     "buffer 0 has a malformed data URI (its base64 does not decode: Only base64 data is allowed); not read"),
    ("buffer_uri_cut", {"buffers": [{"byteLength": 240, "uri": "data:application/octet-stream;base64,AAAAA"}]},
     "buffer 0 has a malformed data URI (its base64 does not decode: Invalid base64-encoded string: number of data "
     "characters (5) cannot be 1 more than a multiple of 4); not read"),
    ("image_uri_no_comma", {"images": [{"uri": "data:image/png;base64"}]},
     "image 0 has a malformed data URI (no 'base64,' before its data: glTF embeds data as base64); not read"),
]


def _document() -> dict:
    """A one-cube glTF document, its buffer embedded as a data URI."""
    doc, buf = _gltf_doc(CUBE)
    doc["buffers"] = [{"byteLength": len(buf), "uri": "data:application/octet-stream;base64,"
                       + base64.b64encode(buf).decode()}]
    return doc


def _write(path, change: dict) -> None:
    """``path``: the one-cube document with ``change``'s keys set (None: removed); infinity is
    written as JSON's ``1e309``."""
    doc = copy.deepcopy(_document())
    for key, value in change.items():
        doc.pop(key) if value is None else doc.__setitem__(key, value)
    path.write_text(json.dumps(doc).replace("-Infinity", "-1e309").replace("Infinity", "1e309"))


@pytest.mark.parametrize("name,change,expected", REFUSED, ids=[r[0] for r in REFUSED])
def test_a_document_naming_what_it_lacks_is_refused_saying_so(tmp_path, name, change, expected):
    path = tmp_path / f"{name}.gltf"
    _write(path, change)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no NumPy RuntimeWarning naming no file
        with pytest.raises(MeshError) as e:
            load_mesh(path)
    assert str(e.value) == f"{path}: {expected}"


def test_refusals_reach_the_index_and_harmless_transforms_render_quietly(tmp_path, capfd):
    """Through ``render``: the failures are the lines above, nothing else reaches stderr, and a
    non-finite transform of a node that moves no drawn mesh (beside it, or a child without a
    mesh) draws the same images and voxels as the plain cube, without NumPy's warning."""
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    for name, change, _ in REFUSED[:3]:
        _write(meshes / f"{name}.gltf", change)
    _write(meshes / "plain.gltf", {})
    _write(meshes / "inf_beside.gltf", {"nodes": [{"mesh": 0}, {"translation": [1e309, -1e309, 0]}],
                                        "scenes": [{"nodes": [0, 1]}]})
    _write(meshes / "inf_child.gltf", {"nodes": [{"mesh": 0, "children": [1]}, {"rotation": [1e309, 0, 0, 1]}]})
    out = tmp_path / "out"
    capfd.readouterr()
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--voxelize", *FAST])
    assert "RuntimeWarning" not in capfd.readouterr().err
    assert sorted(f["reason"] for f in index_of(out)["failures"]) == sorted(
        f"{meshes / name}.gltf: {expected}" for name, _, expected in REFUSED[:3])
    objects = _objects(out)
    assert sorted(objects) == ["inf_beside", "inf_child", "plain"]
    for name in ("inf_beside", "inf_child"):
        for field in ("images", "masks", "voxels"):
            np.testing.assert_array_equal(objects[name][field], objects["plain"][field], err_msg=f"{name} {field}")


def test_an_empty_mesh_beside_a_drawn_one_loads_as_before(tmp_path):
    """Only a file with nothing else to draw is refused for meshes without primitives: an empty mesh
    drawn beside the cube draws nothing for its node and the cube as before (fix_small)."""
    path = tmp_path / "beside.gltf"
    _write(path, {"meshes": [_MESH, {"primitives": []}], "nodes": [{"mesh": 0}, {"mesh": 1}],
                  "scenes": [{"nodes": [0, 1]}]})
    assert len(load_mesh(path)[2]) == 12  # the cube's triangles
