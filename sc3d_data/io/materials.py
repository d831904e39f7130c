"""The material and texture files a mesh file names: where they may lie, which exist and decode,
and the resolver through which trimesh reads them. Conventions:

- **Real file**: a mesh reached through a symlink names its companion files (``.mtl``,
  textures, glTF buffers) relative to the file the link points to (``os.path.realpath``), as
  the program that wrote them did, never relative to the link.
- **Texture root** (:func:`texture_root`): the folder every ``.mtl``, texture or external glTF file a mesh names
  must lie in, after resolving ``..`` and symlinks: the dataset folder (``--meshes``) when the real file lies in
  it, else (no dataset folder, or a link that points out of it) the real file's own folder. A ShapeNetCore v2
  mesh (``MODEL/models/model_normalized.obj``, whose ``.mtl`` names ``../images/textureN.jpg``) may also read
  its model folder ``MODEL/``.
- A reference is judged from its path alone (``Path.resolve``: string work and symlink reads,
  no file opened) before any file it names is opened. A reference outside the root is never
  opened: with ``outside="warn"`` the object renders without it and a warning says so, with
  ``"refuse"`` the object fails.
- Everything trimesh asks for goes through :class:`_RootResolver` (rooted at the texture root),
  which records what it could not serve, so a texture that is named but not loaded is reported
  (:func:`loader_misses`), never dropped silently.
"""
from __future__ import annotations

import io
import os
import re
import struct
import urllib.parse
from dataclasses import dataclass, field
from pathlib import Path

from sc3d_data.io.gltf_check import read_gltf
from sc3d_data.io.names import printable
from sc3d_data.io.obj_statements import statement_values

__all__ = ["SHAPENET_V2_MESH", "MaterialReport", "dataset_folder", "loader_misses", "make_resolver",
           "material_report", "named_files", "real_file", "texture_root"]

#: ShapeNetCore v2's mesh inside a model folder
SHAPENET_V2_MESH = ("models", "model_normalized.obj")
#: numbers and switches that follow an option of an MTL map statement (``-s 1 1 1``, ``-clamp on``)
_OPTION_VALUE = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^(on|off)$")


def _inside(path: Path, folder: Path) -> bool:
    return Path(path).resolve().is_relative_to(Path(folder).resolve())


def real_file(path: Path) -> Path:
    """The file mesh ``path`` is, symlinks resolved (module doc): its companion files are named
    relative to this file's folder."""
    return Path(os.path.realpath(path))


def dataset_folder(meshes: str | Path) -> Path:
    """The folder a run's ``--meshes`` makes the root of its meshes' companion files
    (:func:`texture_root`): the folder itself, or a single mesh file's folder."""
    meshes = Path(meshes)
    return meshes if meshes.is_dir() else meshes.parent


def texture_root(path: Path, root: Path | None) -> Path:
    """The folder the files named by mesh ``path`` must lie in (module doc): ``root`` when the
    real file lies in it, else the real file's folder, widened to the model folder of a
    ShapeNetCore v2 mesh that lies inside it."""
    path = real_file(path)
    base = Path(root).resolve() if root is not None else path.parent
    if not path.is_relative_to(base):  # a link out of the dataset folder: its target's own folder
        base = path.parent
    if path.parts[-2:] == SHAPENET_V2_MESH:
        model = path.parent.parent
        if _inside(base, model):
            return model
    return base


def map_file_name(value: str) -> str:
    """The file name of an MTL map statement's value, without its options:
    ``"-s 1 1 1 -clamp on tex.png"`` -> ``"tex.png"``; Windows separators become ``/``."""
    tokens = value.split()
    while len(tokens) > 1 and tokens[0].startswith("-") and not _OPTION_VALUE.match(tokens[0]):
        if tokens.pop(0).lower() in ("-imfchan", "-type") and len(tokens) > 1:  # a word: r/g/b/m/l/z, sphere...
            tokens.pop(0)
        while len(tokens) > 1 and _OPTION_VALUE.match(tokens[0]):
            tokens.pop(0)
    return " ".join(tokens).replace("\\", "/")


def _image_problem(data_or_path) -> str | None:
    from PIL import Image

    try:
        src = io.BytesIO(data_or_path) if isinstance(data_or_path, (bytes, bytearray)) else data_or_path
        with Image.open(src) as im:
            im.load()
    except Exception as e:  # noqa: BLE001 - any decoder error is the texture's problem
        return f"{type(e).__name__}: {e}"
    return None


