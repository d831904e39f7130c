"""Data-half defects of the twenty-first round (items of the left-alone list and the twenty-first
attack), each with the real loader, renderer and command; expected values come from hand-built
reference files that draw the same thing without the feature under test, never from the code
under test."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST, index_of
from test_faults_round19_data import _objects, _reasons


def _vertex_coloured_obj(folder: Path, colour: tuple[float, float, float], mtl: str | None = None,
                         uv: bool = False, texture: tuple[int, int, int] | None = None) -> None:
    """A unit cube ``folder/m.obj`` whose every ``v`` line carries the vertex colour ``colour``
    (``v x y z r g b``, floats 0-1); with ``mtl`` (the text of ``m.mtl``, defining ``mat``) its
    faces use ``mat``; with ``uv`` they carry texture coordinates; ``texture``: an 8 x 8 PNG
    ``t.png`` of that colour beside it."""
    import trimesh
    from PIL import Image

    folder.mkdir(parents=True)
    box = trimesh.creation.box()
    lines = ["mtllib m.mtl"] if mtl is not None else []
    lines += ["v %f %f %f %g %g %g" % (*p, *colour) for p in box.vertices]
    if uv:
        lines += ["vt %f %f" % tuple(p[:2] + 0.5) for p in box.vertices]
    lines += ["usemtl mat"] if mtl is not None else []
    corner = "%d/%d" if uv else "%d"
    lines += ["f " + " ".join(corner % ((i,) * corner.count("%d")) for i in face) for face in box.faces + 1]
    (folder / "m.obj").write_text("\n".join(lines) + "\n")
    if mtl is not None:
        (folder / "m.mtl").write_text(mtl)
    if texture is not None:
        Image.new("RGB", (8, 8), texture).save(folder / "t.png")


def test_obj_vertex_colours_beside_a_material_are_drawn(tmp_path):
    """Blender's and MeshLab's OBJ exporters write vertex colours as ``v x y z r g b``; trimesh's
    loader dropped them where the faces also use a material, and the object was drawn in the
    material's colour (a white cube for red vertices, exit 0). sc3d draws material colour x
    texture x vertex colour, as glTF defines for ``COLOR_0`` (the decision in
    ``io.loader_visuals``). References: the same cube with the vertex colours and no material
    (trimesh's plain vertex colours), and with ``vt`` but no ``.mtl`` (trimesh's placeholder
    material, which must not hide them either). A white material (and a white texture) must draw
    the reference's pixels; a blue material on red vertices black (red x blue = 0)."""
    meshes = tmp_path / "m" / "c"
    red, green = (1, 0, 0), (0, 1, 0)
    _vertex_coloured_obj(meshes / "red_plain", red)
    _vertex_coloured_obj(meshes / "red_white_material", red, "newmtl mat\nKd 1 1 1\n")
    _vertex_coloured_obj(meshes / "red_vt_no_material", red, uv=True)
    _vertex_coloured_obj(meshes / "red_blue_material", red, "newmtl mat\nKd 0 0 1\n")
    _vertex_coloured_obj(meshes / "green_plain", green)
    _vertex_coloured_obj(meshes / "green_white_texture", green, "newmtl mat\nKd 1 1 1\nmap_Kd t.png\n", uv=True,
                         texture=(255, 255, 255))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == [] and index_of(out)["warnings"] == []
    objects = _objects(out)
    red_px = objects["red_plain"]["images"][objects["red_plain"]["masks"] > 0].astype(int)
    assert (red_px[:, 0] > 100).all() and (red_px[:, 1:] < 10).all()  # the reference is red
    for name, reference in (("red_white_material", "red_plain"), ("red_vt_no_material", "red_plain"),
                            ("green_white_texture", "green_plain")):
        np.testing.assert_array_equal(objects[name]["masks"], objects[reference]["masks"], err_msg=name)
        np.testing.assert_array_equal(objects[name]["images"], objects[reference]["images"], err_msg=name)
    blue_red = objects["red_blue_material"]
    assert (blue_red["images"][blue_red["masks"] > 0] < 10).all()


