"""The OBJ text the loader is given where the file as written would be read as something else.

trimesh's OBJ loader (``trimesh.exchange.obj``, 5.x) reads an index below 0 as counting back
from the end of the whole file's vertices (numpy's negative indexing), but the OBJ format counts
it back from the vertices read *so far* (``f -4 -3 -2 -1``: the last four before this line). A
file that writes its objects one after the other, each with its own vertices and relative faces
(``o A``, ``v`` x8, ``f -8 ...``, ``o B``, ``v`` x8, ``f -8 ...``), drew A's faces on B's
vertices. And it decodes a file that is not UTF-8 by a guess of its character set
(``charset-normalizer``) while the material files are served as Latin-1
(``io.texture_resolver``), so a material name in such bytes could match in neither. And it reads
a face's index 0 as the last vertex, where the format counts from 1: :func:`check_obj_indices`
refuses such a file (an exporter that wrote 0-based indices), naming the line.

:func:`loader_obj_bytes` returns the text to load instead of the file where either applies: the
relative indices of faces that come before later vertices (``v``, ``vt`` or ``vn``) rewritten as
the absolute ones they mean, and the text of a file that is not UTF-8 read as Latin-1 (each byte
one character, as its material files; a UTF-16 or UTF-32 file, with a byte-order mark or NUL bytes,
is left to the loader's own decoding), given to the loader as UTF-8. Two more things the loader
misreads are written as it can read them: a UTF-8 byte-order mark (which Windows editors put
first) is left out, since the loader took it for part of the first statement (a first ``v`` lost,
and every face index after it one off: "cannot parse"); and a comment after the data of a
vertex or element statement (``f 1 2 3 # back``, ``v 0 0 1 # tip``), which the loader cannot
parse, is cut off (comments after names, ``usemtl``, ``mtllib``, ``o``, ``g``, are left: a
``#`` may be part of a name). And the loader finds a statement only as ``KEYWORD `` (one space)
at the very start of a line ended by LF or CRLF: a statement written indented, or with a tab after
its keyword (``v\t1.00  0.00  -1.04``, as in Williams College's ``CornellBox-Original.obj``), was
not read (its vertices lost: every later index off by them, "cannot parse ... IndexError", or
wrong triangles), and a file whose lines end with CR alone (classic Mac OS) was read as no
triangles; such a file is given with its lines ended by LF, joined where continued by ``\\``, and
its statements written ``KEYWORD VALUE`` (:func:`plain_statements`). Otherwise None: the loader reads the file (the common case costs a
few ``bytes.find`` calls).
"""
from __future__ import annotations

import re

import numpy as np

from sc3d_data.io.line_ends import lf_lines, lone_cr
from sc3d_data.io.mtl_text import loader_reading

__all__ = ["absolute_indices", "check_obj_indices", "loader_obj_bytes", "plain_statements", "without_number_comments"]

#: a face statement holding a negative index (``f 1 -2``, ``f 1/-1 ...``)
_RELATIVE_FACE = re.compile(rb"(?m)^[ \t]*f[ \t][^\n#]*?(?<=[ \t/])-\d")
#: vertex statements whose counts relative indices refer to
_VERTEX_KEYS = ("v", "vt", "vn")
#: statements that hold numbers only, after which a ``#`` can only start a comment
_NUMBER_KEYS = frozenset({"v", "vt", "vn", "vp", "f", "l", "p"})
_NUMBER_KEYS_BYTES = frozenset(k.encode() for k in _NUMBER_KEYS)
UTF8_BOM = b"\xef\xbb\xbf"
#: a statement the loader does not find: indented, or a tab after its keyword
_LOOSE_STATEMENT = re.compile(rb"(?m)^(?:[ \t]+[^\s#]|[a-z_]+\t)")


def _is_any(values: np.ndarray, chars: bytes) -> np.ndarray:
    """``values [n] uint8`` -> ``[n] bool``: which are one of the bytes ``chars``."""
    return np.logical_or.reduce([values == c for c in chars])


def _loose_statements(data: bytes) -> bool:
    """Whether OBJ ``data`` holds a statement the loader would not find, or lines it would not
    split (module doc)."""
    return lone_cr(data) or ((b"\t" in data or b"\n " in data or data[:1] == b" ")
                              and _LOOSE_STATEMENT.search(data) is not None)


def plain_statements(data: bytes) -> bytes:
    """OBJ ``data`` as the loader reads it (module doc): lines ended by LF, a line continued by
    ``\\`` joined to the next (before any line is trimmed: the space before the ``\\`` stays),
    and each statement written ``KEYWORD VALUE`` without indentation; the value is kept as written
    (a material name may hold a tab)."""
    data = lf_lines(data).replace(b"\\\n", b"")
    lines = data.split(b"\n")
    for n, line in enumerate(lines):
        if line[:1] in (b" ", b"\t") or b"\t" in line[:8]:
            lines[n] = b" ".join(line.split(None, 1))
    return b"\n".join(lines)


