"""Skinned glTF meshes posed by their joints, as glTF 2.0 and every viewer draw them.

trimesh's glTF loader (``trimesh.exchange.gltf``, 5.x) reads no ``skin``: a node with both ``mesh``
and ``skin`` (a character from Blender, Mixamo or Sketchfab) was drawn and voxelized in its bind
pose, with the node's own transform applied, exit 0 and no warning. glTF says a skinned vertex
is ``v' = sum_i w_i (W(joint_i) @ IBM_i) @ v`` (``W``: the joint node's world matrix; ``IBM``: its
inverse bind matrix, the identity when the skin has none; ``JOINTS_n``/``WEIGHTS_n`` per vertex)
and the skinned node's own transform, and its parents', do not apply.

The decision: the skin is applied in the document the loader is given
(``sc3d_data.io.gltf_loader_doc``), not to the loaded scene, so that the loader, the renderer and
the voxelizer see one geometry. :func:`apply_skins` gives each skinned node of the drawn scene a
copy of its mesh whose triangle primitives' POSITION are the posed vertices in world space
(computed in float64, stored as float32 in a new buffer, a base64 data URI, which the loader
reads in a .gltf and a .glb alike), drawn by a new root node of the scene with no transform; the
skinned node keeps its transform and children but loses ``mesh`` and ``skin`` (its children stay
where they were; the original mesh is left as it is for any other node that draws it unskinned).
The copy has no NORMAL or TANGENT (bind-pose ones; shading uses face normals). Weights are
divided by their sum per vertex, as viewers do, and a vertex with none (all 0, common in exported
characters) is bound to its first joint, as three.js binds it; joint indices stored as floats or
unsigned ints (some exporters' types) are read where they are whole numbers; a joint index out of
range is judged only where its weight is not 0 (it moves nothing otherwise). A buffer file is read
as the loader reads it (``resolver``: inside the dataset folder).

Where a skin cannot be applied (``JOINTS_n`` without ``WEIGHTS_n`` or none at all, a sparse
accessor among these, a component type or element type glTF does not allow for them, a joint
index out of range, weights that are not finite or sum below 0, a buffer that cannot be read
inside the dataset folder, a Draco-compressed primitive, whose data is in its bitstream)
:func:`skin_problems` names it, one phrase per node, and the file is refused
(``sc3d_data.io.gltf_check``). Primitives that are not triangles (points, lines) are not drawn and
are left as they are. A POSITION that is sparse is refused by ``gltf_check`` already.
"""
from __future__ import annotations

import copy
import struct
from pathlib import Path

import numpy as np

from sc3d_data.io.gltf_buffers import AccessorError, Buffers, FloatBuffer, read_accessor

__all__ = ["apply_skins", "skin_problems", "skinned_nodes"]

#: glTF's allowed ``(componentType, normalized)`` for JOINTS_n and WEIGHTS_n
_JOINT_TYPES = {(5121, False), (5123, False), (5125, False), (5126, False)}  # + what exporters write: whole
# numbers as unsigned ints or floats
_WEIGHT_TYPES = {(5126, False), (5121, True), (5123, True)}
_TRIANGLE_MODES = (4, 5)
_CHUNK = 1 << 16  # vertices posed at once: [chunk, K, 4, 4] float64 matrices


class SkinError(ValueError):
    """A skin that cannot be applied; the message is the reason."""


def skinned_nodes(doc: dict, drawn_nodes: list[int]) -> list[int]:
    """The nodes of ``drawn_nodes`` (indices of nodes of ``doc`` reachable from the drawn scene)
    that have both a ``mesh`` and a ``skin``, in order."""
    nodes = doc.get("nodes", [])
    return [i for i in drawn_nodes if isinstance(nodes[i], dict) and "mesh" in nodes[i] and "skin" in nodes[i]]


def _quaternion(q) -> np.ndarray:
    """``[4, 4]`` rotation of glTF quaternion ``q`` (x, y, z, w), normalized as trimesh does
    (the identity for one of length 0)."""
    x, y, z, w = np.asarray(q, dtype=np.float64).reshape(4)
    n = x * x + y * y + z * z + w * w
    if n < 1e-12:
        return np.eye(4)
    s = 2.0 / n
    return np.array([[1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w), 0],
                     [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w), 0],
                     [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y), 0], [0, 0, 0, 1]])


def local_matrix(node: dict) -> np.ndarray:
    """``[4, 4]`` float64: node's transform to its parent's frame, ``matrix`` (column-major in the
    JSON) @ T @ R @ S, as the loader composes them (glTF allows one or the other)."""
    m = np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T if "matrix" in node else np.eye(4)
    if "translation" in node:
        t = np.eye(4)
        t[:3, 3] = np.asarray(node["translation"], dtype=np.float64).reshape(3)
        m = m @ t
    if "rotation" in node:
        m = m @ _quaternion(node["rotation"])
    if "scale" in node:
        m = m @ np.diag([*np.asarray(node["scale"], dtype=np.float64).reshape(3), 1.0])
    return m


