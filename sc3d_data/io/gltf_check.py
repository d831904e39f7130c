"""The JSON document of a glTF/GLB file, and the geometry in it that trimesh would not read as written.

trimesh's glTF loader (``trimesh.exchange.gltf``, 5.x) builds triangles from primitives of mode
TRIANGLES (4) and TRIANGLE_STRIP (5) only: a TRIANGLE_FAN (6) primitive is skipped with a debug
log line, and an accessor's ``sparse`` substitution is never applied (the base values, or zeros,
are read). Either way the object would render and voxelize as other geometry than the file's,
with no warning. :func:`gltf_refusal` says why to refuse such a file before it is loaded, judging
from the JSON alone (for a GLB only its JSON chunk and its BIN chunk's 8-byte header are read,
never the binary data; an external buffer file is only stat'ed), except where the drawn scene has
skinned nodes, whose skins are computed to judge them, quantized attributes, which are read, or
Draco-compressed primitives, which are decoded (below).

Modes and sparse accessors are judged where the loader draws them: the meshes of the nodes
reachable from the scene it uses (``scene``, else the first; the root nodes without scenes), their
surface primitives' ``indices`` and the accessors of the attributes the renderer draws with
(POSITION, ``COLOR_0``, and ``TEXCOORD_0`` where the material has a base colour texture: a sparse
one drew the texture at (0, 0), the colours black).
Points and lines (modes 0-3) carry no surface and are not drawn, which is right: left alone.
A file that is no glTF document (JSON that does not parse, or is not an object; a GLB without its
header) is refused in one line saying so. A data layout the loader cannot read (a buffer without
its data, a bufferView or accessor naming what the file lacks or reaching beyond it, an unknown
component type; :mod:`sc3d_data.io.gltf_accessors`, which judges every buffer, bufferView and
accessor, as the loader reads every one) is refused in one line naming the buffer, bufferView
or accessor and its use. Extensions the loader cannot decode that the file requires (meshopt;
Draco without ``DracoPy``), and base colour textures of drawn meshes read through another ``texCoord`` than 0 or
moved by ``KHR_texture_transform``, which the loader ignores, are refused the same way
(:mod:`sc3d_data.io.gltf_features`), and so are skinned nodes of the drawn scene whose skin
cannot be applied (:mod:`sc3d_data.io.gltf_skins`, which reads their accessors' data), files
whose quantized attributes cannot be read (:mod:`sc3d_data.io.gltf_dequantize`) and drawn Draco
primitives whose data does not decode (:mod:`sc3d_data.io.gltf_draco`), and instanced nodes whose
instances cannot be read (:mod:`sc3d_data.io.gltf_instancing`). A document without meshes, with root
arrays of other than objects, or whose drawn scene names a scene, node or mesh it lacks or moves a drawn
mesh by a transform that is not finite is refused naming it (:mod:`sc3d_data.io.gltf_structure`: the
loader failed in Python's words, "IndexError: list index out of range", or drew nothing for the node).
A document malformed otherwise (its materials, animations) is left for the loader.
"""
from __future__ import annotations

import functools
import importlib.util
import json
import struct
from dataclasses import dataclass
from pathlib import Path

from sc3d_data.io.gltf_accessors import layout_problems
from sc3d_data.io.gltf_features import feature_problems, read_texcoord_sets, set_read, textured
from sc3d_data.io.gltf_instancing import instanced_nodes, instancing_problems
from sc3d_data.io.gltf_dequantize import dequantize_problems, quantized_accessors
from sc3d_data.io.gltf_draco import draco_primitives, draco_problems
from sc3d_data.io.gltf_skins import skin_problems, skinned_nodes
from sc3d_data.io.gltf_structure import parents, scene_roots, structure_problems

__all__ = ["GLTF_SUFFIXES", "GltfFile", "MALFORMED_SCENE", "SKIPPED_SURFACE_MODES", "drawn_meshes", "drawn_nodes", "gltf_refusal",
           "judge_gltf", "read_gltf"]

