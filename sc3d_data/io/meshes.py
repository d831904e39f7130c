"""Load mesh files (OBJ(+MTL, textures), GLB/GLTF, PLY, OFF, STL) as one object and validate them.

Every file becomes a ``trimesh.Scene`` (a multi-part file is one object: all its geometries
with their node transforms). ``load_mesh_triangles`` returns exactly the triangles the
renderer draws, in the SOURCE frame of the file (node transforms baked in); the canonical
frame is reached with the 4x4 ``to_canonical`` of ``sc3d_data.geometry.normalize``.

Bad input raises ``MeshError`` whose message names the file and the problem: a file that does
not parse, no triangles, NaN/inf vertices, zero surface area, more than ``max_faces``
triangles, or (``bad_texture="fail"``, the default) a texture that is referenced but cannot be
read or decoded, coordinates beyond float32 range (the renderer draws in float32), or an OBJ
whose text cannot be decoded. Warnings (recorded in the index, the object still renders): an
OBJ's ``.mtl`` that is missing, and a texture read from outside the dataset folder (an absolute
path or ``../``; ``outside_textures="refuse"`` makes that a failure). Loaders that hang are handled by the per-object time limit of
``sc3d_data.pipeline.local_pool`` (a worker is killed), not here.
"""
from __future__ import annotations

import json
import re
import struct
from pathlib import Path

import numpy as np

from sc3d_data.geometry.normalize import used_vertices

MESH_SUFFIXES = (".obj", ".glb", ".gltf", ".ply", ".off", ".stl")
#: meshes with more triangles than this are rejected (so a 2-million-face mesh is skipped);
#: ``--max-faces`` changes it
DEFAULT_MAX_FACES = 1_000_000
#: largest coordinate accepted: the renderer draws float32 positions scaled by 1/extent, and
#: below sqrt(float32 max) ~ 1.8e19 both the coordinates and that scale stay normal float32
FLOAT32_SAFE = 1e18
#: what to do with a texture read from outside the dataset folder
OUTSIDE_TEXTURES = ("warn", "refuse")


class MeshError(ValueError):
    """A mesh file that cannot be used; the message names the file and the reason."""


def load_scene(path: Path):
    """Parse ``path`` into a ``trimesh.Scene`` (no validation). Raises ``MeshError`` when the
    file does not parse."""
    import trimesh

    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise MeshError(f"{path}: unsupported mesh format {path.suffix!r} (use one of {', '.join(MESH_SUFFIXES)})")
    try:
        scene = trimesh.load(str(path), force="scene", process=False)
    except (UnicodeDecodeError, ModuleNotFoundError) as e:  # text formats: bytes that no charset decodes
        raise MeshError(f"{path}: cannot decode the file as text (not UTF-8 and no other encoding "
                        f"detected; {type(e).__name__}: {e})") from e
    except Exception as e:  # trimesh raises many kinds of errors on garbage
        raise MeshError(f"{path}: cannot parse mesh file ({type(e).__name__}: {e})") from e
    return scene


def scene_triangles(scene) -> tuple[np.ndarray, np.ndarray]:
    """All triangles of a ``trimesh.Scene`` with node transforms baked in:
    ``(vertices [n,3] float64, faces [m,3] int64)`` in the scene's (source) frame."""
    import trimesh

    verts, faces, offset = [], [], 0
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        geom = scene.geometry[name]
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue
        v = np.asarray(geom.vertices, dtype=np.float64)
        v = v @ transform[:3, :3].T + transform[:3, 3]
        verts.append(v)
        faces.append(np.asarray(geom.faces, dtype=np.int64) + offset)
        offset += len(v)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.concatenate(verts), np.concatenate(faces)


