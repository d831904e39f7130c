"""glTF features the loader would ignore, so that an object would render other than the file says.

trimesh's glTF loader (``trimesh.exchange.gltf``, 5.x) without ``DracoPy`` installed cannot decode
``KHR_draco_mesh_compression`` (it logs two lines naming no file and reads zeros, which then fail
as "zero surface area", blaming the mesh), never decodes ``EXT_meshopt_compression`` or
``KHR_meshopt_compression``, always maps a base colour texture with ``TEXCOORD_0`` whatever its
``texCoord`` says, and ignores ``KHR_texture_transform`` (the offset, rotation and scale with
which Blender tiles a fabric or gltfpack packs an atlas): the texture is drawn at the wrong place.
It also reads every accessor's integers as they are stored, never applying ``normalized`` (an
unsigned short 65535 means 1.0); the document it is given holds such positions and texture
coordinates as floats (``sc3d_data.io.gltf_dequantize``).

:func:`feature_problems` names from the JSON alone what cannot be read as written, so that the
file is refused in one line whatever ``--bad-texture`` says (the loader would draw a texture, at
the wrong place, and which of its parts to draw plain cannot be told from what it loaded):

* an extension in ``extensionsRequired`` that the loader cannot decode (:data:`UNDECODED`; Draco
  only where ``DracoPy`` is missing), or does not know (not in :data:`READ_OR_MOOT`): the file
  itself says it cannot be read without it;
* a primitive of a drawn mesh whose material's base colour texture
  (``pbrMetallicRoughness.baseColorTexture``, or the ``diffuseTexture`` of
  ``KHR_materials_pbrSpecularGlossiness``: the textures the renderer draws) reads another set
  than ``TEXCOORD_0`` (its ``texCoord``, or its ``KHR_texture_transform``'s) that it lacks, or
  that is Draco-compressed. Where the primitive has that set, :func:`read_texcoord_sets` makes it
  ``TEXCOORD_0`` in the document the judges and the loader read.

:func:`apply_texture_transforms` applies every ``KHR_texture_transform`` to the texture
coordinates of the loaded geometries whose material has the name :func:`transform_names` gives it:
its own where no other material has it, else one the loader's copy of the document gives it
(gltfpack leaves its materials unnamed) (an identity transform, offset 0, scale 1, rotation 0, is
no change and is not applied).

:func:`read_spec_gloss_as_matte` makes the loader read a ``KHR_materials_pbrSpecularGlossiness``
material (older Sketchfab and Objaverse files) as the renderer's matte shading draws every
material: its diffuse colour (``diffuseFactor`` x ``diffuseTexture``) is the albedo, as viewers
show it. trimesh's own reading converts it to metallic-roughness, whose base colour for the
extension's default ``specularFactor`` [1, 1, 1] is white (a mirror): the texture was lost.
"""
from __future__ import annotations

import importlib.util

import numpy as np

__all__ = ["READ_OR_MOOT", "UNDECODED", "apply_texture_transforms", "base_colour_textures", "element", "feature_problems", "feature_warnings",
           "read_spec_gloss_as_matte", "read_texcoord_sets", "set_read", "textured",
           "material_name", "transform_matrix", "transform_names"]

#: required extensions the loader cannot decode: ``{name: what it is}``
UNDECODED = {"KHR_draco_mesh_compression": "Draco mesh compression",
             "EXT_meshopt_compression": "meshoptimizer compression",
             "KHR_meshopt_compression": "meshoptimizer compression",
             "KHR_texture_basisu": "KTX2 / Basis Universal textures"}


#: extensions a file may require that the loader reads, or that change nothing the renderer draws
#: (its matte shading of the albedo leaves lights and other material looks out anyway); with
#: :data:`UNDECODED` and every ``KHR_materials_*``, the rest are refused where required
READ_OR_MOOT = frozenset({"KHR_mesh_quantization", "KHR_texture_transform", "EXT_texture_webp", "KHR_lights_punctual",
                          "KHR_materials_variants", "KHR_xmp_json_ld", "KHR_animation_pointer"})


def _unknown(name: str) -> bool:
    """Whether required extension ``name`` is one the loader neither reads nor may leave out."""
    return not (name in READ_OR_MOOT or name in UNDECODED or name.startswith("KHR_materials_")
                or name == "EXT_mesh_gpu_instancing")  # applied: io.gltf_instancing