def test_an_obj_with_a_byte_order_mark_or_comments_after_numbers_draws_as_without(tmp_path):
    """Two ways real OBJ files are written that the loader misread: a UTF-8 byte-order mark first
    (Windows editors; the loader took it for part of the first ``v``, lost that vertex and
    failed "cannot parse"), and comments after the numbers of a statement (``f 1 2 3 4 # top``,
    ``v 0 0 1 # tip``; "cannot parse"). Both must draw the pixels of the same file without them
    (the reference: a red cube with its material); a ``#`` in a material name is kept."""
    import trimesh

    box = trimesh.creation.box()
    vertices = ["v %f %f %f" % tuple(p) for p in box.vertices]
    faces = ["f %d %d %d" % tuple(f) for f in box.faces + 1]
    files = {
        "plain": ["mtllib m.mtl", *vertices, "usemtl red#1", *faces],
        "bom": ["mtllib m.mtl", *vertices, "usemtl red#1", *faces],
        "bom_before_v": [*vertices, "mtllib m.mtl", "usemtl red#1", *faces],
        "comments": ["# exported", "mtllib m.mtl", vertices[0] + " # first corner", *vertices[1:],
                     "usemtl red#1", *(f + f"  #face {i}" for i, f in enumerate(faces)), "# end"],
    }
    for name, lines in files.items():
        folder = tmp_path / "m" / "c" / name
        folder.mkdir(parents=True)
        text = ("\n".join(lines) + "\n").encode()
        (folder / "m.obj").write_bytes(b"\xef\xbb\xbf" + text if name.startswith("bom") else text)
        (folder / "m.mtl").write_text("newmtl red#1\nKd 1 0 0\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == [] and index_of(out)["warnings"] == []
    objects = _objects(out)
    plain = objects["plain"]["images"][objects["plain"]["masks"] > 0].astype(int)
    assert (plain[:, 0] > 100).all() and (plain[:, 1:] < 10).all()  # the reference is red: its material read
    for name in ("bom", "bom_before_v", "comments"):
        np.testing.assert_array_equal(objects[name]["masks"], objects["plain"]["masks"], err_msg=name)
        np.testing.assert_array_equal(objects[name]["images"], objects["plain"]["images"], err_msg=name)


def test_gltf_nodes_that_name_a_camera_draw_their_mesh_and_children(tmp_path):
    """glTF allows a node with both a ``camera`` and a ``mesh``, and children under a camera's
    node; trimesh's loader took the first camera node for the scene's camera and skipped the rest
    of it: its mesh was not drawn (another object, exit 0) and a child failed the file ("No path
    from world->2!"). Reference: the same cube under the same node scale with no camera."""
    from test_gltf_accessors import _edit_gltf

    camera = [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.01}}]
    folder = tmp_path / "m" / "box"
    folder.mkdir(parents=True)
    _edit_gltf(folder / "plain.gltf", lambda d: d["nodes"][0].update(scale=[2, 1, 1]))
    _edit_gltf(folder / "camera_and_mesh.gltf",
               lambda d: (d["nodes"][0].update(scale=[2, 1, 1], camera=0), d.update(cameras=camera)))
    _edit_gltf(folder / "camera_parent.gltf", lambda d: d.update(
        nodes=[{"camera": 0, "scale": [2, 1, 1], "children": [1]}, {"mesh": 0}], cameras=camera))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == []
    objects = _objects(out)
    for name in ("camera_and_mesh", "camera_parent"):
        np.testing.assert_array_equal(objects[name]["masks"], objects["plain"]["masks"], err_msg=name)
        np.testing.assert_array_equal(objects[name]["images"], objects["plain"]["images"], err_msg=name)


