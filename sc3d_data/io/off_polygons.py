"""The OFF text the loader is given where the file has faces of five or more corners.

trimesh's OFF loader (``trimesh.exchange.off``, 5.x) splits quads and polygons into triangles
with ``triangulate_quads`` but hands it the face lines' indices as strings; for a polygon of five
or more corners beside faces of another size that fails ("cannot parse mesh file (TypeError: The
'out' kwarg is necessary when using the string multiply ufunc)"), so a good file (a hexagonal
prism; CAD exports) was refused. :func:`loader_off_bytes` gives the loader the file with each
such polygon written as the fan of ``n - 2`` triangles ``(0, i, i + 1)`` that trimesh makes of
polygons elsewhere (OBJ, PLY; a concave polygon is drawn as that fan, as documented). Comments
are left out, the header and vertex lines kept, a face line keeps its corners (per-face colours
after them, which the loader does not read either, are dropped).
"""
from __future__ import annotations

import re
from pathlib import Path

__all__ = ["loader_off_bytes"]

#: a line that starts with a whole number of five or more and five more whole numbers: a candidate
#: polygon's face line (the counts line has two more; a vertex line of whole numbers with a colour
#: may match too, and only costs the full reading)
_POLYGON = re.compile(rb"(?m)^[ \t]*(?:[5-9]|[1-9]\d+)(?:[ \t]+\d+){5}(?![\d.eE])")
#: the header keyword (``OFF``, ``COFF``, ``NOFF``, ``STOFF``...) and what follows it on its line
_HEADER = re.compile(r"^([A-Z]*OFF)\s*(.*)$")


def loader_off_bytes(path: Path) -> bytes | None:
    """The OFF text to give the loader in place of file ``path`` (module doc), or None to load the
    file as it is (no polygon of five or more corners, or a file the loader is left to judge)."""
    data = Path(path).read_bytes()
    if not _POLYGON.search(data):
        return None
    lines = [line.split("#", 1)[0].strip() for line in data.decode("latin-1").splitlines()]
    lines = [line for line in lines if line]
    header = _HEADER.match(lines[0]) if lines else None
    if header is None:
        return None
    body = ([header.group(2)] if header.group(2) else []) + lines[1:]
    try:
        n_vertices, n_faces = (int(n) for n in body[0].split()[:2])
        faces, polygons = [], False
        for line in body[1 + n_vertices:1 + n_vertices + n_faces]:
            words = line.split()
            corners = words[1:1 + int(words[0])]
            polygons |= len(corners) >= 5
            faces += ([f"3 {corners[0]} {corners[i]} {corners[i + 1]}" for i in range(1, len(corners) - 1)]
                      if len(corners) >= 5 else [" ".join([str(len(corners)), *corners])])
    except (ValueError, IndexError):
        return None  # malformed: the loader names it
    if not polygons:
        return None
    out = [header.group(1), f"{n_vertices} {len(faces)} 0", *body[1:1 + n_vertices], *faces]
    return ("\n".join(out) + "\n").encode("latin-1")