def _undecoded(name: str) -> bool:
    if name == "KHR_draco_mesh_compression":
        return importlib.util.find_spec("DracoPy") is None  # trimesh decodes Draco through DracoPy
    return name in UNDECODED


def _spec_gloss_matte(context: dict) -> dict:
    """trimesh material-extension handler (``trimesh.exchange.gltf.extensions``): the base colour
    (factor and texture) of a ``KHR_materials_pbrSpecularGlossiness`` material is its diffuse
    colour; no metal; roughness 1 - glossiness (module doc)."""
    data = context["parse_textures"](data=context["data"])
    found = {"metallicFactor": 0.0, "roughnessFactor": 1.0 - float(data.get("glossinessFactor", 1.0))}
    if data.get("diffuseTexture") is not None:
        found["baseColorTexture"] = data["diffuseTexture"]
    if data.get("diffuseFactor") is not None:
        found["baseColorFactor"] = data["diffuseFactor"]
    return found


def read_spec_gloss_as_matte() -> None:
    """Make this process's glTF loader read specular-glossiness materials by their diffuse
    colour (module doc); idempotent, before loading."""
    from trimesh.exchange.gltf.extensions import register_handler

    register_handler("KHR_materials_pbrSpecularGlossiness", scope="material")(_spec_gloss_matte)


def _moves(transform: dict) -> bool:
    """Whether a ``KHR_texture_transform`` changes the texture coordinates."""
    return (list(transform.get("offset", [0, 0])) != [0, 0] or list(transform.get("scale", [1, 1])) != [1, 1]
            or transform.get("rotation", 0) != 0 or transform.get("texCoord", 0) != 0)


def transform_matrix(transform: dict) -> np.ndarray:
    """``[3, 3]``: the ``KHR_texture_transform`` ``transform`` as the extension defines it,
    ``T(offset) @ R(rotation) @ S(scale)`` acting on ``(u, v, 1)`` in glTF's texture frame
    (origin at the image's top left, v down), ``R = [[cos r, sin r], [-sin r, cos r]]``."""
    (ox, oy), (sx, sy) = transform.get("offset", [0, 0]), transform.get("scale", [1, 1])
    r = transform.get("rotation", 0)
    c, s = np.cos(r), np.sin(r)
    return (np.array([[1, 0, ox], [0, 1, oy], [0, 0, 1]], dtype=np.float64)
            @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) @ np.diag([sx, sy, 1.0]))


def _transforms(doc: dict) -> dict[int, dict]:
    """``{material index: its base colour texture's KHR_texture_transform}`` where it moves."""
    found = {}
    for i, material in enumerate(doc.get("materials", [])):
        for _, info in base_colour_textures(material):
            transform = info.get("extensions", {}).get("KHR_texture_transform")
            if isinstance(transform, dict) and _moves(transform):
                found[i] = transform
    return found


def material_name(doc: dict, i: int) -> str:
    """The name by which the loaded geometries of glTF ``doc``'s material ``i`` are found after
    loading (a texture transform, ``io.texture_wraps``' sampler wrap): the material's own name
    where no other material has it, else ``sc3d: material I``, which ``io.gltf_loader_doc`` gives
    the loader's copy of the document (gltfpack leaves its materials unnamed)."""
    names = [m.get("name") if isinstance(m, dict) else None for m in doc.get("materials", [])]
    own = names[i]
    name = own if isinstance(own, str) and own != "" and names.count(own) == 1 else f"sc3d: material {i}"
    while name != own and name in names:  # a name some material of the file has already
        name += "'"
    return name


def transform_names(doc: dict) -> dict[int, str]:
    """``{material index: material_name}`` of the materials whose base colour texture a
    ``KHR_texture_transform`` moves (a transform to another set: ``read_texcoord_sets`` made it
    ``TEXCOORD_0``)."""
    return {i: material_name(doc, i) for i in _transforms(doc)}


