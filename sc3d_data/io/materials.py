"""The material and texture files a mesh file names: where they may lie, which exist and decode.
Conventions:

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
- Everything trimesh asks for goes through the resolver of ``io.texture_resolver`` (rooted at
  the texture root), which records what it could not serve, so a texture that is named but not
  loaded is reported, never dropped silently.
- An OBJ's ``usemtl`` of a material its material files do not define, and a material whose only
  texture is ``map_Ka`` (not drawn), are warned about: either renders without its look.
"""
from __future__ import annotations

import io
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

from sc3d_data.io.gltf_check import GltfFile, read_gltf
from sc3d_data.io.gltf_images import UNDRAWN, gltf_image_refs, gltf_uri_path, not_drawn
from sc3d_data.io.lfs_pointers import MAX_POINTER_BYTES, file_lfs_pointer, lfs_pointer
from sc3d_data.io.names import printable
from sc3d_data.io.mtl_text import TextureMove, mtl_materials, read_obj_text
from sc3d_data.io.obj_statements import statement_values
from sc3d_data.io.ply_textures import texture_names
from sc3d_data.io.stand_ins import inside, silent, stand_in
from sc3d_data.io.texture_wraps import CLAMP_TO_BORDER

__all__ = ["SHAPENET_V2_MESH", "MaterialReport", "dataset_folder", "material_report", "mtllib_names",
           "named_files", "real_file", "texture_root"]

#: what a warning of an image the renderer does not draw adds (``io.gltf_images``)
MOOT = "; sc3d draws base colour textures only, so the object renders the same without it"
#: ShapeNetCore v2's mesh inside a model folder
SHAPENET_V2_MESH = ("models", "model_normalized.obj")


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
        if inside(base, model):
            return model
    return base


def _image_problem(data_or_path) -> str | None:
    from PIL import Image

    data = bytes(data_or_path[:MAX_POINTER_BYTES]) if isinstance(data_or_path, (bytes, bytearray)) else None
    pointer = lfs_pointer(data) if data is not None else file_lfs_pointer(data_or_path)
    if pointer is not None:
        return pointer
    try:
        src = io.BytesIO(data_or_path) if isinstance(data_or_path, (bytes, bytearray)) else data_or_path
        with Image.open(src) as im:
            im.load()
    except Exception as e:  # noqa: BLE001 - any decoder error is the texture's problem
        if type(e).__name__ == "UnidentifiedImageError":  # its text names the file object, not the image
            return "not an image format Pillow reads"
        return f"{type(e).__name__}: {e}"
    return None


@dataclass
class MaterialReport:
    """What the materials of one mesh file name. ``problems``: textures inside the root that are missing or do
    not decode; ``warnings``: ``.mtl`` files that are missing; ``outside``: one line per file outside the root
    (never opened); ``reported``: resolved paths of all of these; ``textures``: the file names of the textures
    inside the root that exist and decode; ``texture_only``: an OBJ's materials with a ``map_Kd`` texture
    and no ``Kd``; ``texture_moves``: ``{material: TextureMove}`` of an OBJ's ``map_Kd`` textures
    moved by ``-o``/``-s`` (``io.mtl_text``); ``wraps``: ``{material: (wrap u, wrap v)}`` of an OBJ's
    materials whose ``map_Kd`` is clamped (``-clamp on``: ``io.texture_wraps``); ``replaced``: files as
    named that are not there, read under their bare name (``io.stand_ins``; fingerprinted: one put
    in place is read instead)."""

    textures: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    outside: list[str] = field(default_factory=list)
    reported: set[str] = field(default_factory=set)
    texture_only: set[str] = field(default_factory=set)
    texture_moves: dict[str, TextureMove] = field(default_factory=dict)
    wraps: dict[str, tuple[int, int]] = field(default_factory=dict)
    replaced: list[Path] = field(default_factory=list)
    leaving: list[str] = field(default_factory=list)  # of ``replaced``, those named by a ``../`` out of the root


def mtllib_names(path: Path, text: str | None = None) -> list[str]:
    """The material files OBJ ``path`` (its ``text`` when already read) names, in order: every
    ``mtllib`` statement, each of which may name several files separated by spaces (OBJ allows
    it); a statement whose whole text names an existing file is that one file (a name with spaces)."""
    names = []
    text = read_obj_text(path) if text is None else text
    for value in statement_values(text, "mtllib"):  # io.obj_statements
        names += [value] if (path.parent / value).is_file() else value.split()
    return names


