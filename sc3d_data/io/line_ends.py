"""Lines ended by LF, whatever a text file wrote: CRLF (Windows) or CR alone (classic Mac OS).

trimesh's OBJ and ASCII STL readers split their text at LF, so a file whose lines end with CR
alone is one line to them; sc3d gives the loader such a file with LF lines, and the checks that
read it line by line (OBJ face indices, keyword case and statements, STL's ``endsolid``) read it
the same way. One definition for all of them.
"""
from __future__ import annotations

__all__ = ["lf_lines", "lone_cr"]


def lone_cr(data: bytes) -> bool:
    """Whether a line of ``data`` ends with CR alone (two counts, no scan in Python)."""
    return data.count(b"\r") != data.count(b"\r\n")


def lf_lines(data: bytes | str) -> bytes | str:
    """``data`` (bytes or text, returned as given) with every CRLF and every lone CR written LF."""
    crlf, cr, lf = ("\r\n", "\r", "\n") if isinstance(data, str) else (b"\r\n", b"\r", b"\n")
    return data.replace(crlf, lf).replace(cr, lf)
