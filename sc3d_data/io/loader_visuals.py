"""What trimesh's loader puts into a mesh's visual that the file did not say.

A geometry with texture coordinates but no material of the file (an OBJ with ``vt`` and no
``mtllib`` or ``usemtl``, or whose ``.mtl`` is missing) gets ``TextureVisuals`` with trimesh's
placeholder material (``trimesh.visual.material.empty_material``: a 2 x 2 image of grey
(100, 100, 100) under the default diffuse 0.4). Drawn as a texture it made such an object darker
(0.4 x 0.13 in linear light) than the same file without ``vt`` (the renderer's grey for meshes
without material, pyrender's 0.3), and it passed for a texture drawn. :func:`is_placeholder`
tells it apart, so the renderer draws it as no material and a named texture drawn on no face is
still warned about.

A texture the file gives no colour to multiply with (a PLY's ``comment TextureFile``; an MTL
material with ``map_Kd`` and no ``Kd``) gets trimesh's default diffuse, 0.4, and was drawn at 40%,
unlike every viewer: :func:`texture_as_is` gives its material a white diffuse colour.

An OBJ material's ``map_Kd`` moved by ``-o``/``-s`` (offset, scale) was drawn unmoved (trimesh
reads neither option): :func:`move_texture` applies the move (``io.mtl_text.TextureMove``) to the
texture coordinates of the material's faces.

An OBJ's vertex colours (``v x y z r g b``, as Blender's and MeshLab's exporters write them) on
faces that also name a material were dropped: trimesh's OBJ loader parses them, then builds the
geometry with the material's visual only, and the object was drawn in the material's colour
without a word. The OBJ format defines no rule for both; sc3d draws them as glTF does a material
with ``COLOR_0`` (material colour x texture x vertex colour, ``render.renderer.material_vertex_colors``),
so a white material shows the vertex colours as they are. Where the only material is trimesh's
placeholder (``vt`` and no ``.mtl``), the vertex colours are drawn as in a file without ``vt``.
:func:`keep_obj_vertex_colours` makes this process's OBJ loader do so.

An OBJ vertex colour that is not a number (``v x y z nan nan nan``, as trimesh's deliberately
malformed ``models/nancolor.obj``) was cast to 0 by the loader: that corner and the faces around
it drawn black, exit 0. Such a file is refused (``NotFiniteColours``, one line naming the
count), as vertices with NaN coordinates are (``io.meshes.validate_triangles``).
"""
from __future__ import annotations

import numpy as np

__all__ = ["NotFiniteColours", "is_placeholder", "keep_obj_vertex_colours", "move_texture", "texture_as_is"]

#: the pixel of trimesh's placeholder image (``trimesh.visual.material.color_image``'s default)
PLACEHOLDER_PIXEL = (100, 100, 100, 255)


class NotFiniteColours(ValueError):
    """An OBJ whose vertex colours hold NaN or inf (module doc)."""


def is_placeholder(material) -> bool:
    """Whether ``material`` is trimesh's placeholder (module doc): a material whose image is the
    2 x 2 placeholder grey (trimesh names it like any other, ``material_0``; an image read from a
    file carries its file name, so it is never taken for one)."""
    image = getattr(material, "image", None)
    if image is None or getattr(image, "size", None) != (2, 2) or getattr(image, "filename", None) \
            or image.info.get("file_path"):
        return False
    pixels = np.asarray(image.convert("RGBA")).reshape(-1, 4)
    return bool((pixels == PLACEHOLDER_PIXEL).all())


def texture_as_is(geometry, materials: set[str] | None = None) -> None:
    """``geometry``'s texture drawn as it is (module doc): where its visual draws a texture of the
    file (and its material is one of ``materials``, by name, where given), the material's diffuse
    colour white."""
    visual = getattr(geometry, "visual", None)
    material = getattr(visual, "material", None)
    if materials is not None and getattr(material, "name", None) not in materials:
        return
    if getattr(visual, "kind", None) == "texture" and getattr(material, "image", None) is not None \
            and hasattr(material, "diffuse") and not is_placeholder(material):
        material.diffuse = [255, 255, 255, 255]


def move_texture(geometry, moves: dict) -> None:
    """Where ``geometry``'s visual draws a texture of a material (by name) of ``moves``
    (``{material: io.mtl_text.TextureMove}``), its texture coordinates ``uv [n,2]`` become
    ``scale * uv + offset``: the texture is read where the file's options move it."""
    visual = getattr(geometry, "visual", None)
    move = moves.get(getattr(getattr(visual, "material", None), "name", None))
    if move is None or getattr(visual, "kind", None) != "texture" or getattr(visual, "uv", None) is None:
        return
    visual.uv = np.asarray(visual.uv, dtype=np.float64) * move.scale + move.offset


def keep_obj_vertex_colours() -> None:
    """Make this process's OBJ loader (trimesh's ``mesh_loaders["obj"]``) keep vertex colours
    beside a material (module doc); idempotent, before loading."""
    from trimesh.exchange import load

    loader = load.mesh_loaders.get("obj")
    if loader is None or getattr(loader, "keeps_vertex_colours", False):
        return

    def load_obj(*args, **kwargs):
        loaded = loader(*args, **kwargs)
        for mesh in loaded.get("geometry", {}).values():
            _check_colours_finite(mesh.get("vertex_colors"))
            _colours_beside_material(mesh)
        return loaded

    load_obj.keeps_vertex_colours = True
    load.mesh_loaders["obj"] = load_obj


def _check_colours_finite(colours) -> None:
    """``NotFiniteColours`` where the vertex colours trimesh's OBJ loader parsed (floats [n,3|4]
    or None) hold NaN or inf."""
    if colours is None:
        return
    colours = np.asarray(colours)
    if colours.dtype.kind == "f" and not (finite := np.isfinite(colours).all(axis=-1)).all():
        raise NotFiniteColours(f"{int((~finite).sum())} vertex colours are not numbers (NaN/inf), "
                               "which would be drawn black")


def _colours_beside_material(mesh: dict) -> None:
    """One geometry of trimesh's OBJ loader (its ``Trimesh`` keyword arguments): vertex colours
    parsed beside a visual go into the visual's ``vertex_attributes["color"]`` (uint8 RGBA, read
    as trimesh reads vertex colours without a material); beside the placeholder material, the
    visual is dropped so the geometry is coloured by them."""
    from trimesh.visual.color import to_rgba

    colours, visual = mesh.get("vertex_colors"), mesh.get("visual")
    if colours is None or visual is None or len(colours) != len(mesh.get("vertices", ())):
        return
    if is_placeholder(getattr(visual, "material", None)):
        mesh["visual"] = None
    else:
        visual.vertex_attributes["color"] = to_rgba(colours)
