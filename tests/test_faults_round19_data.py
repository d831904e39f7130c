"""Data-half defects of the nineteenth round (items of the left-alone list and the nineteenth
attack), each with the real loader, renderer and command; expected values come from the file
formats' specifications (glTF 2.0, the MTL format) and from hand-built fixtures, never from the
code under test."""
from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
import pytest

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST, index_of
from test_gltf_accessors import CUBE
from test_gltf_primitives import _gltf_doc


def _coloured_cube(path: Path, colors: np.ndarray, component_type: int, material: dict | None) -> None:
    """The cube as .gltf with every corner's ``COLOR_0`` = ``colors`` (one row, repeated; stored
    with glTF ``component_type``, normalised where an integer type) and ``material`` on its primitive."""
    doc, buf = _gltf_doc(CUBE)
    data = np.tile(colors, (8, 1)).tobytes()
    doc["bufferViews"].append({"buffer": 0, "byteOffset": len(buf), "byteLength": len(data)})
    accessor = {"bufferView": len(doc["bufferViews"]) - 1, "componentType": component_type, "count": 8,
                "type": "VEC3" if len(colors) == 3 else "VEC4"}
    doc["accessors"].append(accessor | ({"normalized": True} if component_type != 5126 else {}))
    buf += data + b"\0" * (-len(data) % 4)
    prim = doc["meshes"][0]["primitives"][0]
    prim["attributes"]["COLOR_0"] = len(doc["accessors"]) - 1
    if material is not None:
        doc["materials"], prim["material"] = [material], 0
    doc["buffers"] = [{"byteLength": len(buf),
                       "uri": "data:application/octet-stream;base64," + base64.b64encode(buf).decode()}]
    path.write_text(json.dumps(doc))


def test_vertex_colours_of_a_glTF_primitive_with_a_material_are_drawn(tmp_path):
    """glTF 2.0 (3.9.2): a primitive's base colour is ``baseColorFactor`` x texture x ``COLOR_0``.
    The reference is the same red cube without a material, drawn through the loader's plain
    vertex colours: a white material with red ``COLOR_0`` (floats, or normalised bytes with
    alpha) must draw the same pixels, and a blue material with red ``COLOR_0`` must draw black
    (red x blue = 0). Before, trimesh's loader kept the material and the colours were dropped:
    white and blue cubes, exit 0. And unsigned-short colours without a material (Blender's
    exporter writes them so) were cast to bytes, not scaled: 32768 (0.5) became 0; now they
    draw as the float colours they mean, in a .gltf and in a GLB."""
    folder = tmp_path / "m" / "box"
    folder.mkdir(parents=True)
    red, white, blue = np.float32([1, 0, 0]), [1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 1.0, 1.0]
    _coloured_cube(folder / "plain.gltf", red, 5126, None)
    _coloured_cube(folder / "white_float.gltf", red, 5126,
                   {"pbrMetallicRoughness": {"baseColorFactor": white, "metallicFactor": 0}})
    _coloured_cube(folder / "white_bytes.gltf", np.uint8([255, 0, 0, 255]), 5121,
                   {"pbrMetallicRoughness": {"baseColorFactor": white, "metallicFactor": 0}})
    _coloured_cube(folder / "blue_float.gltf", red, 5126,
                   {"pbrMetallicRoughness": {"baseColorFactor": blue, "metallicFactor": 0}})
    # unsigned shorts without a material, as Blender writes vertex paint: trimesh cast them to bytes (wrapped)
    _coloured_cube(folder / "orange_shorts.gltf", np.uint16([65535, 32768, 0, 65535]), 5123, None)  # 0.5: Blender 4
    _coloured_cube(folder / "orange_float.gltf", np.float32([1, 128 / 255, 0]), 5126, None)  # 32768 / 257 -> 128
    _as_glb(json.loads((folder / "orange_shorts.gltf").read_text()), folder / "orange_shorts_glb.glb")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == []
    objects = _objects(out)
    plain = objects["plain"]
    assert _looks(out)["plain"] == "red"  # the reference
    for name in ("orange_shorts", "orange_shorts_glb"):
        np.testing.assert_array_equal(objects[name]["images"], objects["orange_float"]["images"], err_msg=name)
    for name in ("white_float", "white_bytes"):
        np.testing.assert_array_equal(objects[name]["masks"], plain["masks"])
        np.testing.assert_array_equal(objects[name]["images"], plain["images"], err_msg=name)
    blue_red = objects["blue_float"]
    assert (blue_red["images"][blue_red["masks"] > 0] < 10).all()


