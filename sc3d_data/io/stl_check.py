"""STL files whose triangle count the loader cannot trust, judged before it reads them.

trimesh's STL reader (5.x) reads a file as binary only where its size is exactly ``84 + 50 x``
the triangle count in its header; otherwise it tries ASCII, and a binary file (or an ASCII one
without its closing ``endsolid`` line) comes out as no triangles: the object failed "empty mesh
(no triangles)", which names neither cause. :func:`loader_stl_bytes` decides, from the header and
the file's size (binary) or its last bytes (ASCII), as assimp, admesh and numpy-stl do:

- a binary STL whose header count is 0 while its body holds whole 50-byte triangles (writers
  that stream triangles and never go back to fill in the count) is read by its size: the loader
  is given a copy with the count filled in;
- a binary STL whose header count differs otherwise from what its size holds (a file cut short,
  or data after the triangles) is refused in one line giving both numbers: reading either would
  draw a part of the object or something that is not part of it;
- an ASCII STL (``solid`` first) that does not end with an ``endsolid`` line is refused as cut
  short: its last facets may be missing.
"""
from __future__ import annotations

import os
import re
import struct
from pathlib import Path

__all__ = ["loader_stl_bytes"]

_HEADER, _TRIANGLE = 84, 50
#: the end of an ASCII STL: an ``endsolid`` line (with or without a name), then only whitespace
_ASCII_END = re.compile(rb"(^|\n)\s*endsolid\b[^\n]*\s*$")


def loader_stl_bytes(path: Path) -> bytes | None:
    """The STL to give the loader in place of ``path`` (module doc): a copy whose header count is
    filled in, or None for the file as it is; ``ValueError`` saying why a file whose count
    cannot be trusted is refused."""
    size = os.path.getsize(path)
    with open(path, "rb") as f:
        head = f.read(_HEADER)
        if len(head) < _HEADER:
            return None  # too short for a binary header: the loader reports it
        count = struct.unpack_from("<I", head, 80)[0]
        if size == _HEADER + _TRIANGLE * count:
            return None  # a binary STL as the loader reads it
        if head.lstrip().startswith(b"solid") and _looks_ascii(head):
            f.seek(max(0, size - 4096))
            if not _ASCII_END.search(f.read()):
                raise ValueError("an ASCII STL that does not end with an `endsolid` line: cut short? (its last "
                                 "facets may be missing)")
            return None
    held, extra = divmod(size - _HEADER, _TRIANGLE)
    if count == 0 and held and not extra:
        data = Path(path).read_bytes()
        return data[:80] + struct.pack("<I", held) + data[_HEADER:]
    whole = f"{held:,} triangles" + (f" and {extra} bytes more" if extra else "")
    raise ValueError(f"a binary STL whose header says {count:,} triangles while its size ({size:,} bytes) holds "
                     f"{whole}: cut short, or data after its triangles?")


def _looks_ascii(head: bytes) -> bool:
    """Whether the first bytes of an STL are text (an ASCII STL), not a binary header that happens
    to start with ``solid`` (some CAD tools write binary STLs so)."""
    return all(b in b"\t\n\r" or 32 <= b < 127 for b in head)