def test_gltf_instancing_unknown_required_extensions_and_sparse_colours_are_refused(tmp_path):
    """What the loader would draw as another object, exit 0, is refused in one line naming it (a
    node drawing its mesh through ``EXT_mesh_gpu_instancing`` was, until instancing was applied:
    it renders now), an extension in ``extensionsRequired`` the loader does not
    know (the glTF spec: a loader must not load such a file), and a sparse ``COLOR_0`` (the
    loader read its base values: black). Controls: required extensions the loader reads or the
    matte renderer may leave out, and a sparse ``TEXCOORD_0`` of an untextured primitive (it
    places nothing), render."""
    from test_gltf_accessors import _edit_gltf

    def sparse(attribute: str, kind: str):
        def edit(doc):
            doc["accessors"].append({"bufferView": 0, "componentType": 5126, "count": 8, "type": kind, "sparse": {
                "count": 1, "indices": {"bufferView": 1, "componentType": 5125}, "values": {"bufferView": 0}}})
            doc["meshes"][0]["primitives"][0]["attributes"][attribute] = len(doc["accessors"]) - 1
        return edit

    folder = tmp_path / "m" / "box"
    folder.mkdir(parents=True)
    _edit_gltf(folder / "instanced.gltf", lambda d: d["nodes"][0].update(
        extensions={"EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": 0}}}))  # 8 VEC3: 8 instances
    _edit_gltf(folder / "requires_lod.gltf", lambda d: d.update(extensionsRequired=["MSFT_lod"]))
    _edit_gltf(folder / "sparse_colours.gltf", sparse("COLOR_0", "VEC3"))
    _edit_gltf(folder / "sparse_uv_untextured.gltf", sparse("TEXCOORD_0", "VEC2"))  # places nothing: drawn
    _edit_gltf(folder / "requires_known.gltf",
               lambda d: d.update(extensionsRequired=["KHR_materials_unlit", "KHR_mesh_quantization"]))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert _reasons(out) == {  # instancing is applied since: tests/test_gltf_instancing.py
        "requires_lod": "it requires MSFT_lod, an extension the loader does not read; not read",
        "sparse_colours": "accessor 2 (COLOR_0 of mesh 0) is sparse, which the loader does not apply; not read"}
    assert set(_objects(out)) == {"requires_known", "sparse_uv_untextured", "instanced"}


def _prism_off(hexagons_as_triangles: bool, header: str = "OFF", cap_colour: str = "") -> str:
    """A hexagonal prism as OFF text: two hexagons and six quad sides, or (``hexagons_as_triangles``)
    each hexagon written by hand as the four triangles of its fan from corner 0; ``cap_colour``
    (``" r g b"``) after the corners of each hexagon (or each of its triangles)."""
    import math

    ring = [(math.cos(k * math.pi / 3), math.sin(k * math.pi / 3)) for k in range(6)]
    vertices = [f"{x:.6f} {y:.6f} {z}" for z in (0, 1) for x, y in ring]
    bottom, top = list(range(5, -1, -1)), list(range(6, 12))
    caps = [[h[0], h[i], h[i + 1]] for h in (bottom, top) for i in range(1, 5)] if hexagons_as_triangles \
        else [bottom, top]
    sides = [[k, (k + 1) % 6, (k + 1) % 6 + 6, k + 6] for k in range(6)]
    faces = [f"{len(f)} " + " ".join(map(str, f)) + (cap_colour if f in caps else "") for f in caps + sides]
    return "\n".join([header, "# a prism", f"{len(vertices)} {len(faces)} 0", *vertices, *faces]) + "\n"