def _textured_obj(folder: Path, mtl: bytes, usemtl: str = "mat", texture: bytes = b"t.png") -> None:
    """A unit cube ``folder/m.obj`` with texture coordinates, ``mtllib m.mtl`` (whose bytes are
    ``mtl``) and ``usemtl``, beside an all-red 8 x 8 PNG whose file name is the bytes ``texture``."""
    import os

    import trimesh
    from PIL import Image

    folder.mkdir(parents=True)
    box = trimesh.creation.box()
    lines = ["mtllib m.mtl"] + ["v %f %f %f" % tuple(p) for p in box.vertices]
    lines += ["vt %f %f" % tuple(p[:2] + 0.5) for p in box.vertices] + [f"usemtl {usemtl}"]
    lines += ["f %d/%d %d/%d %d/%d" % (a, a, b, b, c, c) for a, b, c in box.faces + 1]
    (folder / "m.obj").write_text("\n".join(lines) + "\n")
    (folder / "m.mtl").write_bytes(mtl)
    Image.new("RGB", (8, 8), (255, 0, 0)).save(os.fsdecode(os.fsencode(folder) + b"/" + texture), format="PNG")


def _objects(out: Path) -> dict[str, dict]:
    """``{model: its arrays}`` of every object of dataset ``out``, named by the first part of its
    model id (the folder of a mesh ``c/NAME/m.obj``, or the stem of ``box/NAME.gltf``)."""
    return {name[1].split("/")[0]: obj for name, obj in objects_by_id(out).items()}


def _reasons(out: Path) -> dict[str, str]:
    """``{stem of the mesh file: its failure's reason without the path}`` of dataset ``out``."""
    return {Path(f["source"]).stem: f["reason"].split(": ", 1)[1] for f in index_of(out)["failures"]}


def _looks(out: Path) -> dict[str, str]:
    """``{model: "red" | "grey"}`` of every object of dataset ``out``: red where every masked pixel
    is red (the texture drawn), grey where every one is grey (material colour)."""
    looks = {}
    for name, obj in _objects(out).items():
        px = obj["images"][obj["masks"] > 0].astype(int)
        looks[name] = "red" if ((px[:, 0] > 100) & (px[:, 1:] < 10).all(1)).all() else \
            "grey" if (np.ptp(px, axis=1) < 3).all() else "mixed"
    return looks