def check_obj_indices(data: bytes) -> None:
    """``ValueError`` naming the line when a face of OBJ ``data`` (the file's bytes) names index 0.

    OBJ indices count from 1 (negative ones count back from the last vertex read); some
    exporters write 0-based indices, which trimesh reads without complaint as wrong triangles
    (0 becomes the last vertex). Such a file is refused, not rendered wrong. Vectorised (a
    70 MB OBJ in a fraction of its parse time): every token ``0`` between separators is a
    candidate, kept when its line is an ``f`` statement and it comes before any ``#``."""
    data = lf_lines(data) if lone_cr(data) else data  # lines ended by CR alone
    text = b"\n" + data + b"\n"  # padded: a byte each side
    b = np.frombuffer(text, dtype=np.uint8)
    zeros = np.flatnonzero(b == ord("0"))
    zeros = zeros[_is_any(b[zeros - 1], b" \t/") & _is_any(b[zeros + 1], b" \t/\r\n")]
    newlines = np.flatnonzero(b == ord("\n"))
    line_no = np.searchsorted(newlines, zeros)  # newlines before each candidate = its line number
    starts = newlines[line_no - 1] + 1
    maybe_face = (b[starts] == ord("f")) | _is_any(b[starts], b" \t")  # the exact test below
    for pos, start, number in zip(zeros[maybe_face], starts[maybe_face], line_no[maybe_face]):
        line = text[start:text.index(b"\n", pos)].strip()
        if line[:2] in (b"f ", b"f\t") and b"#" not in text[start:pos]:
            raise ValueError(f"line {number} ({line[:60].decode('utf-8', 'replace')!r}) names index 0, but OBJ "
                             "indices count from 1 (an exporter that writes 0-based indices?)")


def _later_vertices(data: bytes) -> bool:
    """Whether a vertex statement comes after the first face statement of OBJ ``data``."""
    first_face = 0 if data.startswith((b"f ", b"f\t")) else \
        min((i for i in (data.find(b"\nf "), data.find(b"\nf\t")) if i != -1), default=-1)
    return first_face != -1 and any(data.find(b"\n" + k + sep, first_face) != -1
                                    for k in (b"v", b"vt", b"vn") for sep in (b" ", b"\t"))


def absolute_indices(text: str) -> str:
    """OBJ ``text`` with every negative index of its face statements replaced by the absolute
    index it means (counted back from the ``v``/``vt``/``vn`` statements read before the face),
    lines continued by ``\\`` joined first (as the loader joins them). ``ValueError`` naming the
    line for an index that is no number, or that counts back past the first vertex."""
    counts = dict.fromkeys(_VERTEX_KEYS, 0)
    out = []
    for number, line in enumerate(text.replace("\r\n", "\n").replace("\\\n", "").split("\n"), 1):
        parts = line.split(None, 1)
        key = parts[0] if parts else ""
        if key in counts:
            counts[key] += 1
        elif key == "f" and "-" in line:
            body = line.partition("#")[0]
            corners = []
            for corner in body.split()[1:]:
                indices = []
                for k, p in zip(_VERTEX_KEYS, corner.split("/")):
                    if p.startswith("-"):
                        if not p[1:].isdigit() or counts[k] + int(p) < 0:
                            raise ValueError(f"line {number} ({line.strip()[:60]!r}): index {p} counts back past the "
                                             f"first {k} statement or is no number")
                        p = str(counts[k] + int(p) + 1)
                    indices.append(p)
                corners.append("/".join(indices))
            line = "f " + " ".join(corners)  # without its comment, which the loader cannot parse there
        out.append(line)
    return "\n".join(out)


def _comment_after_numbers(data: bytes) -> bool:
    """Whether a ``#`` of OBJ ``data`` comes after the data of a statement of numbers (one
    ``bytes.find`` per comment line)."""
    start = 0
    while (i := data.find(b"#", start)) != -1:
        words = data[data.rfind(b"\n", 0, i) + 1:i].split(None, 1)
        if words and words[0] in _NUMBER_KEYS_BYTES:
            return True
        if (start := data.find(b"\n", i) + 1) == 0:
            return False
    return False


def without_number_comments(text: str) -> str:
    """OBJ ``text`` with the comment cut off each statement of numbers that has one (module doc)."""
    lines = text.split("\n")
    for n, line in enumerate(lines):
        if "#" in line and (words := line.split(None, 1)) and words[0] in _NUMBER_KEYS:
            lines[n] = line.partition("#")[0].rstrip()
    return "\n".join(lines)


def loader_obj_bytes(data: bytes) -> bytes | None:
    """The text to give the loader in place of OBJ bytes ``data`` (module doc), UTF-8; None to load
    the file as it is (an ASCII file without relative indices or comments after numbers is not
    decoded)."""
    bom = data.startswith(UTF8_BOM)
    data = data[len(UTF8_BOM):] if bom else data
    if loose := _loose_statements(data):
        data = plain_statements(data)
    relative = _later_vertices(data) and _RELATIVE_FACE.search(data) is not None
    comments = _comment_after_numbers(data)
    as_is = data if bom or loose else None  # the bytes to read, or the file itself
    if not (relative or comments) and data.isascii():
        return as_is
    if data[:2] in (b"\xff\xfe", b"\xfe\xff") or b"\0" in data[:4096]:  # UTF-16/32: the loader's own decoding
        return None
    text, utf8 = loader_reading(data)  # io.mtl_text: UTF-8, else Latin-1 as the material files
    if not (relative or comments) and utf8:
        return as_is
    text = without_number_comments(text) if comments else text
    return (absolute_indices(text) if relative else text).encode("utf-8")
