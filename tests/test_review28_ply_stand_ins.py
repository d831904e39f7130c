"""A PLY's ``comment TextureFile`` is one of the companion files read under its bare name beside
the PLY (``io.stand_ins``; docs/data.md: "That is the file drawn, checked (a stand-in texture that
does not decode fails the object as any other) ... and a warning says"). A PLY's texture was
neither checked nor warned about: one that did not decode (named, or read in place of
``textures/t.png``) rendered grey, exit 0, without a word (review28). Hand-built files; the
loader only (no rendering)."""
from __future__ import annotations

from pathlib import Path

import pytest
from PIL import Image

PLY = """ply
format ascii 1.0
comment TextureFile {name}
element vertex 4
property float x
property float y
property float z
property float s
property float t
element face 2
property list uchar int vertex_indices
end_header
0 0 0 0 0
1 0 0 1 0
1 1 0 1 1
0 1 0 0 1
3 0 1 2
3 0 2 3
"""


def _ply(tmp_path: Path, name: str, texture: bytes | None) -> Path:
    """``tmp_path/ds/thing/m.ply`` naming texture ``name``, with ``t.png`` beside it (``texture``'s bytes;
    None: a red PNG)."""
    folder = tmp_path / "ds" / "thing"
    folder.mkdir(parents=True)
    (folder / "m.ply").write_text(PLY.format(name=name))
    if texture is None:
        Image.new("RGB", (8, 8), (200, 30, 30)).save(folder / "t.png")
    else:
        (folder / "t.png").write_bytes(texture)
    return folder / "m.ply"


@pytest.mark.parametrize("name", ["t.png", "textures/t.png"])
def test_a_ply_texture_that_does_not_decode_fails_the_object(tmp_path, name):
    from sc3d_data.io.meshes import MeshError, load_mesh

    path = _ply(tmp_path, name, b"not an image")
    with pytest.raises(MeshError, match=f"texture {name} unreadable"):
        load_mesh(path, root=tmp_path / "ds")


def test_a_ply_texture_read_in_place_of_its_name_is_warned_about(tmp_path):
    from sc3d_data.io.meshes import load_mesh

    path = _ply(tmp_path, "textures/t.png", None)
    scene, _, _, warnings = load_mesh(path, root=tmp_path / "ds")
    (geometry,) = scene.geometry.values()
    assert geometry.visual.material.image.convert("RGB").getpixel((0, 0)) == (200, 30, 30)  # drawn with it
    assert warnings == [f"{path}: texture textures/t.png not found; t.png beside the PLY is read in its place"]
