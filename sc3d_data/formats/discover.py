"""Find the meshes under a folder and name them: ``(category, model_id)`` per mesh.

Layouts recognised (``root`` is what the user passes to ``--meshes``):

* ShapeNetCore v1: ``SYNSET/MODEL_ID/model.obj``
* ShapeNetCore v2: ``SYNSET/MODEL_ID/models/model_normalized.obj``
  (``SYNSET`` is an 8-digit synset id; these two rules apply wherever the synset folder sits:
  ``root`` may be the ShapeNetCore folder, one synset folder, or a folder above them.)
  Inside a ShapeNet model folder only that mesh is used (textures, ``.mtl``, ``.json``,
  ``.binvox`` are not meshes; any other mesh file in it is reported as skipped). A model
  folder without it is reported as a problem.
* ``CATEGORY/NAME.ext`` (any of ``MESH_EXTENSIONS``): category = the folder's name, mapped to
  its synset id when it is a known name (``airplane`` -> ``02691156``), model id = ``NAME``.
* Deeper folders ``CATEGORY/A/B/NAME.ext``: category = the top-level folder under ``root``,
  model id = the path below it without the extension (``A/B/NAME``), so ids stay unique.
* A flat folder ``root/NAME.ext``: category = ``root``'s own folder name (mapped like above).

Symlinks are followed; a symlink that leads back into one of its own ancestors is a loop and is
reported, not followed. Hidden files and folders (name starting with ``.``) are skipped.
Things named like a mesh that are not regular files (a folder ``x.obj/``, a FIFO, a device) are
reported as problems with ``"skipped": True`` (a render lists them under ``skipped``); a folder's
contents are still searched.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable

from sc3d_data.formats.shapenet import is_synset_id, resolve_categories, resolve_category
from sc3d_data.io.materials import SHAPENET_V2_MESH
from sc3d_data.io.names import normal_form_note, normal_forms

MESH_EXTENSIONS = (".obj", ".glb", ".gltf", ".ply", ".off", ".stl")
SHAPENET_V1_MESH = ("model.obj",)


@dataclass(frozen=True)
class MeshEntry:
    """One mesh found on disk.

    ``path``: the mesh file; ``model_id``: ShapeNet model id, or the file stem (path below the
    category folder without extension for deeper layouts); ``category``: ShapeNet synset id
    where known, else the folder name."""

    path: Path
    model_id: str
    category: str


def _problem(source, reason: str, skipped: bool = False) -> dict:
    p = {"source": str(source), "reason": reason}
    if skipped:
        p["skipped"] = True
    return p


def _walk(root: Path, problems: list[dict]) -> list[tuple[Path, list[str]]]:
    """All folders under ``root`` (``root`` included), following symlinks with loop detection.

    Returns ``[(folder, sorted file names)]``; folders that cannot be read are reported."""
    out: list[tuple[Path, list[str]]] = []

    def visit(folder: Path, ancestors: frozenset) -> None:
        try:
            st = folder.stat()
            key = (st.st_dev, st.st_ino)
            if key in ancestors:
                problems.append(_problem(folder, "symlink loop: this folder leads back to one of "
                                                 "its own parent folders; not followed"))
                return
            with os.scandir(folder) as it:
                children = sorted(it, key=lambda e: e.name)
        except PermissionError as e:
            problems.append(_problem(folder, f"folder cannot be read ({e.strerror or e})"))
            return
        except OSError as e:
            problems.append(_problem(folder, f"folder cannot be read ({e.strerror or e})"))
            return
        files, dirs = [], []
        for child in children:
            if child.name.startswith("."):
                continue
            mesh_name = Path(child.name).suffix.lower() in MESH_EXTENSIONS
            try:
                if child.is_dir(follow_symlinks=True):
                    dirs.append(child.name)
                    if mesh_name:
                        problems.append(_problem(folder / child.name, "a folder named like a mesh file, "
                                                 "not a mesh (its contents are searched)", skipped=True))
                elif child.is_file(follow_symlinks=True):
                    files.append(child.name)
                elif child.is_symlink() and not os.path.exists(child.path):
                    problems.append(_problem(folder / child.name, "broken symlink"))
                elif mesh_name:
                    problems.append(_problem(folder / child.name, _special_reason(child.path), skipped=True))
            except OSError as e:
                problems.append(_problem(folder / child.name, f"cannot be read ({e.strerror or e})"))
        out.append((folder, files))
        for d in dirs:
            visit(folder / d, ancestors | {key})

    visit(root, frozenset())
    return out


def _special_reason(path: str) -> str:
    """Why ``path`` (not a regular file or folder) is not read: its kind, and where a symlink leads."""
    from sc3d_data.io.meshes import file_kind

    kind = file_kind(os.stat(path).st_mode)
    via = f", a symlink to {os.path.realpath(path)}" if os.path.islink(path) else ""
    return f"not a regular file ({kind}{via}); not read"


def _shapenet_model_dir(folder: Path, root: Path) -> tuple[Path, str, str] | None:
    """``(model folder as walked, synset, model id)`` of the ShapeNet model folder
    (``SYNSET/MODEL_ID``) that ``folder`` (walked from ``root``) is or lies in, if any.

    Names are read from the absolute path, so ``--meshes .`` inside a synset folder reads as
    its full path. A model folder at or above ``root`` (``root`` itself, or the folder that holds
    a v2 ``models/`` given as ``root``) counts only when it holds ShapeNet's mesh (``model.obj``
    or ``models/model_normalized.obj``): a folder of plain meshes whose parent has an 8-digit
    name (a date, a job id) is not a model folder."""
    here, top = Path(os.path.abspath(folder)), Path(os.path.abspath(root))
    for cand, walked in ((here, folder), (here.parent, folder.parent)):
        if cand.parent == cand or not is_synset_id(cand.parent.name) or is_synset_id(cand.name):
            continue
        below_root = cand != top and top in cand.parents
        if below_root or (cand / SHAPENET_V1_MESH[0]).is_file() or cand.joinpath(*SHAPENET_V2_MESH).is_file():
            return walked, cand.parent.name, cand.name
    return None


def discover_meshes(root, categories=None, category_override=None
                    ) -> tuple[list[MeshEntry], list[dict]]:
    """Find the meshes under ``root`` (a folder, or a single mesh file).

    ``categories``: names or synset ids (``"airplane,car"`` or an iterable) to keep; ``None``
    keeps all. ``category_override``: one category (name or id) given to every mesh instead of
    the one derived from the layout.

    Returns ``(entries, problems)``: entries sorted by ``(category, model_id)`` and unique in
    that pair (the first path in sorted order wins; the others are reported), and problems
    ``[{"source": path, "reason": text}]``.
    """
    root = Path(root)
    problems: list[dict] = []
    if not root.exists():
        raise FileNotFoundError(f"{root}: no such file or folder")
    found: list[MeshEntry] = []
    if root.is_file():
        if root.suffix.lower() not in MESH_EXTENSIONS:
            raise ValueError(f"{root}: not a mesh file (expected one of {', '.join(MESH_EXTENSIONS)})")
        file = Path(os.path.abspath(root))
        model = _shapenet_model_dir(file.parent, file.parent)
        if model is not None and file in (model[0] / SHAPENET_V1_MESH[0], model[0].joinpath(*SHAPENET_V2_MESH)):
            found.append(MeshEntry(root, model[2], model[1]))  # SYNSET/MODEL_ID/.../model*.obj
        else:
            found.append(MeshEntry(root, root.stem, resolve_category(file.parent.name or "unknown")))
    else:
        root_name = Path(os.path.abspath(root)).name  # as given: a symlinked folder is named by its link
        folders = _walk(root, problems)
        shapenet_models: dict[Path, Path | None] = {}   # model folder -> its mesh (None: none yet)
        model_ids: dict[Path, tuple[str, str]] = {}     # model folder -> (synset, model id)
        model_files: dict[Path, list[Path]] = {}        # model folder -> every mesh file inside it
        for folder, files in folders:
            model = _shapenet_model_dir(folder, root)
            if model is not None:
                model_dir = model[0]
                model_ids[model_dir] = model[1:]
                shapenet_models.setdefault(model_dir, None)
                model_files.setdefault(model_dir, []).extend(
                    folder / f for f in files if Path(f).suffix.lower() in MESH_EXTENSIONS)
                v1 = model_dir / SHAPENET_V1_MESH[0]
                v2 = model_dir.joinpath(*SHAPENET_V2_MESH)
                if folder == model_dir and SHAPENET_V1_MESH[0] in files:
                    shapenet_models[model_dir] = v1
                elif (folder == v2.parent and SHAPENET_V2_MESH[-1] in files
                      and shapenet_models[model_dir] is None):
                    shapenet_models[model_dir] = v2
                continue
            meshes = [f for f in files if Path(f).suffix.lower() in MESH_EXTENSIONS]
            if not meshes:
                continue
            rel = folder.relative_to(root).parts
            for name in meshes:
                path = folder / name
                if not rel:      # flat folder: category = the folder's own name
                    category = root_name or "unknown"
                    model_id = Path(name).stem
                else:
                    category = rel[0]
                    model_id = "/".join(rel[1:] + (Path(name).stem,))
                found.append(MeshEntry(path, model_id, resolve_category(category)))
        wanted_synsets = (resolve_categories(categories)
                          if categories is not None and not category_override else None)
        for model_dir, mesh in shapenet_models.items():
            synset, model_id = model_ids[model_dir]
            if mesh is None and (wanted_synsets is None or synset in wanted_synsets):
                problems.append(_problem(model_dir, "ShapeNet model folder without its mesh "
                                                    "(neither model.obj nor models/model_normalized.obj)"))
            elif mesh is not None:
                found.append(MeshEntry(mesh, model_id, synset))
            if wanted_synsets is None or synset in wanted_synsets:
                problems += [_problem(f, f"in ShapeNet model folder {model_dir.name} but not its mesh (only "
                                         f"{mesh.relative_to(model_dir) if mesh else 'model.obj'} is read)", skipped=True)
                             for f in sorted(model_files[model_dir]) if f != mesh]

    if category_override:
        cat = resolve_category(str(category_override))
        found = [replace(e, category=cat) for e in found]
    if categories is not None:
        wanted = resolve_categories(categories)
        present = {e.category for e in found}
        for c in sorted(wanted - present):
            problems.append(_problem(root, f"requested category {c!r} matches no mesh"
                                           + normal_form_note(c, normal_forms(present))))
        found = [e for e in found if e.category in wanted]

    found.sort(key=lambda e: (e.category, e.model_id, str(e.path)))
    entries: list[MeshEntry] = []
    for e in found:
        if entries and (entries[-1].category, entries[-1].model_id) == (e.category, e.model_id):
            problems.append(_problem(e.path, f"duplicate id {e.category}/{e.model_id} "
                                             f"(also {entries[-1].path}, which is used)"))
            continue
        entries.append(e)
    return entries, problems


#: file name ends of 3D formats sc3d does not read, named in :func:`no_meshes_found`'s error
OTHER_3D_FORMATS = (".fbx", ".dae", ".3ds", ".blend", ".usd", ".usda", ".usdc", ".usdz", ".x3d", ".wrl", ".3mf",
                    ".abc", ".max", ".ma", ".mb", ".c4d", ".lwo", ".drc", ".step", ".stp", ".iges", ".igs",
                    ".skp", ".ifc", ".dxf", ".x", ".ase", ".ms3d", ".md2", ".md5mesh", ".b3d", ".ac", ".vtk")


def no_meshes_found(root) -> ValueError:
    """The error of a ``--meshes`` folder holding nothing named like a mesh (one line, exit 1);
    where it holds files of 3D formats sc3d does not read (``.fbx``, ``.usdz``, ...), it names
    them and says to convert them."""
    found: dict[str, int] = {}
    for _, dirs, files in os.walk(root, followlinks=False):
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        for name in files:
            if (suffix := os.path.splitext(name)[1].lower()) in OTHER_3D_FORMATS and not name.startswith("."):
                found[suffix] = found.get(suffix, 0) + 1
    others = ""
    if found:
        kinds = ", ".join(f"{n:,} {suffix}" for suffix, n in sorted(found.items(), key=lambda kv: (-kv[1], kv[0])))
        others = (f"; it holds {sum(found.values()):,} files of 3D formats sc3d does not read ({kinds}): "
                  "convert them to glTF/GLB or OBJ, e.g. with Blender or assimp")
    return ValueError(f"--meshes {root}: no mesh files found (looked for {', '.join(MESH_EXTENSIONS)}){others}")


def categories_of(entries: Iterable[MeshEntry]) -> list[str]:
    """Sorted distinct categories of ``entries``."""
    return sorted({e.category for e in entries})
