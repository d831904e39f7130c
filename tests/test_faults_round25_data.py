"""Defects found rendering the test and tutorial meshes of other projects (PyTorch3D's
``docs/tutorials/data`` and ``tests/data``, meshio's ``tests/meshes``), fixed with these tests."""
from __future__ import annotations

import numpy as np
import pytest

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import FAST, index_of
from test_faults_round19_data import _objects, _textured_obj

FIELDS = ("images", "masks", "voxels")


def _render(tmp_path, voxelize: bool = True) -> dict[str, dict]:
    """Render ``tmp_path/m`` into ``tmp_path/out`` (``--voxelize`` where asked) and return its
    objects by name (``_objects``), checking that none failed and none was warned about."""
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *(["--voxelize"] * voxelize), *FAST])
    assert index_of(out)["failures"] == [] and index_of(out)["warnings"] == []
    return _objects(out)


def _assert_same(objects: dict, name: str, reference: str, fields=FIELDS) -> None:
    """Object ``name``'s arrays ``fields`` equal those of ``reference``, element for element."""
    for field in fields:
        np.testing.assert_array_equal(objects[name][field], objects[reference][field], err_msg=f"{name} {field}")


def test_a_colour_with_a_comment_after_its_numbers_is_read(tmp_path):
    """PyTorch3D's tutorial cow has ``Kd 1.000 1.000 1.000  # white`` in its ``.mtl``: trimesh
    could not read the numbers, dropped the colour, and the texture was drawn at its default 0.4
    (a dark cow, no warning). References: the same materials without the comments."""
    meshes = tmp_path / "m" / "c"
    for name, kd in (("commented", b"Kd 1.000 1.000 1.000  # white\nKs 0 0 0 # black\nNs 10.0 # shine\n"),
                     ("plain", b"Kd 1.000 1.000 1.000\nKs 0 0 0\nNs 10.0\n"),
                     ("grey_commented", b"Kd 0.5 # one value: grey\n"), ("grey", b"Kd 0.5 0.5 0.5\n")):
        _textured_obj(meshes / name, b"newmtl mat\nmap_Kd t.png\n" + kd)
    objects = _render(tmp_path, voxelize=False)
    _assert_same(objects, "commented", "plain", ("images",))
    _assert_same(objects, "grey_commented", "grey", ("images",))
    seen = objects["plain"]["masks"] > 0  # the red texture under white is brighter than under grey 0.5
    assert objects["plain"]["images"][seen][:, 0].mean() > objects["grey"]["images"][seen][:, 0].mean() + 30


# ----------------------------------------------------------------------------- PLY as exporters write it
def _ply(path, fmt: str, faces, colours=True, header_end: bytes = b"\n") -> None:
    """A pyramid (square base, apex) as PLY ``path`` with faces ``faces`` (lists of corners),
    each face with an RGB colour when ``colours``, in ``fmt``: "ascii", "binary_little_endian" or
    "binary_big_endian"; the header's lines end with ``header_end``."""
    import struct

    vertices = [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (1.0, 1.0, 0.0), (0.0, 1.0, 0.0), (0.5, 0.5, 0.8)]
    palette = [(230, 30, 30), (30, 200, 30), (30, 30, 220), (220, 220, 30), (30, 210, 210), (200, 30, 200)]
    header = ["ply", f"format {fmt} 1.0", "comment made by a test", "element vertex 5", "property float x",
              "property float y", "property double z", f"element face {len(faces)}",
              "property list uchar int vertex_indices"]
    header += ["property uchar red", "property uchar green", "property uchar blue"] * colours + ["end_header"]
    head = header_end.join(h.encode() for h in header) + header_end
    if fmt == "ascii":
        rows = [f"{x} {y} {z}" for x, y, z in vertices]
        rows += [" ".join(map(str, [len(f), *f] + list(palette[i]) * colours)) for i, f in enumerate(faces)]
        path.write_bytes(head + "\n".join(rows).encode() + b"\n")
        return
    o = "<" if fmt == "binary_little_endian" else ">"
    body = b"".join(struct.pack(o + "ffd", *v) for v in vertices)
    body += b"".join(struct.pack(f"{o}B{len(f)}i", len(f), *f) + (struct.pack("3B", *palette[i]) if colours else b"")
                     for i, f in enumerate(faces))
    path.write_bytes(head + body)


