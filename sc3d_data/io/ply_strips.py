"""PLY surfaces stored as triangle strips (``element tristrips``), read as triangles.

The Stanford and Cyberware scans (``igea.ply`` and its kin) store their surface not as ``element
face`` but as ``element tristrips``: one or more lists of vertex indices, each holding strips
separated by ``-1``. trimesh's PLY reader (5.x) reads only ``face``, so such a file came out as a
point cloud and failed "empty mesh (no triangles)". It keeps the elements it parsed in the
geometry's ``metadata["_ply_raw"]``; :func:`strips_as_faces` turns the strips found there into
triangles as the strip convention defines them: strip ``s`` makes the triangles ``(s[i], s[i+1],
s[i+2])`` for even ``i`` and ``(s[i+1], s[i], s[i+2])`` for odd ``i`` (every triangle wound as the
first), and the repeated indices that join strips make triangles of no area, which the renderer
leaves out (``io.meshes.validate_triangles``).

A file may hold both elements (a ``face`` element beside its ``tristrips``): trimesh then reads
the faces alone and the strips' triangles were dropped without a word. They are drawn too, as a
second geometry of the same vertices at the same place, coloured or textured as the faces'
geometry where its colours or texture coordinates are per vertex (face colours belong to the
``face`` rows alone: the strips' triangles are then drawn in the default colour, as the
triangles of a file without colours).
"""
from __future__ import annotations

import numpy as np

__all__ = ["strip_triangles", "strips_as_faces"]


def strip_triangles(indices: np.ndarray) -> np.ndarray:
    """``[m, 3]`` int64 triangles of the strips in ``indices`` (1-D ints; a negative index ends
    a strip), in the order and winding of the module doc."""
    indices = np.asarray(indices, dtype=np.int64).ravel()
    triangles = []
    for strip in np.split(indices, np.flatnonzero(indices < 0)):
        strip = strip[strip >= 0]
        if len(strip) < 3:
            continue
        tri = np.stack([strip[:-2], strip[1:-1], strip[2:]], axis=1)
        tri[1::2, :2] = tri[1::2, 1::-1]  # odd triangles: first two corners swapped
        triangles.append(tri)
    return np.concatenate(triangles) if triangles else np.zeros((0, 3), dtype=np.int64)


def _strip_rows(data) -> list[np.ndarray]:
    """The index lists of a parsed ``tristrips`` element (trimesh: a dict of property arrays for
    ASCII files, a structured array with ``(count, list)`` fields for binary ones)."""
    if isinstance(data, dict):
        values = data.get("vertex_indices", next(iter(data.values()), None))
        rows = [] if values is None else list(values)
    elif isinstance(data, np.ndarray) and data.dtype.names:
        field = data["vertex_indices"] if "vertex_indices" in data.dtype.names else data[data.dtype.names[0]]
        rows = list(field["f1"] if field.dtype.names else field)
    else:
        rows = []
    return [np.asarray(row, dtype=np.int64).ravel() for row in rows]


def strips_as_faces(scene) -> None:
    """Replace each point cloud of ``scene`` (loaded by trimesh from a PLY) whose file gave it
    triangle strips by the mesh of those triangles (its vertices and vertex colours kept); where
    the file also has faces, add the strips' triangles as a geometry beside the faces' (module doc)."""
    import trimesh

    for name, geometry in list(scene.geometry.items()):
        raw = getattr(geometry, "metadata", {}).get("_ply_raw", {})
        if "tristrips" not in raw or not isinstance(geometry, (trimesh.PointCloud, trimesh.Trimesh)):
            continue
        rows = _strip_rows(raw["tristrips"].get("data"))
        faces = strip_triangles(np.concatenate([np.append(r, -1) for r in rows])) if rows else np.zeros((0, 3))
        if isinstance(geometry, trimesh.Trimesh):
            if len(faces):
                _add_beside(scene, name, trimesh.Trimesh(
                    vertices=geometry.vertices, faces=faces, process=False,
                    visual=geometry.visual.copy() if geometry.visual.kind in ("vertex", "texture") else None))
            continue
        colours = geometry.colors if len(geometry.colors) == len(geometry.vertices) else None
        scene.geometry[name] = trimesh.Trimesh(vertices=geometry.vertices, faces=faces, vertex_colors=colours,
                                               process=False)


def _add_beside(scene, name: str, mesh) -> None:
    """Draw ``mesh`` wherever ``scene`` draws its geometry ``name`` (at each node's transform)."""
    for node in list(scene.graph.nodes_geometry):
        transform, drawn = scene.graph[node]
        if drawn == name:
            scene.add_geometry(mesh, geom_name=f"{name} tristrips", transform=transform)