def test_ply_diffuse_colours_off_polygons_and_clamped_mtl_textures(tmp_path):
    """Three more files as tools write them. A PLY whose vertex colours are named
    ``diffuse_red/green/blue`` (the Stanford tools' examples) was drawn grey, exit 0: it must draw
    the pixels of the same file with ``red/green/blue``. An OFF with hexagons beside quads (a
    prism; CAD exports) failed "cannot parse" (trimesh's OFF loader): it must draw the pixels of
    the same prism whose hexagons are written as triangles by hand, also after a header with the
    counts on its line and in ``COFF`` with a colour after each hexagon's corners (drawn since
    ``io.off_colours``: the reference's triangles carry it). A ``map_Kd -clamp on`` texture renders
    without a warning (it was warned of as repeated; it is drawn clamped since ``io.texture_wraps``)."""
    import trimesh

    box = trimesh.creation.box()
    colours = [(25, 50, 80), (230, 200, 180), (25, 200, 80), (230, 50, 180)] * 2

    def ply(prefix: str) -> str:
        head = ["ply", "format ascii 1.0", "element vertex 8", *(f"property float {a}" for a in "xyz"),
                *(f"property uchar {prefix}{c}" for c in ("red", "green", "blue")), "element face 12",
                "property list uchar int vertex_indices", "end_header"]
        return "\n".join(head + ["%f %f %f %d %d %d" % (*p, *c) for p, c in zip(box.vertices, colours)]
                         + ["3 %d %d %d" % tuple(f) for f in box.faces]) + "\n"

    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    (meshes / "plain_colours.ply").write_text(ply(""))
    (meshes / "diffuse_colours.ply").write_text(ply("diffuse_"))
    (meshes / "prism_triangles.off").write_text(_prism_off(True))
    (meshes / "prism_hexagons.off").write_text(_prism_off(False))
    (meshes / "prism_red_triangles.off").write_text(_prism_off(True, cap_colour=" 255 0 0"))
    (meshes / "prism_coff_counts_on_header.off").write_text(
        _prism_off(False, "COFF", " 255 0 0").replace("COFF\n# a prism\n", "COFF ", 1))
    _textured_clamp = meshes / "clamped"
    _textured_clamp.mkdir()
    (_textured_clamp / "m.obj").write_text("mtllib m.mtl\n" + "\n".join("v %f %f %f" % tuple(p) for p in box.vertices)
                                           + "\n" + "\n".join("vt %f %f" % tuple(p[:2] + 0.5) for p in box.vertices)
                                           + "\nusemtl wood\n" + "\n".join("f %d/%d %d/%d %d/%d" % (a, a, b, b, c, c)
                                                                           for a, b, c in box.faces + 1) + "\n")
    (_textured_clamp / "m.mtl").write_text("newmtl wood\nKd 1 1 1\nmap_Kd -clamp on t.png\n")
    from PIL import Image
    Image.new("RGB", (8, 8), (200, 120, 40)).save(_textured_clamp / "t.png")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == []
    assert index_of(out)["warnings"] == []  # the clamp is drawn since io.texture_wraps (test_faults_round27_data)
    objects = {Path(name[1]).name if "/" not in name[1] else name[1].split("/")[0]: obj
               for name, obj in objects_by_id(out).items()}
    grey = objects["plain_colours"]["images"][objects["plain_colours"]["masks"] > 0]
    assert np.ptp(grey.astype(int), axis=1).max() > 50  # the reference is coloured, not grey
    for name, reference in (("diffuse_colours", "plain_colours"), ("prism_hexagons", "prism_triangles"),
                            ("prism_coff_counts_on_header", "prism_red_triangles")):
        np.testing.assert_array_equal(objects[name]["masks"], objects[reference]["masks"], err_msg=name)
        np.testing.assert_array_equal(objects[name]["images"], objects[reference]["images"], err_msg=name)


def test_large_palette_and_one_bit_textures_are_drawn(tmp_path):
    """A texture over 1024 px is box-filtered down before upload, and PIL's ``reduce`` refuses
    palette and 1-bit images (PNG optimisers write them: glTF's CesiumMilkTruck has a 2048 px
    palette texture), so such an object failed with "image has wrong mode". Reference: the same
    2048 px texture saved as RGB; both must draw its pixels (the palette holds the colour exactly,
    and the 1-bit texture is white, drawn as a white RGB texture)."""
    from PIL import Image

    def textured(name: str, image) -> None:
        _vertex_coloured_obj(tmp_path / "m" / "c" / name, (1, 1, 1), "newmtl mat\nKd 1 1 1\nmap_Kd t.png\n", uv=True)
        obj = tmp_path / "m" / "c" / name / "m.obj"  # the same cube without its vertex colours
        obj.write_text("\n".join(" ".join(line.split()[:4]) if line.startswith("v ") else line
                                 for line in obj.read_text().splitlines()) + "\n")
        image.save(tmp_path / "m" / "c" / name / "t.png")

    red = Image.new("RGB", (2048, 2048), (200, 30, 30))
    textured("red_rgb", red)
    textured("red_palette", red.convert("P", palette=Image.ADAPTIVE, colors=16))
    textured("white_rgb", Image.new("RGB", (2048, 2048), (255, 255, 255)))
    textured("white_one_bit", Image.new("1", (2048, 2048), 1))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == []
    objects = _objects(out)
    assert Image.open(tmp_path / "m" / "c" / "red_palette" / "t.png").mode == "P"
    for name, reference in (("red_palette", "red_rgb"), ("white_one_bit", "white_rgb")):
        np.testing.assert_array_equal(objects[name]["images"], objects[reference]["images"], err_msg=name)
    red_px = objects["red_rgb"]["images"][objects["red_rgb"]["masks"] > 0].astype(int)
    assert (red_px[:, 0] > red_px[:, 1] + 50).all()  # the reference draws its red texture


