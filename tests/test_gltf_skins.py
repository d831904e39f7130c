"""Skinned glTF meshes are drawn posed by their joints (``sc3d_data.io.gltf_skins``), as glTF 2.0
and every viewer draw them: trimesh's loader drew them in their bind pose with the skinned
node's own transform applied, exit 0. The expected geometry comes from references without a skin
whose vertices were posed by hand, rendered by the same ``sc3d-data render``."""
from __future__ import annotations

import base64
import json
import struct
from pathlib import Path

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import FAST, index_of
from test_faults_round19_data import _objects, _reasons

S = float(np.sqrt(0.5))
#: a bar with x, z in [-0.15, 0.15] and three rings of 4 vertices at y = 0, 1, 2
RING = [(-0.15, -0.15), (0.15, -0.15), (0.15, 0.15), (-0.15, 0.15)]
BAR = [(x, y, z) for y in (0, 1, 2) for (x, z) in RING]
#: the bar posed by a joint at y = 1 turned 90 degrees about +z, by hand: (x, y - 1, z) turned is
#: (-(y - 1), x, z); the lower ring follows joint 0 (the identity), the upper one joint 1, the
#: middle one half of each ((x, 1, z) and (0, 1 + x, z)): an L
BENT = ([(x, 0, z) for (x, z) in RING] + [(x / 2, 1 + x / 2, z) for (x, z) in RING]
        + [(-1, 1 + x, z) for (x, z) in RING])
FACES = [f for r in (0, 1) for i in range(4) for f in (4 * r + i, 4 * r + (i + 1) % 4, 4 * r + 4 + (i + 1) % 4,
                                                         4 * r + i, 4 * r + 4 + (i + 1) % 4, 4 * r + 4 + i)]
FACES += [0, 2, 1, 0, 3, 2, 8, 9, 10, 8, 10, 11]
#: joint 1 bound at y = 1 (column-major, as glTF stores matrices)
IBM = np.stack([np.eye(4), [[1, 0, 0, 0], [0, 1, 0, -1], [0, 0, 1, 0], [0, 0, 0, 1]]]).transpose(0, 2, 1)


class _Doc:
    """A glTF document under construction whose data go into one buffer."""

    def __init__(self):
        self.blob, self.doc = bytearray(), {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": []}],
                                            "nodes": [], "meshes": [], "bufferViews": [], "accessors": []}

    def view(self, data: bytes, stride: int | None = None) -> int:
        self.blob += b"\0" * (-len(self.blob) % 4)
        self.doc["bufferViews"].append({"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(data),
                                        **({"byteStride": stride} if stride else {})})
        self.blob += data
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, view: int, ctype: int, count: int, kind: str, **more) -> int:
        self.doc["accessors"].append({"bufferView": view, "componentType": ctype, "count": count, "type": kind, **more})
        return len(self.doc["accessors"]) - 1

    def mesh(self, positions) -> int:
        p = np.asarray(positions, np.float32)
        a = self.accessor(self.view(p.tobytes()), 5126, len(p), "VEC3", min=p.min(0).tolist(), max=p.max(0).tolist())
        i = self.accessor(self.view(np.asarray(FACES, np.uint16).tobytes()), 5123, len(FACES), "SCALAR")
        self.doc["meshes"].append({"primitives": [{"attributes": {"POSITION": a}, "indices": i}]})
        return len(self.doc["meshes"]) - 1

    def node(self, root: bool = True, **node) -> int:
        self.doc["nodes"].append(node)
        if root:
            self.doc["scenes"][0]["nodes"].append(len(self.doc["nodes"]) - 1)
        return len(self.doc["nodes"]) - 1

    def write(self, path: Path, bin_file: str | None = None) -> None:
        """Write a .gltf (its data in a base64 data URI, or in ``bin_file`` beside it) or a .glb."""
        doc = dict(self.doc, buffers=[{"byteLength": len(self.blob)}])
        if bin_file:
            (path.parent / bin_file).write_bytes(self.blob)
            path.write_text(json.dumps(dict(doc, buffers=[dict(doc["buffers"][0], uri=bin_file)])))
            return
        if path.suffix == ".gltf":
            doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(self.blob).decode()
            path.write_text(json.dumps(doc))
            return
        text = json.dumps(doc).encode()
        text += b" " * (-len(text) % 4)
        blob = bytes(self.blob) + b"\0" * (-len(self.blob) % 4)
        body = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(blob), b"BIN\0") + blob
        path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)