def validate_triangles(vertices: np.ndarray, faces: np.ndarray, source: str = "mesh",
                       max_faces: int = DEFAULT_MAX_FACES) -> None:
    """Raise ``MeshError`` naming ``source`` when the triangles cannot make an object:
    no triangles, more than ``max_faces``, non-finite coordinates, or zero total area."""
    if len(faces) == 0:
        raise MeshError(f"{source}: empty mesh (no triangles)")
    if max_faces and len(faces) > max_faces:
        raise MeshError(f"{source}: {len(faces):,} triangles, more than the limit of {max_faces:,} (--max-faces)")
    used = used_vertices(vertices, faces)
    bad = ~np.isfinite(used).all(axis=1)
    if bad.any():
        raise MeshError(f"{source}: {int(bad.sum())} vertices with NaN/inf coordinates")
    big = (np.abs(used) > FLOAT32_SAFE).any(axis=1)
    if big.any():
        raise MeshError(f"{source}: {int(big.sum())} vertices with coordinates beyond +-{FLOAT32_SAFE:.0e} "
                        f"(largest {np.abs(used).max():.3g}); the renderer draws in float32")
    tri = vertices[faces]
    with np.errstate(over="ignore", invalid="ignore"):
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    if not area > 0:
        raise MeshError(f"{source}: zero surface area (all {len(faces)} triangles degenerate)")


# ----------------------------------------------------------------------------- textures
def _image_problem(data_or_path) -> str | None:
    from PIL import Image
    import io

    try:
        src = io.BytesIO(data_or_path) if isinstance(data_or_path, (bytes, bytearray)) else data_or_path
        with Image.open(src) as im:
            im.load()
    except Exception as e:
        return f"{type(e).__name__}: {e}"
    return None


def _outside(ref: Path, root: Path | None) -> bool:
    """True when ``ref`` (a texture or material file) resolves outside the folder ``root``."""
    if root is None:
        return False
    try:
        Path(ref).resolve().relative_to(Path(root).resolve())
    except ValueError:
        return True
    return False


def _obj_materials(path: Path, root: Path | None) -> tuple[list[str], list[str], list[Path]]:
    """``(problems, warnings, referenced files)`` of an OBJ's materials: problems = textures
    missing or unreadable; warnings = ``mtllib`` files that are missing; referenced = every
    ``.mtl`` and texture path it names (for the outside-the-folder check)."""
    problems, warnings, refs = [], [], []
    text = path.read_text(errors="replace")
    for lib in re.findall(r"^\s*mtllib\s+(.+?)\s*$", text, flags=re.M):
        mtl = path.parent / lib
        refs.append(mtl)
        if not mtl.is_file():
            warnings.append(f"material file {lib} not found; rendered with the default material")
            continue
        for tex in re.findall(r"^\s*map_Kd\s+(?:-\S+\s+\S+\s+)*(.+?)\s*$", mtl.read_text(errors="replace"), flags=re.M):
            tex_path = mtl.parent / tex.replace("\\", "/")
            refs.append(tex_path)
            if not tex_path.is_file():
                problems.append(f"texture {tex} (from {mtl.name}) not found")
            elif (p := _image_problem(tex_path)) is not None:
                problems.append(f"texture {tex} (from {mtl.name}) unreadable ({p})")
    return problems, warnings, refs


def _gltf_texture_problems(path: Path) -> tuple[list[str], list[str], list[Path]]:
    raw = path.read_bytes()
    binary = None
    if path.suffix.lower() == ".glb":
        if len(raw) < 20 or raw[:4] != b"glTF":
            return [], [], []  # the parser reports it
        json_len = struct.unpack_from("<I", raw, 12)[0]
        doc = json.loads(raw[20:20 + json_len])
        rest = 20 + json_len
        if len(raw) >= rest + 8:
            bin_len = struct.unpack_from("<I", raw, rest)[0]
            binary = raw[rest + 8:rest + 8 + bin_len]
    else:
        doc = json.loads(raw)
    problems, refs = [], []
    for i, image in enumerate(doc.get("images", [])):
        if "uri" in image:
            uri = image["uri"]
            if uri.startswith("data:"):
                continue
            img_path = path.parent / uri
            refs.append(img_path)
            if not img_path.is_file():
                problems.append(f"texture image {i} ({uri}) not found")
                continue
            p = _image_problem(img_path)
        elif "bufferView" in image and binary is not None:
            view = doc["bufferViews"][image["bufferView"]]
            start = view.get("byteOffset", 0)
            p = _image_problem(binary[start:start + view["byteLength"]])
        else:
            continue
        if p is not None:
            problems.append(f"texture image {i} unreadable ({p})")
    return problems, [], refs