def world_matrices(doc: dict) -> list[np.ndarray]:
    """``[4, 4]`` float64 per node of ``doc``: its transform to the scene's frame (the product of
    its own and its parents' local matrices). Raises ``SkinError`` where the hierarchy loops."""
    nodes = doc.get("nodes", [])
    parent: dict[int, int] = {}
    for i, node in enumerate(nodes):
        for c in node.get("children", []):
            parent.setdefault(c, i)
    world: list[np.ndarray | None] = [None] * len(nodes)
    for i in range(len(nodes)):
        chain, j = [], i
        while j is not None and world[j] is None:
            if j in chain:
                raise SkinError(f"node {j} is its own ancestor")
            chain.append(j)
            j = parent.get(j)
        m = np.eye(4) if j is None else world[j]
        for k in reversed(chain):
            m = world[k] = m @ local_matrix(nodes[k])
    return world


def joint_matrices(doc: dict, buffers: Buffers, s: int, world: list[np.ndarray]) -> np.ndarray:
    """``[joints, 4, 4]`` float64: ``W(joint_i) @ IBM_i`` of skin ``s`` (scene frame <- bind frame)."""
    skin = doc["skins"][s]
    joints = skin.get("joints")
    if not isinstance(joints, list) or not joints:
        raise SkinError("it names no joints")
    if not all(isinstance(j, int) and 0 <= j < len(world) for j in joints):
        raise SkinError(f"its joints {joints[:8]} name nodes the file lacks ({len(world)} nodes)")
    ibm = np.broadcast_to(np.eye(4), (len(joints), 4, 4))
    if (a := skin.get("inverseBindMatrices")) is not None:
        acc = doc["accessors"][a]
        if acc.get("type") != "MAT4" or acc.get("componentType") != 5126:
            raise SkinError(f"accessor {a} (inverseBindMatrices) is {acc.get('type')} of componentType "
                            f"{acc.get('componentType')}, not MAT4 of floats")
        if acc["count"] < len(joints):
            raise SkinError(f"accessor {a} (inverseBindMatrices) holds {acc['count']} matrices for "
                            f"{len(joints)} joints")
        ibm = read_accessor(doc, buffers, a, "inverseBindMatrices")[:len(joints)].reshape(-1, 4, 4).transpose(0, 2, 1)
    return np.stack([world[j] for j in joints]) @ ibm


def _more(bad: np.ndarray) -> str:
    return f" (and {bad.size - 1:,} more)" if bad.size > 1 else ""


def skin_primitive(doc: dict, buffers: Buffers, prim: dict, joints: np.ndarray, where: str) -> np.ndarray:
    """``[vertices, 3]`` float64: the POSITION of primitive ``prim`` (``where`` names it) posed by
    the joint matrices ``joints [J, 4, 4]``, in the scene's frame; weights divided by their sum."""
    attributes = prim.get("attributes", {})
    if isinstance(prim.get("extensions"), dict) and "KHR_draco_mesh_compression" in prim["extensions"]:
        raise SkinError(f"{where} is Draco-compressed, and skins are applied to accessors' data (decompress the "
                        "file first, e.g. with gltf-transform copy)")
    sets = sorted({int(k.split("_")[1]) for k in attributes if k.startswith(("JOINTS_", "WEIGHTS_"))
                   and k.split("_")[1].isdigit()})
    if not sets:
        raise SkinError(f"{where} has no JOINTS_0 and WEIGHTS_0")
    positions = read_accessor(doc, buffers, attributes["POSITION"], "POSITION")
    indices, weights = [], []
    for n in sets:
        for role, allowed in ((f"JOINTS_{n}", _JOINT_TYPES), (f"WEIGHTS_{n}", _WEIGHT_TYPES)):
            if role not in attributes:
                raise SkinError(f"{where} has {'WEIGHTS' if role[0] == 'J' else 'JOINTS'}_{n} but no {role}")
            a = attributes[role]
            acc = doc["accessors"][a]
            c, norm = acc.get("componentType"), acc.get("normalized") is True
            if (c, norm) not in allowed or acc.get("type") != "VEC4":
                raise SkinError(f"accessor {a} ({role} of {where}) is {acc.get('type')} of "
                                f"{'normalized ' * norm}componentType {c}, which glTF does not allow for {role[:-2]}")
            values = read_accessor(doc, buffers, a, role)
            if role[0] == "J" and c == 5126:
                if not (np.isfinite(values).all() and (values == np.round(values)).all() and (values >= 0).all()):
                    raise SkinError(f"accessor {a} ({role} of {where}) holds floats that are no joint indices")
                values = values.astype(np.int64)
            if len(values) != len(positions):
                raise SkinError(f"accessor {a} ({role} of {where}) has {len(values)} elements for "
                                f"{len(positions)} vertices")
            (indices if role[0] == "J" else weights).append(values)
    idx, w = np.concatenate(indices, axis=1), np.concatenate(weights, axis=1)
    total = w.sum(axis=1)
    if (bad := np.flatnonzero(~np.isfinite(total) | (total < 0))).size:
        raise SkinError(f"{where} vertex {bad[0]}{_more(bad)} has weights summing to {total[bad[0]]}")
    unweighted = total == 0  # bound wholly to its first joint, as three.js binds it
    w[unweighted, 0], total[unweighted] = 1.0, 1.0
    if (bad := np.flatnonzero(((idx >= len(joints)) & (w != 0)).any(axis=1))).size:
        raise SkinError(f"{where} vertex {bad[0]}{_more(bad)} names joint {idx[bad[0]].max()}, "
                        f"but the skin has {len(joints)}")
    w, idx = w / total[:, None], np.where(w != 0, idx, 0)
    out = np.empty((len(positions), 3))
    hom = np.concatenate([positions, np.ones((len(positions), 1))], axis=1)
    for s in range(0, len(positions), _CHUNK):
        m = np.einsum("nk,nkij->nij", w[s:s + _CHUNK], joints[idx[s:s + _CHUNK]])
        out[s:s + _CHUNK] = np.einsum("nij,nj->ni", m[:, :3], hom[s:s + _CHUNK])
    return out


