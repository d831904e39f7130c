"""PLY polygons with per-face texture coordinates, given to the loader as triangles.

MeshLab (vcglib's ``ExporterPLY``) writes a mesh's texture coordinates per face corner, as a list
on the face element after its corners: ``property list uchar float texcoord``, a row ``4 a b c d 8
ua va ub vb uc vc ud vd`` for a quad (its ASCII files write a face of any number of corners; its
binary ones triangles). trimesh's PLY reader (``trimesh.exchange.ply``, 5.x) reads such lists
only where every face has the same number of corners: faces of different sizes (quads beside
triangles) failed "cannot parse mesh file (ValueError: ...)", and so did a file of one face
("TypeError: object of type 'numpy.int64' has no len()"). :func:`textured_faces_as_triangles`
gives the loader such an ASCII file with each face of more than three corners split into the fan
``(0, k, k + 1)``, its corners' texture coordinates split with it and its other properties (a face
colour, MeshLab's ``texnumber``) repeated for each triangle; the face count in the header follows.
The fan is right for convex polygons, as the loader's own splitting of faces without texture
coordinates is (``docs/data.md``). The rows are read as trimesh reads them: one row per line. A
file of a single textured triangle, which has nothing to split, still fails in trimesh. The split
runs in Python: 0.6 s for 90,000 quads on a 2-core CPU box.
"""
from __future__ import annotations

import re

__all__ = ["textured_faces_as_triangles"]

#: the header line of a face list named ``texcoord``
TEXCOORD = re.compile(rb"(?m)^property[ \t]+list[ \t]+\w+[ \t]+\w+[ \t]+texcoord[ \t]*\r?$")
#: names of the corner list of a face
CORNERS = ("vertex_indices", "vertex_index")


def _elements(lines: list[str]) -> list[tuple[str, int, list[tuple[str, bool]]]] | None:
    """``[(name, count, [(property, is a list)])]`` of a PLY header's lines, or None where a line
    is not read (the loader then reads the file as it is)."""
    elements = []
    for line in lines:
        words = line.split()
        if words[:1] == ["element"]:
            if len(words) != 3 or not words[2].isdigit():
                return None
            elements.append((words[1], int(words[2]), []))
        elif words[:1] == ["property"]:
            if not elements or len(words) != (5 if words[1:2] == ["list"] else 3):
                return None
            elements[-1][2].append((words[-1], words[1] == "list"))
    return elements


def _fan(tokens: list[str], props: list[tuple[str, bool]], row: int) -> list[str] | None:
    """The rows of triangles of face row ``tokens`` (module doc), or None where it has three
    corners or fewer (kept as written). ``ValueError`` where the row does not hold its properties,
    or a face to split has not two texture coordinates per corner."""
    values, at = {}, 0
    try:
        for name, is_list in props:
            n = int(float(tokens[at])) if is_list else 0
            values[name] = tokens[at + 1:at + 1 + n] if is_list else tokens[at]
            at += 1 + n
    except (IndexError, ValueError):
        at = -1
    if at != len(tokens):
        raise ValueError(f"face {row:,}'s line does not hold the values its header names")
    corners = next(values[name] for name in CORNERS if name in values)
    uv = values["texcoord"]
    if len(corners) <= 3:
        return None
    if len(uv) != 2 * len(corners):
        raise ValueError(f"face {row:,} has {len(corners)} corners and {len(uv)} texture coordinates "
                         "(two per corner expected)")
    rows = []
    for k in range(1, len(corners) - 1):
        row_tokens = []
        for name, is_list in props:
            chosen = [corners[0], corners[k], corners[k + 1]] if name in CORNERS else \
                uv[0:2] + uv[2 * k:2 * k + 4] if name == "texcoord" else values[name]
            row_tokens += [str(len(chosen)), *chosen] if is_list else [chosen]
        rows.append(" ".join(row_tokens))
    return rows


def textured_faces_as_triangles(data: bytes, max_faces: int | None = None) -> bytes | None:
    """ASCII PLY ``data`` with its faces of more than three corners split into triangles where its
    face element has a ``texcoord`` list (module doc), or None where nothing is split (no such
    list, a binary file, every face a triangle, a header this module does not read). ``ValueError``
    naming the face where a face's row does not hold what its header names, or where the face
    element has more rows than ``max_faces`` (checked before any row is split: each face is at
    least a triangle)."""
    end = data.find(b"end_header")
    line_end = data.find(b"\n", end)
    if end == -1 or line_end == -1 or not TEXCOORD.search(data[:end]) \
            or re.search(rb"(?m)^format[ \t]+ascii\b", data[:end]) is None:
        return None
    header_lines = data[:line_end + 1].decode("latin-1").splitlines()
    elements = _elements(header_lines)
    face = next((e for e in elements or () if e[0] == "face"), None)
    if face is None or not any(n in CORNERS for n, is_list in face[2] if is_list) \
            or ("texcoord", True) not in face[2]:
        return None
    if max_faces and face[1] > max_faces:
        raise ValueError(f"{face[1]:,} faces, more than the limit of {max_faces:,} (--max-faces)")
    lines = data[line_end + 1:].decode("latin-1").splitlines()
    first = sum(count for name, count, _ in elements[:elements.index(face)])  # rows before the faces: one a line
    out, split = [], False
    for row, line in enumerate(lines[first:first + face[1]]):
        triangles = _fan(line.split(), face[2], row)
        split |= triangles is not None
        out += [line] if triangles is None else triangles
    if not split:
        return None
    header = [re.sub(r"^(\s*element\s+face\s+)\d+", rf"\g<1>{len(out)}", line) for line in header_lines]
    return "\n".join(header + lines[:first] + out + lines[first + face[1]:]).encode("latin-1") + b"\n"
