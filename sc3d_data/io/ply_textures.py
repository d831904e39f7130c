"""PLY texture names as MeshLab reads them: ``<this>``, and several textures chosen by ``texnumber``.

MeshLab (vcglib's ``ImporterPLY``/``ExporterPLY``) names a PLY's textures in its header, one
``comment TextureFile NAME`` line each, and where a mesh has several textures gives every face a
``texnumber`` property: the index, in header order, of the texture the face is drawn with.
trimesh's PLY reader (5.x) keeps only the last ``TextureFile`` and drew every face with it: a
model of two textures rendered, exit 0, with the second texture on the first one's faces.
:func:`split_by_texnumber` draws each face with its own texture: the geometry becomes one part
per texture, the images read through the loader's resolver (a missing one is a miss the loader
reports, as for the texture trimesh reads itself). A ``texnumber`` that names no texture of the
header fails the object in one line.

vcglib also reads ``<this>`` in a texture name (any case) as the PLY's own file name without its
``.ply`` extension (``wrap/ply/plylib.cpp: interpret_texture_name``), so that a renamed file keeps
its textures: MeshLab's sample ``TextureDouble.ply`` names ``<this>_A.png``. trimesh looked for a
file literally named ``<this>_A.png`` and the object failed "not found". :func:`this_named`
gives the loader the header with the name filled in, as vcglib fills it.
"""
from __future__ import annotations

import io
import os
import re
from pathlib import Path

import numpy as np

__all__ = ["texture_names", "this_named", "split_by_texnumber"]

#: a header's texture line, as trimesh reads it: ``comment TextureFile NAME`` (name to the line's end)
TEXTURE_FILE = re.compile(rb"(?mi)^comment[ \t]+texturefile[ \t]+(.*?)[ \t]*\r?$")
#: vcglib's placeholder for the PLY's own name
THIS = re.compile(rb"(?i)<this>")
#: bytes read to find the header's end (as ``io.ply_header``)
HEADER_BYTES = 1 << 16


def _stem(path: Path) -> bytes:
    """The file name vcglib puts for ``<this>``: ``path``'s name without a ``.ply`` ending (any case),
    that of the file a symlink points to (its textures lie beside it: ``io.materials.real_file``)."""
    name = Path(os.path.realpath(path)).name
    return (name[:-4] if name.lower().endswith(".ply") else name).encode("utf-8", "surrogateescape")


def _header(data: bytes) -> bytes:
    """``data`` up to ``end_header`` (all of it where there is none)."""
    end = data.find(b"end_header")
    return data if end == -1 else data[:end]


def texture_names(path: Path, data: bytes | None = None) -> list[str]:
    """The textures PLY ``path`` (or its bytes ``data``) names, in header order, ``<this>`` filled in."""
    if data is None:
        with open(path, "rb") as f:
            data = f.read(HEADER_BYTES)
    stem = _stem(path)
    return [THIS.sub(lambda _: stem, m.group(1)).decode("utf-8", "surrogateescape")
            for m in TEXTURE_FILE.finditer(_header(data))]


def this_named(path: Path, text: bytes | None) -> bytes | None:
    """``text`` (the bytes the loader is to read for PLY ``path``; None: the file's) with ``<this>``
    in its header's texture names filled in (module doc), or ``text`` where the header has none."""
    data = text
    if data is None:
        with open(path, "rb") as f:
            if not THIS.search(_header(f.read(HEADER_BYTES))):
                return None
        data = Path(path).read_bytes()
    header = _header(data)
    if not THIS.search(header):
        return text
    stem = _stem(path)
    named = TEXTURE_FILE.sub(lambda m: m.group(0).replace(m.group(1), THIS.sub(lambda _: stem, m.group(1))), header)
    return named + data[len(header):]


def _texnumbers(geometry) -> np.ndarray | None:
    """The ``texnumber`` of each triangle of ``geometry`` as the loader parsed them (one per face of
    the file: where the loader split quads or polygons, as ``io.ply_colors.face_sources`` says), or None."""
    from sc3d_data.io.ply_colors import face_lists, face_sources

    raw = getattr(geometry, "metadata", {}).get("_ply_raw", {})
    face = raw.get("face", {})
    data = face.get("data") if isinstance(face, dict) else None
    try:
        numbers = np.asarray(data["texnumber"]).astype(np.int64).ravel()
    except (KeyError, ValueError, TypeError, IndexError):
        return None
    lists = face_lists(raw) if len(numbers) != len(geometry.faces) else None
    if lists is not None and len(lists) == len(numbers) and all(len(f) >= 3 for f in lists):
        origin = face_sources(np.array([len(f) for f in lists]))
        numbers = numbers[origin] if len(origin) == len(geometry.faces) else numbers
    return numbers


def _image(resolver, name: str):
    """Texture ``name`` decoded (PIL), or None where ``resolver`` has no such file (it records the miss)."""
    from PIL import Image

    try:
        data = resolver.get(name)
    except (FileNotFoundError, OSError):
        return None
    image = Image.open(io.BytesIO(data))
    image.load()
    return image


def split_by_texnumber(scene, path: Path, resolver) -> str | None:
    """Each textured geometry of ``scene`` (loaded from ``path``, where a PLY) whose faces carry ``texnumber``
    and whose header names several textures, replaced by one part per texture drawn with it (module
    doc); a texture ``resolver`` cannot serve leaves its faces in the part as loaded (the miss is
    reported by ``io.texture_resolver.loader_misses``). Returns the one-line refusal where a face's
    number names no texture, the numbers do not match the faces or a texture does not decode, else None."""
    import trimesh

    names = texture_names(path) if Path(path).suffix.lower() == ".ply" else []
    if len(names) < 2:
        return None
    for name, geometry in list(scene.geometry.items()):
        numbers, visual = _texnumbers(geometry), getattr(geometry, "visual", None)
        if numbers is None or getattr(visual, "kind", None) != "texture" or getattr(visual, "uv", None) is None:
            continue
        if len(numbers) != len(geometry.faces):
            return f"{path}: {len(numbers):,} texnumber values for {len(geometry.faces):,} faces; not read"
        if (bad := numbers[(numbers < 0) | (numbers >= len(names))]).size:
            return (f"{path}: a face's texnumber {int(bad[0])} names no texture (the header names "
                    f"{len(names)}: {', '.join(names)}); not read")
        parts = []
        for k in np.unique(numbers):
            faces = geometry.faces[numbers == k]
            used, local = np.unique(faces, return_inverse=True)
            material = visual.material.copy()
            try:
                material.image = _image(resolver, names[k])  # None: drawn in the material's colour (a miss)
            except (OSError, ValueError) as e:  # PIL: not an image it decodes
                return f"{path}: texture {names[k]} unreadable ({type(e).__name__}: {e}); not read"
            parts.append(trimesh.Trimesh(
                vertices=geometry.vertices[used], faces=local.reshape(-1, 3), process=False,
                visual=trimesh.visual.TextureVisuals(uv=np.asarray(visual.uv)[used], material=material)))
        _replace(scene, name, parts)
    return None


def _replace(scene, name: str, parts: list) -> None:
    """Draw ``parts`` wherever ``scene`` draws its geometry ``name`` (at each node's transform), in its place."""
    nodes = [(node, scene.graph[node][0]) for node in scene.graph.nodes_geometry if scene.graph[node][1] == name]
    scene.delete_geometry(name)
    for j, (_, transform) in enumerate(nodes):
        for i, part in enumerate(parts):
            scene.add_geometry(part.copy() if j else part, geom_name=f"{name} texture {i}" + (f" {j}" if j else ""),
                               transform=transform)
