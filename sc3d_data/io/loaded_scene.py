"""What ``io.meshes.load_mesh`` puts back into a scene after the loader (trimesh) has read it:
the visual features of the file that the loader drops or misreads, format by format.

* PLY: faces stored as triangle strips (``io.ply_strips``), one face colour per triangle of a
  split polygon and a texture drawn as it is (``io.ply_colors``).
* OBJ: a ``map_Kd`` without ``Kd`` drawn as it is, one moved by ``-o``/``-s``
  (``io.loader_visuals``), a ``-clamp on`` texture clamped (``io.texture_wraps``).
* glTF: ``KHR_texture_transform`` (``io.gltf_features``) and the base colour texture's sampler
  wrap modes (``io.texture_wraps``).
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["finish_visuals"]


def _ply_face_colours(scene, path: Path) -> str | None:
    """One face colour per triangle in each PLY geometry of ``scene`` whose quads or polygons the
    loader split into triangles, and its texture drawn as it is (``io.ply_colors``); the one-line
    refusal where the colours cannot be matched."""
    from sc3d_data.io.loader_visuals import texture_as_is
    from sc3d_data.io.ply_colors import per_triangle_face_colors

    for geometry in scene.geometry.values():
        if hasattr(geometry, "faces") and (refusal := per_triangle_face_colors(geometry, str(path))):
            return refusal
        texture_as_is(geometry)
    return None


def finish_visuals(scene, path: Path, report, gltf_doc: dict | None) -> str | None:
    """Put back into ``scene`` (loaded from ``path``) what the loader dropped (module doc).
    ``report``: the file's ``io.materials.MaterialReport``; ``gltf_doc``: its glTF document as
    judged (None for other formats). Returns the one-line refusal where a PLY's colours do not
    match, else None."""
    from sc3d_data.io.gltf_features import apply_texture_transforms
    from sc3d_data.io.loader_visuals import move_texture, texture_as_is
    from sc3d_data.io.ply_strips import strips_as_faces
    from sc3d_data.io.texture_wraps import apply_wraps, gltf_wrap_names

    if Path(path).suffix.lower() == ".ply":
        strips_as_faces(scene)
        if (refusal := _ply_face_colours(scene, path)) is not None:
            return refusal
    elif report.texture_only or report.texture_moves:  # an OBJ's materials' map_Kd without Kd, moved by -o/-s
        for geometry in scene.geometry.values():
            texture_as_is(geometry, report.texture_only)
            move_texture(geometry, report.texture_moves)
    elif gltf_doc is not None:
        apply_texture_transforms(scene, gltf_doc)
    apply_wraps(scene, gltf_wrap_names(gltf_doc) if gltf_doc is not None else report.wraps)
    return None
