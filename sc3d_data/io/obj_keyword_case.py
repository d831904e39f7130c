"""OBJ statements whose keyword is written in another case (``MTLLIB m.mtl``, ``USEMTL red``,
``V 0 0 1``, ``VT 0.5 0.5``, ``F 1 2 3``).

The OBJ format's keywords are lower case, and the widely used readers match them so: trimesh's
loader (``text.find("mtllib")``, ``"\\nusemtl "``, ``"\\nv "``), Blender's OBJ importer and
tinyobjloader (``strncmp(token, "mtllib", 6)``, ``token[0] == 'v'``) all pass such a line over as
an unknown statement. Read so, ``MTLLIB`` or ``USEMTL`` drew the object in the default grey
without a word, a ``VT`` lost its texture coordinates (the texture drawn as one texel), and a
``V`` or ``F`` lost vertices or faces (every later index off, or no triangles). sc3d reads the
file as those readers do, and says so: :func:`check_keyword_case` fails the object, naming the
line, where a statement of the geometry drawn (``v``, ``vt``, ``f``) is not read, and
returns one warning naming the keywords where a material statement (``mtllib``, ``usemtl``) is
not (the object renders, without the look those statements give it). Other statements in
another case (``O``, ``G``, ``S``; ``VN``, whose normals the renderer does not use: it shades by
face normals; ``L`` and ``P``, lines and points, which are not drawn) change nothing drawn and are
left alone: the file renders as with those statements in lower case. Material files are
another matter: trimesh reads their keywords in any case (``NEWMTL``, ``KD``, ``MAP_KD``), and
so do sc3d's checks (``io.mtl_text``).
"""
from __future__ import annotations

import re

from sc3d_data.io.line_ends import lf_lines

__all__ = ["check_keyword_case"]

#: keywords of statements that hold the geometry drawn, and of those that give it its materials
#: (``vn``, ``l``, ``p``: nothing drawn, module doc)
GEOMETRY_KEYS = ("v", "vt", "f")
MATERIAL_KEYS = ("mtllib", "usemtl")
#: a line whose first word holds an upper-case letter (the only lines that can be such a statement)
_UPPER_FIRST_WORD = re.compile(rb"\n[ \t]*([A-Za-z_]*[A-Z][A-Za-z_]*)[ \t]")
_UPPER = bytes(range(ord("A"), ord("Z") + 1))


def _other_case(data: bytes) -> dict[str, tuple[int, str]]:
    """``{keyword as written: (line number, line)}`` of the first statement of each keyword of
    :data:`GEOMETRY_KEYS` or :data:`MATERIAL_KEYS` written in another case in OBJ ``data``. A
    file without an upper-case letter costs one ``bytes.translate``; else one regex over it."""
    if len(data.translate(None, _UPPER)) == len(data):
        return {}
    text = b"\n" + lf_lines(data)
    found = {}
    for match in _UPPER_FIRST_WORD.finditer(text):
        word = match.group(1).decode("ascii")
        if word.lower() in GEOMETRY_KEYS + MATERIAL_KEYS and word not in found:
            start, end = match.start() + 1, text.find(b"\n", match.start() + 1)
            line = text[start:len(text) if end == -1 else end].strip().decode("utf-8", "replace")
            found[word] = (text.count(b"\n", 0, start), line)
    return found


def check_keyword_case(data: bytes) -> list[str]:
    """The warnings of OBJ ``data`` (the file's bytes) for its material statements written in
    another case (module doc); ``ValueError`` naming the line where a statement of its geometry
    is written so."""
    found = _other_case(data)
    for word, (number, line) in found.items():
        if word.lower() in GEOMETRY_KEYS:
            raise ValueError(f"line {number} ({line[:60]!r}) is a {word!r} statement, which OBJ readers (trimesh, "
                             f"Blender, tinyobjloader) do not read: OBJ keywords are lower case ({word.lower()!r}); "
                             "its geometry would be drawn without it")
    return [f"{', '.join(found)} (line {found[next(iter(found))][0]}) not read: OBJ keywords are lower case "
            f"({', '.join(w.lower() for w in found)}), as trimesh, Blender and tinyobjloader read them; "
            "rendered without the materials they name"] if found else []
