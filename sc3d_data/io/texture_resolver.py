"""The resolver through which trimesh reads the files a mesh names (materials, textures, glTF
buffers): it serves only files inside the mesh's texture root (``io.materials.texture_root``) and
records every name it could not serve, so that a texture named but not loaded is reported
(:func:`loader_misses`), never dropped silently.

Names are tried as written, without the map statement's options, each also percent-decoded (glTF
URIs), then as the bare file name of each: the file read in place of one that is not there, which
``io.materials`` warns about, fingerprints and checks as the file drawn (``io.stand_ins``). A
material file that is not UTF-8 is served as the UTF-8 text of its Latin-1 reading (each byte one
character), so trimesh reads the same text whatever its encoding guess, and a texture name of
such a file is tried as the bytes it was written in first (``io.names``: a name that is not UTF-8
is a ``str`` with lone surrogates), then as the UTF-8 of its characters (``io.stand_ins.respelled``;
tried first, the UTF-8 file was drawn where both lie there, while the checks judged the other). trimesh asks for every texture relative to the OBJ's folder,
but an MTL names its textures relative to its own (``mtllib mats/m.mtl`` naming ``map_Kd t.png``
means ``mats/t.png``, as Blender's importer and sc3d's checks, ``io.materials``, read it): a material
file in another folder is served with each ``map_Kd`` named by a key that the resolver reads from
that folder, so a ``t.png`` beside the OBJ is not drawn in its place.
"""
from __future__ import annotations

import logging
import os
import re
import threading
import urllib.parse
from contextlib import contextmanager
from pathlib import Path

from sc3d_data.io.materials import MaterialReport, mtllib_names, real_file, texture_root
from sc3d_data.io.mtl_text import loader_mtl_text, loader_reading, map_file_name, read_obj_text
from sc3d_data.io.names import printable
from sc3d_data.io.obj_statements import loader_lines
from sc3d_data.io.stand_ins import respelled

__all__ = ["loader_misses", "make_resolver", "quiet_loader"]


#: how many loads are running quietly in this process, and the trimesh logger's level before the first
_quiet = {"loads": 0, "level": logging.NOTSET}
_quiet_lock = threading.Lock()


@contextmanager
def quiet_loader():
    """trimesh's log lines not printed while it loads: a file the resolver cannot serve is
    reported by :func:`loader_misses` in one line naming the mesh, where trimesh's own logger
    printed a traceback naming neither (a PLY's missing ``comment TextureFile``), interleaved
    between workers. Its modules log as ``trimesh.util``, ...: their level is the ``trimesh``
    logger's, raised while any thread of this process loads, restored after the last."""
    logger = logging.getLogger("trimesh")
    with _quiet_lock:
        if _quiet["loads"] == 0:
            _quiet["level"] = logger.level
            logger.setLevel(logging.CRITICAL + 1)
        _quiet["loads"] += 1
    try:
        yield
    finally:
        with _quiet_lock:
            _quiet["loads"] -= 1
            if _quiet["loads"] == 0:
                logger.setLevel(_quiet["level"])


def _as_written(name: str) -> str | None:
    """``name`` as trimesh read it from a material file served as Latin-1 text, back as the file
    name of the bytes it was written in (None where ``name`` cannot have come from there)."""
    try:
        return os.fsdecode(name.encode("latin-1"))
    except UnicodeEncodeError:
        return None


def _served_material(data: bytes) -> bytes:
    """A material file's bytes as served to trimesh: without a UTF-8 mark (Notepad's, which would
    hide its first ``newmtl``), and when not UTF-8, the UTF-8 text of its Latin-1 reading; its
    colours as ``io.mtl_text.loader_mtl_text`` gives them."""
    return loader_mtl_text(loader_reading(data.removeprefix(b"\xef\xbb\xbf"))[0]).encode("utf-8")


