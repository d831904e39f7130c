"""The PLY the loader is given where its header names vertex colours in words the loader does not read.

trimesh's PLY loader (``trimesh.exchange.ply``, 5.x) reads colours from the properties ``red``,
``green``, ``blue`` (and ``alpha``) only. The Stanford PLY tools' own examples, and scanners and
exporters that followed them, name them ``diffuse_red``, ``diffuse_green``, ``diffuse_blue``: such
an object was drawn in the default grey, exit 0. :func:`loader_ply_bytes` gives the loader the file
with those properties renamed in its header (the header is text; the data after ``end_header``,
text or binary, is kept byte for byte), where the header has no property of the plain names.

The loader also reads the header line by line up to LF: a header whose lines end with CR alone
(Rhinoceros 6's PLY export) was read as one line and the file failed "cannot decode the file as
text". Such a header is given LF line ends (and an ASCII file's data too; a binary file's data is
kept byte for byte, after the one line end that closes the header).

A binary file whose list properties vary in length from row to row (faces of 3 and 4 corners) is
given to the loader as ASCII PLY (``io.ply_binary_lists``): its binary reader assumes one length.
An ASCII file (or such a conversion) whose polygons have per-face texture coordinates (MeshLab's
``texcoord`` lists) is given to it with those polygons split into triangles (``io.ply_texcoords``).
A texture name holding MeshLab's ``<this>`` is given to it filled in (``io.ply_textures``).
"""
from __future__ import annotations

import mmap
import re
from pathlib import Path

from sc3d_data.io.ply_binary_lists import ascii_ply
from sc3d_data.io.ply_texcoords import textured_faces_as_triangles
from sc3d_data.io.ply_textures import this_named

__all__ = ["loader_ply_bytes"]

#: bytes read to find the header's end; a header longer than this is left to the loader
HEADER_BYTES = 1 << 16
#: a colour property named with the ``diffuse_`` prefix: ``property <type> diffuse_red``
_DIFFUSE = re.compile(rb"(?m)^(property[ \t]+\w+[ \t]+)diffuse_(red|green|blue|alpha)[ \t]*\r?$")


def _renamed(header: bytes) -> bytes | None:
    """``header`` (up to ``end_header``) with its ``diffuse_`` colour properties renamed, or None
    where it has none, or has the plain name beside them."""
    if b"diffuse_" not in header or not _DIFFUSE.search(header) or any(
            re.search(rb"(?m)^property[ \t]+\w+[ \t]+" + name + rb"[ \t]*\r?$", header)
            for name in (b"red", b"green", b"blue")):
        return None
    return _DIFFUSE.sub(rb"\1\2", header)


def loader_ply_bytes(path: Path, max_faces: int | None = None) -> bytes | None:
    """PLY ``path``'s bytes with its ``diffuse_``-prefixed colour properties renamed and a header
    of CR line ends given LF ones, a binary file whose lists vary in length as ASCII PLY, textured
    polygons as triangles, ``<this>`` in texture names filled in (module doc), or None to load the file as it is. ``ValueError`` where a
    binary file's data ends before its rows do, where one to convert or split has more faces than
    ``max_faces``, or where a textured polygon's row cannot be read."""
    with open(path, "rb") as f:
        head = f.read(HEADER_BYTES)
    text = _loader_text(path, head, max_faces)
    if b"texcoord" in head[:head.find(b"end_header")]:  # (all of the file read only for such a header)
        text = textured_faces_as_triangles(Path(path).read_bytes() if text is None else text, max_faces) or text
    return this_named(path, text)


def _loader_text(path: Path, head: bytes, max_faces: int | None) -> bytes | None:
    """:func:`loader_ply_bytes` but for textured polygons; ``head``: the file's first bytes."""
    end = head.find(b"end_header")
    if end == -1:
        return None
    header = head[:end]
    cr_only = b"\r" in header and b"\n" not in header
    if cr_only:
        header = header.replace(b"\r", b"\n")  # the same length: the data after the header keeps its place
    renamed = _renamed(header)
    lists = re.search(rb"(?m)^format[ \t]+binary", header) is not None and b"property list" in header
    if renamed is None and not cr_only and not lists:
        return None
    if renamed is None and not cr_only:  # lists alone: judged on the file mapped, not read (most are fine)
        line_end = head.find(b"\n", end)
        if line_end == -1:
            return None
        with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data, \
                memoryview(data) as view, view[line_end + 1:] as body:
            return ascii_ply(head[:line_end + 1], body, max_faces)
    header, rest = renamed if renamed is not None else header, Path(path).read_bytes()[end:]
    if cr_only:
        ascii_data = re.search(rb"(?m)^format[ \t]+ascii\b", header) is not None
        rest = rest.replace(b"\r", b"\n") if ascii_data else rest[:10] + rest[10:11].replace(b"\r", b"\n") + rest[11:]
    if lists and (line_end := rest.find(b"\n")) != -1:
        converted = ascii_ply(header + rest[:line_end + 1], memoryview(rest)[line_end + 1:], max_faces)
        if converted is not None:
            return converted
    return header + rest