def apply_texture_transforms(scene, doc: dict) -> None:
    """Move the texture coordinates of each geometry of ``scene`` (loaded by trimesh from glTF
    ``doc``) whose material is one with a ``KHR_texture_transform`` (module doc), found by its
    name. trimesh keeps ``uv`` with v up (``1 - v`` of glTF's), so the transform is applied in
    glTF's frame between two flips."""
    transforms = _transforms(doc)
    by_name = {name: transform_matrix(transforms[i]) for i, name in transform_names(doc).items()}
    for geometry in scene.geometry.values():
        visual = getattr(geometry, "visual", None)
        name = getattr(getattr(visual, "material", None), "name", None)
        if getattr(visual, "kind", None) != "texture" or visual.uv is None or name not in by_name:
            continue
        u, v = np.asarray(visual.uv, dtype=np.float64).T
        moved = by_name[name] @ np.stack([u, 1.0 - v, np.ones_like(u)])
        visual.uv = np.stack([moved[0], 1.0 - moved[1]], axis=1)


def element(doc: dict, key: str, i) -> dict:
    """``doc[key][i]`` (a texture, a sampler...) where ``i`` indexes an object of that list, else
    ``{}``: a reference that names nothing is read as absent."""
    items = doc.get(key, [])
    return items[i] if isinstance(i, int) and 0 <= i < len(items) and isinstance(items[i], dict) else {}


def base_colour_textures(material: dict) -> list[tuple[str, dict]]:
    """``[(name, textureInfo)]`` of the base colour textures of glTF ``material``."""
    found = []
    if isinstance(info := material.get("pbrMetallicRoughness", {}).get("baseColorTexture"), dict):
        found.append(("base colour texture", info))
    gloss = material.get("extensions", {}).get("KHR_materials_pbrSpecularGlossiness", {})
    if isinstance(info := gloss.get("diffuseTexture"), dict):
        found.append(("diffuse texture", info))
    return found


def textured(doc: dict, prim: dict) -> bool:
    """Whether glTF primitive ``prim`` of ``doc`` is drawn with a texture: its material has a base
    colour texture (the loader maps it with ``TEXCOORD_0``; an untextured primitive's texture
    coordinates place nothing)."""
    materials, i = doc.get("materials", []), prim.get("material")
    return isinstance(i, int) and 0 <= i < len(materials) and bool(base_colour_textures(materials[i]))


def morph_problems(doc: dict, drawn: set[int]) -> list[str]:
    """The drawn meshes (indices ``drawn``) whose morph targets are weighted (the mesh's or a node's
    ``weights`` not all 0: Blender's shape keys at their values): the loader draws the base shape
    without them, another geometry."""
    problems = []
    for m in sorted(drawn):
        mesh = doc["meshes"][m]
        if not any(prim.get("targets") for prim in mesh.get("primitives", [])):
            continue
        weights = [mesh.get("weights", [])] + [n.get("weights", []) for n in doc.get("nodes", []) if n.get("mesh") == m]
        if any(isinstance(w, (int, float)) and w != 0 for ws in weights if isinstance(ws, list) for w in ws):
            problems.append(f"mesh {m} has morph targets with weights other than 0 (shape keys), which the loader "
                            "does not apply: it would draw and voxelize the shape without them")
    return problems


def feature_warnings(doc: dict, drawn: set[int]) -> list[str]:
    """What of glTF document ``doc`` is drawn other than the file means, or other than the voxels
    hold, though close enough to render with a warning: materials of the drawn meshes ``drawn``
    (mesh indices) with ``alphaMode`` MASK (cut-outs: leaves, fences), which the renderer cuts out
    of the images and masks as glTF says while the voxels fill their whole triangles (``check``
    may flag such an object), and triangle primitives of the drawn meshes with a base colour
    texture but no ``TEXCOORD_0`` to place it (drawn in the material's colour, as an OBJ's faces
    without ``vt``)."""
    materials = doc.get("materials", [])
    prims = [(m, k, p) for m in sorted(drawn) for k, p in enumerate(doc["meshes"][m].get("primitives", []))
             if p.get("mode", 4) in (4, 5)]
    cut = sorted({p["material"] for _, _, p in prims if isinstance(p.get("material"), int)
                  and 0 <= p["material"] < len(materials) and materials[p["material"]].get("alphaMode") == "MASK"})
    return [f"material {i} is a cut-out (alphaMode MASK): its cut-out texels are left out of the images and masks, "
            "while its voxels fill its whole triangles" for i in cut] + [
        f"mesh {m} primitive {k} has no TEXCOORD_0 to place its material's texture, so it is drawn in the "
        "material's colour without it" for m, k, p in prims
        if textured(doc, p) and "TEXCOORD_0" not in p.get("attributes", {})]