def _skinned_bar(joint_rotation=None, node: dict | None = None, parent: dict | None = None, packed: bool = False,
                 edit=None) -> _Doc:
    """The bar skinned to two joints (joint 0 at the origin, joint 1 at y = 1 under it, turned by
    ``joint_rotation``), drawn by a skinned node with ``node``'s transform under a parent with
    ``parent``'s. ``packed``: JOINTS_0 as unsigned bytes and WEIGHTS_0 as normalized unsigned bytes
    (128, 128 in the middle: summing to 256/255, divided by it), interleaved in one bufferView
    (byteStride 8, the weights at accessor byteOffset 4); else unsigned shorts and floats.
    ``edit(doc, attributes)`` changes the document last."""
    d = _Doc()
    m = d.mesh(BAR)
    joints = np.array([[0, 1, 0, 0]] * 12)
    if packed:
        weights = np.array([[255, 0, 0, 0]] * 4 + [[128, 128, 0, 0]] * 4 + [[0, 255, 0, 0]] * 4, np.uint8)
        v = d.view(np.concatenate([joints.astype(np.uint8), weights], axis=1).tobytes(), stride=8)
        j, w = d.accessor(v, 5121, 12, "VEC4"), d.accessor(v, 5121, 12, "VEC4", byteOffset=4, normalized=True)
    else:
        weights = np.array([[1, 0, 0, 0]] * 4 + [[0.5, 0.5, 0, 0]] * 4 + [[0, 1, 0, 0]] * 4, np.float32)
        j = d.accessor(d.view(joints.astype(np.uint16).tobytes()), 5123, 12, "VEC4")
        w = d.accessor(d.view(weights.tobytes()), 5126, 12, "VEC4")
    attributes = d.doc["meshes"][m]["primitives"][0]["attributes"]
    attributes.update(JOINTS_0=j, WEIGHTS_0=w)
    ibm = d.accessor(d.view(IBM.astype(np.float32).tobytes()), 5126, 2, "MAT4")
    skinned = d.node(root=False, mesh=m, skin=0, **(node or {}))
    d.node(children=[skinned], **(parent or {}))
    joint1 = d.node(root=False, translation=[0, 1, 0], **({"rotation": joint_rotation} if joint_rotation else {}))
    joint0 = d.node(children=[joint1])
    d.doc["skins"] = [{"joints": [joint0, joint1], "inverseBindMatrices": ibm}]
    if edit:
        edit(d.doc, attributes)
    return d


def _reference(*placed) -> _Doc:
    """A document without a skin drawing each ``(positions, translation)`` of ``placed``."""
    d = _Doc()
    for positions, translation in placed:
        d.node(mesh=d.mesh(positions), translation=translation)
    return d


def test_a_skinned_gltf_is_drawn_posed_by_its_joints_without_its_nodes_transform(tmp_path):
    """A bar whose upper joint is turned 90 degrees about z draws as the L posed by hand (.gltf with
    float weights; .glb, and .gltf with an external .bin, with normalized byte weights interleaved
    with byte joints); a skinned node
    with its own rotation and a rotated parent (which glTF ignores) at bind pose draws as the
    straight bar; a node drawing the same mesh unskinned, beside the skinned one, draws it
    unposed where its own transform puts it."""
    turn = [0, 0, S, S]
    turned = {"rotation": [S, 0, 0, S]}
    folder = tmp_path / "m" / "bar"
    folder.mkdir(parents=True)
    _reference((BENT, [0, 0, 0])).write(folder / "ref_bent.gltf")
    _reference((BAR, [0, 0, 0])).write(folder / "ref_straight.gltf")
    _reference((BENT, [0, 0, 0]), (BAR, [3, 0, 0])).write(folder / "ref_pair.gltf")
    _skinned_bar(turn).write(folder / "bent.gltf")
    _skinned_bar(turn, packed=True).write(folder / "bent_packed.glb")
    _skinned_bar(turn, packed=True).write(folder / "bent_bin.gltf", bin_file="bent.bin")
    _skinned_bar(node=turned, parent={"translation": [5, 0, 0], "scale": [2, 2, 2]}).write(folder / "node_turned.gltf")
    pair = _skinned_bar(turn)
    pair.node(mesh=0, translation=[3, 0, 0])
    pair.write(folder / "pair.gltf")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == [] and index_of(out)["warnings"] == []
    objects = _objects(out)
    assert not np.array_equal(objects["ref_bent"]["masks"], objects["ref_straight"]["masks"])  # the L shows
    for name, reference in (("bent", "ref_bent"), ("bent_packed", "ref_bent"), ("bent_bin", "ref_bent"),
                            ("node_turned", "ref_straight"), ("pair", "ref_pair")):
        np.testing.assert_array_equal(objects[name]["masks"], objects[reference]["masks"], err_msg=name)
        np.testing.assert_array_equal(objects[name]["images"], objects[reference]["images"], err_msg=name)


