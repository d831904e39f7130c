"""PLY files with one colour per face whose faces are quads or polygons. trimesh splits them into
triangles but keeps one colour per source face; the renderer then drew half of a quad cube black
(it read past the end of its colour buffer) and ``check`` passed. Now each triangle takes its
face's colour (``sc3d_data.io.ply_colors``). Real PLY files, the real loader and renderer."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import FAST

#: the unit cube's corners and its six sides as quads
CORNERS = [(x, y, z) for z in (-0.5, 0.5) for y in (-0.5, 0.5) for x in (-0.5, 0.5)]
SIDES = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
#: six colours with no channel in common pattern: a pixel's lit channels name its side
COLOURS = [(255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0), (0, 255, 255), (255, 0, 255)]


def write_ply(path, corners, faces, colours) -> None:
    """An ASCII PLY of ``corners`` and ``faces`` (vertex index lists of any length) with one
    ``red green blue`` per face."""
    lines = ["ply", "format ascii 1.0", f"element vertex {len(corners)}", "property float x", "property float y",
             "property float z", f"element face {len(faces)}", "property list uchar int vertex_indices",
             "property uchar red", "property uchar green", "property uchar blue", "end_header"]
    lines += [" ".join(map(str, c)) for c in corners]
    lines += [" ".join(map(str, [len(f), *f, *c])) for f, c in zip(faces, colours)]
    path.write_text("\n".join(lines) + "\n")


def test_a_quad_cube_renders_each_side_in_its_own_colour(tmp_path):
    """Every object pixel of the 4 views lights exactly the channels of one side's colour
    (shading scales a colour, it never lights a channel the colour lacks); before, 1,278 of
    2,160 object pixels of view 0 were black."""
    (tmp_path / "m" / "box").mkdir(parents=True)
    write_ply(tmp_path / "m" / "box" / "cube.ply", CORNERS, SIDES, COLOURS)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    with h5py.File(out / "shard-00000.h5") as f:
        images, masks = f["images"][0], f["masks"][0] > 0
    lit = images[masks] > 0                                   # [pixels, 3]
    patterns = np.array(COLOURS) > 0                          # [6, 3]
    matches = (lit[:, None, :] == patterns[None]).all(2)      # [pixels, 6]
    assert masks.sum() > 1000 and matches.any(1).all(), f"{(~matches.any(1)).sum()} of {masks.sum()} pixels"
    # every side but the bottom (y = -0.5, +Y up: side 2, blue) is seen from the elevation of 30 degrees
    assert sorted(np.unique(matches.argmax(1))) == [0, 1, 3, 4, 5]


def test_triangles_of_quads_and_polygons_take_their_faces_colours(tmp_path):
    """A triangle, quads and a pentagon in one file, in mixed order: each triangle the loader
    makes gets the colour of the face whose corners it uses (found here by corner sets, not by
    the order ``face_sources`` assumes)."""
    from sc3d_data.io.meshes import load_mesh

    corners = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (2, 1, 0), (3, 0.5, 0), (0, 2, 0), (1, 2, 1)]
    faces = [(0, 1, 2, 3), (1, 4, 5, 6, 2), (3, 2, 8), (2, 5, 8, 7)]
    colours = [(200, 0, 0), (0, 200, 0), (0, 0, 200), (200, 200, 0)]
    path = tmp_path / "mixed.ply"
    write_ply(path, corners, faces, colours)
    scene, *_ = load_mesh(path)
    (geometry,) = scene.geometry.values()
    assert len(geometry.faces) == 2 + 3 + 1 + 2
    for triangle, colour in zip(geometry.faces, geometry.visual.face_colors):
        (face,) = [i for i, f in enumerate(faces) if set(triangle) <= set(f)]
        assert tuple(colour[:3]) == colours[face], (triangle, colour)


def test_face_sources_follow_trimesh_triangulation():
    """The order :func:`face_sources` assumes, against trimesh's own ``triangulate_quads`` on a
    hand-made mixed list: triangles first, then first halves of quads, then second halves, then
    pentagon fans, so for faces of 4, 3, 5, 4 corners the sources are 1, 0, 3, 0, 3, 2, 2, 2."""
    from trimesh.geometry import triangulate_quads

    from sc3d_data.io.ply_colors import face_sources

    faces = [[0, 1, 2, 3], [4, 5, 6], [7, 8, 9, 10, 11], [12, 13, 14, 15]]
    origin = face_sources([4, 3, 5, 4])
    assert origin.tolist() == [1, 0, 3, 0, 3, 2, 2, 2]
    for triangle, face in zip(triangulate_quads(faces), origin):
        assert set(triangle.tolist()) <= set(faces[face])


def test_colours_that_match_no_face_order_are_refused_not_drawn(tmp_path):
    """A geometry with fewer face colours than triangles and no PLY face lists to match them
    with (as another loader could make) is refused in one line, and the renderer never draws
    colours that do not cover every triangle."""
    import trimesh

    from sc3d_data.io.ply_colors import per_triangle_face_colors
    from sc3d_data.render.renderer import mesh_parts

    cube = trimesh.creation.box()  # as trimesh's PLY loader makes it: 6 colours given for 12 triangles
    box = trimesh.Trimesh(cube.vertices, cube.faces, face_colors=np.tile(np.uint8([255, 0, 0, 255]), (6, 1)),
                          process=False)
    assert box.visual.kind == "face" and len(box.visual.face_colors) == 6
    assert per_triangle_face_colors(box, "box.ply") == ("box.ply: 6 face colours for 12 triangles, and which triangle "
                                                       "came from which face cannot be told; not read")
    with pytest.raises(ValueError, match="6 face colours for 12 triangles"):
        list(mesh_parts(trimesh.Scene(box), np.eye(4)))
