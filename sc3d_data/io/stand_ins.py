"""The file the loader reads in place of a companion file that is not where its name says.

A material file, texture or glTF file that a mesh names and that is no file inside the dataset
folder is looked for by the loader's resolver (``io.texture_resolver``) under its bare file name in
the folder its name is relative to: an OBJ's ``mtllib scenes/a.mtl`` reads ``a.mtl`` beside the
OBJ, an MTL's ``map_Kd textures/t.png`` or ``map_Kd C:/Users/me/t.png`` reads ``t.png`` beside the
MTL, a glTF image ``textures/t.png`` reads ``t.png`` beside the glTF. Blender's OBJ importer does the
same for textures (the image path's base name in the MTL's folder, after the path as written),
trimesh's own resolver for every name; exporters write paths from a repository's root
(``mtllib scenes/CornellBox-Original.mtl`` beside ``CornellBox-Original.mtl``) or from the machine
that wrote them. What is warned about, fingerprinted (``io.materials.named_files``) and checked
(``io.materials.material_report``) is that file, :func:`stand_in`, the file drawn. Another machine's
absolute or drive-letter path read so is silent (it can name no file of this tree); a relative
name is warned about (:func:`silent`), since the file read is a guess of the name's meaning.

A name whose bytes are not those of the file's name on disk only by its encoding (a Latin-1
``.mtl`` of an old Windows exporter naming ``caf\xe9.png`` where the file, unpacked on Linux, is
``café.png`` in UTF-8, or the reverse) reads that file (:func:`respelled`), with the same
warning: the loader's resolver already read it so (it tries a Latin-1 text's name as UTF-8 and
as the bytes it was written in: ``io.texture_resolver``), where sc3d's own check failed the
object with "not found".
"""
from __future__ import annotations

import os
import re
from pathlib import Path

__all__ = ["inside", "respelled", "silent", "stand_in"]


def inside(path: Path, folder: Path) -> bool:
    """Whether ``path``, links followed, lies in ``folder``."""
    return Path(path).resolve().is_relative_to(Path(folder).resolve())


def respelled(name: str) -> str | None:
    """File name ``name`` (as ``os`` gives it: bytes that are not UTF-8 as lone surrogates) in the
    other encoding (module doc): a name of Latin-1 bytes as the UTF-8 of those characters, a
    UTF-8 name beyond ASCII as their Latin-1 bytes; None where there is no other (ASCII, or
    characters Latin-1 lacks)."""
    data = os.fsencode(name)
    if data.isascii():
        return None
    try:
        return os.fsdecode(data.decode("utf-8").encode("latin-1"))
    except UnicodeDecodeError:
        return os.fsdecode(data.decode("latin-1").encode("utf-8"))
    except UnicodeEncodeError:
        return None


def stand_in(folder: Path, ref: Path, root: Path) -> Path | None:
    """The file the loader reads for companion file ``ref`` (its name joined to ``folder``, the
    folder it is relative to) when ``ref`` is no file inside ``root``: the file of its name in the
    other encoding (:func:`respelled`), else of its bare name in ``folder``, where that is one
    inside ``root`` (module doc); else None (``ref`` is read, or none)."""
    if inside(ref, root) and ref.is_file():
        return None
    head, ref = str(folder) + os.sep, Path(ref)
    name = str(ref)[len(head):] if str(ref).startswith(head) else ref.name
    tries = [respelled(name), ref.name, respelled(ref.name)]
    for local in (Path(folder) / t for t in tries if t is not None):
        if local != ref and inside(local, root) and local.is_file():
            return local
    return None


def silent(folder: Path, ref: Path) -> bool:
    """Whether companion file ``ref`` (its name joined to ``folder``) is named by another machine's
    path, absolute (``/home/someone/t.png``) or with a drive letter (``C:/Users/me/t.png``), whose
    stand-in is read without a warning (module doc)."""
    head, ref = str(folder) + os.sep, str(ref)
    return not ref.startswith(head) or re.match(r"[A-Za-z]:/", ref[len(head):]) is not None