PYRAMID = [[0, 3, 2, 1], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]  # a quad beside triangles


def test_a_binary_ply_of_triangles_and_quads_reads_as_its_ascii_twin(tmp_path):
    """Blender's and Rhinoceros' binary PLY export write a mesh's faces as they are, triangles
    beside quads: trimesh's binary reader takes every face to have the first face's corners and
    failed "PLY is unexpected length!" (the draco project's Box.ply, exported by Rhinoceros 6,
    whose header lines also end with CR alone: "cannot decode the file as text"). Reference: the
    same file as ASCII PLY, which the loader reads as written."""
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    _ply(meshes / "ascii.ply", "ascii", PYRAMID)
    _ply(meshes / "little.ply", "binary_little_endian", PYRAMID)
    _ply(meshes / "big.ply", "binary_big_endian", PYRAMID)
    _ply(meshes / "little_cr.ply", "binary_little_endian", PYRAMID, header_end=b"\r")
    _ply(meshes / "ascii_cr.ply", "ascii", PYRAMID, header_end=b"\r")
    _ply(meshes / "grey_ascii.ply", "ascii", PYRAMID[::-1], colours=False)
    _ply(meshes / "grey_little.ply", "binary_little_endian", PYRAMID[::-1], colours=False)
    # a quad, a triangle and a pentagon: the size of three quads, so the first row's length seemed to hold
    coincide = [[0, 3, 2, 1], [0, 1, 4], [1, 2, 4, 3, 0]]
    _ply(meshes / "coincide_ascii.ply", "ascii", coincide)
    _ply(meshes / "coincide_little.ply", "binary_little_endian", coincide)
    objects = _render(tmp_path)
    for name, reference in (("little", "ascii"), ("big", "ascii"), ("little_cr", "ascii"), ("ascii_cr", "ascii"),
                            ("grey_little", "grey_ascii"), ("coincide_little", "coincide_ascii")):
        _assert_same(objects, name, reference)
    seen = objects["ascii"]["masks"] > 0
    assert len(np.unique(objects["ascii"]["images"][seen].reshape(-1, 3), axis=0)) > 4  # the faces' colours


def test_a_binary_ply_cut_short_is_refused_in_one_line_and_uniform_lists_stay_binary(tmp_path):
    from sc3d_data.io.ply_binary_lists import ascii_ply

    _ply(tmp_path / "t.ply", "binary_little_endian", PYRAMID)
    data = (tmp_path / "t.ply").read_bytes()
    split = data.index(b"end_header\n") + len(b"end_header\n")
    assert ascii_ply(data[:split], data[split:]).startswith(b"ply\nformat ascii 1.0\ncomment made by a test\n")
    _ply(tmp_path / "tri.ply", "binary_little_endian", [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    tri = (tmp_path / "tri.ply").read_bytes()
    split_tri = tri.index(b"end_header\n") + len(b"end_header\n")
    assert ascii_ply(tri[:split_tri], tri[split_tri:]) is None  # the loader's binary reading is right
    # a face count over --max-faces is refused before any row is converted; a negative list length is named
    with pytest.raises(ValueError, match=r"^5 faces, more than the limit of 4 \(--max-faces\)$"):
        ascii_ply(data[:split], data[split:], max_faces=4)
    import struct

    signed = (b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
              b"property float z\nelement face 2\nproperty list char int vertex_indices\nend_header\n")
    with pytest.raises(ValueError, match=r"^a list of its face rows has a negative length \(-1\)$"):
        ascii_ply(signed, np.zeros(9, np.float32).tobytes() + struct.pack("<b3ib", 3, 0, 1, 2, -1))
    # an element of a billion rows without properties is not walked row by row (left to the loader)
    huge = data[:split].replace(b"element face", b"element huge 1000000000\nelement face")
    assert ascii_ply(huge, data[split:]) is None
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    (meshes / "short.ply").write_bytes(data[:-10])
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST], expect_exit=1)
    (failure,) = index_of(out)["failures"]
    assert failure["reason"] == (f"{meshes / 'short.ply'}: its binary data ends before its 10 rows do "
                                 f"({len(data) - split - 10:,} bytes); not read")


