"""The fingerprint of a source mesh file, recorded per object in ``index.json`` (``source_file``),
so that a rerun notices a mesh that changed after it was rendered.

A fingerprint is ``{"bytes", "mtime_ns", "sha256"}`` of the file as it was when its shard was
listed. :func:`source_change` compares a file with one: the same size and modification time
mean unchanged (no read); another size means changed; the same size with another time (a copy
made without keeping times, a touched file) is settled by the SHA-256 of the content, so moving
or copying a dataset does not count as a change.

A mesh's companion files (an OBJ's material files and their textures, a glTF's external images
and buffer files:
``io.materials.named_files``) are fingerprinted beside it (:func:`material_fingerprints`, kept
in the mesh's fingerprint as ``"materials"``: ``{name relative to the mesh's folder:
fingerprint, or None where the file was missing}``), so that a rerun renders again an object
whose texture was replaced, or whose missing material file was put in place after it rendered
with a warning (:func:`materials_change`).
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

from sc3d_data.io.hashing import file_sha256

__all__ = ["fingerprint", "material_fingerprints", "materials_change", "source_change"]


def fingerprint(path: str | Path) -> dict | None:
    """``{"bytes", "mtime_ns", "sha256"}`` of regular file ``path``; None for anything else (a
    folder of 3D-R2N2 renderings, a file gone)."""
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            return None
        return {"bytes": st.st_size, "mtime_ns": st.st_mtime_ns, "sha256": file_sha256(Path(path))}
    except OSError:
        return None


def source_change(path: str | Path, recorded: dict) -> str | None:
    """How file ``path`` differs from its ``recorded`` fingerprint, in a few words, or None when
    it has the same content (module doc). Same content under another time: ``recorded`` takes the
    file's time (the index it came from is written back), so a copied dataset is hashed once."""
    try:
        st = os.stat(path)
    except OSError as e:
        return f"cannot be read ({e.strerror or e})"
    if not stat.S_ISREG(st.st_mode):  # a FIFO or device in its place: never opened
        return "no longer a regular file"
    if st.st_size != recorded.get("bytes"):
        return f"{recorded.get('bytes')} -> {st.st_size} bytes"
    if st.st_mtime_ns == recorded.get("mtime_ns"):
        return None
    if file_sha256(Path(path)) != recorded.get("sha256"):
        return "same size, other content"
    recorded["mtime_ns"] = st.st_mtime_ns  # the same content: the next check needs no read
    return None


def material_fingerprints(path: str | Path, root: str | Path | None) -> dict[str, dict | None]:
    """``{name: fingerprint or None}`` of the companion files mesh ``path`` names inside its
    texture root (``root``: the dataset folder; ``io.materials``), names relative to the folder
    of the real mesh file, as its materials name them."""
    from sc3d_data.io.materials import named_files, real_file

    folder = real_file(Path(path)).parent
    return {os.path.relpath(f, folder): fingerprint(f) for f in named_files(Path(path), root)}


def materials_change(path: str | Path, recorded: dict[str, dict | None], root: str | Path | None) -> str | None:
    """How the companion files of mesh ``path`` differ from their ``recorded`` fingerprints
    (:func:`material_fingerprints`), in a few words naming the first that differs, or None. A
    recorded name outside the mesh's texture root (``root``: this run's dataset folder; an edited
    index) is never opened."""
    from sc3d_data.io.materials import real_file, texture_root

    folder = real_file(Path(path)).parent
    top = texture_root(Path(path), None if root is None else Path(root)).resolve()
    for name, was in recorded.items():
        file = folder / name
        if not file.resolve().is_relative_to(top):
            continue
        if was is None:
            if file.is_file():
                return f"{name} was missing and is there now"
        elif (why := source_change(file, was)) is not None:
            return f"{name}: {why}"
    return None
