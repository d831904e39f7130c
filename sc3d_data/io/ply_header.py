"""The PLY the loader is given where its header names vertex colours in words the loader does not read.

trimesh's PLY loader (``trimesh.exchange.ply``, 5.x) reads colours from the properties ``red``,
``green``, ``blue`` (and ``alpha``) only. The Stanford PLY tools' own examples, and scanners and
exporters that followed them, name them ``diffuse_red``, ``diffuse_green``, ``diffuse_blue``: such
an object was drawn in the default grey, exit 0. :func:`loader_ply_bytes` gives the loader the file
with those properties renamed in its header (the header is text; the data after ``end_header``,
text or binary, is kept byte for byte), where the header has no property of the plain names.
"""
from __future__ import annotations

import re
from pathlib import Path

__all__ = ["loader_ply_bytes"]

#: bytes read to find the header's end; a header longer than this is left to the loader
HEADER_BYTES = 1 << 16
#: a colour property named with the ``diffuse_`` prefix: ``property <type> diffuse_red``
_DIFFUSE = re.compile(rb"(?m)^(property[ \t]+\w+[ \t]+)diffuse_(red|green|blue|alpha)[ \t]*\r?$")


def loader_ply_bytes(path: Path) -> bytes | None:
    """PLY ``path``'s bytes with its ``diffuse_``-prefixed colour properties renamed (module doc),
    or None to load the file as it is (no such property, or the plain name beside it)."""
    with open(path, "rb") as f:
        head = f.read(HEADER_BYTES)
    end = head.find(b"end_header")
    if end == -1 or b"diffuse_" not in head[:end]:
        return None
    header = head[:end]
    if not _DIFFUSE.search(header) or any(re.search(rb"(?m)^property[ \t]+\w+[ \t]+" + name + rb"[ \t]*\r?$", header)
                                          for name in (b"red", b"green", b"blue")):
        return None
    return _DIFFUSE.sub(rb"\1\2", header) + Path(path).read_bytes()[end:]