GLTF_SUFFIXES = (".gltf", ".glb")
#: primitive modes that draw a surface but which the loader skips: ``{mode: name}``
SKIPPED_SURFACE_MODES = {6: "TRIANGLE_FAN"}
#: the attributes whose ``sparse`` accessors are judged: those the renderer draws with (normals are
#: not: shading uses face normals; ``TEXCOORD_0`` where the primitive is textured)
SPARSE_JUDGED = ("POSITION", "TEXCOORD_0", "COLOR_0")
#: primitive modes the loader reads as triangles (the default mode is TRIANGLES)
TRIANGLE_MODES = (4, 5)
#: what following a malformed document's scenes and nodes raises (a node that is no object, an
#: index past the nodes, a ``children`` that is no list): ``drawn_nodes``/``drawn_meshes``' ``safe``
MALFORMED_SCENE = (KeyError, IndexError, TypeError, AttributeError, RecursionError)
_GLB_MAGIC, _JSON_CHUNK = b"glTF", b"JSON"


def read_gltf(path: Path, binary: bool = False) -> tuple[dict, bytes | None]:
    """``(JSON document, binary chunk)`` of glTF/GLB ``path``; the binary chunk (a GLB's ``BIN``,
    else None) is read only when ``binary``. Raises ``OSError``/``ValueError``/``struct.error``
    when the file is not a glTF document (the loader reports it)."""
    path = Path(path)
    if path.suffix.lower() != ".glb":
        return json.loads(path.read_bytes()), None
    with open(path, "rb") as f:
        header = f.read(20)
        if len(header) >= 8 and header[:4] == _GLB_MAGIC and struct.unpack_from("<I", header, 4)[0] == 1:
            raise ValueError(f"{path}: a binary glTF of version 1 (glTF 1.0's KHR_binary_glTF): sc3d reads glTF 2.0 "
                             "(convert the file, e.g. with Blender or gltf-pipeline)")
        if len(header) < 20 or header[:4] != _GLB_MAGIC or header[16:20] != _JSON_CHUNK:
            raise ValueError(f"{path}: not a GLB file (no glTF header and JSON chunk)")
        json_len = struct.unpack_from("<I", header, 12)[0]
        doc = json.loads(f.read(json_len))
        if not binary:
            return doc, None
        chunk = f.read(8)
        if len(chunk) < 8:
            return doc, None
        return doc, f.read(struct.unpack_from("<I", chunk, 0)[0])


@dataclass
class GltfFile:
    """A glTF/GLB file's JSON document and its binary chunk (:attr:`binary`), which is read on its
    first use and kept: the judges that read data (skins, quantized attributes, Draco, instancing)
    and the loader's copy of the document (``io.gltf_loader_doc``) share one read."""

    path: Path
    doc: dict
    #: primitives whose TEXCOORD_0 ``doc`` names another set's accessor than the file
    #: (``gltf_features.read_texcoord_sets``: the set their base colour texture reads)
    texcoord_sets_read: int = 0

    @functools.cached_property
    def binary(self) -> bytes | None:
        """A GLB's ``BIN`` chunk (None for a ``.gltf``, or a GLB without one)."""
        return read_gltf(self.path, binary=True)[1] if Path(self.path).suffix.lower() == ".glb" else None


def drawn_nodes(doc: dict, safe: bool = False) -> list[int]:
    """Indices of the nodes reachable from the root nodes the loader draws (:func:`scene_roots`),
    in the order they are found; ``safe``: none where the document's scenes or nodes cannot be
    followed (:data:`MALFORMED_SCENE`; else the error is raised)."""
    try:
        nodes, queue, seen, found = doc.get("nodes", []), scene_roots(doc), set(), []
        while queue:
            i = queue.pop()
            if i in seen:
                continue
            seen.add(i)
            found.append(i)
            queue.extend(nodes[i].get("children", []))
    except MALFORMED_SCENE:
        if safe:
            return []
        raise
    return found


def drawn_meshes(doc: dict, safe: bool = False) -> set[int]:
    """Indices of the meshes of the nodes reachable from the root nodes the loader draws
    (:func:`scene_roots`); ``safe``: none where the document's scenes or nodes cannot be followed
    (:data:`MALFORMED_SCENE`; else the error is raised)."""
    nodes = doc.get("nodes", [])
    try:
        return {nodes[i]["mesh"] for i in drawn_nodes(doc) if "mesh" in nodes[i]}
    except MALFORMED_SCENE:
        if safe:
            return set()
        raise


