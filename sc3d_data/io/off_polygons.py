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

The loader also reads each face from one line: a file whose face lists run over several lines
(libigl's tutorial meshes ``inspired_mesh_quads_*.off`` write a corner per line), which
Geomview's OFF reader and libigl read as tokens, failed "empty mesh (no triangles)".
:func:`faces_one_per_line` writes such a file's faces one per line; ``io.meshes`` gives it to the
loader where the file as written yields no triangle.

The loader reads no colour of an OFF file (``COFF`` vertex colours, a colour after a face's
corners); ``io.off_colours`` gives it such a file as a PLY, and :func:`colour_notes` finds the
files that have colours and, where that module cannot read them, says so in a warning.
"""
from __future__ import annotations

import re
from pathlib import Path

__all__ = ["FACE_COLOURS_UNREAD", "POLYGON_LINE", "colour_notes", "faces_one_per_line", "loader_off_bytes", "off_lines"]

#: a line that starts with a whole number of five or more and five more whole numbers: a candidate
#: polygon's face line (the counts line has two more; a vertex line of whole numbers with a colour
#: may match too, and only costs the full reading)
POLYGON_LINE = re.compile(rb"(?m)^[ \t]*(?:[5-9]|[1-9]\d+)(?:[ \t]+\d+){5}(?![\d.eE])")
#: a header keyword of Geomview's points of other dimensions (``4OFF``: 4; ``nOFF``: the number
#: after it), whose first three coordinates the loader would draw as a 3D mesh
_DIMENSIONS = re.compile(rb"\A(?:\s|#[^\n]*\n)*([STCN]*(?:4n?|n)OFF)\b")
#: a counts line (vertices, faces and perhaps edges), and a file that starts with one
_COUNTS = re.compile(r"\d+\s+\d+(?:\s+\d+)?")
_COUNTS_FIRST = re.compile(rb"\A(?:\s|#[^\n]*\n)*\d+[ \t]+\d+(?:[ \t]+\d+)?[ \t]*(?:#[^\n]*)?\r?\n")
#: the warning phrase of per-face colours that are not read
FACE_COLOURS_UNREAD = "its per-face colours are not read: it renders in the default grey"
#: the header keyword (``OFF``, ``COFF``, ``NOFF``, ``STOFF``...) and what follows it on its line
_HEADER = re.compile(r"^([A-Z]*OFF)\s*(.*)$")


def off_lines(data: bytes) -> tuple[str, list[str]] | None:
    """``(header keyword, lines after it)`` of OFF ``data`` without comments and blank lines (the
    counts that may follow the keyword on its line first), or None for a file without a header."""
    lines = [line.split("#", 1)[0].strip() for line in data.decode("latin-1").splitlines()]
    lines = [line for line in lines if line]
    header = _HEADER.match(lines[0]) if lines else None
    if header is None:  # Geomview's keyword is optional: a file may start with its counts
        return ("OFF", lines) if lines and _COUNTS.fullmatch(lines[0]) else None
    return header.group(1), ([header.group(2)] if header.group(2) else []) + lines[1:]


def _fan(corners: list[str]) -> list[str]:
    """Face lines of a face's ``corners``: itself, or the fan of triangles of a polygon of five or more."""
    if len(corners) < 5:
        return [" ".join([str(len(corners)), *corners])]
    return [f"3 {corners[0]} {corners[i]} {corners[i + 1]}" for i in range(1, len(corners) - 1)]


def _text(keyword: str, vertices: list[str], faces: list[str]) -> bytes:
    return ("\n".join([keyword, f"{len(vertices)} {len(faces)} 0", *vertices, *faces]) + "\n").encode("latin-1")


def loader_off_bytes(path: Path) -> bytes | None:
    """The OFF text to give the loader in place of file ``path`` (module doc), or None to load the
    file as it is (no polygon of five or more corners, or a file the loader is left to judge); a
    file without a header keyword (optional in Geomview's OFF; trimesh's loader needs it) gets one.
    Raises ValueError for a file of points of another dimension than 3 (``4OFF``, ``nOFF``)."""
    data = Path(path).read_bytes()
    if (dimensions := _DIMENSIONS.match(data)) is not None:
        raise ValueError(f"its header {dimensions.group(1).decode()} says its points have "
                         f"{'4' if b'4' in dimensions.group(1) else 'N (given after it)'} coordinates: not a 3D mesh")
    headless = _COUNTS_FIRST.match(data) is not None
    if not (headless or POLYGON_LINE.search(data)) or (read := off_lines(data)) is None:
        return None
    keyword, body = read
    try:
        n_vertices, n_faces = (int(n) for n in body[0].split()[:2])
        faces, polygons = [], False
        for line in body[1 + n_vertices:1 + n_vertices + n_faces]:
            words = line.split()
            corners = words[1:1 + int(words[0])]
            polygons |= len(corners) >= 5
            faces += _fan(corners)
    except (ValueError, IndexError):
        return None  # malformed: the loader names it
    if not polygons and not headless:
        return None
    return _text(keyword, body[1:1 + n_vertices], faces)


def faces_one_per_line(path: Path) -> bytes | None:
    """The OFF text of file ``path`` with each face on one line, where its face lists run over
    several lines (module doc), or None (no such face, or a file the loader is left to judge)."""
    read = off_lines(Path(path).read_bytes())
    if read is None:
        return None
    keyword, body = read
    try:
        n_vertices, n_faces = (int(n) for n in body[0].split()[:2])
        rest, faces, split = body[1 + n_vertices:], [], False
        row = 0
        for _ in range(n_faces):
            words = rest[row].split()
            count = int(words[0])
            corners = words[1:1 + count]
            while len(corners) < count:  # the list goes on on the next lines (tokens, as Geomview reads it)
                row, split = row + 1, True
                corners += rest[row].split()[:count - len(corners)]
            faces += _fan(corners)  # what follows the last corner on its line (a colour) is dropped
            row += 1
    except (ValueError, IndexError):
        return None  # malformed: the loader names it
    return _text(keyword, body[1:1 + n_vertices], faces) if split else None


def colour_notes(path: Path) -> list[str]:
    """A warning phrase when OFF file ``path`` has colours the loader drops (module doc): a
    ``C`` in its header keyword (``COFF``: vertex colours) and a colour after its first vertex's
    coordinates, or a colour after the corners of its last face line (per-face colours, which
    files give every face or none, as a rule); reads the file's first and last 4 KiB only."""
    with open(path, "rb") as f:
        head = f.read(4096)
        f.seek(0, 2)
        f.seek(max(0, f.tell() - 4096))
        tail = f.read()
    read = off_lines(head)
    if read is not None and "C" in read[0][:-3] and len(read[1]) > 1 and len(read[1][1].split()) > 3:
        return [f"its vertex colours ({read[0]}) are not read: it renders in the default grey"]
    lines = [line.split(b"#", 1)[0].split() for line in tail.splitlines()]
    words = next((w for w in reversed(lines) if w), [])
    if words and words[0].isdigit() and len(words) > 1 + int(words[0]) >= 4:  # a face line with more than its corners
        return [FACE_COLOURS_UNREAD]
    return []
