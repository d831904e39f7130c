"""glTF geometry the loader would read as other geometry is refused, not rendered wrong.

trimesh's glTF loader skips a TRIANGLE_FAN primitive (mode 6) and never applies an accessor's
``sparse`` substitution, so a cube plus a fan-drawn disk rendered as the cube alone and a
POSITION accessor whose sparse values move a corner rendered unmoved, with no warning. Now
such an object fails with one line naming the file and the primitive or accessor; points and
lines (no surface, not drawn) and strips (which trimesh loads) are left alone. Real renderer
and HDF5; every fixture is built here and expected messages come from the fixtures' JSON."""
from __future__ import annotations

import base64
import json
import struct
from pathlib import Path

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST, index_of

#: glTF primitive mode names, from the glTF 2.0 specification
MODE_NAMES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP", 4: "TRIANGLES",
              5: "TRIANGLE_STRIP", 6: "TRIANGLE_FAN"}
DISK_SIDES = 8


def _cube():
    import trimesh

    box = trimesh.creation.box((1, 1, 1))
    return box.vertices.astype(np.float32), box.faces.astype(np.uint32).ravel()


def _disk():
    """A flat disk above the cube as a fan: its centre, then the rim, closed (DISK_SIDES triangles)."""
    ang = np.linspace(0, 2 * np.pi, DISK_SIDES, endpoint=False)
    rim = np.c_[1.5 * np.cos(ang), 1.5 * np.sin(ang), np.full(DISK_SIDES, 1.5)]
    v = np.concatenate([[[0, 0, 1.5]], rim]).astype(np.float32)
    return v, np.r_[np.arange(DISK_SIDES + 1), 1].astype(np.uint32)


def _segment():
    """Two points far off the cube: drawn as LINES they carry no surface."""
    return np.array([[0, 0, 0], [3, 3, 3]], np.float32), None


def _gltf_doc(parts: list[tuple[np.ndarray, np.ndarray | None, int]], sparse_corner=None) -> tuple[dict, bytes]:
    """``(JSON document, buffer bytes)`` of one mesh whose primitives are ``parts``
    ``[(vertices, indices or None, mode)]``; with ``sparse_corner=(i, xyz)`` the first part's
    POSITION accessor gets a sparse substitution moving vertex ``i`` to ``xyz``. The buffer is
    not yet referenced (the caller adds ``buffers``)."""
    chunks, views, accessors, prims = [], [], [], []

    def view(data: bytes) -> int:
        offset = sum(len(c) for c in chunks)
        chunks.append(data + b"\0" * (-len(data) % 4))
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(data)})
        return len(views) - 1

    for v, idx, mode in parts:
        prim = {"attributes": {"POSITION": len(accessors)}, "mode": mode}
        accessors.append({"bufferView": view(v.tobytes()), "componentType": 5126, "count": len(v),
                          "type": "VEC3", "min": v.min(0).tolist(), "max": v.max(0).tolist()})
        if idx is not None:
            prim["indices"] = len(accessors)
            accessors.append({"bufferView": view(idx.tobytes()), "componentType": 5125, "count": len(idx),
                              "type": "SCALAR"})
        prims.append(prim)
    if sparse_corner is not None:
        i, xyz = sparse_corner
        position = accessors[prims[0]["attributes"]["POSITION"]]
        position["sparse"] = {"count": 1,
                              "indices": {"bufferView": view(np.uint32([i]).tobytes()), "componentType": 5125},
                              "values": {"bufferView": view(np.float32([xyz]).tobytes())}}
        position["max"] = np.maximum(position["max"], xyz).tolist()
    doc = {"asset": {"version": "2.0"}, "bufferViews": views, "accessors": accessors,
           "meshes": [{"primitives": prims}], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}], "scene": 0}
    return doc, b"".join(chunks)