def test_textures_named_in_quotes_or_in_latin1_bytes_are_drawn(tmp_path):
    """An MTL's ``map_Kd "my tex.png"`` names ``my tex.png`` (quotes are not part of the name), and
    a Latin-1 MTL's ``map_Kd caf\\xe9.png`` names the file of those bytes (an exporter on a Latin-1
    system wrote both). Before, both objects failed "texture ... not found". Controls: the same
    name in a UTF-8 MTL, and a plain name."""
    meshes = tmp_path / "m" / "c"
    _textured_obj(meshes / "quoted", b'newmtl mat\nKd 1 1 1\nmap_Kd "my tex.png"\n', texture=b"my tex.png")
    _textured_obj(meshes / "latin1", b"newmtl mat\nKd 1 1 1\nmap_Kd caf\xe9.png\n", texture=b"caf\xe9.png")
    _textured_obj(meshes / "utf8", "newmtl mat\nKd 1 1 1\nmap_Kd café.png\n".encode(), texture="café.png".encode())
    _textured_obj(meshes / "plain", b"newmtl mat\nKd 1 1 1\nmap_Kd t.png\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == [] and index_of(out).get("warnings", []) == []
    assert _looks(out) == {"quoted": "red", "latin1": "red", "utf8": "red", "plain": "red"}


def test_a_material_used_but_not_defined_or_textured_by_map_Ka_alone_is_warned_of(tmp_path):
    """``usemtl other`` when the MTL defines only ``mat`` draws the faces with trimesh's default
    material, and a material whose texture is given only as ``map_Ka`` draws no texture (only
    ``map_Kd`` is drawn): both rendered grey without a word before. Now one warning each, naming
    the material; controls: a defined material, and ``map_Ka`` beside ``map_Kd`` (red, no warning)."""
    meshes = tmp_path / "m" / "c"
    _textured_obj(meshes / "undefined", b"newmtl mat\nKd 1 1 1\nmap_Kd t.png\n", usemtl="other")
    _textured_obj(meshes / "ambient", b"newmtl mat\nKd 1 1 1\nmap_Ka t.png\n")
    _textured_obj(meshes / "both", b"newmtl mat\nKd 1 1 1\nmap_Ka t.png\nmap_Kd t.png\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    warnings = {}
    for w in index_of(out)["warnings"]:
        warnings.setdefault(Path(w["source"]).parent.name, []).append(w["warning"].split(": ", 1)[1])
    assert set(warnings) == {"undefined", "ambient"}
    assert warnings["undefined"] == [  # the cause, and what it costs (the texture t.png is drawn on no face)
        "usemtl names other, which its material files do not define; those faces are drawn with the default material",
        "its materials name the texture(s) t.png, but no face is drawn with them (faces without texture coordinates "
        "`vt`?); rendered with material colours"]
    assert warnings["ambient"] == ["material mat of m.mtl gives its texture t.png as map_Ka (ambient), which is not "
                                   "drawn (only map_Kd is); rendered in its colour"]
    assert _looks(out) == {"undefined": "grey", "ambient": "grey", "both": "red"}


def test_voxelize_shards_writes_the_grids_settings_into_each_shard(tmp_path):
    """SPEC: every value used is written into the shard attributes. ``voxelize SHARDS
    --resolution 16`` on shards rendered without voxels left each shard's attributes saying
    ``voxelize: false``, ``voxel_resolution: 32`` beside 16^3 grids (only the index knew). Now each
    rewritten shard carries the attribute ``voxels`` (resolution, occupancy rule), read here with
    h5py, and its grids have that size; the render's own ``settings`` are left as they were."""
    import h5py

    from sc3d_data.io.shards import shard_files

    out = tmp_path / "out"
    run_cli(data_main, ["render", "--out", out, *FAST])
    run_cli(data_main, ["voxelize", out, "--resolution", "16", "--workers", "1", "--no-progress"])

    def assert_attributes():
        shards = shard_files(out)
        assert shards
        for path in shards:
            with h5py.File(path, "r") as f:
                made, settings = json.loads(f.attrs["voxels"]), json.loads(f.attrs["settings"])
                assert f["voxels"].shape[1:] == (16, 16, 16)
            assert made["resolution"] == 16 and "winding number" in made["occupancy"]
            assert settings["voxelize"] is False  # the render's settings, as the render wrote them

    assert_attributes()
    # a render rerun rewrites a shard (an object dropped from the index is rendered again, at the grids'
    # resolution): the rewritten shard keeps the attribute (the review found it dropped, and never written again)
    index = index_of(out)
    index["objects"].pop(0)
    (out / "index.json").write_text(json.dumps(index))
    run_cli(data_main, ["render", "--out", out, *FAST])
    assert_attributes()


def test_a_texture_named_by_another_machines_path_is_read_from_beside_the_material_file(tmp_path):
    """An MTL written elsewhere names its texture by that machine's path (``map_Kd
    C:\\Users\\me\\textures\\t.png``, ``/home/someone/textures/t.png``) and the texture was copied
    beside it. The loader reads ``t.png`` from beside the MTL (trimesh's resolver falls back to
    the bare file name), but the checks judged the path as written: the Windows-path object failed
    "not found" and the other got the warning "not read; rendered without it" while drawn with
    it. Now both render red without a word; control: with no ``t.png`` beside the MTL, the
    Windows path still fails "not found"."""
    meshes = tmp_path / "m" / "c"
    _textured_obj(meshes / "windows", b"newmtl mat\nKd 1 1 1\nmap_Kd C:\\Users\\me\\textures\\t.png\n")
    _textured_obj(meshes / "unix", b"newmtl mat\nKd 1 1 1\nmap_Kd /home/someone/textures/t.png\n")
    _textured_obj(meshes / "missing", b"newmtl mat\nKd 1 1 1\nmap_Kd C:\\Users\\me\\textures\\gone.png\n")
    # a missing relative name is read from beside the MTL too, as the loader reads it, but with a warning naming
    # both files (round 28: it failed "not found" while the loader drew t.png with --bad-texture fallback)
    _textured_obj(meshes / "relative", b"newmtl mat\nKd 1 1 1\nmap_Kd textures/t.png\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    index = index_of(out)
    assert sorted((Path(f["source"]).parent.name, f["reason"].split(": ", 1)[1]) for f in index["failures"]) == [
        ("missing", "texture C:/Users/me/textures/gone.png (from m.mtl) not found (use --bad-texture fallback to "
                    "render with material colours)")]
    assert [(Path(w["source"]).parent.name, w["warning"].split(": ", 1)[1]) for w in index.get("warnings", [])] == [
        ("relative", "texture textures/t.png (from m.mtl) not found; t.png beside m.mtl is read in its place")]
    assert _looks(out) == {"windows": "red", "unix": "red", "relative": "red"}


def test_an_object_dropped_from_the_index_is_rendered_again_once(tmp_path):
    """A rerun after an object's entry was removed from ``index.json`` (its row still in the
    shard) renders it again, as it should, but kept the old row too: the shard held the object
    twice (7 rows for 6 meshes), and ``info --verify`` and ``check`` passed. Now the new row
    replaces the old: one row per mesh file, the same pixels as before."""
    import collections

    import h5py

    from sc3d_data.io.shards import shard_files

    meshes = tmp_path / "m"
    for category in ("chair", "car"):
        (meshes / category).mkdir(parents=True)
        for glb in (Path(__file__).parent.parent / "assets" / "sample_meshes" / category).glob("*.glb"):
            (meshes / category / glb.name).symlink_to(glb)
    n_meshes = len(list(meshes.rglob("*.glb")))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", meshes, "--out", out, *FAST])
    before = objects_by_id(out)
    index = index_of(out)
    dropped = index["objects"].pop(1)
    (out / "index.json").write_text(json.dumps(index))
    run_cli(data_main, ["render", "--meshes", meshes, "--out", out, *FAST])
    ids = []
    for path in shard_files(out):
        with h5py.File(path, "r") as f:
            ids += [(c.decode(), m.decode()) for c, m in zip(f["category"][()], f["model_id"][()])]
    assert len(ids) == n_meshes and collections.Counter(ids).most_common(1)[0][1] == 1
    assert index_of(out)["counts"]["total"] == n_meshes
    key = (dropped["category"], dropped["model_id"])
    np.testing.assert_array_equal(objects_by_id(out)[key]["images"], before[key]["images"])


def test_a_mesh_it_had_skipped_is_not_called_new(tmp_path):
    """A mesh in no split of ``--split-file`` is skipped; adding it to the split file and
    rendering again (where that moves objects to other shards) was refused as "1 mesh(es) are
    new ...; move the new ones away", though the mesh had been there all along. Now the refusal
    says it was skipped, and why. A run without ``--part`` over a part's folder is no longer
    called "part 0/1"."""
    meshes = tmp_path / "m"
    for category in ("car", "chair"):
        (meshes / category).mkdir(parents=True)
        for glb in (Path(__file__).parent.parent / "assets" / "sample_meshes" / category).glob("*.glb"):
            (meshes / category / glb.name).symlink_to(glb)
    chairs = sorted(p.stem for p in (meshes / "chair").glob("*.glb"))
    split = tmp_path / "sp.txt"
    split.write_text(f"train chair/{chairs[1]}\ntest chair/{chairs[2]}\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", meshes, "--out", out, "--split-file", split,
                        "--objects-per-shard", "1", *FAST])
    split.write_text(split.read_text() + f"train chair/{chairs[0]}\n")  # sorts before the kept ones
    res = run_cli(data_main, ["render", "--meshes", meshes, "--out", out, "--split-file", split,
                              "--objects-per-shard", "1", *FAST], expect_exit=1)
    assert (f"1 mesh(es) it skipped are now to be done ({meshes}/chair/{chairs[0]}.glb: skipped as not in any "
            "split (--split-file)); give the settings that skipped them again") in res.output
    assert "are new" not in res.output

    parts = tmp_path / "parts"
    run_cli(data_main, ["render", "--out", parts, "--part", "0/2", *FAST])
    res = run_cli(data_main, ["render", "--out", parts, *FAST], expect_exit=1)
    assert "holds part 0/2, this run is of all objects (no --part); give each part its own --out" in res.output


def test_check_says_when_the_dataset_it_passes_is_incomplete(tmp_path):
    """``check`` of a dataset whose render stopped part-way (its index says ``complete: false``,
    as an interrupted run leaves it) printed PASS with no word that objects are missing. Now a
    note says the verdict covers the objects written so far; control: no note when complete."""
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--out", out, "--voxelize", *FAST])
    res = run_cli(data_main, ["check", out, "--no-progress"])
    assert "incomplete" not in res.output
    index = index_of(out)
    index["complete"] = False
    (out / "index.json").write_text(json.dumps(index))
    res = run_cli(data_main, ["check", out, "--no-progress"])
    assert f"note: {out} is incomplete" in res.output and "the verdict is on the objects written so far" in res.output


def test_a_specular_glossiness_material_draws_its_diffuse_texture(tmp_path):
    """``KHR_materials_pbrSpecularGlossiness`` (older Sketchfab and Objaverse files): the diffuse
    texture is the surface's colour, as viewers show it. trimesh converts the material to
    metallic-roughness, whose base colour for the default specularFactor [1, 1, 1] is white, and
    the cube whose diffuse texture is red where it is mapped rendered white, exit 0. Now red; a
    diffuseFactor multiplies it (blue x red: black), and the same texture as a plain
    baseColorTexture draws the same pixels as the diffuse one."""
    from test_gltf_features import _half_red_half_green_cube

    folder = tmp_path / "m" / "box"
    folder.mkdir(parents=True)
    gloss = "KHR_materials_pbrSpecularGlossiness"
    _half_red_half_green_cube(folder / "gloss.gltf", {"extensions": {gloss: {"diffuseTexture": {"index": 0}}}})
    _half_red_half_green_cube(folder / "gloss_blue.gltf", {"extensions": {gloss: {
        "diffuseTexture": {"index": 0}, "diffuseFactor": [0, 0, 1, 1]}}})
    _half_red_half_green_cube(folder / "metal_rough.gltf", {"pbrMetallicRoughness": {
        "baseColorTexture": {"index": 0}, "metallicFactor": 0}})
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == []
    objects = _objects(out)
    reference = objects["metal_rough"]
    assert _looks(out)["metal_rough"] == "red"
    np.testing.assert_array_equal(objects["gloss"]["images"], reference["images"])
    assert (objects["gloss_blue"]["images"][objects["gloss_blue"]["masks"] > 0] < 10).all()


def test_a_texture_without_a_colour_factor_is_drawn_as_it_is_and_one_value_colours_spread(tmp_path):
    """A texture the file gives no colour to multiply with (an MTL material with ``map_Kd`` and no
    ``Kd``; a PLY's ``comment TextureFile``, which has no colour at all) was drawn at 40%
    (trimesh's default diffuse 0.4), unlike Blender and MeshLab; and ``Kd 0.8`` (the MTL format:
    g and b default to r) dropped the material for the default grey. References: the same files
    with ``Kd 1 1 1`` and ``Kd 0.8 0.8 0.8`` written out."""
    import trimesh

    meshes = tmp_path / "m" / "c"
    _textured_obj(meshes / "no_kd", b"newmtl mat\nmap_Kd t.png\n")
    _textured_obj(meshes / "kd_white", b"newmtl mat\nKd 1 1 1\nmap_Kd t.png\n")
    _textured_obj(meshes / "kd_one", b"newmtl mat\nKd 0.8\n")
    _textured_obj(meshes / "kd_three", b"newmtl mat\nKd 0.8 0.8 0.8\n")
    box = trimesh.creation.box()
    (meshes / "ply").mkdir()
    from PIL import Image
    Image.new("RGB", (8, 8), (255, 0, 0)).save(meshes / "ply" / "t.png")
    header = ["ply", "format ascii 1.0", "comment TextureFile t.png", f"element vertex {len(box.vertices)}",
              "property float x", "property float y", "property float z", "property float texture_u",
              "property float texture_v", f"element face {len(box.faces)}", "property list uchar int vertex_indices",
              "end_header"]
    rows = ["%g %g %g %g %g" % (*p, *(p[:2] + 0.5)) for p in box.vertices] + ["3 %d %d %d" % tuple(f) for f in box.faces]
    (meshes / "ply" / "m.ply").write_text("\n".join(header + rows) + "\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == []
    objects = _objects(out)
    for name, reference in (("no_kd", "kd_white"), ("ply", "kd_white"), ("kd_one", "kd_three")):
        np.testing.assert_array_equal(objects[name]["images"], objects[reference]["images"], err_msg=name)
    assert _looks(out)["kd_white"] == "red"

    # the review: with --bad-texture fallback, such a material whose texture is missing is drawn in the colour the
    # file gives (none: the loader's default), as the same material without the map_Kd line, not white
    fallback = tmp_path / "fallback"
    _textured_obj(fallback / "c" / "missing", b"newmtl mat\nmap_Kd gone.png\n")
    _textured_obj(fallback / "c" / "plain", b"newmtl mat\n")
    out = tmp_path / "out_fallback"
    run_cli(data_main, ["render", "--meshes", fallback, "--out", out, "--bad-texture", "fallback", *FAST])
    objects = _objects(out)
    np.testing.assert_array_equal(objects["missing"]["images"], objects["plain"]["images"])


def _two_boxes_obj(relative: bool) -> str:
    """Two unit boxes at x = -2 and x = +2, written object by object (``o``, 8 ``v``, 12 faces),
    the faces by relative indices (``f -8 -7 -5``: counted back from the vertices read so far, as
    per-object exporters write them) or by absolute ones."""
    import trimesh

    box = trimesh.creation.box()
    lines = []
    for k, x in enumerate((-2.0, 2.0)):
        lines += [f"o box{k}"] + ["v %g %g %g" % (px + x, py, pz) for px, py, pz in box.vertices]
        first = 8 * k + 1
        lines += ["f " + " ".join(str(i - 8 if relative else first + i) for i in face) for face in box.faces]
    return "\n".join(lines) + "\n"


def test_relative_obj_indices_count_back_from_the_vertices_read_so_far(tmp_path):
    """OBJ: a negative index counts back from the vertices read so far. trimesh counts it back
    from the end of the whole file, so the first box's faces were drawn on the second box's
    vertices: one box rendered where the file has two, exit 0. Reference: the same file with the
    absolute indices written out; control: relative indices after all vertices load as before."""
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    (meshes / "relative.obj").write_text(_two_boxes_obj(relative=True))
    (meshes / "absolute.obj").write_text(_two_boxes_obj(relative=False))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--voxelize", *FAST])
    assert index_of(out)["failures"] == []
    objects = _objects(out)
    for array in ("images", "masks", "voxels"):
        np.testing.assert_array_equal(objects["relative"][array], objects["absolute"][array], err_msg=array)

    from sc3d_data.io.obj_loader_text import absolute_indices

    assert absolute_indices("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf -3/-1 -2/-1 -1/-1 # c\n") == \
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1\n"  # a comment after a face: the loader cannot parse it
    assert absolute_indices("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 \\\n-1\n") == "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    with pytest.raises(ValueError, match="line 2 .*index -2 counts back past the first v statement"):
        absolute_indices("v 0 0 0\nf -2 -1 -1\n")


def test_a_latin1_obj_and_mtl_keep_their_material(tmp_path):
    """A Latin-1 OBJ whose ``usemtl Mat\\xe9riau`` names a material of its Latin-1 MTL: trimesh
    decoded the OBJ by a guess of its character set (mac_iceland, cp775 ...) and the MTL as
    Latin-1, the names differed, and the cube rendered untextured without a word. Now both are
    read as Latin-1: red, as its UTF-8 twin."""
    meshes = tmp_path / "m" / "c"
    for name, encoding in (("latin1", "latin-1"), ("utf8", "utf-8")):
        _textured_obj(meshes / name, "newmtl Matériau\nKd 1 1 1\nmap_Kd t.png\n".encode(encoding), usemtl="Matériau")
        obj = meshes / name / "m.obj"
        obj.write_bytes(obj.read_text().encode(encoding))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == [] and index_of(out).get("warnings", []) == []
    assert _looks(out) == {"latin1": "red", "utf8": "red"}


def test_a_ktx2_texture_with_a_png_fallback_draws_the_png(tmp_path):
    """``KHR_texture_basisu`` as gltfpack and gltf-transform write it: the texture's ``source`` is a
    PNG (what a reader without KTX2 draws) and the extension names a KTX2 image. Every image of
    the file was decoded, the KTX2 could not be, and the good file failed with a reason naming
    ``<_io.BytesIO object at 0x...>``. Now the PNG is drawn (the same pixels as the file without
    the extension); required (no fallback), the file is refused in one line naming the extension;
    an image the loader reads that does not decode is named, not a Python object."""
    import copy

    from test_gltf_features import _half_red_half_green_cube

    folder = tmp_path / "m" / "box"
    folder.mkdir(parents=True)
    material = {"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0}}
    _half_red_half_green_cube(folder / "png.gltf", material)
    doc = json.loads((folder / "png.gltf").read_text())
    ktx2 = "data:image/ktx2;base64," + base64.b64encode(b"\xabKTX 20\xbb\r\n\x1a\n" + bytes(64)).decode()
    doc["images"].append({"uri": ktx2})
    doc["textures"] = [{"source": 0, "extensions": {"KHR_texture_basisu": {"source": 1}}}]
    doc["extensionsUsed"] = ["KHR_texture_basisu"]
    (folder / "fallback.gltf").write_text(json.dumps(doc))
    required = copy.deepcopy(doc)
    required["extensionsRequired"] = ["KHR_texture_basisu"]
    (folder / "required.gltf").write_text(json.dumps(required))
    broken = copy.deepcopy(doc)
    broken["textures"] = [{"source": 1}]  # the KTX2 as the texture the loader reads
    (folder / "broken.gltf").write_text(json.dumps(broken))
    _as_glb(doc, folder / "fallback_glb.glb")  # the images in the BIN chunk, as gltfpack writes them
    # an image no texture draws still has where it lies judged (the loader asks for it): outside --meshes, a
    # warning as before this change, not a failure (the review found it failed)
    unused = json.loads((folder / "png.gltf").read_text())
    unused["images"].append({"uri": "../../outside.png"})
    (folder / "unused_outside.gltf").write_text(json.dumps(unused))
    (tmp_path / "outside.png").write_bytes(b"not read")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert _reasons(out) == {
        "required": "it requires KHR_texture_basisu (KTX2 / Basis Universal textures), which the loader cannot "
                    "decode; not read",
        "broken": "texture image 1 unreadable (not an image format Pillow reads) (use --bad-texture fallback to "
                  "render with material colours)"}
    assert [(Path(w["source"]).stem, w["warning"].split(": ", 2)[2]) for w in index_of(out)["warnings"]] == [
        ("unused_outside", "not read; rendered without it (--outside-textures)")]
    objects = _objects(out)
    np.testing.assert_array_equal(objects["fallback"]["images"], objects["png"]["images"])
    np.testing.assert_array_equal(objects["unused_outside"]["images"], objects["png"]["images"])
    np.testing.assert_array_equal(objects["fallback_glb"]["images"], objects["png"]["images"])


def _as_glb(doc: dict, path: Path) -> None:
    """``doc`` (a .gltf whose buffer and images are data URIs) written as a GLB whose images are
    bufferViews of its BIN chunk."""
    import copy

    from test_gltf_primitives import _write_glb_document

    doc = copy.deepcopy(doc)
    buf = base64.b64decode(doc["buffers"][0].pop("uri").split(",", 1)[1])
    for image in doc.get("images", []):
        head, data = image.pop("uri").split(",", 1)
        buf += b"\0" * (-len(buf) % 4)
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(buf), "byteLength": len(base64.b64decode(data))})
        image.update(bufferView=len(doc["bufferViews"]) - 1, mimeType=head[5:].split(";")[0])
        buf += base64.b64decode(data)
    buf += b"\0" * (-len(buf) % 4)
    doc["buffers"][0]["byteLength"] = len(buf)
    _write_glb_document(path, doc, buf)


def test_a_mesh_with_weighted_morph_targets_is_refused(tmp_path):
    """glTF morph targets (Blender's shape keys) with weights other than 0 change the shape; the
    loader ignores them and drew the base cube where the file has a box twice as tall, exit 0.
    Now refused in one line naming the mesh; control: the same file with weight 0 (the base
    shape is the file's shape) renders."""
    def morphed(path: Path, weight: float) -> None:
        doc, buf = _gltf_doc(CUBE)
        delta = np.zeros((8, 3), np.float32)
        delta[:, 1] = np.where(np.asarray(CUBE[0][0])[:, 1] > 0, 1.0, 0.0)  # the top face up by 1
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(buf), "byteLength": delta.nbytes})
        doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "componentType": 5126, "count": 8,
                                 "type": "VEC3", "min": delta.min(0).tolist(), "max": delta.max(0).tolist()})
        buf += delta.tobytes()
        doc["meshes"][0]["primitives"][0]["targets"] = [{"POSITION": len(doc["accessors"]) - 1}]
        doc["meshes"][0]["weights"] = [weight]
        doc["buffers"] = [{"byteLength": len(buf),
                           "uri": "data:application/octet-stream;base64," + base64.b64encode(buf).decode()}]
        path.write_text(json.dumps(doc))

    folder = tmp_path / "m" / "box"
    folder.mkdir(parents=True)
    morphed(folder / "weighted.gltf", 1.0)
    morphed(folder / "unweighted.gltf", 0.0)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert [(Path(f["source"]).stem, f["reason"].split(": ", 1)[1]) for f in index_of(out)["failures"]] == [
        ("weighted", "mesh 0 has morph targets with weights other than 0 (shape keys), which the loader does not "
                     "apply: it would draw and voxelize the shape without them; not read")]
    assert [name[1] for name in objects_by_id(out)] == ["unweighted"]


