"""A glTF/GLB whose data layout the loader cannot read fails in one line saying what is wrong.

trimesh reads every buffer, bufferView and accessor of a glTF before it builds a mesh, and stops
the whole file in its own words where the layout is malformed: ``KeyError: 'uri'`` for a .gltf
buffer without uri, ``IndexError: list index out of range`` for an accessor naming bufferView 7
of 2 or a GLB without its BIN chunk, ``cannot reshape array of size 288 into shape
(1000000000,3)`` for a count past the end of its view, a bare ``AssertionError`` for a view past
the end of its buffer. Now such an object fails with one line naming the file and the buffer,
bufferView or accessor and what is wrong with it, and a good mesh beside it still renders. Real
renderer and HDF5; every fixture is built here (the cube glTF/GLB writers of
test_gltf_primitives) and expected messages come from the fixtures' JSON."""
from __future__ import annotations

import json
import struct
from pathlib import Path

import pytest

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST, index_of
from test_gltf_primitives import _cube, _gltf_doc, _write_glb, _write_gltf

CUBE = [(*_cube(), 4)]  # one primitive: 8 float32 VEC3 positions, 36 uint32 indices


def _edit_gltf(path: Path, edit) -> dict:
    """The cube as .gltf ``path`` (buffer embedded as a data URI), its JSON document changed in
    place by ``edit(doc)`` before it is written; returns the document as written."""
    doc = _write_gltf(path, CUBE)
    edit(doc)
    path.write_text(json.dumps(doc))
    return doc


def _cut_glb(path: Path, drop: int | None = None) -> dict:
    """The cube as .glb ``path`` without its last ``drop`` bytes (None: all after its JSON chunk,
    so it has no BIN chunk), its header's total length kept true; returns its JSON document."""
    doc = _write_glb(path, CUBE)
    data = path.read_bytes()
    data = data[:20 + struct.unpack_from("<I", data, 12)[0] if drop is None else len(data) - drop]
    path.write_bytes(data[:8] + struct.pack("<I", len(data)) + data[12:])
    return doc


def _position(doc: dict) -> int:
    return doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]


def _indices_view(doc: dict) -> int:
    return doc["accessors"][doc["meshes"][0]["primitives"][0]["indices"]]["bufferView"]


def _set(mapping: dict, **values):
    mapping.update(values)


def _broken(folder: Path) -> dict[str, str]:
    """Writes the malformed cubes into ``folder``: ``{file name: its expected one-line refusal}``."""
    def view_end(doc, v):
        view = doc["bufferViews"][v]
        return view.get("byteOffset", 0) + view["byteLength"]

    expected = {}
    doc = _edit_gltf(folder / "bufferview7.gltf", lambda d: _set(d["accessors"][_position(d)], bufferView=7))
    expected["bufferview7.gltf"] = (f"accessor {_position(doc)} (POSITION of mesh 0) names bufferView 7, "
                                    f"but the file has {len(doc['bufferViews'])}")
    doc = _edit_gltf(folder / "count.gltf", lambda d: _set(d["accessors"][_position(d)], count=10**9))
    view = doc["accessors"][_position(doc)]["bufferView"]
    expected["count.gltf"] = (f"accessor {_position(doc)} (POSITION of mesh 0) reaches beyond the end of bufferView "
                              f"{view} ({doc['bufferViews'][view]['byteLength']} bytes): count 1,000,000,000 of "
                              "12-byte elements from byte 0 needs 12,000,000,000 bytes")
    doc = _edit_gltf(folder / "longview.gltf", lambda d: _set(d["bufferViews"][_indices_view(d)],
                                                              byteLength=d["buffers"][0]["byteLength"]))
    v = _indices_view(doc)
    expected["longview.gltf"] = (f"bufferView {v} (bytes {doc['bufferViews'][v]['byteOffset']} to {view_end(doc, v)}) "
                                 f"reaches beyond the end of buffer 0 ({doc['buffers'][0]['byteLength']} bytes)")
    _edit_gltf(folder / "nouri.gltf", lambda d: d["buffers"][0].pop("uri"))
    expected["nouri.gltf"] = "buffer 0 has no uri, which a .gltf needs to name its data"
    _cut_glb(folder / "nobin.glb")
    expected["nobin.glb"] = "buffer 0 has no uri and the file has no BIN chunk to hold it"
    doc = _cut_glb(folder / "cut.glb", drop=8)
    v, held = _indices_view(doc), doc["buffers"][0]["byteLength"] - 8
    expected["cut.glb"] = (f"bufferView {v} (bytes {doc['bufferViews'][v]['byteOffset']} to {view_end(doc, v)}) "
                           f"reaches beyond the end of buffer 0, whose BIN chunk holds {held} bytes")
    return {name: f"{folder / name}: {problem}; not read" for name, problem in expected.items()}


