"""Per-face colours of a PLY whose faces are not all triangles, one colour per triangle.

trimesh's PLY loader (``trimesh.exchange.ply``, 5.x) splits quads and polygons into triangles
(``trimesh.geometry.triangulate_quads``) but keeps the file's face colours as they are: one
colour per *source* face for more triangles than that. The renderer then had fewer colours than
triangle corners, drew half of a quad mesh black and read past the end of its colour buffer,
with no warning. :func:`per_triangle_face_colors` gives each triangle the colour of the face it
came from.

Which triangle comes from which face is ``triangulate_quads``' order: the triangles as they are,
then every quad's first half ``(0, 1, 2)``, then every quad's second half ``(2, 3, 0)``, then each
polygon of five or more corners as a fan of ``n - 2`` triangles, polygon by polygon (a file of
quads alone: first halves, then second halves). The face lists come from the raw PLY elements the
loader keeps in ``metadata["_ply_raw"]``. The result is checked, not trusted: every triangle's
corners must be corners of its face, else (another trimesh, another order) the mesh is refused.
"""
from __future__ import annotations

import numpy as np

__all__ = ["face_lists", "face_sources", "per_triangle_face_colors"]


def face_lists(raw: dict) -> list[np.ndarray] | None:
    """The vertex index list of each face of the raw PLY ``face`` element, or None."""
    face = raw.get("face", {}).get("data") if isinstance(raw, dict) else None
    if not isinstance(face, dict):
        return None
    for name in ("vertex_indices", "vertex_index"):
        if name in face:
            return [np.asarray(f).ravel() for f in face[name]]
    return None


def face_sources(lengths: np.ndarray) -> np.ndarray:
    """``[T]`` int: the source face of each triangle that ``triangulate_quads`` makes of faces
    with ``lengths [F]`` corners (module doc), for faces of 3 or more corners."""
    lengths = np.asarray(lengths, dtype=np.int64)
    faces = np.arange(len(lengths))
    tri, quad, poly = faces[lengths == 3], faces[lengths == 4], faces[lengths > 4]
    return np.concatenate([tri, quad, quad, np.repeat(poly, lengths[poly] - 2)]).astype(np.int64)


def _corners_of_their_faces(faces: np.ndarray, origin: np.ndarray, lists: list[np.ndarray]) -> bool:
    """Whether every corner of triangle ``faces[t]`` is a corner of face ``lists[origin[t]]``
    (faces padded with -1 to the longest, in chunks of triangles: memory stays small)."""
    width = max(len(f) for f in lists)
    padded = np.full((len(lists), width), -1, dtype=np.int64)
    for i, f in enumerate(lists):
        padded[i, :len(f)] = f
    step = max(1, 2**22 // (3 * width))
    return all((faces[lo:lo + step, :, None] == padded[origin[lo:lo + step]][:, None, :]).any(2).all()
               for lo in range(0, len(faces), step))


def per_triangle_face_colors(geometry, source: str) -> str | None:
    """Give ``geometry`` (a ``trimesh.Trimesh`` loaded from a PLY) one face colour per triangle
    where the file has fewer colours than triangles (module doc). Returns None when nothing was
    needed or it was done, else the one-line reason (naming ``source``) to refuse the mesh."""
    colors = geometry.visual.face_colors if geometry.visual.kind == "face" else None
    if colors is None or len(colors) == len(geometry.faces):
        return None
    lists = face_lists(geometry.metadata.get("_ply_raw"))
    if lists is None or len(lists) != len(colors) or any(len(f) < 3 for f in lists):
        return (f"{source}: {len(colors):,} face colours for {len(geometry.faces):,} triangles, and which triangle "
                "came from which face cannot be told; not read")
    origin = face_sources(np.array([len(f) for f in lists]))
    if len(origin) != len(geometry.faces) or not _corners_of_their_faces(np.asarray(geometry.faces), origin, lists):
        return (f"{source}: {len(colors):,} face colours for {len(geometry.faces):,} triangles, whose order is not the "
                "one this version of sc3d matches to the faces (another trimesh?); not read")
    geometry.visual.face_colors = np.asarray(colors)[origin]
    return None
