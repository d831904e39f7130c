"""Binary PLY files whose lists vary in length from row to row, given to the loader as ASCII PLY.

trimesh's binary PLY reader (``trimesh.exchange.ply``, 5.x) reads the length of each list property
from the element's first row and takes every row to have it: a binary PLY whose faces have
different numbers of corners (triangles beside quads, as Blender's and Rhinoceros' PLY exports
write meshes that are not triangulated) failed "PLY is unexpected length!". Its ASCII reader reads
each row's own length. :func:`ascii_ply` reads such a file's elements row by row and writes the
same file as ASCII PLY: the same elements, properties, comments and values (floats with the
digits that read back the same number: 9 significant digits for 32-bit, 17 for 64-bit). Files
whose first rows' lengths do hold for every row are left to the loader's binary reading (judged
from the first row of each element and the data's size: ~1 ms). The conversion runs in Python,
about 3 seconds per million rows (vertices and faces: 0.8 s for a 4 MB file of 100,000 vertices
and 200,000 faces on a 2-core CPU box, 2026-11-28).
"""
from __future__ import annotations

import io
import struct

__all__ = ["ascii_ply"]

#: PLY type names -> (struct format character, is a float)
_TYPES = {"char": ("b", False), "int8": ("b", False), "uchar": ("B", False), "uint8": ("B", False),
          "short": ("h", False), "int16": ("h", False), "ushort": ("H", False), "uint16": ("H", False),
          "int": ("i", False), "int32": ("i", False), "uint": ("I", False), "uint32": ("I", False),
          "float": ("f", True), "float32": ("f", True), "double": ("d", True), "float64": ("d", True)}


def _elements(lines: list[str]) -> list[tuple[str, int, list[tuple]]] | None:
    """``[(name, count, [(type, None) or (count type, item type)])]`` of a PLY header's lines, or
    None where the header is not one this module reads (an unknown type, a malformed line)."""
    elements = []
    for line in lines:
        words = line.split()
        if words[:1] == ["element"] and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[:2] == ["property", "list"] and len(words) == 5 and elements \
                and words[2] in _TYPES and words[3] in _TYPES:
            elements[-1][2].append((words[2], words[3]))
        elif words[:1] == ["property"] and len(words) == 3 and elements and words[1] in _TYPES:
            elements[-1][2].append((words[1], None))
        elif words[:1] == ["property"]:
            return None
    return elements


def _first_rows_fit(elements: list, body, order: str) -> bool:
    """Whether every element's rows have its first row's list lengths, as trimesh's binary
    reading takes them to (module doc): the rows make up ``body`` exactly, and every row's list
    counts, read at that spacing, equal the first row's (a quad, a triangle and a pentagon have
    the size of three quads)."""
    import numpy as np

    at = 0
    for _, count, props in elements:
        row, counts = 0, []
        for kind, items in props:
            fmt = order + _TYPES[kind][0]
            if items is None:
                row += struct.calcsize(fmt)
                continue
            if count == 0:
                break
            if at + row + struct.calcsize(fmt) > len(body):
                return False
            n = struct.unpack_from(fmt, body, at + row)[0]
            counts.append((row, fmt, n))
            row += struct.calcsize(fmt) + n * struct.calcsize(order + _TYPES[items][0])
        if count and row and at + count * row <= len(body):
            for offset, fmt, n in counts:  # every row's count at the spacing the first row gives
                seen = np.ndarray((count,), np.dtype(fmt), buffer=body, offset=at + offset, strides=(row,))
                if not (seen == n).all():
                    return False
        at += count * row
    return at == len(body)


def _text(value, kind: str) -> str:
    """``value`` of PLY type ``kind`` as text that reads back the same number."""
    if not _TYPES[kind][1]:
        return str(value)
    return format(value, ".9g" if _TYPES[kind][0] == "f" else ".17g")


def ascii_ply(header: bytes, body, max_faces: int | None = None) -> bytes | None:
    """The ASCII PLY of a binary PLY (``header``: its bytes up to and including the line
    ``end_header``; ``body``: the rest, bytes or a memoryview) whose list lengths vary from row to row (module doc), or
    None: an ASCII file, lists that the loader reads right, or a file this module cannot read
    (the loader then reports it). ``ValueError`` where the data ends before its rows do, a list's
    length is negative, or the ``face`` element has more rows than ``max_faces`` (checked before
    any row is converted: each face is at least a triangle)."""
    lines = header.decode("latin-1").replace("\r\n", "\n").split("\n")
    formats = [line.split() for line in lines if line.split()[:1] == ["format"]]
    if len(formats) != 1 or len(formats[0]) < 2 or formats[0][1] not in ("binary_little_endian", "binary_big_endian"):
        return None
    order = "<" if formats[0][1] == "binary_little_endian" else ">"
    elements = _elements(lines)
    if not elements or not any(items for _, _, props in elements for _, items in props) \
            or any(count and not props for _, count, props in elements) or _first_rows_fit(elements, body, order):
        return None  # (an element of rows without properties: nothing to convert row by row)
    faces = sum(count for name, count, _ in elements if name == "face")
    if max_faces and faces > max_faces:
        raise ValueError(f"{faces:,} faces, more than the limit of {max_faces:,} (--max-faces)")
    text = [("format ascii 1.0" if line.split()[:1] == ["format"] else line) for line in lines if line.strip()]
    out, at = io.StringIO(), 0  # rows written as they are read: no list of a million strings
    out.write("\n".join(text) + "\n")
    try:
        for name, count, props in elements:
            for _ in range(count):
                row = []
                for kind, items in props:
                    fmt = order + _TYPES[kind][0]
                    value = struct.unpack_from(fmt, body, at)[0]
                    at += struct.calcsize(fmt)
                    if items is None:
                        row.append(_text(value, kind))
                        continue
                    if value < 0:
                        raise ValueError(f"a list of its {name} rows has a negative length ({value})")
                    item = order + _TYPES[items][0]
                    values = struct.unpack_from(f"{order}{value}{item[1]}", body, at)
                    at += value * struct.calcsize(item)
                    row += [str(value)] + [_text(v, items) for v in values]
                out.write(" ".join(row) + "\n")
    except struct.error:
        raise ValueError(f"its binary data ends before its {sum(c for _, c, _ in elements):,} rows do "
                         f"({len(body):,} bytes)") from None
    return out.getvalue().encode("latin-1")

