"""Defects found reviewing the twenty-seventh round's texture wrap modes (``io.texture_wraps``):
real loader (trimesh) and the renderer's reading of its scene (``render.renderer.mesh_parts``)."""
from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from sc3d_data.io.meshes import load_mesh
from sc3d_data.render.renderer import mesh_parts

CLAMP_TO_BORDER, REPEAT = 0x812D, 0x2901
QUAD = ["v 0 0 0", "v 1 0 0", "v 1 1 0", "v 0 1 0", "vt -1 0", "vt 2 0", "vt 2 1", "vt -1 1",
        "usemtl m", "f 1/1 2/2 3/3", "f 1/1 3/3 4/4"]


@pytest.mark.parametrize("mtls, wrap", [
    ({"a.mtl": "newmtl m\nKd 1 1 1\nmap_Kd -clamp on red.png\n", "b.mtl": "newmtl m\nKd 1 1 1\nmap_Kd blue.png\n"},
     REPEAT),  # a later material file's definition of m is the one drawn
    ({"a.mtl": "newmtl m\nKd 1 1 1\nmap_Kd -clamp on red.png\nnewmtl m\nKd 1 1 1\nmap_Kd blue.png\n"}, REPEAT),
    ({"a.mtl": "newmtl m\nKd 1 1 1\nmap_Kd -clamp on red.png\nmap_Kd blue.png\n"}, REPEAT),  # the last map_Kd
    ({"a.mtl": "newmtl m\nKd 1 1 1\nmap_Kd red.png\n", "b.mtl": "newmtl m\nKd 1 1 1\nmap_Kd -clamp on blue.png\n"},
     CLAMP_TO_BORDER),  # control: the drawn definition clamps
])
def test_mtl_clamp_is_that_of_the_definition_the_loader_draws(tmp_path, mtls, wrap):
    """An MTL material defined twice (in two material files, or twice in one) or given two
    ``map_Kd`` is drawn by the loader with its last definition's last ``map_Kd`` (blue.png here).
    A ``-clamp on`` of an earlier one, which the loader does not draw, clamped the texture drawn
    (exit 0, no warning): the clamp must be the drawn ``map_Kd``'s."""
    (tmp_path / "m.obj").write_text("\n".join([f"mtllib {' '.join(mtls)}", *QUAD]) + "\n")
    for name, text in mtls.items():
        (tmp_path / name).write_text(text)
    Image.new("RGB", (4, 4), (255, 0, 0)).save(tmp_path / "red.png")
    Image.new("RGB", (4, 4), (0, 0, 255)).save(tmp_path / "blue.png")
    scene, _, _, warnings = load_mesh(tmp_path / "m.obj", root=tmp_path)
    [part] = list(mesh_parts(scene, np.eye(4)))
    assert part.image.getpixel((0, 0)) == (0, 0, 255) and warnings == []
    assert part.wrap == (wrap, wrap)


def test_mtl_texture_move_is_that_of_the_definition_the_loader_draws(tmp_path):
    """Same cause for ``map_Kd -o``: a material file's move of its ``m`` moved the texture of a
    later file's ``m`` (the one drawn, not moved): texture coordinates shifted by 0.5, exit 0."""
    (tmp_path / "m.obj").write_text("mtllib a.mtl b.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\n"
                                    "usemtl m\nf 1/1 2/2 3/3\n")
    (tmp_path / "a.mtl").write_text("newmtl m\nKd 1 1 1\nmap_Kd -o 0.5 0 red.png\n")
    (tmp_path / "b.mtl").write_text("newmtl m\nKd 1 1 1\nmap_Kd blue.png\n")
    Image.new("RGB", (4, 4), (255, 0, 0)).save(tmp_path / "red.png")
    Image.new("RGB", (4, 4), (0, 0, 255)).save(tmp_path / "blue.png")
    scene = load_mesh(tmp_path / "m.obj", root=tmp_path)[0]
    [part] = list(mesh_parts(scene, np.eye(4)))
    assert part.image.getpixel((0, 0)) == (0, 0, 255)
    np.testing.assert_allclose(part.uv, [[0, 0], [1, 0], [1, 1]])
