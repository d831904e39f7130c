"""How a texture is drawn where texture coordinates leave [0, 1]: glTF samplers' wrap modes and
MTL's ``-clamp on``.

trimesh's loaders keep neither (5.x): a glTF sampler's ``wrapS``/``wrapT`` (``CLAMP_TO_EDGE``,
``MIRRORED_REPEAT``; glTF-Blender-IO's ``13_texture_wrapping``) and an OBJ material's ``map_Kd
-clamp on`` were drawn repeated. This module finds them in the file and puts them on the loaded
materials (``sc3d_wrap``: OpenGL's numbers for u and v), which the renderer gives the material's
texture (``render.renderer.MeshPart.wrap``).

* glTF: the sampler of each material's base colour texture (the only texture drawn); glTF's
  numbers are OpenGL's. The loaded geometries of such a material are found by
  ``gltf_features.material_name`` (the loader's copy of the document names unnamed materials).
* MTL: ``-clamp on`` means "one copy of the texture; outside it, the underlying material is
  unchanged" (Wavefront's MTL specification): ``CLAMP_TO_BORDER`` with a white border, so the
  material's colour ``Kd`` (times 1) is drawn there. Found by the material's name, as trimesh
  names its materials.
"""
from __future__ import annotations

from sc3d_data.io.gltf_features import base_colour_textures, element, material_name

__all__ = ["CLAMP_TO_BORDER", "CLAMP_TO_EDGE", "MIRRORED_REPEAT", "REPEAT", "apply_wraps", "gltf_wrap_names"]

#: OpenGL's (and glTF's) numbers of the wrap modes
REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT, CLAMP_TO_BORDER = 0x2901, 0x812F, 0x8370, 0x812D
#: the modes a glTF sampler may name
GLTF_WRAPS = (REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT)


def gltf_wraps(doc: dict) -> dict[int, tuple[int, int]]:
    """``{material index: (wrap u, wrap v)}`` of glTF ``doc``'s materials whose base colour
    texture's sampler wraps other than REPEAT (a mode glTF does not name: REPEAT, its default)."""
    found = {}
    for i, material in enumerate(doc.get("materials", [])):
        for _, info in base_colour_textures(material) if isinstance(material, dict) else []:
            sampler = element(doc, "samplers", element(doc, "textures", info.get("index")).get("sampler"))
            wrap = tuple(w if w in GLTF_WRAPS else REPEAT for w in (sampler.get("wrapS"), sampler.get("wrapT")))
            if wrap != (REPEAT, REPEAT):
                found[i] = wrap
    return found


def gltf_wrap_names(doc: dict) -> dict[str, tuple[int, int]]:
    """``{material_name: (wrap u, wrap v)}`` of :func:`gltf_wraps`."""
    return {material_name(doc, i): wrap for i, wrap in gltf_wraps(doc).items()}


def apply_wraps(scene, by_name: dict[str, tuple[int, int]]) -> None:
    """Give each textured geometry of ``scene`` whose material is named in ``by_name`` that
    material's wrap modes (``material.sc3d_wrap``, read by ``render.renderer.mesh_parts``)."""
    for geometry in scene.geometry.values() if by_name else ():
        material = getattr(getattr(geometry, "visual", None), "material", None)
        if getattr(material, "name", None) in by_name:
            material.sc3d_wrap = by_name[material.name]