def shared_children(doc: dict) -> list[str]:
    """The nodes of the drawn scene that are children of several nodes, or a root of the scene and
    a child (glTF 2.0 allows one parent: the loader draws such a node once, where other readers,
    the draco project's among them, draw it once per parent), one phrase each. Only drawn parents
    count: one outside the scene (UniGLTF's ``tmpParent``, Kenney's kits) draws nothing."""
    parents_of, drawn = parents(doc), drawn_nodes(doc)
    roots, reached = (set(scene_roots(doc)) if doc.get("scenes") else set()), set(drawn)
    problems = []
    for i in drawn:
        of = [p for p in parents_of.get(i, []) if p in reached]
        if len(of) > 1 or (of and i in roots):
            whose = f"a root of the scene and a child of node {of[0]}" if i in roots else \
                f"a child of nodes {', '.join(map(str, of))}"
            problems.append(f"node {i} is {whose}, where glTF allows one parent; the loader would draw it once")
    return problems


def gltf_problems(doc: dict) -> list[str]:
    """What of glTF document ``doc``'s drawn geometry the loader would not read as written
    (module doc), one phrase each, in file order."""
    problems, sparse_seen = shared_children(doc), set()
    accessors, meshes, drawn = doc.get("accessors", []), doc.get("meshes", []), drawn_meshes(doc)
    unreached = sorted(set(range(len(doc.get("nodes", [])))) - set(drawn_nodes(doc))) if not doc.get("scenes") else []
    if unreached:  # without scenes every node that is no child is a root: the others hang in a cycle
        problems.append(f"it has no scene, and node(s) {', '.join(map(str, unreached[:5]))}{', ...' * (len(unreached) > 5)} "
                        "form a cycle of children (glTF's nodes form trees), which no root reaches")
    elif meshes and not drawn:  # the loader draws nothing: "empty mesh (no triangles)" said less
        problems.append(f"none of its {len(meshes)} mesh(es) is drawn by a node of the scene it draws (glTF draws a "
                        "mesh only through a node), so there is nothing to render")
    for m in sorted(drawn):
        for k, prim in enumerate(doc["meshes"][m].get("primitives", [])):
            mode = prim.get("mode", 4)
            if mode in SKIPPED_SURFACE_MODES:
                problems.append(f"mesh {m} primitive {k} is a {SKIPPED_SURFACE_MODES[mode]} (mode {mode}), "
                                "which the loader skips")
                continue
            if mode not in TRIANGLE_MODES:
                continue  # points and lines: no surface, not drawn
            attributes = prim.get("attributes", {})
            used = [("indices", prim.get("indices"))] + [(role, attributes.get(role)) for role in SPARSE_JUDGED
                                                         if role != "TEXCOORD_0" or textured(doc, prim)]
            for role, a in used:
                if a is not None and a not in sparse_seen and "sparse" in accessors[a]:
                    sparse_seen.add(a)
                    role = set_read(attributes, role, a)
                    problems.append(f"accessor {a} ({role} of mesh {m}) is sparse, which the loader does not apply")
    return problems


# The judges that read the file's data, each only where the drawn scene has what it judges; the
# binary chunk is read by the first that needs it (``GltfFile.binary``) and kept for the others.
def _skin_problems(gltf: GltfFile, resolver=None) -> list[str]:
    """The skinned nodes of the drawn scene whose skin cannot be applied (``gltf_skins``; buffer
    files read through ``resolver``)."""
    nodes = drawn_nodes(gltf.doc)
    return skin_problems(gltf.path, gltf.doc, gltf.binary, nodes, resolver) if skinned_nodes(gltf.doc, nodes) else []


def _instancing_problems(gltf: GltfFile, resolver=None) -> list[str]:
    """The instanced nodes of the drawn scene whose instances cannot be read (``gltf_instancing``)."""
    nodes = drawn_nodes(gltf.doc)
    return instancing_problems(gltf.path, gltf.doc, gltf.binary, nodes, resolver) \
        if instanced_nodes(gltf.doc, nodes) else []