@dataclass
class MaterialReport:
    """What the materials of one mesh file name. ``problems``: textures inside the root that are missing or do
    not decode; ``warnings``: ``.mtl`` files that are missing; ``outside``: one line per file outside the root
    (never opened); ``reported``: resolved paths of all of these; ``textures``: the file names of the textures
    inside the root that exist and decode."""

    textures: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    outside: list[str] = field(default_factory=list)
    reported: set[str] = field(default_factory=set)


def mtllib_names(path: Path, text: str | None = None) -> list[str]:
    """The material files OBJ ``path`` (its ``text`` when already read) names, in order: every
    ``mtllib`` statement, each of which may name several files separated by spaces (OBJ allows
    it); a statement whose whole text names an existing file is that one file (a name with spaces)."""
    names = []
    text = path.read_text(errors="replace") if text is None else text
    for value in statement_values(text, "mtllib"):  # io.obj_statements
        names += [value] if (path.parent / value).is_file() else value.split()
    return names


def _obj_refs(path: Path, root: Path, report: MaterialReport, libs: list[str] | None = None
              ) -> list[tuple[str, Path]]:
    """``[(name as written, path)]`` of the textures an OBJ's material files (``libs``, else
    :func:`mtllib_names`) name; material files outside ``root`` are noted in ``report`` and not
    read, missing ones warned about."""
    refs = []
    for lib in mtllib_names(path) if libs is None else libs:
        mtl = path.parent / lib
        if not _inside(mtl, root):
            refs.append((lib, mtl))
            continue
        if not mtl.is_file():
            report.warnings.append(f"material file {lib} not found; rendered with the default material")
            report.reported.add(str(mtl.resolve()))
            continue
        for tex in re.findall(r"^\s*map_Kd\s+(.+?)\s*$", mtl.read_text(errors="replace"), flags=re.M | re.I):
            name = map_file_name(tex)
            refs.append((f"{name} (from {mtl.name})", mtl.parent / name))
    return refs


def gltf_uri_path(folder: Path, uri: str) -> Path:
    """The file a glTF ``uri`` names relative to ``folder``: glTF URIs are percent-encoded
    (Blender writes ``my%20tex.png`` for ``my tex.png``), so the decoded name, unless only the
    name as written exists."""
    literal, decoded = folder / uri, folder / urllib.parse.unquote(uri)
    return literal if literal.exists() and not decoded.exists() else decoded


def _gltf_refs(path: Path, doc: dict, binary: bytes | None) -> tuple[list[tuple[str, Path]], list[tuple[str, bytes]]]:
    """``(external images [(name, path)], embedded images [(name, bytes)])`` of GLTF/GLB ``path``
    (its JSON ``doc`` and binary chunk, ``read_gltf``; the embedded images only with ``binary``)."""
    external, embedded = [], []
    for i, image in enumerate(doc.get("images", [])):
        if "uri" in image and not image["uri"].startswith("data:"):
            external.append((f"image {i} ({image['uri']})", gltf_uri_path(path.parent, image["uri"])))
        elif "bufferView" in image and binary is not None:
            view = doc["bufferViews"][image["bufferView"]]
            start = view.get("byteOffset", 0)
            embedded.append((f"texture image {i}", binary[start:start + view["byteLength"]]))
    return external, embedded


def named_files(path: Path, root: Path | None = None) -> list[Path]:
    """The companion files of mesh ``path`` inside :func:`texture_root` that it names, there or
    not: an OBJ's material files and the textures they name, a glTF's external images and buffer
    files; sorted, each once. What a rerun compares (``io.source_fingerprint.material_fingerprints``)
    to notice a texture replaced, or a missing one put in place. Unparseable files name none."""
    path = real_file(path)
    top, suffix = texture_root(path, root), path.suffix.lower()
    try:
        if suffix == ".obj":
            libs = mtllib_names(path)
            refs = _obj_refs(path, top, MaterialReport(), libs) + [(lib, path.parent / lib) for lib in libs]
        elif suffix in (".glb", ".gltf"):  # its images, and its buffers in files (the geometry)
            doc = read_gltf(path)[0]  # not a glTF document: ValueError, the loader reports it
            refs = _gltf_refs(path, doc, None)[0] + [
                (b["uri"], gltf_uri_path(path.parent, b["uri"])) for b in doc.get("buffers", [])
                if isinstance(b.get("uri"), str) and not b["uri"].startswith("data:")]
        else:
            return []
    except (OSError, ValueError, KeyError, IndexError, TypeError, AttributeError, struct.error):
        return []
    return sorted({Path(os.path.abspath(ref)) for _, ref in refs if _inside(ref, top)})


