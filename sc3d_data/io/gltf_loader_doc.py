"""The glTF/GLB document the loader is given where the file as written would be read wrong.

trimesh's glTF loader (5.x) turns the ``COLOR_0`` of a primitive without a material into vertex
colours by casting its numbers to bytes, never scaling normalized ones: unsigned shorts wrap
(65535 -> 255, but 32768, i.e. 0.5, -> 0), as Blender's exporter has written vertex colours since
2.91 (colours that came from bytes, k x 257, happen to wrap right; float colours do not). With a
material it keeps them as stored, and the renderer scales them
(``render.renderer.material_vertex_colors``). :func:`loader_gltf_bytes` gives such primitives a
white matte material in a copy of the document.

A document without ``scenes`` (glTF calls it a library and leaves drawing it to the viewer) was
drawn empty: the loader reads its meshes but draws no node ("empty mesh (no triangles)"). The copy
draws its root nodes (``gltf_structure.scene_roots``), as Blender's importer does.

It also takes the first node with a ``camera`` for the scene's camera and skips the rest of that
node: a mesh on the same node was not drawn (glTF allows both on one node), and a child of it
failed the file ("No path from world->2!"). The copy's nodes name no camera (sc3d renders at its
own cameras), so such nodes are read as any other.

Skinned nodes of the drawn scene are posed by their joints in the copy (``sc3d_data.io.gltf_skins``:
the loader drew them in their bind pose, with the node's own transform, which glTF ignores), and
quantized positions and texture coordinates are stored as the floats they mean
(``sc3d_data.io.gltf_dequantize``: the loader read the integers unscaled), and nodes drawn through
``EXT_mesh_gpu_instancing`` get a child node per instance (``sc3d_data.io.gltf_instancing``: the
loader drew them once). A primitive whose base colour texture reads another texture coordinate
set than ``TEXCOORD_0`` has that set as ``TEXCOORD_0`` (``gltf_features.read_texcoord_sets``: the
loader maps every texture with ``TEXCOORD_0``). Materials whose texture a
``KHR_texture_transform`` moves, or whose sampler wraps other than REPEAT (``io.texture_wraps``),
and that have no name of their own (gltfpack's) get one (``gltf_features.material_name``), by
which the transform or wrap is applied to their geometries after loading.
"""
from __future__ import annotations

import copy
import json
import struct
from pathlib import Path

from sc3d_data.io.gltf_check import GltfFile, drawn_nodes
from sc3d_data.io.gltf_features import material_name, transform_names
from sc3d_data.io.texture_wraps import gltf_wraps
from sc3d_data.io.gltf_dequantize import dequantize, quantized_accessors
from sc3d_data.io.gltf_instancing import apply_instancing, instanced_nodes
from sc3d_data.io.gltf_skins import apply_skins, skinned_nodes
from sc3d_data.io.gltf_structure import scene_roots

__all__ = ["loader_gltf_bytes"]


def _ushort_colours_alone(doc: dict) -> list[dict]:
    """The primitives of ``doc`` without a material whose ``COLOR_0`` is stored as unsigned shorts
    (Blender's exporter since 2.91 writes them so)."""
    accessors = doc.get("accessors", [])
    return [p for mesh in doc.get("meshes", []) for p in mesh.get("primitives", [])
            if "material" not in p and isinstance(a := p.get("attributes", {}).get("COLOR_0"), int)
            and 0 <= a < len(accessors) and accessors[a].get("componentType") == 5123]


def _camera_nodes(doc: dict) -> list[dict]:
    """The nodes of ``doc`` that name a camera."""
    return [node for node in doc.get("nodes", []) if isinstance(node, dict) and "camera" in node]


def _json_after_bom(path) -> bool:
    """Whether the JSON of glTF/GLB ``path`` starts with a UTF-8 byte order mark: ``json.loads``
    of bytes (``gltf_check.read_gltf``) skips it, trimesh's loader decodes to text first and fails
    ("model.gltf: not found" for a .gltf), three.js reads past it. The loader gets the document."""
    with open(path, "rb") as f:
        head = f.read(23)
    start = 20 if Path(path).suffix.lower() == ".glb" else 0
    return head[start:start + 3] == b"\xef\xbb\xbf"


def loader_gltf_bytes(gltf: GltfFile, resolver=None) -> bytes | None:
    """The glTF/GLB to give the loader in place of file ``gltf`` (``io.gltf_check.GltfFile``:
    its path, JSON document and binary chunk, read once), or None for the file as
    it is. trimesh turns the vertex colours of a primitive without a material into bytes by
    casting, not scaling, so unsigned shorts wrap (65535 -> 255, 32768 -> 0: Blender's vertex
    paint in wrong colours); with a material it keeps them as stored, and the renderer scales
    them (``render.renderer.material_vertex_colors``). Such primitives get a white matte
    material (white x colour: the colours as they are), nodes lose their ``camera``, skinned
    nodes are posed and quantized attributes stored as floats (module doc; buffer files read
    through ``resolver``, as the loader reads them); the binary chunk is kept as it is."""
    path, doc = gltf.path, gltf.doc
    nodes = drawn_nodes(doc, safe=True)  # none for a malformed scene: the loader reports it
    skinned = skinned_nodes(doc, nodes)
    quantized = quantized_accessors(doc)
    sceneless = not doc.get("scenes") and bool(doc.get("nodes"))
    instanced = instanced_nodes(doc, nodes)
    try:
        found = set(transform_names(doc)) | set(gltf_wraps(doc))  # found by name after loading
        renamed = {i: material_name(doc, i) for i in sorted(found) if doc["materials"][i].get("name") != material_name(doc, i)}
    except (AttributeError, TypeError):  # malformed materials: the loader reports them
        renamed = {}
    if not (_ushort_colours_alone(doc) or _camera_nodes(doc) or skinned or quantized or sceneless or instanced
            or renamed or gltf.texcoord_sets_read or _json_after_bom(path)):
        return None
    doc = copy.deepcopy(doc)
    for i, name in renamed.items():  # apply_texture_transforms and apply_wraps find their geometries by these names
        doc["materials"][i]["name"] = name
    if sceneless:  # the loader draws no node of a document without scenes: its root nodes, as Blender
        doc.update(scenes=[{"nodes": scene_roots(doc)}], scene=0)
    binary = gltf.binary
    if instanced:
        apply_instancing(path, doc, binary, nodes, resolver)
    if skinned:
        apply_skins(path, doc, binary, nodes, resolver)
    if quantized:  # after the skins, which read the integers as they are stored
        dequantize(path, doc, binary, resolver)
    if _ushort_colours_alone(doc):
        doc.setdefault("materials", []).append({"name": "sc3d: white under vertex colours", "pbrMetallicRoughness":
                                                {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0}})
        for prim in _ushort_colours_alone(doc):
            prim["material"] = len(doc["materials"]) - 1
    for node in _camera_nodes(doc):
        del node["camera"]
    text = json.dumps(doc).encode()
    if Path(path).suffix.lower() != ".glb":
        return text
    text += b" " * (-len(text) % 4)
    body = struct.pack("<I4s", len(text), b"JSON") + text
    if binary is not None:
        binary += b"\0" * (-len(binary) % 4)
        body += struct.pack("<I4s", len(binary), b"BIN\0") + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body
