"""What a glTF document's structure names that it does not hold, judged from the JSON before loading.

trimesh's glTF loader (5.x) follows the scene it draws (``scene``, else the first) from its root
nodes through their ``children`` and draws each node's ``mesh``. Where an index names nothing it
failed in Python's words, naming no cause: a child or root node past the node list ("IndexError:
list index out of range"), a document with bufferViews but no meshes or accessors (glTF-Validator's
``buffer_view/valid.gltf``, ``image/valid.glb``: "KeyError: 'accessors'"), a root array element
that is no object ("AttributeError: 'str' object has no attribute 'get'"); a node's ``mesh`` past
the meshes drew nothing for that node without a word, and a document with no meshes at all failed
"empty mesh (no triangles)". :func:`structure_problems` says each in one phrase: the root arrays
whose elements are not objects, a document without meshes (nothing to draw), and in the drawn scene
an index that names no scene, node or mesh, and a node transform holding a number that is not
finite (JSON's ``1e309`` reads as infinity) above a drawn mesh, which put it nowhere (the loader's
NumPy printed "RuntimeWarning: invalid value encountered in dot" naming no file). A non-finite
transform of a node that moves no drawn mesh changes nothing drawn and is left alone. A mesh without
a ``primitives`` list ("KeyError: 'primitives'"), and drawn meshes whose lists are all empty ("empty
mesh (no triangles)"), are named too.

``scenes: []`` is read as no ``scenes`` (the root nodes are drawn, :func:`scene_roots`), and so
is ``scene`` beside it: glTF requires a non-empty list, but what to draw is as clear as without one.
"""
from __future__ import annotations

import json
import math

__all__ = ["ROOT_ARRAYS", "scene_roots", "structure_problems"]

#: glTF 2.0's root arrays, each a list of objects
ROOT_ARRAYS = ("accessors", "animations", "buffers", "bufferViews", "cameras", "images", "materials", "meshes",
               "nodes", "samplers", "scenes", "skins", "textures")
#: a node's transform properties
TRANSFORMS = ("matrix", "translation", "rotation", "scale")


def parents(doc: dict) -> dict[int, list[int]]:
    """``{node: [the nodes that list it among their children]}``; a malformed ``children`` (no
    list, or no index) is passed over: :func:`structure_problems` names it."""
    found: dict[int, list[int]] = {}
    for i, node in enumerate(doc.get("nodes", [])):
        if isinstance(node, dict) and isinstance(node.get("children"), list):
            for c in node["children"]:
                if isinstance(c, int):
                    found.setdefault(c, []).append(i)
    return found


def scene_roots(doc: dict) -> list[int]:
    """The root nodes of the scene the loader draws: the nodes of ``scene`` (else scene 0); in a
    document without ``scenes`` (glTF calls it a library), every node that is no node's child, as
    Blender's importer draws it (``io.gltf_loader_doc`` gives the loader such a scene)."""
    nodes, scenes = doc.get("nodes", []), doc.get("scenes")
    if scenes:
        return list(scenes[doc.get("scene", 0)].get("nodes", []))
    children = parents(doc)
    return [i for i in range(len(nodes)) if i not in children]


def _count(n: int, what: str) -> str:
    """``"no nodes"``, ``"1 node"``, ``"3 nodes"``, ``"2 meshes"``."""
    return f"{n or 'no'} {what}{('es' if what.endswith('sh') else 's') * (n != 1)}"


def _names(index, n: int) -> bool:
    """Whether ``index`` is an index into a list of ``n`` (a bool or float is none; -1 is none,
    where Python would read the last)."""
    return isinstance(index, int) and not isinstance(index, bool) and 0 <= index < n


def _shown(value) -> str:
    """``value`` as the file writes it, cut at 20 characters."""
    text = json.dumps(value)
    return text if len(text) <= 20 else text[:17] + "..."


def _not_objects(doc: dict) -> list[str]:
    """The root arrays that are no list, or hold elements that are no object, one phrase each."""
    problems = []
    for key in (k for k in ROOT_ARRAYS if k in doc):
        if not isinstance(doc[key], list):
            problems.append(f"its {key} is {_shown(doc[key])}, not a list")
            continue
        bad = [i for i, e in enumerate(doc[key]) if not isinstance(e, dict)]
        if bad:
            listed = ", ".join(map(str, bad[:5])) + ", ..." * (len(bad) > 5)
            one = key[:-2] if key == "meshes" else key[:-1]  # "node 1 is", "nodes 1, 2 are"
            problems.append(f"{one if len(bad) == 1 else key} {listed} {'is' if len(bad) == 1 else 'are'} "
                            f"{_shown(doc[key][bad[0]])}"
                            f"{', ...' * (len(bad) > 1)}, not {'an object' if len(bad) == 1 else 'objects'}")
    return problems


