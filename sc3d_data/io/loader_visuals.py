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
"""
from __future__ import annotations

import numpy as np

__all__ = ["is_placeholder", "texture_as_is"]

#: the pixel of trimesh's placeholder image (``trimesh.visual.material.color_image``'s default)
PLACEHOLDER_PIXEL = (100, 100, 100, 255)


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
