"""glTF materials with ``alphaMode`` MASK (cut-outs: leaves, fences, hair cards) are drawn as
glTF 2.0 says: a fragment whose alpha (``baseColorFactor`` alpha x texture alpha x ``COLOR_0``
alpha) is below ``alphaCutoff`` (default 0.5) is not drawn, so it is in neither the image nor
the mask; OPAQUE ignores alpha, and BLEND is drawn opaque (documented). Before, MASK was drawn
opaque with a warning. A warning still names a cut-out material: its voxels fill its whole
triangles, so the dataset's masks and voxels of such an object no longer agree everywhere.

Each file holds two unit cubes side by side, primitive A (the material under test) and primitive
B (plain green, no texture). The references are rendered by the renderer from plain trimesh
scenes with no material of glTF's (cube B alone where A is cut out, both cubes where it is
drawn), with the canonical frame of both cubes, so a reference never goes through the cut-out
path."""
from __future__ import annotations

import base64
import io
import json
from pathlib import Path

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST, index_of
from test_gltf_primitives import _gltf_doc

CUBE_V = np.float32([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)])
CUBE_F = np.uint32([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                    [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
OFFSET_B = np.float32([1.5, 0, 0])  # cube B beside cube A, a gap between them
#: texture 8 x 16: left half red with alpha ALPHA_LEFT, right half red opaque; cube A samples
#: the left half's middle (u 0.25) or the right half's (u 0.75)
U_LEFT, U_RIGHT = 0.25, 0.75


def _png(alpha_left: int) -> bytes:
    from PIL import Image

    texture = np.zeros((8, 16, 4), np.uint8)
    texture[..., 0], texture[..., 3] = 255, 255
    texture[:, :8, 3] = alpha_left
    png = io.BytesIO()
    Image.fromarray(texture, "RGBA").save(png, format="PNG")
    return png.getvalue()


def _two_cubes(path: Path, material_a: dict, u: float = U_LEFT, alpha_left: int = 0,
               color_alpha: float | None = None) -> None:
    """The two cubes as a .gltf: A's corners all at TEXCOORD_0 (``u``, 0.5) with material
    ``material_a`` (its texture, if any, is texture 0: ``_png(alpha_left)``), and with
    ``color_alpha`` a COLOR_0 of white with that alpha; B with material 1 (green, opaque)."""
    doc, buf = _gltf_doc([(CUBE_V, CUBE_F.ravel(), 4), (CUBE_V + OFFSET_B, CUBE_F.ravel(), 4)])

    def accessor(data: np.ndarray, kind: str) -> int:
        nonlocal buf
        buf += b"\0" * (-len(buf) % 4)
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(buf), "byteLength": data.nbytes})
        doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "componentType": 5126,
                                 "count": len(data), "type": kind})
        buf += data.tobytes()
        return len(doc["accessors"]) - 1

    prim_a, prim_b = doc["meshes"][0]["primitives"]
    prim_a["attributes"]["TEXCOORD_0"] = accessor(np.tile(np.float32([u, 0.5]), (8, 1)), "VEC2")
    if color_alpha is not None:
        prim_a["attributes"]["COLOR_0"] = accessor(np.tile(np.float32([1, 1, 1, color_alpha]), (8, 1)), "VEC4")
    prim_a["material"], prim_b["material"] = 0, 1
    doc.update(buffers=[{"byteLength": len(buf), "uri": "data:application/octet-stream;base64,"
                         + base64.b64encode(buf).decode()}],
               images=[{"uri": "data:image/png;base64," + base64.b64encode(_png(alpha_left)).decode()}],
               textures=[{"source": 0}],
               materials=[material_a, {"pbrMetallicRoughness": {"baseColorFactor": [0, 1, 0, 1], "metallicFactor": 0}}])
    path.write_text(json.dumps(doc))