def _pose(path: Path, doc: dict, binary: bytes | None, drawn_nodes: list[int], resolver) -> tuple[list[str], dict]:
    """``(problems, {node: {primitive: posed positions [n, 3] float64}})`` of the skinned nodes of
    ``drawn_nodes``; a node whose skin cannot be applied has a problem and no entry."""
    nodes, buffers, problems, posed, world = doc.get("nodes", []), Buffers(path, doc, binary, resolver), [], {}, None
    for i in skinned_nodes(doc, drawn_nodes):
        m, s = nodes[i]["mesh"], nodes[i]["skin"]
        try:
            world = world_matrices(doc) if world is None else world
            joints = joint_matrices(doc, buffers, s, world)
            posed[i] = {k: skin_primitive(doc, buffers, prim, joints, f"mesh {m} primitive {k}")
                        for k, prim in enumerate(doc["meshes"][m].get("primitives", []))
                        if prim.get("mode", 4) in _TRIANGLE_MODES and "POSITION" in prim.get("attributes", {})}
        except (SkinError, AccessorError) as e:
            problems.append(f"node {i}'s skin {s} cannot be applied: {e}")
        except (KeyError, IndexError, TypeError, ValueError, AttributeError, OSError, struct.error) as e:
            problems.append(f"node {i}'s skin {s} cannot be applied: it cannot be read ({type(e).__name__}: {e})")
    return problems, posed


def skin_problems(path: Path, doc: dict, binary: bytes | None, drawn_nodes: list[int], resolver=None) -> list[str]:
    """Why the skins of the skinned nodes of ``drawn_nodes`` cannot be applied (module doc), one
    phrase per node; ``binary`` is a GLB's BIN chunk (else None)."""
    return _pose(path, doc, binary, drawn_nodes, resolver)[0]


def apply_skins(path: Path, doc: dict, binary: bytes | None, drawn_nodes: list[int], resolver=None) -> None:
    """Pose the skinned nodes of ``drawn_nodes`` in ``doc`` (a copy the loader reads; changed in
    place): each gets a copy of its mesh with posed world-space POSITIONs, drawn by a new root
    node of the drawn scene with no transform; the node loses ``mesh`` and ``skin`` (module
    doc). Nodes whose skin cannot be applied (:func:`skin_problems`) are left as they are."""
    _, posed = _pose(path, doc, binary, drawn_nodes, resolver)
    if not posed:
        return
    floats = FloatBuffer(doc)
    roots = doc["scenes"][doc.get("scene", 0)].setdefault("nodes", [])
    for i, prims in posed.items():
        node = doc["nodes"][i]
        mesh = copy.deepcopy(doc["meshes"][node["mesh"]])
        for k, positions in prims.items():
            attributes = mesh["primitives"][k]["attributes"]
            attributes["POSITION"] = floats.accessor(positions, "VEC3")
            attributes.pop("NORMAL", None)
            attributes.pop("TANGENT", None)
        doc["meshes"].append(mesh)
        doc["nodes"].append({"mesh": len(doc["meshes"]) - 1, **({"name": f"{node['name']} (posed)"} if "name" in node
                                                               else {})})
        roots.append(len(doc["nodes"]) - 1)
        del node["mesh"], node["skin"]
    floats.close()
