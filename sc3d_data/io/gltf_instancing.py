"""glTF nodes that draw their mesh through ``EXT_mesh_gpu_instancing`` (Blender's "GPU Instances"
export option, gltfpack ``-mi``), drawn once per instance.

trimesh's glTF loader (5.x) reads no instancing: it draws such a node's mesh once, at the node,
where the file draws it once per instance, at the node's transform times the instance's
``TRANSLATION`` x ``ROTATION`` x ``SCALE`` (accessors with one row per instance; a missing one is
the identity). Such files were refused. In the copy of the document the loader is given
(``io.gltf_loader_doc``), :func:`apply_instancing` gives each instanced node of the drawn scene
one child node per instance that draws the mesh with that instance's translation, rotation and
scale (quantized ones read as the numbers they mean: ``io.gltf_buffers.read_accessor``); the
node keeps its own transform and children and loses its mesh and the extension. A node whose
instances cannot be read (an accessor that is sparse, of another type than the extension allows,
or cannot be read; counts that differ; a skinned node, which the extension does not define) is
named by :func:`instancing_problems`, and the file is refused (``io.gltf_check``).
"""
from __future__ import annotations

from pathlib import Path

from sc3d_data.io.gltf_buffers import AccessorError, Buffers, read_accessor

__all__ = ["INSTANCING", "apply_instancing", "instanced_nodes", "instancing_problems"]

INSTANCING = "EXT_mesh_gpu_instancing"
#: instance attribute -> (node property it becomes, components)
_ROLES = {"TRANSLATION": ("translation", 3), "ROTATION": ("rotation", 4), "SCALE": ("scale", 3)}


class InstancingError(ValueError):
    """Instances that cannot be read; the message is the reason."""


def instanced_nodes(doc: dict, drawn_nodes: list[int]) -> list[int]:
    """The nodes of ``drawn_nodes`` that draw a mesh through ``EXT_mesh_gpu_instancing``."""
    nodes = doc.get("nodes", [])
    return [i for i in drawn_nodes if "mesh" in nodes[i] and isinstance(nodes[i].get("extensions"), dict)
            and isinstance(nodes[i]["extensions"].get(INSTANCING), dict)]


def _instances(doc: dict, buffers: Buffers, i: int) -> list[dict]:
    """``[{"translation": [3], "rotation": [4], "scale": [3]}]`` (the attributes node ``i`` has),
    one per instance of node ``i``; ``InstancingError`` where they cannot be read."""
    node = doc["nodes"][i]
    if "skin" in node:
        raise InstancingError("it is also skinned, which EXT_mesh_gpu_instancing does not define")
    attributes = node["extensions"][INSTANCING].get("attributes", {})
    columns = {}
    for role, a in attributes.items() if isinstance(attributes, dict) else ():
        if role not in _ROLES:
            continue  # custom attributes (_ID, ...) place nothing
        key, n = _ROLES[role]
        try:
            values = read_accessor(doc, buffers, a, f"{role} of node {i}'s instances")
        except (AccessorError, KeyError, IndexError, TypeError, ValueError, OSError) as e:
            raise InstancingError(f"its {role} accessor cannot be read ({type(e).__name__}: {e})") from None
        if values.shape[1] != n or values.dtype.kind != "f":
            raise InstancingError(f"its {role} accessor holds {values.shape[1]}-component "
                                  f"{'integers' if values.dtype.kind != 'f' else 'numbers'}, not VEC{n} floats")
        columns[key] = values
    counts = {len(v) for v in columns.values()}
    if len(counts) > 1:
        raise InstancingError(f"its attributes hold different numbers of instances ({', '.join(map(str, sorted(counts)))})")
    count = counts.pop() if counts else 0
    return [{key: [float(x) for x in values[j]] for key, values in columns.items()} for j in range(count)]


def instancing_problems(path: Path, doc: dict, binary: bytes | None, drawn_nodes: list[int],
                        resolver=None) -> list[str]:
    """Why the instances of the instanced nodes of ``drawn_nodes`` cannot be read (module doc),
    one phrase per node; ``binary``: a GLB's BIN chunk, ``resolver``: the loader's."""
    buffers, problems = Buffers(path, doc, binary, resolver), []
    for i in instanced_nodes(doc, drawn_nodes):
        try:
            _instances(doc, buffers, i)
        except InstancingError as e:
            problems.append(f"node {i}'s EXT_mesh_gpu_instancing cannot be applied: {e}")
    return problems


def apply_instancing(path: Path, doc: dict, binary: bytes | None, drawn_nodes: list[int], resolver=None) -> None:
    """Draw each instanced node of ``drawn_nodes`` once per instance in ``doc`` (a copy the loader
    reads; changed in place), as the module doc says; nodes whose instances cannot be read
    (:func:`instancing_problems`) are left as they are."""
    buffers = Buffers(path, doc, binary, resolver)
    for i in instanced_nodes(doc, drawn_nodes):
        try:
            instances = _instances(doc, buffers, i)
        except InstancingError:
            continue
        node = doc["nodes"][i]
        first = len(doc["nodes"])
        doc["nodes"] += [{"mesh": node["mesh"], **instance} for instance in instances]
        node["children"] = list(node.get("children", [])) + list(range(first, len(doc["nodes"])))
        del node["mesh"]
        del node["extensions"][INSTANCING]