def _read_as(folder: Path, ref: Path, root: Path, report: MaterialReport, what: str, beside: str) -> Path:
    """The file the loader reads for companion file ``ref`` (its name joined to ``folder``): ``ref``,
    or the file of its bare name in ``folder`` (``io.stand_ins``), then noted in ``report`` and, for
    a relative name, warned about (``what``: how the warning names ``ref``; ``beside``: ``folder``); one whose
    ``../`` leaves ``root`` also in ``report.leaving``, so that ``--outside-textures refuse`` still refuses it."""
    local = stand_in(folder, ref, root)
    if local is None:
        return ref
    report.replaced.append(ref)
    leaves = not inside(ref, root) and not silent(folder, ref)  # this tree's ../ out of it: --outside-textures refuse
    if leaves:
        report.leaving.append(f"{ref.resolve()} lies outside the dataset folder {Path(root).resolve()}")
    why = "lies outside the dataset folder, not read" if leaves else "not found"
    warning = f"{what} {why}; {printable(local.name)} beside {beside} is read in its place"
    if not silent(folder, ref) and warning not in report.warnings:
        report.warnings.append(warning)
    return local


def _obj_refs(path: Path, root: Path, report: MaterialReport, text: str | None = None) -> list[tuple[str, Path]]:
    """``[(name as written, path)]`` of the textures an OBJ's material files (:func:`mtllib_names`;
    ``text``: the OBJ's, when already read) name; material files outside ``root`` are noted in ``report`` and not
    read, missing ones warned about. The OBJ's ``usemtl`` of materials that the material files
    read do not define, and materials whose only texture is ``map_Ka``, are warned about."""
    refs, defined, text = [], None, read_obj_text(path) if text is None else text
    for lib in mtllib_names(path, text):
        mtl = _read_as(path.parent, path.parent / lib, root, report, f"material file {printable(lib)}", "the OBJ")
        if not inside(mtl, root):
            refs.append((printable(lib), mtl))
            continue
        if not mtl.is_file() or (pointer := file_lfs_pointer(mtl)) is not None:
            why = "not found" if not mtl.is_file() else f"is {pointer}"
            report.warnings.append(f"material file {printable(lib)} {why}; rendered with the default material")
            report.reported.add(str(mtl.resolve()))
            continue
        materials = mtl_materials(read_obj_text(mtl))
        defined = (defined or set()) | set(materials.names)
        report.texture_only |= set(materials.texture_only)
        refs += [(f"{printable(name)} (from {printable(mtl.name)})", _read_as(
            mtl.parent, mtl.parent / name, root, report, f"texture {printable(name)} (from {printable(mtl.name)})",
            printable(mtl.name)))
                 for _, name in materials.textures]
        report.warnings += [f"material {printable(m)} of {printable(mtl.name)} gives its texture {printable(name)} as "
                            "map_Ka (ambient), which is not drawn (only map_Kd is); rendered in its colour"
                            for m, name in materials.ambient_only]
        for m in materials.names:  # a later file's material replaces an earlier one's of its name, as in the loader
            report.texture_moves.pop(m, None), report.wraps.pop(m, None)
        report.texture_moves.update(materials.moves)
        report.wraps.update({m: (CLAMP_TO_BORDER, CLAMP_TO_BORDER) for m, _ in materials.clamped})  # io.texture_wraps
    undefined = [] if defined is None else list(dict.fromkeys(
        m for m in statement_values(text, "usemtl") if m not in defined))
    if undefined:
        report.warnings.append(f"usemtl names {', '.join(printable(m) for m in undefined)}, which its material "
                               "files do not define; those faces are drawn with the default material")
    return refs


