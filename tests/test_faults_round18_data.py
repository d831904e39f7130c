"""Textures the eighteenth attack on the commands (2026-11-28) found lost without a word: an MTL
saved with a UTF-8 byte-order mark, and an OBJ whose comment names a material file. The
expected images come from the same cube written plainly (a simpler route to the same object),
rendered by the real renderer in the same run."""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
from PIL import Image

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import index_of

FAST = ["--views", "2", "--no-progress", "--workers", "1"]
CUBE = [(-1, -1, -1), (1, -1, -1), (1, 1, -1), (-1, 1, -1), (-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)]
QUADS = [(1, 2, 3, 4), (5, 8, 7, 6), (1, 5, 6, 2), (2, 6, 7, 3), (3, 7, 8, 4), (5, 1, 4, 8)]


def textured_cube(folder: Path, header: str = "", mtl_prefix: bytes = b"") -> None:
    """A cube whose every face maps a red/blue checker (``texture.png`` through ``model.mtl``)."""
    folder.mkdir(parents=True)
    rows, cols = np.mgrid[:64, :64]
    checker = ((rows // 8 + cols // 8) % 2).astype(bool)
    image = np.zeros((64, 64, 3), np.uint8)
    image[checker], image[~checker] = (255, 0, 0), (0, 0, 255)
    Image.fromarray(image).save(folder / "texture.png")
    lines = ([header] if header else []) + ["mtllib model.mtl"] + [f"v {x} {y} {z}" for x, y, z in CUBE]
    lines += ["vt 0 0", "vt 1 0", "vt 1 1", "vt 0 1", "usemtl mat"]
    for a, b, c, d in QUADS:
        lines += [f"f {a}/1 {b}/2 {c}/3", f"f {a}/1 {c}/3 {d}/4"]
    (folder / "model.obj").write_text("\n".join(lines) + "\n")
    (folder / "model.mtl").write_bytes(mtl_prefix + b"newmtl mat\nKd 0.8 0.8 0.8\nmap_Kd texture.png\n")


def _images(out: Path) -> dict[str, np.ndarray]:
    images = {}
    for shard in sorted(out.glob("shard-*.h5")):
        with h5py.File(shard, "r") as f:
            for i, model_id in enumerate(f["model_id"][:]):
                images[model_id.decode()] = f["images"][i]
    return images


def test_an_mtl_with_a_byte_order_mark_and_an_mtllib_in_a_comment_keep_their_texture(tmp_path):
    """``bom``: its ``model.mtl`` starts with Notepad's UTF-8 mark, which hid its ``newmtl`` from
    trimesh: the cube rendered flat grey, exit 0, no warning. ``comment``: a comment ``# mtllib
    old.mtl`` above the real statement made the loader read ``old.mtl`` (a stale green material)
    instead. ``gone``: the same comment without an ``old.mtl`` failed the object, blaming a file
    the OBJ does not name. Each renders as the plain cube now, pixel for pixel."""
    meshes = tmp_path / "m" / "02958343"
    textured_cube(meshes / "plain")
    textured_cube(meshes / "bom", mtl_prefix=b"\xef\xbb\xbf")
    textured_cube(meshes / "comment", header="# mtllib old.mtl")
    (meshes / "comment" / "old.mtl").write_text("newmtl mat\nKd 0 0.8 0\n")
    textured_cube(meshes / "gone", header="# mtllib old.mtl")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", meshes.parent, "--out", out, *FAST])
    assert index_of(out)["failures"] == [] and index_of(out).get("warnings", []) == []
    images = _images(out)
    assert sorted(images) == ["bom", "comment", "gone", "plain"]
    plain = images["plain"]
    assert plain[0].reshape(-1, 3).max(axis=0)[0] == 255 and plain[0].reshape(-1, 3).max(axis=0)[2] == 255  # textured
    for name in ("bom", "comment", "gone"):
        assert np.array_equal(images[name], plain), name


def test_map_options_whose_value_is_a_word_are_not_taken_for_the_file_name():
    """``map_Kd -imfchan r texture.png`` failed "texture r texture.png not found": the MTL options
    whose value is a word (``-imfchan r|g|b|m|l|z``, ``-type sphere|cube_top|...``) were read as part
    of the name. Expected names by hand from the MTL format (numeric and on/off options too)."""
    from sc3d_data.io.mtl_text import map_file_name

    assert map_file_name("-imfchan r texture.png") == "texture.png"
    assert map_file_name("-type sphere -s 1 1 1 tex.png") == "tex.png"
    assert map_file_name("-clamp on -bm 0.5 dir\\tex.png") == "dir/tex.png"
    assert map_file_name("plain name.png") == "plain name.png"  # control: a name with a space


def test_a_texture_no_face_is_drawn_with_is_warned_of(tmp_path):
    """``novt``: the cube's faces have no texture coordinates (``f 1 2 3``), so the loader draws its
    ``map_Kd`` checker nowhere: it rendered in the material's grey, exit 0, without a word. One
    warning now names the texture; the plain cube gets none (control)."""
    meshes = tmp_path / "m" / "02958343"
    textured_cube(meshes / "plain")
    textured_cube(meshes / "novt")
    obj = meshes / "novt" / "model.obj"
    lines = obj.read_text().splitlines()
    obj.write_text("\n".join(ln if not ln.startswith("f ") else "f " + " ".join(t.split("/")[0] for t in ln.split()[1:])
                             for ln in lines) + "\n")
    out = tmp_path / "out"
    res = run_cli(data_main, ["render", "--meshes", meshes.parent, "--out", out, *FAST])
    warnings = index_of(out)["warnings"]
    assert len(warnings) == 1 and "novt" in warnings[0]["source"], warnings
    assert "name the texture(s) texture.png, but no face is drawn with them" in warnings[0]["warning"], warnings
    assert "1 with warnings" in res.output, res.output
