"""Load mesh files (OBJ(+MTL, textures), GLB/GLTF, PLY, OFF, STL) as one object and validate them.

Every file becomes a ``trimesh.Scene`` (a multi-part file is one object: all its geometries
with their node transforms). ``load_mesh_triangles`` returns exactly the triangles the
renderer draws, in the SOURCE frame of the file (node transforms baked in); the canonical
frame is reached with the 4x4 ``to_canonical`` of ``sc3d_data.geometry.normalize``.

Bad input raises ``MeshError`` whose message names the file and the problem: a path that is not
a regular file (FIFO, device, a symlink to one: never opened), a file over ``max_file_bytes``
(checked before parsing), a file that does not parse, no triangles, NaN/inf vertices, zero
surface area, more than ``max_faces`` triangles, coordinates beyond float32 range (the renderer
draws in float32), a file whose text cannot be decoded, an OBJ face that names index 0 (OBJ
counts from 1; trimesh would silently read 0 as the last vertex: ``io.obj_loader_text``), a glTF/GLB that draws a
TRIANGLE_FAN primitive (which trimesh skips) or a sparse POSITION/indices accessor (which trimesh
does not apply; both judged from the JSON by ``sc3d_data.io.gltf_check``), or (``bad_texture="fail"``, the default)
a texture that is named but cannot be read, decoded or loaded. Warnings (recorded in the index,
the object still renders): an OBJ's ``.mtl`` that is missing, textures not loaded
(``bad_texture="fallback"``), and material or texture files outside the dataset folder, which
are never read (``outside_textures="refuse"`` makes them a failure). Which files a mesh may read
is ``sc3d_data.io.materials``' business. Loaders that hang are handled by the per-object time
limit of ``sc3d_data.pipeline.executors.local_pool`` (a worker is killed), not here.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from sc3d_data.geometry.normalize import used_vertices
from sc3d_data.io.lfs_pointers import file_lfs_pointer

MESH_SUFFIXES = (".obj", ".glb", ".gltf", ".ply", ".off", ".stl")
#: meshes with more triangles than this are rejected (``--max-faces``; a 2-million-face mesh is skipped)
DEFAULT_MAX_FACES = 1_000_000
#: largest coordinate accepted: the renderer draws float32 positions scaled by 1/extent, and
#: below sqrt(float32 max) ~ 1.8e19 both the coordinates and that scale stay normal float32
FLOAT32_SAFE = 1e18
#: what to do with a texture read from outside the dataset folder
OUTSIDE_TEXTURES = ("warn", "refuse")
#: mesh files larger than this (bytes) are rejected before parsing (``--max-file-mib``); the
#: largest real meshes (ShapeNet, Objaverse GLBs with textures) stay far below it
DEFAULT_MAX_FILE_BYTES = 2 * 2**30


class MeshError(ValueError):
    """A mesh file that cannot be used; the message names the file and the reason."""


def load_scene(path: Path, resolver=None, text: bytes | None = None, text_type: str | None = None):
    """Parse ``path`` (or ``text``, its content to load instead: ``io.obj_loader_text``,
    ``io.gltf_loader_doc``; in format ``text_type``, default the file's suffix) into a
    ``trimesh.Scene`` (no validation), reading the files it names through ``resolver``
    (``io.texture_resolver.make_resolver``; None: trimesh's own, rooted at the mesh's folder).
    Raises ``MeshError`` when the file does not parse."""
    import io

    import trimesh

    from sc3d_data.io.loader_visuals import NotFiniteColours
    from sc3d_data.io.texture_resolver import quiet_loader

    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise MeshError(f"{path}: unsupported mesh format {path.suffix!r} (use one of {', '.join(MESH_SUFFIXES)})")
    try:
        source = dict(file_obj=str(path)) if text is None else dict(file_obj=io.BytesIO(text),
                                                                     file_type=text_type or path.suffix.lower().lstrip("."))
        # NumPy's warnings of NaN/inf (a glTF node transform of 1e309) named no file: what reaches the drawn
        # triangles is refused naming it (io.gltf_structure, validate_triangles), the rest draws nothing
        with quiet_loader(), np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            scene = trimesh.load(**source, force="scene", process=False, resolver=resolver)
    except (UnicodeDecodeError, ModuleNotFoundError) as e:  # text formats: bytes that no charset decodes
        raise MeshError(f"{path}: cannot decode the file as text (not UTF-8 and no other encoding "
                        f"detected; {type(e).__name__}: {e})") from e
    except NotFiniteColours as e:  # parsed, and refused by sc3d's wrapper of the loader
        raise MeshError(f"{path}: {e}") from e
    except Exception as e:  # trimesh raises many kinds of errors on garbage
        raise MeshError(f"{path}: cannot parse mesh file ({type(e).__name__}: {e})") from e
    return scene


def scene_triangles(scene, source: str = "mesh") -> tuple[np.ndarray, np.ndarray]:
    """All triangles of a ``trimesh.Scene`` with node transforms baked in:
    ``(vertices [n,3] float64, faces [m,3] int64)`` in the scene's (source) frame. ``MeshError``
    naming ``source`` when a geometry's vertices do not have 3 coordinates (an OBJ ``v 1 2``)."""
    import trimesh

    verts, faces, offset = [], [], 0
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        geom = scene.geometry[name]
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue
        v = np.asarray(geom.vertices, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 3:
            raise MeshError(f"{source}: the vertices of {name!r} have {v.shape[-1] if v.ndim else 0} coordinates, "
                            "expected 3 (x y z)")
        with np.errstate(invalid="ignore", over="ignore"):  # NaN/inf: validate_triangles names the file
            v = v @ transform[:3, :3].T + transform[:3, 3]
        verts.append(v)
        faces.append(np.asarray(geom.faces, dtype=np.int64) + offset)
        offset += len(v)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.concatenate(verts), np.concatenate(faces)


def validate_triangles(vertices: np.ndarray, faces: np.ndarray, source: str = "mesh",
                       max_faces: int = DEFAULT_MAX_FACES) -> np.ndarray:
    """The triangles of ``faces [m,3]`` that have area (``geometry.triangle_area``: a triangle of
    none draws nothing, and its corners must not move the normalisation's bounding box nor leave
    a voxel); raise ``MeshError`` naming ``source`` when the triangles cannot make an object:
    no triangles, more than ``max_faces``, a corner naming no vertex (an index below 0 or past
    the last vertex: a file's index data out of range, which trimesh keeps), non-finite
    coordinates, or no triangle with area."""
    from sc3d_data.geometry.triangle_area import triangles_with_area

    if len(faces) == 0:
        raise MeshError(f"{source}: empty mesh (no triangles)")
    if max_faces and len(faces) > max_faces:
        raise MeshError(f"{source}: {len(faces):,} triangles, more than the limit of {max_faces:,} (--max-faces)")
    outside = (faces < 0) | (faces >= len(vertices))
    if outside.any():
        raise MeshError(f"{source}: {int(outside.sum()):,} triangle corners name no vertex (indices from "
                        f"{int(faces.min()):,} to {int(faces.max()):,}, but it has {len(vertices):,} vertices)")
    used = used_vertices(vertices, faces)
    bad = ~np.isfinite(used).all(axis=1)
    if bad.any():
        raise MeshError(f"{source}: {int(bad.sum())} vertices with NaN/inf coordinates")
    big = (np.abs(used) > FLOAT32_SAFE).any(axis=1)
    if big.any():
        raise MeshError(f"{source}: {int(big.sum())} vertices with coordinates beyond +-{FLOAT32_SAFE:.0e} "
                        f"(largest {np.abs(used).max():.3g}); the renderer draws in float32")
    keep = triangles_with_area(np.ascontiguousarray(vertices, dtype=np.float64),
                               np.ascontiguousarray(faces, dtype=np.int64))
    if not keep.any():
        raise MeshError(f"{source}: zero surface area (all {len(faces)} triangles degenerate)")
    return faces if keep.all() else faces[keep]


# ----------------------------------------------------------------------------- the file itself
def check_mesh_file(path: Path, max_file_bytes: int = DEFAULT_MAX_FILE_BYTES) -> None:
    """Raise ``MeshError`` naming ``path`` when it is not a regular file (a FIFO, a device, a
    symlink to one: never opened), is larger than ``max_file_bytes`` (checked before parsing) or
    is a Git LFS pointer in place of the mesh (``io.lfs_pointers``)."""
    import stat

    try:
        st = os.stat(path)
    except OSError as e:
        raise MeshError(f"{path}: cannot be read ({e.strerror or e})") from e
    if not stat.S_ISREG(st.st_mode):
        via = f" (a symlink to {os.path.realpath(path)})" if os.path.islink(path) else ""
        raise MeshError(f"{path}: not a regular file but a {file_kind(st.st_mode)}{via}; not read")
    if max_file_bytes and st.st_size > max_file_bytes:
        raise MeshError(f"{path}: {st.st_size:,} bytes, over the limit of {max_file_bytes:,} per mesh file "
                        f"(--max-file-mib); not parsed")
    if (pointer := file_lfs_pointer(path)) is not None:
        raise MeshError(f"{path}: {pointer}; not read")


def file_kind(mode: int) -> str:
    """``"FIFO"``, ``"character device"``, ... for an ``os.stat`` ``st_mode``."""
    import stat

    kinds = ((stat.S_ISDIR, "folder"), (stat.S_ISFIFO, "FIFO"), (stat.S_ISCHR, "character device"),
             (stat.S_ISBLK, "block device"), (stat.S_ISSOCK, "socket"))
    return next((name for test, name in kinds if test(mode)), "special file")


# ----------------------------------------------------------------------------- public API
def load_mesh(path: Path, max_faces: int = DEFAULT_MAX_FACES, bad_texture: str = "fail",
              root: Path | None = None, outside_textures: str = "warn",
              max_file_bytes: int = DEFAULT_MAX_FILE_BYTES):
    """Load and validate one mesh file as a single object.

    Returns ``(scene, vertices, faces, warnings)``: the ``trimesh.Scene`` to render, its
    triangles with area in the source frame (``vertices [n,3]`` float64, ``faces [m,3]`` int64,
    node transforms baked in; triangles of no area, which draw nothing, left out:
    :func:`validate_triangles`) and a list of warnings (textures replaced by material colours when
    ``bad_texture="fallback"``, missing ``.mtl`` files, material files outside the folder
    ``root``, never read: refused when ``outside_textures="refuse"``). Raises ``MeshError`` on
    bad input (see module doc)."""
    from sc3d_data.io.gltf_check import drawn_meshes, judge_gltf
    from sc3d_data.io.gltf_features import feature_warnings, read_spec_gloss_as_matte
    from sc3d_data.io.gltf_loader_doc import loader_gltf_bytes
    from sc3d_data.io.loaded_scene import finish_visuals
    from sc3d_data.io.loader_visuals import keep_obj_vertex_colours
    from sc3d_data.io.materials import material_report
    from sc3d_data.io.obj_keyword_case import check_keyword_case
    from sc3d_data.io.obj_loader_text import check_obj_indices, loader_obj_bytes
    from sc3d_data.io.off_colours import coloured_off_as_ply
    from sc3d_data.io.off_polygons import faces_one_per_line, loader_off_bytes
    from sc3d_data.io.ply_header import loader_ply_bytes
    from sc3d_data.io.ply_textures import split_by_texnumber
    from sc3d_data.io.stl_check import loader_stl_bytes
    from sc3d_data.io.texture_resolver import loader_misses, make_resolver

    path = Path(path)
    if bad_texture not in ("fail", "fallback"):
        raise ValueError(f"bad_texture must be 'fail' or 'fallback', not {bad_texture!r}")
    if outside_textures not in OUTSIDE_TEXTURES:
        raise ValueError(f"outside_textures must be one of {OUTSIDE_TEXTURES}, not {outside_textures!r}")
    check_mesh_file(path, max_file_bytes)
    # glTF/GLB only: not a glTF document, or unread geometry; skins' buffer files read as the loader reads files
    skin_files = make_resolver(path, root) if path.suffix.lower() in (".gltf", ".glb") else None
    gltf, refusal = judge_gltf(path, resolver=skin_files)
    gltf_doc = gltf.doc if gltf is not None else None
    if refusal is not None:
        raise MeshError(refusal)
    try:
        report = material_report(path, root, outside_textures, gltf)
    except ValueError as e:
        raise MeshError(f"{path}: {e} (refused by --outside-textures refuse)") from e
    if report.problems and bad_texture == "fail":
        raise MeshError(f"{path}: {'; '.join(report.problems)} (use --bad-texture fallback to render with "
                        "material colours)")
    text = None if gltf_doc is None else loader_gltf_bytes(gltf, skin_files)  # the text the loader reads right:
    ply_of_off, off_notes = coloured_off_as_ply(path) if path.suffix.lower() == ".off" else (None, [])  # as PLY
    try:
        text = {".ply": lambda p: loader_ply_bytes(p, max_faces), ".off": lambda p: ply_of_off or loader_off_bytes(p),
                ".stl": loader_stl_bytes}.get(path.suffix.lower(), lambda _: text)(path)
    except ValueError as e:  # io.stl_check: a triangle count that cannot be trusted
        raise MeshError(f"{path}: {e}; not read") from e
    if path.suffix.lower() == ".obj":
        data = path.read_bytes()
        try:
            check_obj_indices(data)
            report.warnings += check_keyword_case(data)  # MTLLIB, USEMTL: not read, as by OBJ readers; V, F: refused
            text = loader_obj_bytes(data)  # relative indices as the format counts them; a non-UTF-8 file as Latin-1
        except ValueError as e:
            raise MeshError(f"{path}: {e}; not read") from e
    resolver = make_resolver(path, root)
    read_spec_gloss_as_matte()
    keep_obj_vertex_colours()
    scene = load_scene(path, resolver, text, "ply" if ply_of_off else None)
    if path.suffix.lower() == ".off" and not any(len(getattr(g, "faces", ())) for g in scene.geometry.values()) \
            and (relined := faces_one_per_line(path)) is not None:  # face lists over several lines
        scene = load_scene(path, resolver, relined)
    if (refusal := split_by_texnumber(scene, path, resolver)) is not None:  # a PLY's textures, before misses are judged
        raise MeshError(refusal)
    missed = loader_misses(resolver, report)
    if missed and bad_texture == "fail":
        raise MeshError(f"{path}: {'; '.join(missed)} (use --bad-texture fallback to render with material colours)")
    if (refusal := finish_visuals(scene, path, report, gltf_doc)) is not None:  # what the loader drops
        raise MeshError(refusal)
    vertices, faces = scene_triangles(scene, str(path))
    faces = validate_triangles(vertices, faces, str(path), max_faces)
    notes = report.warnings + report.outside + (feature_warnings(gltf_doc, drawn_meshes(gltf_doc, safe=True))
                                                if gltf_doc is not None else []) + off_notes
    warnings = ([f"{path}: {p}; rendered with material colours" for p in report.problems + missed]
                + [f"{path}: {n}" for n in notes] + unused_texture_warnings(path, scene, report))
    return scene, vertices, faces, warnings


def unused_texture_warnings(path: Path, scene, report) -> list[str]:
    """One warning when OBJ ``path``'s materials name ``map_Kd`` textures that exist and decode
    (``report.textures``: :func:`~sc3d_data.io.materials.material_report`) but no geometry of the loaded
    ``scene`` is drawn with one (it needs a texture image and coordinates: faces without ``vt``
    are drawn in the material's colour): such an object would otherwise render untextured
    without a word."""
    from sc3d_data.io.loader_visuals import is_placeholder

    if Path(path).suffix.lower() != ".obj" or report.problems:
        return []
    named = sorted(set(report.textures))
    for geometry in scene.geometry.values():
        visual = getattr(geometry, "visual", None)
        material = getattr(visual, "material", None)
        if getattr(visual, "kind", None) == "texture" and getattr(visual, "uv", None) is not None \
                and getattr(material, "image", None) is not None and not is_placeholder(material):
            return []
    return [f"{path}: its materials name the texture(s) {', '.join(named)}, but no face is drawn with them (faces "
            "without texture coordinates `vt`?); rendered with material colours"] if named else []


def load_mesh_triangles(path: Path, max_faces: int = DEFAULT_MAX_FACES) -> tuple[np.ndarray, np.ndarray]:
    """The exact geometry the renderer draws for ``path`` (its triangles with area): ``(vertices
    [n,3] float64, faces [m,3] int64)`` in the SOURCE frame (all scene geometry, node transforms baked in).
    Apply the shard's ``to_canonical`` with ``sc3d_data.geometry.normalize.apply_transform`` to get
    canonical coordinates. Raises ``MeshError`` on bad input."""
    _, vertices, faces, _ = load_mesh(path, max_faces=max_faces, bad_texture="fallback")
    return vertices, faces