def _write_gltf(path: Path, parts, sparse_corner=None) -> dict:
    """``path`` (.gltf, buffer embedded as a data URI); returns its JSON document."""
    doc, buf = _gltf_doc(parts, sparse_corner)
    doc["buffers"] = [{"byteLength": len(buf),
                       "uri": "data:application/octet-stream;base64," + base64.b64encode(buf).decode()}]
    path.write_text(json.dumps(doc))
    return doc


def _write_glb(path: Path, parts, sparse_corner=None) -> dict:
    """``path`` (.glb: JSON chunk, then the buffer as the BIN chunk); returns its JSON document."""
    doc, buf = _gltf_doc(parts, sparse_corner)
    doc["buffers"] = [{"byteLength": len(buf)}]
    _write_glb_document(path, doc, buf)
    return doc


def _write_glb_document(path: Path, doc: dict, buf: bytes) -> None:
    """``path`` as a GLB container (glTF 2.0 binary): header, JSON chunk ``doc`` padded with
    spaces to 4 bytes, then ``buf`` as the BIN chunk."""
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(buf), b"BIN\0") + buf
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)


def _fan_message(path: Path, doc: dict) -> str:
    """The expected refusal of ``path``, from its document: its first mode-6 primitive."""
    k, prim = next((k, p) for k, p in enumerate(doc["meshes"][0]["primitives"]) if p["mode"] == 6)
    return (f"{path}: mesh 0 primitive {k} is a {MODE_NAMES[prim['mode']]} (mode {prim['mode']}), "
            "which the loader skips; not read")


def _sparse_message(path: Path, doc: dict) -> str:
    a = next(i for i, acc in enumerate(doc["accessors"]) if "sparse" in acc)
    assert doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"] == a
    return f"{path}: accessor {a} (POSITION of mesh 0) is sparse, which the loader does not apply; not read"


def _loaded_triangles(path: Path) -> tuple[int, np.ndarray]:
    """(triangles, bounds) of ``path`` as trimesh itself loads it, without sc3d."""
    import trimesh

    scene = trimesh.load(str(path), force="scene", process=False)
    return sum(len(g.faces) for g in scene.geometry.values() if isinstance(g, trimesh.Trimesh)), scene.bounds


# ----------------------------------------------------------------------------- the need
def test_trimesh_drops_fans_and_ignores_sparse_accessors(tmp_path):
    """The negative control: without the check, trimesh loads cube + fan as the cube alone
    (the fan's DISK_SIDES triangles are gone) and a sparse-moved corner unmoved."""
    cube, fan, sparse = tmp_path / "cube.gltf", tmp_path / "fan.gltf", tmp_path / "sparse.gltf"
    _write_gltf(cube, [(*_cube(), 4)])
    _write_gltf(fan, [(*_cube(), 4), (*_disk(), 6)])
    _write_gltf(sparse, [(*_cube(), 4)], sparse_corner=(0, (5.0, 5.0, 5.0)))
    cube_tris, cube_bounds = _loaded_triangles(cube)
    assert cube_tris == len(_cube()[1]) // 3
    assert _loaded_triangles(fan)[0] == cube_tris  # the fan should have added DISK_SIDES triangles
    sparse_tris, sparse_bounds = _loaded_triangles(sparse)
    assert sparse_tris == cube_tris
    np.testing.assert_array_equal(sparse_bounds, cube_bounds)  # the corner at (5, 5, 5) is not there


