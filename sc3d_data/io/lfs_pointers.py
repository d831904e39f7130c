"""Git LFS pointer files in place of the files they stand for.

A repository cloned without Git LFS (``git-lfs`` not installed, ``GIT_LFS_SKIP_SMUDGE=1``, a
hub's "download ZIP") holds, for each file stored in LFS, a small text file that names it
(``version https://git-lfs.github.com/spec/v1``, ``oid sha256:...``, ``size N``; the pointer
format keeps such files under 1024 bytes). Read as a mesh it failed "Not a ply file!" or "empty
mesh (no triangles)", as a texture "not an image format Pillow reads", as a glTF buffer "holds
130 bytes": nothing said that the data was never fetched. :func:`lfs_pointer` names it so.
"""
from __future__ import annotations

import os
import re
from pathlib import Path

__all__ = ["MAX_POINTER_BYTES", "file_lfs_pointer", "lfs_pointer"]

#: the pointer format's limit on a pointer file's size (bytes)
MAX_POINTER_BYTES = 1024
#: the first line of a pointer (``hawser`` was Git LFS's name before its release)
_SIGNATURES = (b"version https://git-lfs.github.com/spec/", b"version https://hawser.github.com/spec/")


def lfs_pointer(data: bytes) -> str | None:
    """What ``data`` (a whole file's bytes, or its first :data:`MAX_POINTER_BYTES`) is, where it
    is a Git LFS pointer: ``"a Git LFS pointer to a file of 1,234 bytes, not the file itself:
    fetch it with `git lfs pull` in its repository"``; else None."""
    if len(data) >= MAX_POINTER_BYTES or not data.startswith(_SIGNATURES):
        return None
    size = re.search(rb"^size (\d+)\s*$", data, re.M)
    of = f" to a file of {int(size.group(1)):,} bytes" if size else ""
    return f"a Git LFS pointer{of}, not the file itself: fetch it with `git lfs pull` in its repository"


def file_lfs_pointer(path: Path) -> str | None:
    """:func:`lfs_pointer` of regular file ``path`` (read only when it is smaller than a pointer
    may be); None for larger files and files that cannot be read."""
    try:
        if os.stat(path).st_size >= MAX_POINTER_BYTES:
            return None
        return lfs_pointer(Path(path).read_bytes())
    except OSError:
        return None