def test_a_missing_ply_texture_fails_in_one_line_without_the_loaders_traceback(tmp_path):
    """A PLY naming its texture in ``comment TextureFile`` (MeshLab) that is missing fails the
    object in one line naming it; trimesh's logger also printed a traceback naming neither the
    mesh nor sc3d ("unable to load image!" ... "FileNotFoundError"), from every worker. The
    command runs in its own process, so its workers' output is what it prints (a forkserver
    started by another test would keep that test's streams)."""
    import subprocess
    import sys

    import trimesh

    box = trimesh.creation.box()
    head = ["ply", "format ascii 1.0", "comment TextureFile gone.png", "element vertex 8",
            *(f"property float {a}" for a in ("x", "y", "z", "texture_u", "texture_v")),
            "element face 12", "property list uchar int vertex_indices", "end_header"]
    folder = tmp_path / "m" / "c"
    folder.mkdir(parents=True)
    (folder / "box.ply").write_text("\n".join(head + ["%f %f %f 0.5 0.5" % tuple(p) for p in box.vertices]
                                              + ["3 %d %d %d" % tuple(f) for f in box.faces]) + "\n")
    (folder / "plain.obj").write_text(box.export(file_type="obj"))
    out = tmp_path / "out"
    script = Path(sys.executable).parent / "sc3d-data"  # the installed console script
    printed = subprocess.run([str(script), "render", "--meshes", str(tmp_path / "m"), "--out", str(out), *FAST],
                             capture_output=True, text=True, timeout=300)
    assert printed.returncode == 0, printed.stdout + printed.stderr
    [failure] = index_of(out)["failures"]
    assert failure["reason"].startswith(f"{folder / 'box.ply'}: gone.png named by the mesh or its materials was not "
                                        "loaded (not found)"), failure
    said = printed.stdout + printed.stderr
    assert "Traceback" not in said and "unable to load image" not in said, said


def test_merge_of_parts_planned_from_two_states_of_the_collection_names_the_cause(tmp_path):
    """Part 0/2 rendered from 2 categories, a third added, then part 1/2: ``merge`` said "split
    differs" (the split's record counts the plan's objects), pointing at a setting the user did not
    change. It must name the plans' object counts and the way out (rerun the earlier part, which
    plans again), after which the merge holds every object."""
    import shutil

    from conftest import SAMPLE_MESHES, one_error

    meshes = tmp_path / "m"
    for category in ("airplane", "car"):
        shutil.copytree(Path(SAMPLE_MESHES) / category, meshes / category)
    render = ["render", "--meshes", meshes, "--views", 4, "--image-size", 32, "--workers", 1, "--no-progress"]
    run_cli(data_main, [*render, "--out", tmp_path / "p0", "--part", "0/2"])
    shutil.copytree(Path(SAMPLE_MESHES) / "table", meshes / "table")
    run_cli(data_main, [*render, "--out", tmp_path / "p1", "--part", "1/2"])
    total = sum(1 for p in meshes.rglob("*") if p.is_file() and p.suffix in (".glb", ".obj", ".ply", ".off", ".stl"))
    before = total - sum(1 for p in (meshes / "table").rglob("*") if p.suffix in (".glb", ".obj", ".ply", ".off", ".stl"))
    error = one_error(run_cli(data_main, ["merge", tmp_path / "merged", tmp_path / "p0", tmp_path / "p1"],
                              expect_exit=1).output)
    assert f"planned from {total} objects, {tmp_path / 'p0'} from {before}: the meshes changed" in error, error
    run_cli(data_main, [*render, "--out", tmp_path / "p0", "--part", "0/2"])  # plans again
    run_cli(data_main, ["merge", tmp_path / "merged", tmp_path / "p0", tmp_path / "p1"])
    assert len(index_of(tmp_path / "merged")["objects"]) == total