def feature_problems(doc: dict, drawn: set[int]) -> list[str]:
    """What of glTF document ``doc`` the loader would ignore (module doc), one phrase each:
    required extensions first, then the weighted morph targets, then the textures of the materials of the drawn meshes ``drawn`` (mesh indices), each
    material once."""
    required = [name for name in doc.get("extensionsRequired", []) if isinstance(name, str)]
    problems = [f"it requires {name} ({UNDECODED[name]}), which the loader cannot decode"
                for name in required if _undecoded(name)]
    problems += [f"it requires {name}, an extension the loader does not read" for name in required if _unknown(name)]
    problems += morph_problems(doc, drawn)
    materials = doc.get("materials", [])
    for m in sorted(drawn):
        for prim in doc["meshes"][m].get("primitives", []):
            i = prim.get("material")
            if isinstance(i, int) and 0 <= i < len(materials):
                problem = _texcoord_problem(materials[i], i, m, prim.get("attributes", {}))
                if problem is not None and problem not in problems:
                    problems.append(problem)
    return problems


def _texcoord_problem(material: dict, i: int, m: int, attributes: dict) -> str | None:
    """Why the loader would not map base colour texture of ``material`` (index ``i``) on a
    primitive of mesh ``m`` (its ``attributes``) with the set it reads, or None."""
    n = _texcoord_set(material)
    if n is None:
        return (f"material {i}'s base colour textures read different texture coordinate sets, but the loader "
                "maps every texture with one")
    if n != 0 and f"TEXCOORD_{n}" not in attributes:
        return f"material {i}'s base colour texture reads TEXCOORD_{n}, which a primitive of mesh {m} has not"
    if n != 0 and attributes.get("TEXCOORD_0") != attributes[f"TEXCOORD_{n}"]:  # left by read_texcoord_sets
        return (f"material {i}'s base colour texture reads TEXCOORD_{n} of a Draco-compressed primitive of mesh "
                f"{m}, but the loader maps every texture with TEXCOORD_0")
    return None


def _texcoord_set(material: dict) -> int | None:
    """The texture coordinate set the base colour textures of glTF ``material`` read: the
    ``texCoord`` of their ``KHR_texture_transform``, which overrides theirs (as the extension
    says), else theirs; 0 without such a texture, None where two read different sets."""
    sets = set()
    for _, info in base_colour_textures(material):
        transform = info.get("extensions", {}).get("KHR_texture_transform")
        sets.add(transform["texCoord"] if isinstance(transform, dict) and "texCoord" in transform
                 else info.get("texCoord", 0))
    return (sets.pop() if len(sets) == 1 else None) if sets else 0


def read_texcoord_sets(doc: dict) -> int:
    """Make ``TEXCOORD_0`` of each primitive of ``doc`` whose material's base colour texture reads
    another set (:func:`_texcoord_set`) that set's accessor, in place (the loader maps every
    texture with ``TEXCOORD_0``; the judges, then the loader's copy, read the changed document);
    the number of primitives changed. A primitive without that set, or Draco-compressed (its
    attributes come from its bitstream), is left as it is: :func:`feature_problems` refuses it."""
    materials, changed = doc.get("materials", []), 0
    for mesh in doc.get("meshes", []):
        for prim in mesh.get("primitives", []):
            i, attributes = prim.get("material"), prim.get("attributes", {})
            if not isinstance(i, int) or not 0 <= i < len(materials) or "KHR_draco_mesh_compression" in \
                    prim.get("extensions", {}):
                continue
            n = _texcoord_set(materials[i])
            if isinstance(n, int) and n != 0 and f"TEXCOORD_{n}" in attributes:
                attributes["TEXCOORD_0"] = attributes[f"TEXCOORD_{n}"]
                changed += 1
    return changed


def set_read(attributes: dict, role: str, a: int) -> str:
    """The name the file gives attribute ``role`` (accessor ``a``) of a primitive whose
    ``attributes`` :func:`read_texcoord_sets` may have changed: for a ``TEXCOORD_0`` it took from
    another set, that set's name."""
    if role != "TEXCOORD_0":
        return role
    return next((r for r, b in attributes.items() if r.startswith("TEXCOORD_") and r != role and b == a), role)