def _dequantize_problems(gltf: GltfFile, resolver=None) -> list[str]:
    """The quantized accessors the loader's copy would store as floats (``gltf_dequantize``) that
    cannot be read."""
    return dequantize_problems(gltf.path, gltf.doc, gltf.binary, resolver) if quantized_accessors(gltf.doc) else []


def _draco_problems(gltf: GltfFile, resolver=None) -> list[str]:
    """The Draco primitives of the drawn meshes whose data does not decode (``gltf_draco``; where
    ``DracoPy`` is missing the file is refused by ``gltf_features`` already)."""
    drawn = drawn_meshes(gltf.doc)
    if not draco_primitives(gltf.doc, drawn) or importlib.util.find_spec("DracoPy") is None:
        return []
    return draco_problems(gltf.path, gltf.doc, gltf.binary, drawn, resolver)


def gltf_refusal(path: Path, shown: int = 3) -> str | None:
    """The one-line reason (naming ``path``; the first ``shown`` problems and how many more) to
    refuse glTF/GLB ``path`` because it is no glTF document (JSON that does not parse or is not an
    object, a GLB without its header), has a data layout the loader cannot read, or draws
    geometry the loader would not read as written (module doc), or None. Other files, and
    documents malformed otherwise, pass (the loader reports those)."""
    return judge_gltf(path, shown)[1]


def judge_gltf(path: Path, shown: int = 3, resolver=None) -> tuple[GltfFile | None, str | None]:
    """``(file, refusal)`` of ``path``: its :class:`GltfFile` (None for another format, or a
    file that could not be read as one) and :func:`gltf_refusal`'s line, so that the loader
    reads the document (and a GLB's binary chunk) once for the refusal and for what it applies
    before and after loading; ``resolver``
    (``io.texture_resolver.make_resolver``) reads the buffer files skins are computed from, as
    the loader reads them (None: beside ``path`` only)."""
    path = Path(path)
    if path.suffix.lower() not in GLTF_SUFFIXES:
        return None, None
    try:
        doc = read_gltf(path)[0]
    except json.JSONDecodeError as e:
        return None, f"{path}: not a glTF document: invalid JSON ({e.msg} at line {e.lineno} column {e.colno}); not read"
    except UnicodeDecodeError:
        return None, f"{path}: not a glTF document: its JSON is not UTF-8 text; not read"
    except ValueError as e:  # read_gltf: a GLB without its header and JSON chunk (names the file)
        return None, f"{e}; not read"
    except (OSError, struct.error, RecursionError):
        return None, None  # the loader reports it
    if not isinstance(doc, dict):
        return None, (f"{path}: not a glTF document: its JSON is {type(doc).__name__} {json.dumps(doc)[:20]}, "
                      "not an object; not read")
    version = doc.get("asset", {}).get("version") if isinstance(doc.get("asset"), dict) else None
    if isinstance(version, str) and version.split(".")[0].strip() not in ("2", ""):  # "2", "2.0", "2.1" are read
        return None, (f"{path}: a glTF {version} document: sc3d reads glTF 2.0 (convert the file, e.g. "
                      "with Blender or gltf-pipeline); not read")
    gltf = GltfFile(path, doc)
    try:
        gltf.texcoord_sets_read = read_texcoord_sets(doc)
    except (KeyError, IndexError, TypeError, AttributeError):
        pass  # a malformed document: the loader reports it
    problems = []  # each judge alone: what one cannot follow (a node that is no object) hides nothing of the other
    for judge, args in ((layout_problems, (path, doc)), (structure_problems, (doc,)), (gltf_problems, (doc,)),
                        (lambda d: feature_problems(d, drawn_meshes(d)), (doc,)), (_skin_problems, (gltf, resolver)),
                        (_dequantize_problems, (gltf, resolver)), (_draco_problems, (gltf, resolver)),
                        (_instancing_problems, (gltf, resolver))):
        try:
            problems += judge(*args)
        except (KeyError, IndexError, TypeError, AttributeError, ValueError, RecursionError, OSError,
                struct.error):
            pass  # a malformed document: the loader reports it
    if not problems:
        return gltf, None
    more = f"; and {len(problems) - shown} more like these" if len(problems) > shown else ""
    return gltf, f"{path}: {'; '.join(problems[:shown])}{more}; not read"
