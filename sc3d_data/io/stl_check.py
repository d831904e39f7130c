"""STL files whose triangle count the loader cannot trust, judged before it reads them.

trimesh's STL reader (5.x) reads a file as binary only where its size is exactly ``84 + 50 x``
the triangle count in its header; otherwise it tries ASCII, and a binary file (or an ASCII one
without its closing ``endsolid`` line) comes out as no triangles: the object failed "empty mesh
(no triangles)", which names neither cause. :func:`loader_stl_bytes` decides, from the header and
the file's size (binary) or its last bytes (ASCII), as assimp, admesh and numpy-stl do:

- a binary STL whose header count is 0 while its body holds whole 50-byte triangles (writers
  that stream triangles and never go back to fill in the count) is read by its size: the loader
  is given a copy with the count filled in;
- a binary STL whose triangles are all there as counted, followed by fewer bytes than a triangle
  (padding), is read without them;
- a binary STL whose header count differs otherwise from what its size holds (a file cut short,
  or data after the triangles) is refused in one line giving both numbers: reading either would
  draw a part of the object or something that is not part of it;
- an ASCII STL (``solid``, in any case, after a byte-order mark, with a ``facet`` in its first
  KiB) that does not end with an ``endsolid`` line (then only whitespace, NUL or ^Z padding) is
  refused as cut short: its last facets may be missing;
- an ASCII STL whose lines end with CR alone (classic Mac OS; numpy-stl's ``mac.stl``), which
  the loader cannot split into statements ("cannot parse"), and whose last line was taken for no
  ``endsolid`` line (refused as cut short), is given to the loader with its lines ended by LF.
"""
from __future__ import annotations

import os
import re
import struct
from pathlib import Path

from sc3d_data.io.line_ends import lf_lines, lone_cr

__all__ = ["loader_stl_bytes"]

_HEADER, _TRIANGLE = 84, 50
#: the end of an ASCII STL: an ``endsolid`` line (any case, with or without a name), then only
#: whitespace, NUL or ^Z padding
_ASCII_END = re.compile(rb"(^|\n)[ \t]*endsolid\b[^\n]*[\s\0\x1a]*$", re.IGNORECASE)
#: an ASCII STL's first statements: ``solid`` (any case, after a byte-order mark and whitespace),
#: and a ``facet`` within its first KiB (a binary header that starts with "solid", as some CAD
#: tools write it, is followed by binary numbers)
_ASCII_START = re.compile(rb"^(\xef\xbb\xbf)?\s*solid\b.*?\bfacet\b", re.IGNORECASE | re.DOTALL)


def _lf_lines(path: Path) -> bytes | None:
    """The text of ASCII STL ``path`` with its lines ended by LF where one ends with CR alone
    (module doc); None where none does (CRLF is read as it is)."""
    data = Path(path).read_bytes()
    return lf_lines(data) if lone_cr(data) else None


def loader_stl_bytes(path: Path) -> bytes | None:
    """The STL to give the loader in place of ``path`` (module doc): a copy whose header count is
    filled in, or None for the file as it is; ``ValueError`` saying why a file whose count
    cannot be trusted is refused."""
    size = os.path.getsize(path)
    with open(path, "rb") as f:
        head = f.read(1024)
        if len(head) < _HEADER:
            return None  # too short for a binary header: the loader reports it
        count = struct.unpack_from("<I", head, 80)[0]
        if size == _HEADER + _TRIANGLE * count:
            return None  # a binary STL as the loader reads it
        if _ASCII_START.match(head):
            relined = _lf_lines(path) if b"\r" in head else None
            f.seek(max(0, size - 4096))
            if not _ASCII_END.search(f.read() if relined is None else relined[-4096:]):
                raise ValueError("an ASCII STL that does not end with an `endsolid` line: cut short? (its last "
                                 "facets may be missing)")
            return relined
    held, extra = divmod(size - _HEADER, _TRIANGLE)
    if count == 0 and held and not extra:
        data = Path(path).read_bytes()
        return data[:80] + struct.pack("<I", held) + data[_HEADER:]
    if count and count == held:  # whole triangles as counted, then a few bytes of padding
        return Path(path).read_bytes()[:_HEADER + _TRIANGLE * count]
    whole = f"{held:,} triangles" + (f" and {extra} bytes more" if extra else "")
    raise ValueError(f"a binary STL whose header says {count:,} triangles while its size ({size:,} bytes) holds "
                     f"{whole}: cut short, or data after its triangles?")