def test_texture_coordinates_without_a_material_draw_the_default_grey(tmp_path):
    """An OBJ with ``vt`` but no material of its own got trimesh's placeholder (a 2 x 2 grey image
    under diffuse 0.4) and rendered darker than the same file without ``vt`` (51 against 114);
    the placeholder also passed for a drawn texture, so an OBJ naming a textured material but
    using none (no ``usemtl``) rendered untextured without the warning. Reference: the file
    without ``vt`` (the renderer's grey for meshes without material)."""
    meshes = tmp_path / "m" / "c"
    _textured_obj(meshes / "with_vt", b"")
    obj = (meshes / "with_vt" / "m.obj").read_text()
    (meshes / "with_vt" / "m.obj").write_text(obj.replace("mtllib m.mtl\n", "").replace("usemtl mat\n", ""))
    (meshes / "no_vt").mkdir(parents=True)
    (meshes / "no_vt" / "m.obj").write_text("\n".join(
        line.split("/")[0] if not line.startswith("f") else " ".join(c.split("/")[0] for c in line.split())
        for line in obj.splitlines() if not line.startswith(("vt", "mtllib", "usemtl"))) + "\n")
    _textured_obj(meshes / "no_usemtl", b"newmtl mat\nKd 1 1 1\nmap_Kd t.png\n")
    obj = meshes / "no_usemtl" / "m.obj"
    obj.write_text(obj.read_text().replace("usemtl mat\n", ""))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    objects = _objects(out)
    np.testing.assert_array_equal(objects["with_vt"]["images"], objects["no_vt"]["images"])
    assert [(Path(w["source"]).parent.name, w["warning"].split(": ", 1)[1]) for w in index_of(out)["warnings"]] == [
        ("no_usemtl", "its materials name the texture(s) t.png, but no face is drawn with them (faces without texture "
                      "coordinates `vt`?); rendered with material colours")]


def test_a_utf16_obj_still_loads(tmp_path):
    """Reading non-UTF-8 OBJs as Latin-1 (above) must not take UTF-16 files from the loader's own
    decoding: the review found a UTF-16 cube read as "no triangles". Reference: the cube's 12
    triangles, as from its UTF-8 twin."""
    import trimesh

    from sc3d_data.io.meshes import load_mesh_triangles

    box = trimesh.creation.box()
    text = "".join("v %g %g %g\n" % tuple(v) for v in box.vertices) + "".join("f %d %d %d\n" % tuple(f + 1) for f in box.faces)
    (tmp_path / "utf16.obj").write_bytes(text.encode("utf-16"))  # with its byte-order mark
    (tmp_path / "utf8.obj").write_text(text)
    for name in ("utf16.obj", "utf8.obj"):
        vertices, faces = load_mesh_triangles(tmp_path / name)
        assert len(faces) == 12, name