def material_report(path: Path, root: Path | None = None) -> tuple[list[str], list[str]]:
    """``(problems, warnings)`` of the materials of ``path``. Problems: referenced textures
    that are missing or do not decode (OBJ via its MTL files, GLTF external images, GLB
    embedded images). Warnings: missing ``.mtl`` files, and material/texture files that lie
    outside the folder ``root`` (None: no such check)."""
    path = Path(path)
    try:
        suffix = path.suffix.lower()
        if suffix == ".obj":
            problems, warnings, refs = _obj_materials(path, root)
        elif suffix in (".glb", ".gltf"):
            problems, warnings, refs = _gltf_texture_problems(path)
        else:
            return [], []
    except (OSError, ValueError, KeyError, IndexError, struct.error):
        return [], []  # not parseable: load_scene reports it
    seen = set()
    for ref in refs:
        if _outside(ref, root) and str(ref) not in seen:
            seen.add(str(ref))
            warnings.append(f"reads {ref.resolve()} from outside the dataset folder {Path(root).resolve()}")
    return problems, warnings


def texture_problems(path: Path) -> list[str]:
    """Referenced textures of ``path`` that are missing or do not decode; empty when all are
    readable (``material_report``'s problems)."""
    return material_report(path)[0]


# ----------------------------------------------------------------------------- public API
def load_mesh(path: Path, max_faces: int = DEFAULT_MAX_FACES, bad_texture: str = "fail",
              root: Path | None = None, outside_textures: str = "warn"):
    """Load and validate one mesh file as a single object.

    Returns ``(scene, vertices, faces, warnings)``: the ``trimesh.Scene`` to render, its
    triangles in the source frame (``vertices [n,3]`` float64, ``faces [m,3]`` int64, node
    transforms baked in) and a list of warnings (textures replaced by material colours when
    ``bad_texture="fallback"``, missing ``.mtl`` files, material files outside the folder
    ``root``: refused when ``outside_textures="refuse"``). Raises ``MeshError`` on bad input
    (see module doc)."""
    path = Path(path)
    if bad_texture not in ("fail", "fallback"):
        raise ValueError(f"bad_texture must be 'fail' or 'fallback', not {bad_texture!r}")
    if outside_textures not in OUTSIDE_TEXTURES:
        raise ValueError(f"outside_textures must be one of {OUTSIDE_TEXTURES}, not {outside_textures!r}")
    problems, notes = material_report(path, root)
    if problems and bad_texture == "fail":
        raise MeshError(f"{path}: {'; '.join(problems)} (use --bad-texture fallback to render with material colours)")
    outside = [n for n in notes if "outside the dataset folder" in n]
    if outside and outside_textures == "refuse":
        raise MeshError(f"{path}: {'; '.join(outside)} (refused by --outside-textures refuse)")
    scene = load_scene(path)
    vertices, faces = scene_triangles(scene)
    validate_triangles(vertices, faces, str(path), max_faces)
    warnings = ([f"{path}: {p}; rendered with material colours" for p in problems]
                + [f"{path}: {n}" for n in notes])
    return scene, vertices, faces, warnings


def load_mesh_triangles(path: Path, max_faces: int = DEFAULT_MAX_FACES) -> tuple[np.ndarray, np.ndarray]:
    """The exact geometry the renderer draws for ``path``: ``(vertices [n,3] float64,
    faces [m,3] int64)`` in the SOURCE frame (all scene geometry, node transforms baked in).
    Apply the shard's ``to_canonical`` with ``sc3d_data.geometry.normalize.apply_transform`` to get
    canonical coordinates. Raises ``MeshError`` on bad input."""
    _, vertices, faces, _ = load_mesh(path, max_faces=max_faces, bad_texture="fallback")
    return vertices, faces
