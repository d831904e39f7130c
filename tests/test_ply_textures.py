"""PLY files of several textures (MeshLab's ``texnumber``) and ``<this>`` in texture names
(``sc3d_data.io.ply_textures``), from files written here by hand, as MeshLab writes them."""
from __future__ import annotations

import struct

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import FAST, index_of
from test_faults_round19_data import _objects

#: two unit squares facing +Z side by side, the left one (x 0..1) drawn with texture 0
SQUARES = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (3, 0, 0), (3, 1, 0), (2, 1, 0)]
TRIANGLES = [((0, 1, 2), 0), ((0, 2, 3), 0), ((4, 5, 6), 1), ((4, 6, 7), 1)]
UV = {0: (0, 0), 1: (1, 0), 2: (1, 1), 3: (0, 1), 4: (0, 0), 5: (1, 0), 6: (1, 1), 7: (0, 1)}
RED, BLUE = (220, 30, 30), (30, 30, 220)


def _meshlab_ply(path, names: list[str], binary: bool = False, numbers=None) -> None:
    """The two squares as MeshLab writes a mesh of several textures: one ``comment TextureFile`` per
    texture, texture coordinates per face corner, the face's texture in ``texnumber``."""
    numbers = numbers or [n for _, n in TRIANGLES]
    head = ("ply\nformat %s 1.0\ncomment VCGLIB generated\n" % ("binary_little_endian" if binary else "ascii")
            + "".join(f"comment TextureFile {n}\n" for n in names)
            + "element vertex 8\nproperty float x\nproperty float y\nproperty float z\nelement face 4\n"
              "property list uchar int vertex_indices\nproperty list uchar float texcoord\nproperty int texnumber\n"
              "end_header\n").encode()
    rows = [(f, sum((UV[i] for i in f), ()), n) for (f, _), n in zip(TRIANGLES, numbers)]
    if binary:
        body = b"".join(struct.pack("<3f", *p) for p in SQUARES) + b"".join(
            struct.pack("<B3iB6fi", 3, *f, 6, *uv, n) for f, uv, n in rows)
    else:
        body = ("".join("%g %g %g\n" % p for p in SQUARES) + "".join(
            "3 %d %d %d 6 " % f + " ".join("%g" % c for c in uv) + " %d\n" % n for f, uv, n in rows)).encode()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(head + body)


def _left_right(image: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean colour of the masked pixels of the left and of the right half of the object in ``image``."""
    columns = np.flatnonzero(mask.any(axis=0))
    middle = (columns[0] + columns[-1]) // 2
    left, right = mask.copy(), mask.copy()
    left[:, middle:], right[:, :middle + 1] = 0, 0
    return image[left > 0].mean(axis=0), image[right > 0].mean(axis=0)


def test_each_face_is_drawn_with_the_texture_its_texnumber_names(tmp_path):
    """A PLY naming two textures, ``texnumber`` 0 on the left square and 1 on the right, drew both
    squares with the last texture (trimesh keeps one ``TextureFile``): exit 0, the left one blue.
    Now at azimuth 0 (camera on +Z, +X to the right) the left square is red and the right one blue,
    from ASCII and binary files alike, and also where the names use MeshLab's ``<this>`` (the file
    name without ``.ply``, any case), which failed "<this>_a.png ... not found"."""
    from PIL import Image

    meshes = tmp_path / "m" / "c"
    _meshlab_ply(meshes / "ascii" / "m.ply", ["red.png", "blue.png"])
    _meshlab_ply(meshes / "binary" / "m.ply", ["red.png", "blue.png"], binary=True)
    _meshlab_ply(meshes / "this" / "sq.PLY", ["<this>_a.png", "<THIS>_b.png"])
    for name in ("ascii", "binary"):
        Image.new("RGB", (8, 8), RED).save(meshes / name / "red.png")
        Image.new("RGB", (8, 8), BLUE).save(meshes / name / "blue.png")
    Image.new("RGB", (8, 8), RED).save(meshes / "this" / "sq_a.png")
    Image.new("RGB", (8, 8), BLUE).save(meshes / "this" / "sq_b.png")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST, "--elevations", "0"])
    objects = _objects(out)
    for name, obj in objects.items():
        left, right = _left_right(obj["images"][0], obj["masks"][0])
        assert left[0] > 2 * left[2] and right[2] > 2 * right[0], (name, left, right)
    assert index_of(out)["failures"] == []
    assert sorted(objects) == ["ascii", "binary", "this"]


def test_a_texnumber_that_names_no_texture_is_refused_in_one_line(tmp_path):
    """A face whose ``texnumber`` is past the textures the header names fails the object in one
    line naming the number and the textures, instead of drawing it with another texture."""
    from PIL import Image

    meshes = tmp_path / "m" / "c"
    _meshlab_ply(meshes / "bad" / "m.ply", ["red.png", "blue.png"], numbers=[0, 0, 1, 2])
    for name, colour in (("red.png", RED), ("blue.png", BLUE)):
        Image.new("RGB", (8, 8), colour).save(meshes / "bad" / name)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST], expect_exit=1)
    [failure] = index_of(out)["failures"]
    assert failure["reason"] == (f"{meshes / 'bad' / 'm.ply'}: a face's texnumber 2 names no texture (the header "
                                 "names 2: red.png, blue.png); not read")


def test_a_ply_texture_replaced_since_the_render_is_rendered_again(tmp_path):
    """A rerun renders again an object whose texture was replaced, as for an OBJ's or a glTF's
    (``io.materials.named_files``): a PLY's ``TextureFile`` textures were not fingerprinted, so a
    rerun after the texture was fixed kept the old images ("resumed 1"), exit 0."""
    from PIL import Image

    folder = tmp_path / "m" / "c" / "sq"
    _meshlab_ply(folder / "m.ply", ["<this>_a.png", "b.png"])
    Image.new("RGB", (8, 8), BLUE).save(folder / "m_a.png")
    Image.new("RGB", (8, 8), BLUE).save(folder / "b.png")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST, "--elevations", "0"])
    Image.new("RGB", (16, 16), RED).save(folder / "m_a.png")  # the left square's texture, fixed
    res = run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST, "--elevations", "0"])
    assert "changed since it was rendered (m_a.png: " in res.output and "done 1, resumed 0" in res.output, res.output
    obj = _objects(out)["sq"]
    left, right = _left_right(obj["images"][0], obj["masks"][0])
    assert left[0] > 2 * left[2] and right[2] > 2 * right[0], (left, right)
