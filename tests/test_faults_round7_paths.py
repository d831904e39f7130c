"""Hostile inputs to `sc3d-data`, round seven (paths): a symlinked mesh's companion files, empty
`--elevations`, split-file ids with spaces. Expected colours, messages and splits are stated by
hand from the files the tests write."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from sc3d_data.io.meshes import load_mesh

RED = (200, 30, 30)


def _red_box(folder: Path) -> None:
    """``folder/redbox.obj`` (+ ``material.mtl``, ``material_0.png``) and ``folder/redbox.gltf``
    (+ its ``.bin`` buffers and texture): a unit box with an 8x8 texture of one colour, ``RED``."""
    import trimesh
    from PIL import Image

    box = trimesh.creation.box()
    box.visual = trimesh.visual.TextureVisuals(uv=box.vertices[:, :2] + 0.5,
                                               image=Image.fromarray(np.full((8, 8, 3), RED, np.uint8)))
    folder.mkdir(parents=True)
    box.export(folder / "redbox.obj")
    box.export(folder / "redbox.gltf")


def _texture_colour(scene) -> tuple[int, int, int]:
    """The colour of the first texel of the only geometry's texture (OBJ or glTF material)."""
    (geometry,) = scene.geometry.values()
    material = geometry.visual.material
    image = getattr(material, "image", None) or getattr(material, "baseColorTexture", None)
    assert image is not None, f"no texture loaded ({type(material).__name__})"
    return image.convert("RGB").getpixel((0, 0))


@pytest.mark.parametrize("name", ["redbox.obj", "redbox.gltf"])
def test_r7_a_symlinked_mesh_reads_its_companions_beside_its_target(tmp_path, name):
    """A link in the dataset folder to a textured mesh elsewhere looked for its .mtl, texture and
    glTF buffers beside the link: the OBJ rendered grey with 'material file material.mtl not
    found', the glTF failed ('gltf_buffer_0.bin: not found'). They are read beside the target."""
    _red_box(tmp_path / "src")
    (tmp_path / "meshes" / "chair").mkdir(parents=True)
    link = tmp_path / "meshes" / "chair" / ("linked" + Path(name).suffix)
    os.symlink(tmp_path / "src" / name, link)
    scene, _, _, warnings = load_mesh(link, root=tmp_path / "meshes")
    assert warnings == []
    assert _texture_colour(scene) == RED


def test_r7_a_symlinked_mesh_reads_nothing_outside_its_targets_folder(tmp_path):
    """Companions of a link's target stay inside the target's own folder (the rule for every
    path a file names): an .mtl naming `../secret.png` next to the target's folder is not read."""
    _red_box(tmp_path / "src" / "sub")
    secret = tmp_path / "src" / "secret.png"
    (tmp_path / "src" / "sub" / "material_0.png").rename(secret)
    mtl = tmp_path / "src" / "sub" / "material.mtl"
    mtl.write_text(mtl.read_text().replace("material_0.png", "../secret.png"))
    (tmp_path / "meshes" / "chair").mkdir(parents=True)
    link = tmp_path / "meshes" / "chair" / "linked.obj"
    os.symlink(tmp_path / "src" / "sub" / "redbox.obj", link)
    _, _, _, warnings = load_mesh(link, root=tmp_path / "meshes")
    assert len(warnings) == 1 and f"{secret} lies outside the dataset folder {tmp_path / 'src' / 'sub'}" in warnings[0]


@pytest.mark.parametrize("elevations", ["", ",", " , "])
def test_r7_render_refuses_an_empty_elevation_list_in_one_line(tmp_path, elevations):
    """`--elevations ''` (or `,`) raised a ZeroDivisionError traceback while sizing the atlas of
    zero views; now one line names the option, before any mesh is tried or --out is made."""
    from sc3d_cli.data import main
    from conftest import run_cli

    (tmp_path / "meshes" / "chair").mkdir(parents=True)
    (tmp_path / "meshes" / "chair" / "a.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    result = run_cli(main, ["render", "--meshes", tmp_path / "meshes", "--out", tmp_path / "out",
                            "--elevations", elevations, "--no-progress"], expect_exit=1)
    assert result.output.strip() == "Error: --elevations: give at least one elevation"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("file_name, text", [
    ("s.txt", "train\tchair/with space\nTEST   chair/plain\n"),
    ("s.txt", "train  chair/with space  \ntest chair/plain\n"),
    ("train.txt", "chair/with space\n"),
])
def test_r7_split_files_name_ids_with_spaces(tmp_path, file_name, text):
    """A split file could not name an object whose id holds a space ('expected 'SPLIT ID' or
    'ID'', 'expected one id per line'): the id is now the rest of the line after the split name
    (ends stripped), and the whole line in a per-split file. Expected: the splits written."""
    import json

    from sc3d_cli.data import main
    from conftest import run_cli

    (tmp_path / "m" / "chair").mkdir(parents=True)
    for name in ("with space", "plain"):
        (tmp_path / "m" / "chair" / f"{name}.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                                                              "f 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    (split_file := tmp_path / file_name).write_text(text)
    run_cli(main, ["render", "--meshes", tmp_path / "m", "--out", tmp_path / "out", "--split-file", split_file,
                   "--views", 1, "--image-size", 16, "--workers", 1, "--no-progress"])
    index = json.loads((tmp_path / "out" / "index.json").read_text())
    splits = {o["model_id"]: o["split"] for o in index["objects"]}
    assert splits == ({"with space": "train"} if file_name == "train.txt" else {"with space": "train", "plain": "test"})


def test_r7_a_one_word_split_line_still_refuses_a_mistyped_split_name(tmp_path):
    """Control: with ids running to the line's end, a first word that is no split name is still
    refused naming the line (not read as an id with a space, silently put in train)."""
    from sc3d_data.formats.splits import read_split_lines

    (p := tmp_path / "s.txt").write_text("tran chair/a\n")
    with pytest.raises(ValueError, match=r"s\.txt:1: split 'tran' is none of train, val, test"):
        read_split_lines(p)


def test_r7_voxelize_says_a_failed_object_kept_its_grid(tmp_path):
    """A mesh changed since rendering fails `voxelize SHARDS` and keeps the grid made from the
    mesh as rendered, but the closing line said 'their grids are empty'. It now says how many
    kept theirs. Expected: the render's own grid, unchanged, and the line written by hand."""
    import h5py

    from sc3d_cli.data import main
    from conftest import run_cli

    tetra = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n"
    (tmp_path / "m" / "chair").mkdir(parents=True)
    (mesh := tmp_path / "m" / "chair" / "a.obj").write_text(tetra)
    out = tmp_path / "out"
    run_cli(main, ["render", "--meshes", tmp_path / "m", "--out", out, "--voxelize", "--views", 1,
                   "--image-size", 16, "--workers", 1, "--no-progress"])
    with h5py.File(out / "shard-00000.h5", "r") as f:
        rendered = f["voxels"][0]
    mesh.write_text(tetra + "v 2 2 2\nf 1 2 5\n")  # changed since it was rendered
    res = run_cli(main, ["voxelize", out, "--overwrite", "--no-progress"], expect_exit=1)
    assert res.output.strip().splitlines()[-1] == (
        f"Error: no object was voxelized: all 1 failed (earlier grid kept for 1, the others' are empty; "
        f"reasons: `sc3d-data info {out}`)")
    with h5py.File(out / "shard-00000.h5", "r") as f:
        assert rendered.sum() > 0 and (f["voxels"][0] == rendered).all()