# ----------------------------------------------------------------------------- the need
def test_trimesh_stops_on_a_malformed_layout_in_its_own_words(tmp_path):
    """The negative control: trimesh itself stops on each malformed cube with an error that does
    not say what is wrong (a KeyError, an IndexError, a reshape), and reads the good one."""
    import trimesh

    _write_gltf(tmp_path / "good.gltf", CUBE)
    assert len(trimesh.load(str(tmp_path / "good.gltf"), force="mesh", process=False).faces) == 12
    for name in _broken(tmp_path):
        with pytest.raises((KeyError, IndexError, ValueError, AssertionError)):
            trimesh.load(str(tmp_path / name), force="scene", process=False)


# ----------------------------------------------------------------------------- through the CLI
def test_malformed_layouts_fail_in_one_line_and_the_good_cubes_render(tmp_path):
    """One folder: the cube as .gltf and as .glb, and the malformed cubes. Each malformed one
    fails with one line naming the file and the bufferView, buffer or accessor and what is wrong;
    no loader words (KeyError, Traceback) are shown; both good cubes render."""
    chair = tmp_path / "m" / "chair"
    chair.mkdir(parents=True)
    _write_gltf(chair / "good.gltf", CUBE)
    _write_glb(chair / "goodbin.glb", CUBE)
    expected = _broken(chair)
    out = tmp_path / "out"
    result = run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    reasons = {Path(f["source"]).name: f["reason"] for f in index_of(out)["failures"]}
    assert sorted(reasons) == sorted(expected)
    for name, line in expected.items():
        assert line in reasons[name], (name, reasons[name])
    for text in [*reasons.values(), result.output]:
        assert "KeyError" not in text and "Traceback" not in text and "AssertionError" not in text, text
    assert all("\n" not in r for r in reasons.values())
    objs = objects_by_id(out)
    assert sorted(objs) == [("03001627", "good"), ("03001627", "goodbin")]
    assert all(o["masks"].any(axis=(1, 2)).all() for o in objs.values())


# ----------------------------------------------------------------------------- each check, without rendering
@pytest.mark.parametrize("edit, problem", [
    (lambda d: _set(d["accessors"][0], count=1e9),
     "accessor 0 (POSITION of mesh 0) has count 1000000000.0, which is not a whole number >= 0"),
    (lambda d: _set(d["accessors"][0], count=-1),
     "accessor 0 (POSITION of mesh 0) has count -1, which is not a whole number >= 0"),
    (lambda d: _set(d["accessors"][1], componentType=5124),
     "accessor 1 (indices of mesh 0) has componentType 5124, which is none of glTF's "
     "(5120, 5121, 5122, 5123, 5125, 5126)"),
    (lambda d: _set(d["accessors"][0], type="VEC7"),
     'accessor 0 (POSITION of mesh 0) has type "VEC7", which is none of glTF\'s '
     "(SCALAR, VEC2, VEC3, VEC4, MAT2, MAT3, MAT4)"),
    (lambda d: _set(d["accessors"][0], byteOffset=4),
     "accessor 0 (POSITION of mesh 0) reaches beyond the end of bufferView 0 (96 bytes): count 8 of 12-byte "
     "elements from byte 4 needs 100 bytes"),
    (lambda d: _set(d["bufferViews"][0], byteStride=16),
     "accessor 0 (POSITION of mesh 0) reaches beyond the end of bufferView 0 (96 bytes): count 8 of 12-byte "
     "elements every 16 bytes from byte 0 needs 124 bytes"),
    (lambda d: _set(d["bufferViews"][0], byteStride=8),
     "accessor 0 (POSITION of mesh 0) has elements of 12 bytes, longer than the byteStride 8 of bufferView 0"),
    (lambda d: _set(d["bufferViews"][1], buffer=3), "bufferView 1 names buffer 3, but the file has 1"),
    (lambda d: d["bufferViews"][1].pop("byteLength"), "bufferView 1 has no byteLength"),
    (lambda d: _set(d["buffers"][0], uri=7), "buffer 0 has uri 7, which is not text"),
    (lambda d: _set(d["buffers"][0], uri=d["buffers"][0]["uri"][:-8]),  # 320 base64 characters (240 bytes) less 8
     "bufferView 1 (bytes 96 to 240) reaches beyond the end of buffer 0, whose data URI holds 234 bytes"),
    (lambda d: _set(d["meshes"][0]["primitives"][0], indices=9),
     "mesh 0 primitive 0's indices names accessor 9, but the file has 2"),
], ids=["float-count", "negative-count", "componentType", "type", "accessor-offset", "stride", "short-stride",
        "buffer-index", "no-byteLength", "uri-not-text", "short-data-uri", "accessor-index"])
