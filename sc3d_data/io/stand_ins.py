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
"""
from __future__ import annotations

import os
import re
from pathlib import Path

__all__ = ["inside", "silent", "stand_in"]


def inside(path: Path, folder: Path) -> bool:
    """Whether ``path``, links followed, lies in ``folder``."""
    return Path(path).resolve().is_relative_to(Path(folder).resolve())


def stand_in(folder: Path, ref: Path, root: Path) -> Path | None:
    """The file the loader reads for companion file ``ref`` (its name joined to ``folder``, the
    folder it is relative to) when ``ref`` is no file inside ``root``: the file of its bare name in
    ``folder``, where that is one inside ``root`` (module doc); else None (``ref`` is read, or none)."""
    if inside(ref, root) and ref.is_file():
        return None
    local = Path(folder) / Path(ref).name
    if local != Path(ref) and inside(local, root) and local.is_file():
        return local
    return None


def silent(folder: Path, ref: Path) -> bool:
    """Whether companion file ``ref`` (its name joined to ``folder``) is named by another machine's
    path, absolute (``/home/someone/t.png``) or with a drive letter (``C:/Users/me/t.png``), whose
    stand-in is read without a warning (module doc)."""
    head, ref = str(folder) + os.sep, str(ref)
    return not ref.startswith(head) or re.match(r"[A-Za-z]:/", ref[len(head):]) is not None