def _drawn_roots(doc: dict, problems: list[str]) -> list[int]:
    """The root node indices of the scene the loader draws, as written (judged by the caller);
    where ``scene`` names no scene, or the scene's ``nodes`` is no list, a phrase is added to
    ``problems`` and there are none."""
    scenes = doc.get("scenes")
    if not scenes:
        return scene_roots(doc)
    chosen = doc.get("scene", 0)
    if not _names(chosen, len(scenes)):
        problems.append(f"it names scene {_shown(chosen)} to draw, but the file has {_count(len(scenes), 'scene')}")
        return []
    roots = scenes[chosen].get("nodes", [])
    if not isinstance(roots, list):
        problems.append(f"scene {chosen}'s nodes is {_shown(roots)}, not a list")
        return []
    n = len(doc.get("nodes", []))
    problems += [f"scene {chosen} names node {_shown(r)}, but the file has {_count(n, 'node')}"
                 for r in roots if not _names(r, n)]
    return [r for r in roots if _names(r, n)]


def _not_finite(node: dict) -> list[str]:
    """The transform properties of ``node`` that hold a number that is not finite (other malformed
    values, no list or no numbers, are left for the loader to report)."""
    return [key for key in TRANSFORMS if isinstance(node.get(key), list)
            and any(isinstance(x, float) and not math.isfinite(x) for x in node[key])]


def _graph_problems(doc: dict, drawn: set[int]) -> list[str]:
    """The drawn scene's indices that name nothing (scene, root node, child, mesh) and the non-finite
    transforms above its drawn meshes, one phrase each, in the order the nodes are reached; the meshes
    drawn are added to ``drawn``."""
    problems: list[str] = []
    nodes, n_meshes = doc.get("nodes", []), len(doc.get("meshes", []))
    queue = [(r, None) for r in reversed(_drawn_roots(doc, problems))]
    parent: dict[int, int | None] = {}
    while queue:
        i, above = queue.pop()
        if i in parent:
            continue
        parent[i] = above
        children = nodes[i].get("children", [])
        if not isinstance(children, list):
            problems.append(f"node {i}'s children is {_shown(children)}, not a list")
            children = []
        problems += [f"node {i} names child {_shown(c)}, but the file has {_count(len(nodes), 'node')}"
                     for c in children if not _names(c, len(nodes))]
        queue += [(c, i) for c in reversed(children) if _names(c, len(nodes))]
    placing: set[int] = set()  # the nodes whose transform moves a drawn mesh
    for i in parent:
        if "mesh" in nodes[i]:
            if not _names(nodes[i]["mesh"], n_meshes):
                problems.append(f"node {i} names mesh {_shown(nodes[i]['mesh'])}, but the file has "
                                f"{_count(n_meshes, 'mesh')}")
                continue
            drawn.add(nodes[i]["mesh"])
            j = i
            while j is not None and j not in placing:
                placing.add(j)
                j = parent[j]
    for i in sorted(placing):
        problems += [f"node {i}'s {key} holds a number that is not finite (JSON reads numbers past 1.8e308 as "
                     "infinity), so the mesh(es) it moves would be drawn nowhere"
                     for key in _not_finite(nodes[i])]
    return problems


def _primitive_problems(doc: dict, drawn: set[int]) -> list[str]:
    """The meshes without a list of primitives (the loader reads every mesh's: it stopped with
    "KeyError: 'primitives'"), and, where every drawn mesh's list is empty, those meshes: nothing is
    drawn (the loader's "empty mesh (no triangles)" named no cause). An empty mesh beside drawn
    ones draws nothing for its nodes and hides nothing: left alone."""
    meshes = doc.get("meshes", [])
    problems = [f"mesh {m} has no primitives list" if "primitives" not in mesh
                else f"mesh {m}'s primitives is {_shown(mesh['primitives'])}, not a list"
                for m, mesh in enumerate(meshes) if not isinstance(mesh.get("primitives"), list)]
    if not problems and drawn and not any(meshes[m]["primitives"] for m in drawn):
        problems += [f"mesh {m} has no primitives (its primitives list is empty), so there is nothing to draw"
                     for m in sorted(drawn)]
    return problems


def structure_problems(doc: dict) -> list[str]:
    """What glTF document ``doc``'s structure names that it does not hold (module doc), one phrase
    each: root arrays of other than objects first (nothing else is followed then), a document
    without meshes, then the drawn scene's indices and transforms, then meshes without primitives."""
    problems = _not_objects(doc)
    if problems:
        return problems
    if not doc.get("meshes"):
        problems.append("it holds no mesh (its meshes list is empty), so there is nothing to draw" if "meshes" in doc
                        else "it holds no mesh (the document has no meshes), so there is nothing to draw")
    drawn: set[int] = set()
    problems += _graph_problems(doc, drawn)
    return problems + _primitive_problems(doc, drawn)