def test_each_layout_problem_is_named(tmp_path, edit, problem):
    from sc3d_data.io.gltf_check import gltf_refusal

    path = tmp_path / "cube.gltf"
    _edit_gltf(path, edit)
    assert gltf_refusal(path) == f"{path}: {problem}; not read"


def test_external_buffers_are_judged_inside_the_folder_only(tmp_path):
    """An external .bin beside the file is judged by its size (a short one is refused, where
    trimesh raised a bare AssertionError); one outside the folder is not looked at (the loader
    refuses it, naming it); an accessor without bufferView is legal (zeros) and not refused."""
    from sc3d_data.io.gltf_check import gltf_refusal
    from sc3d_data.io.meshes import MeshError, load_mesh

    (tmp_path / "m").mkdir()
    path = tmp_path / "m" / "cube.gltf"
    doc = _write_gltf(path, CUBE)
    data = _gltf_doc(CUBE)[1]  # the buffer of the cube
    (tmp_path / "m" / "cube.bin").write_bytes(data)
    doc["buffers"][0]["uri"] = "cube.bin"
    path.write_text(json.dumps(doc))
    assert gltf_refusal(path) is None and len(load_mesh(path)[2]) == 12

    (tmp_path / "m" / "cube.bin").write_bytes(data[:-8])
    v = _indices_view(doc)
    assert gltf_refusal(path) == (f"{path}: bufferView {v} (bytes {doc['bufferViews'][v]['byteOffset']} to "
                                  f"{len(data)}) reaches beyond the end of buffer 0, whose file cube.bin holds "
                                  f"{len(data) - 8} bytes; not read")

    (tmp_path / "m" / "cube.bin").rename(tmp_path / "cube.bin")  # short, but outside the folder: not judged
    doc["buffers"][0]["uri"] = "../cube.bin"
    path.write_text(json.dumps(doc))
    assert gltf_refusal(path) is None
    with pytest.raises(MeshError, match="outside the dataset folder"):
        load_mesh(path)

    zeros = tmp_path / "zeros.gltf"
    _edit_gltf(zeros, lambda d: d["accessors"][1].pop("bufferView"))  # indices all 0: degenerate
    assert gltf_refusal(zeros) is None
    with pytest.raises(MeshError, match="zero surface area"):
        load_mesh(zeros)


def test_indices_past_the_last_vertex_fail_in_one_line(tmp_path):
    """A layout that reads well whose index data name vertex 99 of the cube's 8: before,
    ``load_mesh`` crashed with an uncaught ``IndexError`` (index 99 is out of bounds for axis 0
    with size 8) instead of a ``MeshError``; now one line says how many corners name no vertex
    and the range. (An OBJ face naming vertex 9 of 3 already fails in trimesh's parser, reported
    as "cannot parse mesh file (IndexError: ...)".)"""
    from sc3d_data.io.meshes import MeshError, load_mesh

    vertices, indices = _cube()
    indices = indices.copy()
    indices[[5, 17]] = 99
    path = tmp_path / "cube.gltf"
    _write_gltf(path, [(vertices, indices, 4)])
    with pytest.raises(MeshError) as e:
        load_mesh(path)
    assert str(e.value) == f"{path}: 2 triangle corners name no vertex (indices from 0 to 99, but it has 8 vertices)"


@pytest.mark.parametrize("n", range(0, 13))
def test_a_data_uri_is_measured_as_base64_decodes_it(n):
    """The length the check counts from a data URI's text equals what ``base64`` decodes from it,
    with its ``=`` padding or without (an undercount would refuse a good file)."""
    import base64

    from sc3d_data.io.gltf_accessors import _base64_bytes

    text = base64.b64encode(bytes(range(n))).decode()
    assert _base64_bytes(text) == len(base64.b64decode(text)) == n
    assert _base64_bytes(text.rstrip("=")) == n