def material_report(path: Path, root: Path | None = None, outside: str = "warn") -> MaterialReport:
    """The materials of mesh ``path`` (module doc), judged against :func:`texture_root`: files outside
    the root are decided on from their paths, before any is opened (``outside="refuse"``: a
    ``ValueError`` lists them; else ``report.outside``, never opened); the textures inside that are
    missing or undecodable go to ``report.problems``, the others to ``report.textures``."""
    path = real_file(path)
    top = texture_root(path, root)
    report = MaterialReport()
    suffix = path.suffix.lower()
    try:
        if suffix == ".obj":
            refs, embedded = _obj_refs(path, top, report), []
        elif suffix in (".glb", ".gltf"):
            refs, embedded = _gltf_refs(path, *read_gltf(path, binary=True))  # not glTF: ValueError, as above
        else:
            return report
    except (OSError, ValueError, KeyError, IndexError, TypeError, AttributeError, struct.error):
        return report  # not parseable: the loader reports it
    inside = []
    for name, ref in refs:
        if _inside(ref, top):
            inside.append((name, ref))
        elif str(ref.resolve()) not in report.reported:
            report.reported.add(str(ref.resolve()))
            report.outside.append(f"{ref.resolve()} lies outside the dataset folder {top.resolve()}")
    if report.outside and outside == "refuse":
        raise ValueError("; ".join(report.outside))
    report.outside = [f"{o}: not read; rendered without it (--outside-textures)" for o in report.outside]
    for name, ref in inside:
        report.reported.add(str(ref.resolve()))
        if not ref.is_file():
            report.problems.append(f"texture {name} not found")
        elif (p := _image_problem(ref)) is not None:
            report.problems.append(f"texture {name} unreadable ({p})")
        else:
            report.textures.append(ref.name)
    for name, data in embedded:
        if (p := _image_problem(data)) is not None:
            report.problems.append(f"{name} unreadable ({p})")
    return report


def make_resolver(path: Path, root: Path | None):
    """A trimesh resolver for mesh ``path`` that serves files inside :func:`texture_root` (names relative to the
    real file's folder (:func:`real_file`), ``..`` allowed while inside; like trimesh's own it also tries the name
    without options and the bare file name, each also percent-decoded (glTF URIs)) and records every name it could
    not serve. For an OBJ, trimesh reads only its first ``mtllib`` statement (the first ``mtllib`` in the text, a
    comment's too) as one file name: asked for it, the resolver serves every material file the statements name
    (:func:`mtllib_names`), so none is dropped and none read that a comment names. An MTL's UTF-8 mark is dropped."""
    from trimesh.resolvers import Resolver

    class _RootResolver(Resolver):
        def __init__(self, folder: Path, top: Path, misses: list):
            self.parent, self.top, self.misses = Path(os.path.abspath(folder)), top.resolve(), misses
            self.file_name = printable(Path(path).name)  # trimesh names (and hashes) geometry by it

        def _candidates(self, name: str) -> list[str]:
            stripped = map_file_name(name.strip())
            names = [name.strip(), stripped, stripped.lstrip("/"), os.path.basename(stripped)]
            return list(dict.fromkeys(names + [urllib.parse.unquote(n) for n in names]))  # glTF URIs

        def get(self, name: str) -> bytes:
            if name.strip() == first_mtllib and (len(libs) > 1 or first_mtllib not in libs):  # see above
                return b"\n".join(self._read(lib) for lib in libs if self._inside_file(lib))
            return self._read(name)

        def _inside_file(self, name: str) -> bool:
            p = (self.parent / name).resolve()
            return p.is_relative_to(self.top) and p.is_file()

        def _read(self, name: str) -> bytes:
            first = (self.parent / map_file_name(name.strip())).resolve()
            for cand in self._candidates(name):
                p = (self.parent / cand).resolve()
                if p.is_relative_to(self.top) and p.exists():
                    with open(p, "rb") as f:  # a material file's UTF-8 mark (Notepad) would hide its first newmtl
                        return f.read().removeprefix(b"\xef\xbb\xbf") if p.suffix.lower() == ".mtl" else f.read()
            inside = first.is_relative_to(self.top)
            self.misses.append((name.strip(), str(first), "not found" if inside else
                                f"outside the dataset folder {self.top}, not read"))
            raise FileNotFoundError(f"{name.strip()}: " + self.misses[-1][2])

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
        text = real.read_text(errors="replace")
        libs = mtllib_names(real, text)
        found = re.search(r"mtllib(.*)", text.replace("\\\n", ""))  # what trimesh asks for (lines joined)
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