def test_binary_triangle_strips_of_different_lengths_draw_their_surface(tmp_path):
    """The binary strips of a scan are rows of different lengths (``element tristrips`` with
    several rows), which trimesh's binary reader failed the same way ("PLY is unexpected
    length!", left alone by the last round). A square pyramid's five faces as two strips of 4
    and 7 corners, against the same faces written as triangles."""
    import struct

    vertices = np.float32([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 0.8]])
    base = [0, 3, 1, 2]  # triangles (0 3 1), (3 1 2)
    sides = [0, 1, 4, 2, 4, 3, 4, 0]  # (0 1 4), (1 4 2), (4 2 4) degenerate, (2 4 3), (4 3 4) degenerate, (3 4 0)
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
            "property float z\nelement tristrips 2\nproperty list int int vertex_indices\nend_header\n").encode()
    rows = b"".join(struct.pack(f"<i{len(s)}i", len(s), *s) for s in (base, sides))
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    (meshes / "strips.ply").write_bytes(head + vertices.astype("<f4").tobytes() + rows)
    triangles = [(0, 3, 1), (3, 1, 2), (0, 1, 4), (1, 4, 2), (2, 4, 3), (3, 4, 0)]
    (meshes / "faces.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 6\nproperty list uchar int vertex_indices\nend_header\n"
        + "".join("%r %r %r\n" % tuple(map(float, p)) for p in vertices) + "".join("3 %d %d %d\n" % t for t in triangles))
    _assert_same(_render(tmp_path), "strips", "faces", ("masks", "voxels"))


