"""The colours of an OFF file: the PLY text the loader is given in place of a coloured OFF.

trimesh's OFF loader (``trimesh.exchange.off``, 5.x) reads vertices and faces only: the vertex
colours of a ``COFF`` file (after each vertex's coordinates: MeshLab writes ``r g b a`` in whole
numbers 0-255, Geomview floats 0-1) and the colours written after a face's corners were dropped,
and such an object rendered in the default grey. Its PLY loader reads both, so
:func:`coloured_off_as_ply` writes a coloured OFF as an ASCII PLY with the same vertices (their
coordinate text as written), every face as the fan of triangles ``(0, i, i + 1)`` that the OFF
path draws (``io.off_polygons``), and the colours of the file on them.

Decisions (docs/data.md, "OFF"):

* a file's colours are whole numbers 0-255 unless one of them is written with a point or an
  exponent, or none is above 1: then they are floats 0-1 (Geomview's ``1 0 0`` is red, as
  MeshLab's ``255 0 0``); alpha is not read (the object is drawn opaque, as every format is);
* where a file has per-face colours they are drawn, over vertex colours it may also have (as
  Geomview does); faces of such a file without a colour of their own are drawn in the renderer's
  default grey (``UNCOLOURED``), as a file without colours;
* what is not read stays a warning (``off_polygons.colour_notes``): a face colour of one or two
  numbers (an index into Geomview's colour map, which no file carries), a header keyword with
  ``4`` or ``n`` (other dimensions), face lists over several lines. A file whose numbers or
  indices do not read is left to the loader, which names the problem.
"""
from __future__ import annotations

import re
from pathlib import Path

from sc3d_data.io.off_polygons import FACE_COLOURS_UNREAD, POLYGON_LINE, colour_notes, off_lines

__all__ = ["UNCOLOURED", "coloured_off_as_ply"]

#: a triangle's or quad's face line with more words after its corners (a colour), wherever it is in
#: the file (``colour_notes`` reads the last face only; polygons of five or more corners are read
#: in full where the file has one with more words than corners, :func:`_coloured_polygon`); a vertex line may match too,
#: and only costs the full reading
_COLOURED_FACE = re.compile(rb"(?m)^[ \t]*(?:3(?:[ \t]+\d+){3}|4(?:[ \t]+\d+){4})[ \t]+[-+.\d]")
#: the renderer's ``DEFAULT_GREY`` (0.3) in bytes: faces of a face-coloured file without a colour
UNCOLOURED = (77, 77, 77)


def _coloured_polygon(data: bytes) -> bool:
    """Whether OFF ``data`` has a line like a polygon's face line (``off_polygons.POLYGON_LINE``) with
    more words than its corners (a colour): only such lines are looked at, so a file of polygons
    without colours (read in full by ``off_polygons``) is not read in full a second time here
    (twice the load time)."""
    for match in POLYGON_LINE.finditer(data):
        end = data.find(b"\n", match.start())
        words = data[match.start():None if end < 0 else end].split(b"#", 1)[0].split()
        if len(words) > 1 + int(words[0]):
            return True
    return False


def _bytes(colours: list[list[str]]) -> list[tuple[int, int, int]]:
    """``colours`` (rows of 3 number words) as bytes 0-255 (module doc: whole numbers 0-255 unless
    written as floats or none is above 1). Raises ValueError on a word that is not a number."""
    values = [[float(w) for w in row] for row in colours]
    floats = any(c in w for row in colours for w in row for c in ".eE") or max(max(row) for row in values) <= 1
    scale = 255.0 if floats else 1.0
    return [tuple(min(255, max(0, round(v * scale))) for v in row) for row in values]


def _ply(vertices: list[str], vertex_colours, triangles: list[tuple[str, str, str]], face_colours) -> bytes:
    """An ASCII PLY of ``vertices`` (``"x y z"`` text), ``triangles`` and their colours (or None)."""
    head = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}", "property double x",
            "property double y", "property double z"]
    head += ["property uchar red", "property uchar green", "property uchar blue"] if vertex_colours else []
    head += [f"element face {len(triangles)}", "property list uchar int vertex_indices"]
    head += ["property uchar red", "property uchar green", "property uchar blue"] if face_colours else []
    rows = [v + ("" if not vertex_colours else " %d %d %d" % c) for v, c in zip(vertices, vertex_colours or vertices)]
    rows += ["3 " + " ".join(t) + ("" if not face_colours else " %d %d %d" % c)
             for t, c in zip(triangles, face_colours or triangles)]
    return ("\n".join(head + ["end_header"] + rows) + "\n").encode("ascii")


def coloured_off_as_ply(path: Path) -> tuple[bytes | None, list[str]]:
    """``(PLY text to load in place of OFF file path, warnings)``: ``(None, [])`` for a file
    without colours; ``(None, colour_notes)`` for colours this module does not read (module doc)."""
    notes, data = colour_notes(path), Path(path).read_bytes()
    read = off_lines(data) if notes or _COLOURED_FACE.search(data) or _coloured_polygon(data) else None
    if read is None or set(read[0][:-3]) - set("STCN"):
        return None, notes
    keyword, body = read
    try:
        n_vertices, n_faces = (int(n) for n in body[0].split()[:2])
        rows = [line.split() for line in body[1:1 + n_vertices]]
        if len(rows) < n_vertices or any(len(row) < 3 for row in rows):
            return None, notes
        vertices = [" ".join(str(float(w)) for w in row[:3]) for row in rows]
        start = 6 if "N" in keyword[:-3] else 3
        end = -2 if "ST" in keyword[:-3] else None
        vertex_colours = [row[start:end][:3] for row in rows] if "C" in keyword[:-3] else []
        triangles, face_colours = [], []
        for line in body[1 + n_vertices:1 + n_vertices + n_faces]:
            words = line.split()
            count = int(words[0])
            corners, after = words[1:1 + count], words[1 + count:]
            if len(after) in (1, 2):  # an index into Geomview's colour map
                return None, notes or [FACE_COLOURS_UNREAD]
            if len(corners) < count or any(not 0 <= int(c) < n_vertices for c in corners):
                return None, notes  # over several lines, an index the loader names
            fan = [(corners[0], corners[i], corners[i + 1]) for i in range(1, count - 1)]
            triangles += fan
            face_colours += [after[:3] or None] * len(fan)
        if any(face_colours):
            coloured = _bytes([c for c in face_colours if c])
            it = iter(coloured)
            return _ply(vertices, None, triangles, [next(it) if c else UNCOLOURED for c in face_colours]), []
        if vertex_colours and all(len(c) == 3 for c in vertex_colours):
            return _ply(vertices, _bytes(vertex_colours), triangles, None), []
    except (ValueError, IndexError):
        pass
    return None, notes