# ----------------------------------------------------------------------------- through the CLI
def test_fan_and_sparse_gltf_fail_lines_render_like_the_cube(tmp_path):
    """One folder: the cube alone, cube + fan, cube with a sparse POSITION, cube + a LINES
    primitive, and cube + fan as a GLB. The fan and sparse files fail with one line naming the
    file and the primitive or accessor; the lines file renders exactly as the cube alone."""
    chair = tmp_path / "m" / "chair"
    chair.mkdir(parents=True)
    _write_gltf(chair / "cube.gltf", [(*_cube(), 4)])
    fan = _write_gltf(chair / "fan.gltf", [(*_cube(), 4), (*_disk(), 6)])
    sparse = _write_gltf(chair / "sparse.gltf", [(*_cube(), 4)], sparse_corner=(0, (5.0, 5.0, 5.0)))
    _write_gltf(chair / "lines.gltf", [(*_cube(), 4), (*_segment(), 1)])
    fan_glb = _write_glb(chair / "fanbin.glb", [(*_cube(), 4), (*_disk(), 6)])
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    index = index_of(out)
    reasons = {Path(f["source"]).name: f["reason"] for f in index["failures"]}
    assert sorted(reasons) == ["fan.gltf", "fanbin.glb", "sparse.gltf"]
    assert _fan_message(chair / "fan.gltf", fan) in reasons["fan.gltf"]
    assert _fan_message(chair / "fanbin.glb", fan_glb) in reasons["fanbin.glb"]
    assert _sparse_message(chair / "sparse.gltf", sparse) in reasons["sparse.gltf"]
    assert all("\n" not in r for r in reasons.values())
    objs = objects_by_id(out)
    assert sorted(objs) == [("03001627", "cube"), ("03001627", "lines")]
    cube, lines = objs[("03001627", "cube")], objs[("03001627", "lines")]
    assert cube["masks"].any(axis=(1, 2)).all()
    np.testing.assert_array_equal(lines["masks"], cube["masks"])
    np.testing.assert_array_equal(lines["images"], cube["images"])


# ----------------------------------------------------------------------------- what is left alone
def test_strips_and_undrawn_meshes_are_not_refused(tmp_path):
    """A TRIANGLE_STRIP (mode 5) is loaded by trimesh, so it is not refused and its triangles are
    drawn; a fan in a mesh that no node of the scene uses is not drawn by any reader, so not
    refused either; a file that is not a glTF document is refused as such (round eight: the
    loader's own words did not say what was wrong)."""
    from sc3d_data.io.meshes import MeshError, load_mesh

    strip = tmp_path / "strip.gltf"
    _write_gltf(strip, [(*_cube(), 4), (*_disk(), 5)])
    _, _, faces, _ = load_mesh(strip)
    cube_tris = len(_cube()[1]) // 3
    assert len(faces) == cube_tris + len(_disk()[1]) - 2  # a strip of n indices draws n - 2 triangles

    unused = tmp_path / "unused.gltf"
    doc = _write_gltf(unused, [(*_cube(), 4), (*_disk(), 6)])
    cube_prim, fan_prim = doc["meshes"][0]["primitives"]
    doc["meshes"] = [{"primitives": [cube_prim]}, {"primitives": [fan_prim]}]  # mesh 1: no node
    unused.write_text(json.dumps(doc))
    assert len(load_mesh(unused)[2]) == cube_tris

    garbage = tmp_path / "garbage.glb"
    garbage.write_bytes(b"glTF" + b"\xff" * 40)
    try:
        load_mesh(garbage)
    except MeshError as e:
        assert f"{garbage}: not a GLB file (no glTF header and JSON chunk)" in str(e)
    else:
        raise AssertionError("a garbage GLB loaded")


def test_a_document_without_scenes_is_judged_on_every_mesh(tmp_path):
    """A glTF without ``scenes`` is drawn whole by the loader (every mesh; the fan still dropped,
    as trimesh shows): it is judged on every mesh, so the fan is refused there too."""
    from sc3d_data.io.gltf_check import gltf_refusal

    path = tmp_path / "noscene.gltf"
    doc = _write_gltf(path, [(*_cube(), 4), (*_disk(), 6)])
    for key in ("scenes", "scene"):
        doc.pop(key)
    path.write_text(json.dumps(doc))
    cube_only = tmp_path / "cube.gltf"
    _write_gltf(cube_only, [(*_cube(), 4)])
    assert _loaded_triangles(path)[0] == _loaded_triangles(cube_only)[0]   # the fan is dropped
    assert gltf_refusal(path) == _fan_message(path, doc)
