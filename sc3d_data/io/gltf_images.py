"""The images a glTF/GLB file names, and which of them the renderer draws.

Every external image (a ``uri`` that is not a ``data:`` URI) is asked for by the loader whether a
texture draws it or not, so where each lies is judged (``io.materials``: inside the dataset
folder, else never opened). The renderer draws a material's base colour texture only
(``baseColorTexture``, or ``KHR_materials_pbrSpecularGlossiness``' ``diffuseTexture``, which is
read as one): an image only a metallic-roughness, normal, occlusion or emissive texture reads, or
no texture at all, changes nothing drawn. Such an image missing or not decoding is a warning, not a
failure: MeshLab's and the glTF samples' ``Avocado.gltf`` without its metallic-roughness PNG failed
("texture image 1 ... not found"), and with ``--bad-texture fallback`` was said to be "rendered
with material colours" while its base colour texture was drawn. Their names end in
:data:`NOT_DRAWN` or :data:`UNDRAWN` (:func:`not_drawn`).
"""
from __future__ import annotations

import urllib.parse
from pathlib import Path

from sc3d_data.io.gltf_features import base_colour_textures, element

__all__ = ["NOT_DRAWN", "UNDRAWN", "gltf_image_refs", "gltf_uri_path", "not_drawn"]

#: the end of the name of an image that no texture draws: where it lies is judged, not its content
UNDRAWN = " (drawn by no texture)"
#: the end of the name of an image that textures read but no base colour texture does
NOT_DRAWN = " (read by no base colour texture)"


def not_drawn(name: str) -> bool:
    """Whether image ``name`` (of :func:`gltf_image_refs`) is one the renderer does not draw."""
    return name.endswith((UNDRAWN, NOT_DRAWN))


def gltf_uri_path(folder: Path, uri: str) -> Path:
    """The file a glTF ``uri`` names relative to ``folder``: glTF URIs are percent-encoded
    (Blender writes ``my%20tex.png`` for ``my tex.png``), so the decoded name, unless only the
    name as written exists."""
    literal, decoded = folder / uri, folder / urllib.parse.unquote(uri)
    return literal if literal.exists() and not decoded.exists() else decoded


def _source(doc: dict, info: dict):
    """The image index a ``textureInfo`` reads (``EXT_texture_webp``'s source first), or None."""
    texture = element(doc, "textures", info.get("index"))
    return texture.get("extensions", {}).get("EXT_texture_webp", {}).get("source", texture.get("source"))


def gltf_image_refs(path: Path, doc: dict, binary: bytes | None, embedded_too: bool = True
                    ) -> tuple[list[tuple[str, Path]], list[tuple[str, bytes]]]:
    """``(external images [(name, path)], embedded images [(name, bytes)])`` of GLTF/GLB ``path``
    (its JSON ``doc`` and binary chunk, ``read_gltf``; the embedded images only with
    ``embedded_too``: in data URIs, and in a GLB's ``binary``). Every external image (module doc);
    of the embedded ones the images textures read (``source``, or ``EXT_texture_webp``'s), not
    those only another extension names (``KHR_texture_basisu``'s KTX2 beside a PNG fallback),
    which would not decode. Names end in :data:`UNDRAWN` or :data:`NOT_DRAWN` where the renderer
    does not draw the image."""
    external, embedded = [], []
    read = {_source(doc, {"index": i}) for i in range(len(doc.get("textures", [])))}
    drawn = {_source(doc, info) for m in doc.get("materials", []) if isinstance(m, dict)
             for _, info in base_colour_textures(m)}
    for i, image in enumerate(doc.get("images", [])):
        mark = "" if i in drawn else NOT_DRAWN if i in read else UNDRAWN
        if "uri" in image and not image["uri"].startswith("data:"):
            external.append((f"image {i} ({image['uri']}){mark}", gltf_uri_path(path.parent, image["uri"])))
            continue
        if i not in read:
            continue
        if "bufferView" in image and binary is not None:
            view = doc["bufferViews"][image["bufferView"]]
            start = view.get("byteOffset", 0)
            embedded.append((f"texture image {i}{mark}", binary[start:start + view["byteLength"]]))
        elif "uri" in image and embedded_too:  # a data URI: the image is in the JSON
            embedded.append((f"texture image {i}{mark}", _data_uri_bytes(image["uri"])))
    return external, embedded


def _data_uri_bytes(uri: str) -> bytes:
    """The bytes of a ``data:`` URI (base64 or percent-encoded); what does not decode, none."""
    import base64
    import binascii

    head, _, payload = uri.partition(",")
    try:
        return base64.b64decode(payload) if head.endswith(";base64") else urllib.parse.unquote_to_bytes(payload)
    except (binascii.Error, ValueError):
        return b""