def _references(views: int) -> dict[str, dict]:
    """``{"B alone" | "both": {"masks", "images"}}`` rendered from plain trimesh scenes (cube A
    red, cube B green, face colours: no material) in the canonical frame of both cubes."""
    import trimesh

    from sc3d_data.geometry.camera import ViewSettings
    from sc3d_data.geometry.normalize import to_canonical_transform
    from sc3d_data.render.renderer import MeshRenderer

    both_v = np.concatenate([CUBE_V, CUBE_V + OFFSET_B]).astype(np.float64)
    to_canonical = to_canonical_transform(both_v)

    def cube(offset, rgb):
        return trimesh.Trimesh(CUBE_V + offset, CUBE_F, face_colors=np.tile([*rgb, 255], (12, 1)), process=False)

    renderer = MeshRenderer(ViewSettings(num_views=views))
    try:
        out = {}
        for name, geometries in (("B alone", [cube(OFFSET_B, (0, 255, 0))]),
                                 ("both", [cube(0, (255, 0, 0)), cube(OFFSET_B, (0, 255, 0))])):
            out[name] = renderer.render(trimesh.Scene(geometries), to_canonical)
    finally:
        renderer.close()
    return out


CASES = {  # file stem: (material A, u, alpha of the texture's left half, COLOR_0 alpha, what is drawn)
    "mask_transparent_texel": ({"alphaMode": "MASK"}, U_LEFT, 0, None, "B alone"),
    "mask_opaque_texel": ({"alphaMode": "MASK"}, U_RIGHT, 0, None, "both"),
    "mask_half_alpha_default_cutoff": ({"alphaMode": "MASK"}, U_LEFT, 192, None, "both"),
    "mask_half_alpha_cutoff_0_8": ({"alphaMode": "MASK", "alphaCutoff": 0.8}, U_LEFT, 192, None, "B alone"),
    "mask_factor_alpha": ({"alphaMode": "MASK", "baseColorFactor": [1, 1, 1, 0.4]}, U_RIGHT, 0, None, "B alone"),
    # an alpha equal to the cutoff is drawn (trimesh keeps the factor in bytes: 0.3 became 76/255 < 0.3)
    "mask_factor_at_cutoff": ({"alphaMode": "MASK", "alphaCutoff": 0.3, "baseColorFactor": [1, 1, 1, 0.3]}, U_RIGHT, 0,
                              None, "both"),
    "mask_vertex_colour_alpha": ({"alphaMode": "MASK"}, U_RIGHT, 0, 0.3, "B alone"),
    "opaque_transparent_texel": ({}, U_LEFT, 0, None, "both"),
    "blend_transparent_texel": ({"alphaMode": "BLEND"}, U_LEFT, 0, None, "both"),
}


def test_a_mask_material_draws_only_what_passes_its_alpha_cutoff(tmp_path):
    folder = tmp_path / "m" / "cubes"
    folder.mkdir(parents=True)
    for stem, (material, u, alpha_left, color_alpha, _) in CASES.items():
        factor = material.pop("baseColorFactor", [1, 1, 1, 1])
        _two_cubes(folder / f"{stem}.gltf", {**material, "pbrMetallicRoughness": {
            "baseColorTexture": {"index": 0}, "baseColorFactor": factor, "metallicFactor": 0}},
            u=u, alpha_left=alpha_left, color_alpha=color_alpha)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    index = index_of(out)
    assert index["failures"] == []
    assert sorted((Path(w["source"]).stem, w["warning"].split(": ", 1)[1]) for w in index["warnings"]) == [
        (stem, "material 0 is a cut-out (alphaMode MASK): its cut-out texels are left out of the images and masks, "
               "while its voxels fill its whole triangles") for stem in sorted(CASES) if stem.startswith("mask")]
    objects = {name[1]: obj for name, obj in objects_by_id(out).items()}
    references = _references(views=4)
    assert references["B alone"]["masks"].sum() < 0.8 * references["both"]["masks"].sum()  # the cases differ
    for stem, (*_, drawn) in CASES.items():
        obj = objects[stem]
        np.testing.assert_array_equal(obj["masks"], references[drawn]["masks"], err_msg=stem)
        seen = obj["masks"].astype(bool)
        np.testing.assert_array_equal(obj["images"][seen], references[drawn]["images"][seen], err_msg=stem)
        assert (obj["images"][~seen] == 255).all(), stem  # cut-out pixels show the background