def make_resolver(path: Path, root: Path | None):
    """A trimesh resolver for mesh ``path`` that serves files inside :func:`texture_root` (names relative to the
    real file's folder (:func:`real_file`), ``..`` allowed while inside; like trimesh's own it also tries the name
    without options and the bare file name, each also percent-decoded (glTF URIs)) and records every name it could
    not serve. For an OBJ, trimesh reads only its first ``mtllib`` statement (the first ``mtllib`` in the text, a
    comment's too) as one file name: asked for it, the resolver serves every material file the statements name
    (:func:`mtllib_names`), so none is dropped and none read that a comment names. A material file is served as :func:`_served_material` says."""
    from trimesh.resolvers import Resolver

    class _RootResolver(Resolver):
        def __init__(self, folder: Path, top: Path, misses: list):
            self.parent, self.top, self.misses = Path(os.path.abspath(folder)), top.resolve(), misses
            self.file_name = printable(Path(path).name)  # trimesh names (and hashes) geometry by it
            self.map_folders = {}  # {name a served material file's map_Kd is given as: (its folder, name as written)}

        def _candidates(self, name: str) -> list[str]:
            names = [name.strip(), map_file_name(name.strip())]
            names += [urllib.parse.unquote(n) for n in names]  # glTF URIs
            names += [n for n in map(respelled, names) if n is not None]  # io.stand_ins: Latin-1 <-> UTF-8
            return list(dict.fromkeys(names + [os.path.basename(n) for n in names]))  # bare: io.stand_ins

        def get(self, name: str) -> bytes:
            if name.strip() == first_mtllib and (len(libs) > 1 or first_mtllib not in libs):  # see above
                return b"\n".join(self._read(lib) for lib in libs if self._find(lib) is not None)
            return self._read(name)

        def _find(self, name: str) -> Path | None:
            """The file inside the root that ``name`` is read from (its first candidate there), or None."""
            for cand in self._candidates(name):
                p = (self.parent / cand).resolve()
                if p.is_relative_to(self.top) and p.exists() and not p.is_dir():  # a FIFO too: its read blocks
                    # until --timeout, as the loader's own would (a folder of the name is passed over)
                    return p
            return None

        def _read(self, name: str) -> bytes:
            if name.strip() in self.map_folders:  # a map_Kd of a material file in another folder: named from there
                folder, written = self.map_folders[name.strip()]
                return _RootResolver(folder, self.top, self.misses)._read(written)
            first = (self.parent / map_file_name(name.strip())).resolve()
            if (p := self._find(name)) is not None:
                with open(p, "rb") as f:
                    data = f.read()
                return self._material(p, data) if p.suffix.lower() == ".mtl" else data
            inside = first.is_relative_to(self.top)
            self.misses.append((name.strip(), str(first), "not found" if inside else
                                f"outside the dataset folder {self.top}, not read"))
            raise FileNotFoundError(f"{name.strip()}: " + self.misses[-1][2])

        def _material(self, p: Path, data: bytes) -> bytes:
            """Material file ``p`` (``data``) as served (:func:`_served_material`); one in another folder
            than the OBJ, or not UTF-8, with each ``map_Kd`` named so that :meth:`_read` reads it from that
            folder, by the bytes it was written in first (the name's UTF-8 spelling only where no such file is)."""
            text, utf8 = _served_material(data).decode("utf-8"), loader_reading(data.removeprefix(b"\xef\xbb\xbf"))[1]
            if p.parent == self.parent.resolve() and utf8:
                return text.encode("utf-8")
            lines = text.split("\n")
            for n, line in enumerate(lines):
                if (words := line.split(None, 1))[:1] and words[0].lower() == "map_kd" and len(words) == 2:
                    key = f"{printable(os.path.relpath(p.parent, self.parent.resolve()))}/{words[1].strip()}"
                    self.map_folders[key] = (p.parent, words[1].strip() if utf8 else _as_written(words[1].strip()))
                    lines[n] = f"map_Kd {key}"
            return "\n".join(lines).encode("utf-8")

        def namespaced(self, namespace: str):
            return _RootResolver(self.parent / namespace, self.top, self.misses)

        def keys(self):
            for folder, _, names in os.walk(self.parent):
                for n in names:
                    yield os.path.relpath(os.path.join(folder, n), self.parent)

        def write(self, name, data):
            raise PermissionError(f"{name}: sc3d does not write beside meshes")

    real, libs, first_mtllib = real_file(path), [], None
    if real.suffix.lower() == ".obj":  # all material files, served for the first statement
        text = read_obj_text(real)
        libs = mtllib_names(real, text)
        found = re.search(r"mtllib(.*)", loader_lines(text))  # what trimesh asks for (lines as it splits them)
        first_mtllib = found.group(1).strip() if found else None
    return _RootResolver(real.parent, texture_root(real, root), [])




def loader_misses(resolver, report: MaterialReport) -> list[str]:
    """Files the loader asked ``resolver`` for and did not get, except those ``report`` already
    lists: one line each (``name: reason``)."""
    lines = []
    for name, resolved, reason in resolver.misses:
        if resolved not in report.reported:
            report.reported.add(resolved)
            lines.append(f"{name} named by the mesh or its materials was not loaded ({reason})")
    return lines
