"""Defects found reviewing the changes of 2026-12-07 (OFF colours, PLY textures, index listing
checks), each test failing without its fix. Files written here by hand; real loader and CLI."""
from __future__ import annotations

import json
import os

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import one_error, run_cli
from test_faults import FAST
from test_ply_textures import BLUE, RED, _meshlab_ply

CUBE = ("OFF\n8 6 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 0 1\n1 0 1\n1 1 1\n0 1 1\n"
        "4 0 3 2 1\n4 4 5 6 7\n4 0 1 5 4\n4 1 2 6 5\n4 2 3 7 6\n4 3 0 4 7\n")


def _cubes(root):
    for category in ("a", "b"):
        (root / category).mkdir(parents=True)
        for i in (1, 2):
            (root / category / f"cube{i}.off").write_text(CUBE)
    return root


def test_merge_again_repairs_an_out_index_whose_lists_disagree(tmp_path):
    """A merged OUT whose index lists a shard twice is refused by readers with 'render or merge it
    again', but merging again (also with --overwrite) was refused with that same line: no command
    repaired it. Merging the same parts again now writes a good index."""
    meshes = _cubes(tmp_path / "m")
    parts = [tmp_path / f"p{i}" for i in (0, 1)]
    for i, part in enumerate(parts):
        run_cli(data_main, ["render", "--meshes", meshes, "--out", part, "--part", f"{i}/2", *FAST,
                            "--objects-per-shard", "1", "--image-size", "32"])
    out = tmp_path / "out"
    run_cli(data_main, ["merge", out, *parts])
    index = json.loads((out / "index.json").read_text())
    index["shards"].append(dict(index["shards"][1]))
    (out / "index.json").write_text(json.dumps(index))
    assert "render or merge it again" in one_error(run_cli(data_main, ["info", out], expect_exit=1).output)
    run_cli(data_main, ["merge", out, *parts])
    assert run_cli(data_main, ["info", out, "--verify"]).exit_code == 0
    assert len(json.loads((out / "index.json").read_text())["shards"]) == 4


def _ply_of_quads_with_vertex_uv(path):
    """The two squares of ``test_ply_textures`` as quads, texture coordinates per vertex (``s t``),
    ``texnumber`` per face: trimesh splits the quads, so there are more triangles than numbers."""
    square = [(0, 0), (1, 0), (1, 1), (0, 1)]
    rows = [f"{x} {y} 0 {s} {t}" for k in (0, 2) for (x, y), (s, t) in zip([(k + a, b) for a, b in square], square)]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("ply\nformat ascii 1.0\ncomment TextureFile red.png\ncomment TextureFile blue.png\n"
                    "element vertex 8\nproperty float x\nproperty float y\nproperty float z\nproperty float s\n"
                    "property float t\nelement face 3\nproperty list uchar int vertex_indices\nproperty int texnumber\n"
                    "end_header\n" + "\n".join(rows) + "\n4 0 1 2 3 0\n3 4 5 6 1\n3 4 6 7 1\n")


def _drawn_colours(scene) -> dict[float, tuple]:
    """``{x of a part's centre: its texture's colour}`` of a loaded scene."""
    return {round(float(np.mean(g.vertices[:, 0])), 1): g.visual.material.image.getpixel((0, 0))[:3]
            for g in scene.geometry.values()}


def test_texnumbers_of_faces_the_loader_split_into_triangles(tmp_path):
    """A PLY of several textures whose quads trimesh splits (texture coordinates per vertex) has
    more triangles than ``texnumber`` values: it was refused '3 texnumber values for 4 faces; not
    read' (before 2026-12-07 it rendered with one texture). Each triangle now takes its face's
    number, in trimesh's order of splitting (``io.ply_colors.face_sources``)."""
    from PIL import Image

    from sc3d_data.io.meshes import load_mesh

    path = tmp_path / "c" / "q.ply"
    _ply_of_quads_with_vertex_uv(path)
    Image.new("RGB", (8, 8), RED).save(path.parent / "red.png")
    Image.new("RGB", (8, 8), BLUE).save(path.parent / "blue.png")
    scene, _, faces, _ = load_mesh(path)
    assert len(faces) == 4 and _drawn_colours(scene) == {0.5: RED, 2.5: BLUE}


def test_this_in_a_ply_reached_through_a_symlink_names_the_file_linked_to(tmp_path):
    """A mesh reached through a symlink names its files relative to the file the link points to
    (docs/data.md); ``<this>`` was filled with the link's name: the loader looked for
    ``chair_a.png`` and failed 'not found', while the rerun fingerprints
    (``materials.named_files``) named ``abc_a.png``. Both now name the linked file's."""
    from PIL import Image

    from sc3d_data.io.materials import named_files
    from sc3d_data.io.meshes import load_mesh

    store, meshes = tmp_path / "store", tmp_path / "m" / "c"
    _meshlab_ply(store / "abc.ply", ["<this>_a.png", "<this>_b.png"])
    Image.new("RGB", (8, 8), RED).save(store / "abc_a.png")
    Image.new("RGB", (8, 8), BLUE).save(store / "abc_b.png")
    meshes.mkdir(parents=True)
    os.symlink(store / "abc.ply", meshes / "chair.ply")
    scene = load_mesh(meshes / "chair.ply")[0]
    assert _drawn_colours(scene) == {0.5: RED, 2.5: BLUE}
    assert [p.name for p in named_files(meshes / "chair.ply")] == ["abc_a.png", "abc_b.png"]


def test_an_off_of_polygons_without_colours_is_not_read_twice(tmp_path, monkeypatch):
    """An OFF with polygons of five or more corners and no colour was read in full a second time by
    ``io.off_colours`` (every coordinate converted, every face split) only to find no colour: a
    240,000-hexagon file loaded in 19 s where it took 9.6 s. It now looks at the polygon lines
    alone; a polygon with a colour is still drawn in it."""
    from sc3d_data.io import off_colours

    read = []
    monkeypatch.setattr(off_colours, "off_lines", lambda data: read.append(1) or None)
    plain, coloured = tmp_path / "plain.off", tmp_path / "coloured.off"
    hexagon = "OFF\n6 1 0\n0 0 0\n1 0 0\n2 1 0\n1 2 0\n0 2 0\n-1 1 0\n6 0 1 2 3 4 5"
    plain.write_text(hexagon + "\n")
    coloured.write_text(hexagon + " 10 20 30\n")
    assert off_colours.coloured_off_as_ply(plain) == (None, []) and read == []
    off_colours.coloured_off_as_ply(coloured)
    assert read == [1]


def test_an_index_object_whose_id_is_not_text_is_no_traceback(tmp_path):
    """A hand-edited index whose object has a list for its ``model_id`` made every reader fail with
    a traceback ('TypeError: unhashable type: list') in ``index_check.listing_problems``; before
    2026-12-07 ``info`` read it. The lists are compared on the ids' text."""
    meshes = _cubes(tmp_path / "m")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", meshes, "--out", out, *FAST, "--image-size", "32"])
    index = json.loads((out / "index.json").read_text())
    index["objects"][0]["model_id"] = ["cube1"]
    (out / "index.json").write_text(json.dumps(index))
    assert run_cli(data_main, ["info", out, "--verify"]).exit_code == 0