def test_a_skin_that_cannot_be_applied_is_refused_in_one_line(tmp_path):
    """JOINTS_0 without WEIGHTS_0 and a weighted joint index past the skin's joints cannot be posed:
    each file fails in one line naming node, skin and reason. Control: the same bar skinned as
    written renders."""
    def no_weights(doc, attributes):
        del attributes["WEIGHTS_0"]

    def far_joint(doc, attributes):
        doc["skins"][0]["joints"] = doc["skins"][0]["joints"][:1]
        doc["skins"][0].pop("inverseBindMatrices")

    folder = tmp_path / "m" / "bar"
    folder.mkdir(parents=True)
    for name, edit in (("no_weights", no_weights), ("far_joint", far_joint)):
        _skinned_bar(edit=edit).write(folder / f"{name}.gltf")
    _skinned_bar().write(folder / "as_written.gltf")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert _reasons(out) == {
        "no_weights": "node 0's skin 0 cannot be applied: mesh 0 primitive 0 has JOINTS_0 but no WEIGHTS_0; not read",
        "far_joint": "node 0's skin 0 cannot be applied: mesh 0 primitive 0 vertex 4 (and 7 more) names joint 1, "
                     "but the skin has 1; not read"}
    assert set(_objects(out)) == {"as_written"}


def test_skins_as_exporters_write_them_are_posed(tmp_path):
    """Skinned files that three.js draws and the first version of the skinning refused (found by a
    review): vertices whose weights are all 0 (common in exported characters: three.js binds
    such a vertex wholly to its first joint; here joint 0, at the origin unturned, so the bar
    draws straight, as the reference posed by hand); JOINTS_0 stored as floats or unsigned ints
    (draw the L, as the bent reference); and a buffer file in a sibling folder inside --meshes
    (``../buffers/bent.bin``, which the loader reads: it was refused as outside the mesh's folder)."""
    turn = [0, 0, S, S]

    def zero_weights(doc, attributes):  # an accessor without bufferView holds zeros (glTF)
        del doc["accessors"][attributes["WEIGHTS_0"]]["bufferView"]

    folder = tmp_path / "m" / "bar"
    folder.mkdir(parents=True)
    (tmp_path / "m" / "buffers").mkdir()
    _reference((BENT, [0, 0, 0])).write(folder / "ref_bent.gltf")
    _reference((BAR, [0, 0, 0])).write(folder / "ref_straight.gltf")
    _skinned_bar(turn, edit=zero_weights).write(folder / "unweighted.gltf")
    for name, ctype, dtype in (("float_joints", 5126, np.float32), ("uint_joints", 5125, np.uint32)):
        d = _skinned_bar(turn)
        joints = d.accessor(d.view(np.array([[0, 1, 0, 0]] * 12, dtype).tobytes()), ctype, 12, "VEC4")
        d.doc["meshes"][0]["primitives"][0]["attributes"]["JOINTS_0"] = joints
        d.write(folder / f"{name}.gltf")
    _skinned_bar(turn).write(folder / "sibling_bin.gltf", bin_file="../buffers/bent.bin")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == [] and index_of(out)["warnings"] == []
    objects = _objects(out)
    for name, reference in (("unweighted", "ref_straight"), ("float_joints", "ref_bent"), ("uint_joints", "ref_bent"),
                            ("sibling_bin", "ref_bent")):
        np.testing.assert_array_equal(objects[name]["masks"], objects[reference]["masks"], err_msg=name)
        np.testing.assert_array_equal(objects[name]["images"], objects[reference]["images"], err_msg=name)