def test_a_missing_texture_that_several_materials_name_is_named_once(tmp_path):
    """The draco project's ``mat_test.obj``: three materials name the missing ``black.png``, and
    the failure said "texture black.png (from mat_test.mtl) not found" three times."""
    _textured_obj(tmp_path / "m" / "c" / "three", b"newmtl mat\nmap_Kd gone.png\nnewmtl b\nmap_Kd gone.png\n"
                                                   b"newmtl c\nmap_Kd gone.png\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST], expect_exit=1)
    (failure,) = index_of(out)["failures"]
    assert failure["reason"].split(": ", 1)[1] == ("texture gone.png (from m.mtl) not found (use --bad-texture "
                                                   "fallback to render with material colours)")


def test_a_gltf_without_scenes_draws_its_root_nodes(tmp_path):
    """glTF-Blender-IO's ``00_no_scenes.gltf``: a document with nodes but no ``scenes`` (glTF
    calls it a library) failed "empty mesh (no triangles)": trimesh reads its meshes and draws no
    node, while the judge took every mesh as drawn. It now draws its root nodes, as Blender's
    importer does. References: the same documents with a scene of those roots."""
    import json

    from test_gltf_accessors import CUBE
    from test_gltf_primitives import _gltf_doc

    doc, buf = _gltf_doc(CUBE)
    doc["buffers"] = [{"byteLength": len(buf), "uri": "cube.bin"}]
    # a second, offset copy of the cube below a parent node: transforms along the chain apply
    doc["nodes"] = [{"mesh": 0}, {"translation": [2, 0, 0], "children": [2]}, {"mesh": 0, "scale": [1, 2, 1]}]
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    (meshes / "cube.bin").write_bytes(buf)
    (meshes / "scene.gltf").write_text(json.dumps({**doc, "scenes": [{"nodes": [0, 1]}], "scene": 0}))
    (meshes / "no_scenes.gltf").write_text(json.dumps({k: v for k, v in doc.items() if k not in ("scenes", "scene")}))
    objects = _render(tmp_path)
    _assert_same(objects, "no_scenes", "scene")
    assert objects["scene"]["voxels"].sum() < 0.5 * 32 ** 3  # two cubes apart, not one block


def test_a_folder_of_other_3d_formats_is_named_in_the_error(tmp_path):
    """Kaolin's samples ship USDZ beside OBJ, many asset folders FBX: a folder of only such files
    said "no mesh files found" and nothing of what it holds. The error now counts them and says
    to convert them."""
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    for name in ("a.fbx", "b.FBX", "c.usdz", "notes.txt", ".hidden.fbx"):
        (meshes / name).write_bytes(b"not read")
    result = run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", tmp_path / "out", *FAST], expect_exit=1)
    assert result.output.strip().splitlines()[-1] == (
        f"Error: --meshes {tmp_path / 'm'}: no mesh files found (looked for .obj, .glb, .gltf, .ply, .off, .stl); it "
        "holds 3 files of 3D formats sc3d does not read (2 .fbx, 1 .usdz): convert them to glTF/GLB or OBJ, e.g. with "
        "Blender or assimp")


def test_the_root_nodes_of_a_document_with_malformed_children_are_found():
    """``"children": 1`` (not a list) in a document without scenes raised a bare TypeError out of
    ``scene_roots``, outside the loader's error handling (the review of this round): such
    children are left to the loader, which names the file."""
    from sc3d_data.io.gltf_check import scene_roots

    assert scene_roots({"nodes": [{"children": 1}, {"mesh": 0}, {"children": [1, "x"]}, 7]}) == [0, 2, 3]


def test_a_gltf_whose_meshes_no_node_draws_is_refused_saying_so(tmp_path):
    """Meshes without nodes (a library), or a document whose ``scene`` names a scene without
    them, failed "empty mesh (no triangles)": the line now says that no node draws them; a
    document without scenes whose nodes form a cycle (alone, or beside a root) names them."""
    import json

    from test_gltf_accessors import CUBE
    from test_gltf_primitives import _gltf_doc

    doc, buf = _gltf_doc(CUBE)
    doc["buffers"] = [{"byteLength": len(buf), "uri": "cube.bin"}]
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    (meshes / "cube.bin").write_bytes(buf)
    (meshes / "no_nodes.gltf").write_text(json.dumps({k: v for k, v in doc.items() if k not in ("nodes", "scenes",
                                                                                              "scene")}))
    (meshes / "other_scene.gltf").write_text(json.dumps({**doc, "scenes": [{"nodes": [0]}, {"nodes": []}], "scene": 1}))
    cycle = {k: v for k, v in doc.items() if k not in ("scenes", "scene")}  # no scene; a cycle alone, beside a root
    (meshes / "cycle.gltf").write_text(json.dumps({**cycle, "nodes": [{"mesh": 0, "children": [1]}, {"children": [0]}]}))
    (meshes / "cycle_beside_root.gltf").write_text(json.dumps({**cycle, "nodes": [{}, {"mesh": 0, "children": [2]},
                                                                                   {"children": [1]}]}))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST], expect_exit=1)
    says = ("none of its 1 mesh(es) is drawn by a node of the scene it draws (glTF draws a mesh only through a node), "
            "so there is nothing to render; not read")
    cycle_says = "it has no scene, and node(s) {} form a cycle of children (glTF's nodes form trees), which no root " \
                 "reaches; not read"
    assert sorted(f["reason"] for f in index_of(out)["failures"]) == [
        f"{meshes / 'cycle.gltf'}: {cycle_says.format('0, 1')}",
        f"{meshes / 'cycle_beside_root.gltf'}: {cycle_says.format('1, 2')}", f"{meshes / 'no_nodes.gltf'}: {says}",
        f"{meshes / 'other_scene.gltf'}: {says}"]