def named_files(path: Path, root: Path | None = None) -> list[Path]:
    """The companion files of mesh ``path`` inside :func:`texture_root` that it names, there or
    not: an OBJ's material files and the textures they name, a glTF's external images and buffer
    files, a PLY's textures (``comment TextureFile``); sorted, each once. What a rerun compares
    (``io.source_fingerprint.material_fingerprints``) to notice a texture replaced, or a missing one put
    in place. Unparseable files name none."""
    path = real_file(path)
    top, suffix = texture_root(path, root), path.suffix.lower()
    try:
        if suffix == ".obj":
            text, report = read_obj_text(path), MaterialReport()
            refs = _obj_refs(path, top, report, text) + [(lib, stand_in(path.parent, path.parent / lib, top) or
                                                          path.parent / lib) for lib in mtllib_names(path, text)]
            refs += [("as named", ref) for ref in report.replaced]  # one put in place is read instead
        elif suffix in (".glb", ".gltf"):  # its images, and its buffers in files (the geometry)
            doc = read_gltf(path)[0]  # not a glTF document: ValueError, the loader reports it
            refs = gltf_image_refs(path, doc, None, embedded_too=False)[0] + [
                (b["uri"], gltf_uri_path(path.parent, b["uri"])) for b in doc.get("buffers", [])
                if isinstance(b.get("uri"), str) and not b["uri"].startswith("data:")]
        elif suffix == ".ply":  # its textures, ``<this>`` filled in as the loader is given them
            refs = [(name, path.parent / name) for name in texture_names(path)]
        else:
            return []
        if suffix != ".obj":  # and the files read in place of those not there (io.stand_ins)
            refs += [(name, local) for name, ref in refs if (local := stand_in(path.parent, ref, top)) is not None]
    except (OSError, ValueError, KeyError, IndexError, TypeError, AttributeError, struct.error):
        return []
    return sorted({Path(os.path.abspath(ref)) for _, ref in refs if inside(ref, top)})


def material_report(path: Path, root: Path | None = None, outside: str = "warn",
                    gltf: GltfFile | None = None) -> MaterialReport:
    """The materials of mesh ``path`` (module doc), judged against :func:`texture_root`: files outside
    the root are decided on from their paths, before any is opened (``outside="refuse"``: a
    ``ValueError`` lists them; else ``report.outside``, never opened); the textures inside that are
    missing or undecodable go to ``report.problems``, the others to ``report.textures``. ``gltf``:
    a glTF/GLB ``path`` as ``io.gltf_check.judge_gltf`` read it (else it is read here); a GLB's
    binary chunk is read only where an image lies in it."""
    path = real_file(path)
    top = texture_root(path, root)
    report = MaterialReport()
    suffix = path.suffix.lower()
    try:
        if suffix == ".obj":
            refs, embedded = _obj_refs(path, top, report), []
        elif suffix in (".glb", ".gltf"):
            gltf = gltf if gltf is not None else GltfFile(path, read_gltf(path)[0])  # not glTF: ValueError, as above
            in_binary = any(isinstance(im, dict) and "bufferView" in im for im in gltf.doc.get("images", []))
            refs, embedded = gltf_image_refs(path, gltf.doc, gltf.binary if in_binary else None)
            refs = [(name, _read_as(path.parent, ref, top, report, f"texture {name}", "the glTF")) for name, ref in refs]
        elif suffix == ".ply":  # its TextureFile files there (a stand-in warned about) decoded as any; one
            # missing or outside is the resolver's to report (io.texture_resolver.loader_misses), as before
            refs = [(printable(name), _read_as(path.parent, path.parent / name, top, report,
                                               f"texture {printable(name)}", "the PLY")) for name in texture_names(path)]
            refs, embedded = [(name, ref) for name, ref in refs if inside(ref, top) and ref.is_file()], []
        else:
            return report
    except (OSError, ValueError, KeyError, IndexError, TypeError, AttributeError, struct.error):
        return report  # not parseable: the loader reports it
    kept = []
    for name, ref in refs:
        if inside(ref, top):
            kept.append((name, ref))
        elif str(ref.resolve()) not in report.reported:
            report.reported.add(str(ref.resolve()))
            report.outside.append(f"{ref.resolve()} lies outside the dataset folder {top.resolve()}")
    if (report.outside or report.leaving) and outside == "refuse":  # a stand-in does not excuse a ../ out
        raise ValueError("; ".join(report.outside + report.leaving))
    report.outside = [f"{o}: not read; rendered without it (--outside-textures)" for o in report.outside]
    for name, ref in dict.fromkeys(kept):  # a texture several materials name: judged and named once
        report.reported.add(str(ref.resolve()))
        moot = not_drawn(name)  # a glTF image the renderer does not draw: a warning (io.gltf_images)
        if not ref.is_file():
            (report.warnings if moot else report.problems).append(f"texture {name} not found" + MOOT * moot)
        elif (p := _image_problem(ref)) is not None and not name.endswith(UNDRAWN):
            (report.warnings if moot else report.problems).append(f"texture {name} unreadable ({p})" + MOOT * moot)
        else:
            report.textures.append(printable(ref.name))
    for name, data in embedded:
        if (p := _image_problem(data)) is not None:
            moot = not_drawn(name)
            (report.warnings if moot else report.problems).append(f"{name} unreadable ({p})" + MOOT * moot)
    return report