def test_an_off_whose_faces_run_over_several_lines_reads_as_written_on_one(tmp_path):
    """libigl's tutorial meshes ``inspired_mesh_quads_*.off`` write each quad's corners one per
    line (Geomview's OFF reader and libigl read tokens): trimesh reads a face per line and failed
    "empty mesh (no triangles)". Reference: the same pyramid with each face on one line; a face
    colour after the last corner is dropped, as on one line."""
    vertices = ["0 0 0", "1 0 0", "1 1 0", "0 1 0", "0.5 0.5 0.8"]
    faces = [[0, 3, 2, 1], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    one_line = "\n".join(f"{len(f)} {' '.join(map(str, f))}" for f in faces)
    split = "\n".join(f"{len(f)} {f[0]}\n" + "\n".join(map(str, f[1:-1])) + f"\n{f[-1]} 255 0 0\n" for f in faces)
    for name, text in (("one_line", one_line), ("split", split)):
        (meshes / f"{name}.off").write_text("OFF\n# a comment\n5 5 0\n" + "\n".join(vertices) + "\n" + text + "\n")
    _assert_same(_render(tmp_path), "split", "one_line", ("masks", "voxels", "images"))


def test_a_texture_name_with_a_comment_after_it_is_read(tmp_path):
    """``map_Kd t.png  # diffuse`` named the file "t.png  # diffuse" for trimesh and for sc3d's
    check: "texture ... not found". The name now ends at its image extension (a ``#`` inside a
    name, ``t#1.png``, stays). Reference: the same material without the comment."""
    meshes = tmp_path / "m" / "c"
    _textured_obj(meshes / "commented", b"newmtl mat\nKd 1 1 1\nmap_Kd t.png  # the diffuse texture\n")
    _textured_obj(meshes / "plain", b"newmtl mat\nKd 1 1 1\nmap_Kd t.png\n")
    _textured_obj(meshes / "hash", b"newmtl mat\nKd 1 1 1\nmap_Kd t#1.png\n", texture=b"t#1.png")
    objects = _render(tmp_path, voxelize=False)
    _assert_same(objects, "commented", "plain", ("images",))
    _assert_same(objects, "hash", "plain", ("images",))


def test_a_gltf_node_with_two_parents_is_refused_naming_it(tmp_path):
    """The draco project's ``CubeScaledInstances/glTF/cube_att.gltf``: four parent nodes share
    one child holding the cube (glTF 2.0 allows one parent; the draco decoder reads four
    instances). sc3d drew one cube, exit 0, no warning (the review of this round). Refused in one
    line naming the node; the same document with one parent renders (control)."""
    import json

    from test_gltf_accessors import CUBE
    from test_gltf_primitives import _gltf_doc

    doc, buf = _gltf_doc(CUBE)
    doc["buffers"] = [{"byteLength": len(buf), "uri": "cube.bin"}]
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    (meshes / "cube.bin").write_bytes(buf)
    doc["nodes"] = [{"children": [1, 2]}, {"children": [3]}, {"translation": [3, 0, 0], "children": [3]}, {"mesh": 0}]
    (meshes / "two_parents.gltf").write_text(json.dumps(doc))
    (meshes / "root_and_child.gltf").write_text(json.dumps({**doc, "nodes": [{"children": [1]}, {"mesh": 0}],
                                                            "scenes": [{"nodes": [0, 1]}]}))
    (meshes / "one_parent.gltf").write_text(json.dumps({**doc, "nodes": [{"children": [1]}, {"mesh": 0}]}))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert sorted(f["reason"].split(": ", 1)[1] for f in index_of(out)["failures"]) == [
        "node 1 is a root of the scene and a child of node 0, where glTF allows one parent; the loader would draw it "
        "once; not read",
        "node 3 is a child of nodes 1, 2, where glTF allows one parent; the loader would draw it once; not read"]
    assert list(_objects(out)) == ["one_parent"]
