"""Data-half defects of the twenty-fourth round (items of the last left-alone list and the
twenty-fourth attack), each with the real loader, renderer and command; expected values come
from hand-built files and from bash itself, never from the code under test."""
from __future__ import annotations

import json
import os
import re
import subprocess

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import FAST, index_of
from test_faults_round19_data import _objects
from test_faults_round21_data import _vertex_coloured_obj


def test_obj_vertex_colours_that_are_not_numbers_are_refused_in_one_line(tmp_path):
    """``v x y z nan nan nan`` (trimesh's deliberately malformed ``models/nancolor.obj``) was cast
    to 0 by the loader: that corner and the faces around it drawn black, exit 0. Now the file is
    refused in one line naming it and the count, with or without a material; the same cube with
    finite colours (the control) renders, and so does every other object of the run."""
    meshes = tmp_path / "m" / "c"
    _vertex_coloured_obj(meshes / "finite", (1, 0, 0))
    for name, mtl in (("nan_plain", None), ("nan_material", "newmtl mat\nKd 1 1 1\n")):
        _vertex_coloured_obj(meshes / name, (1, 0, 0), mtl)
        obj = meshes / name / "m.obj"
        lines = obj.read_text().splitlines()
        first_v = next(i for i, line in enumerate(lines) if line.startswith("v "))
        lines[first_v] = " ".join(lines[first_v].split()[:4] + ["nan", "nan", "nan"])
        obj.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    index = index_of(out)
    assert [o["model_id"] for o in index["objects"]] == ["finite/m"]  # the mesh's path under its category
    reasons = {f["model_id"].split("/")[0]: f["reason"] for f in index["failures"]}
    assert sorted(reasons) == ["nan_material", "nan_plain"]
    for name, reason in reasons.items():
        assert reason == f"{meshes / name / 'm.obj'}: 1 vertex colours are not numbers (NaN/inf), which would be " \
                         "drawn black", reason


def _pasted(command_word: str) -> bytes:
    """What bash makes of ``command_word`` (one shell word, as printed in a message)."""
    return subprocess.run(["bash", "-c", f"printf %s {command_word}"], capture_output=True, check=True).stdout


def test_a_suggested_command_can_be_pasted_whatever_the_output_folder_is_named(tmp_path):
    """render's summary suggests ``sc3d-data info OUT`` when objects failed; OUT was printed as it
    is, so a folder named with a space split into two arguments when pasted and one with a newline
    split the line itself (and the summary's ``index:`` path with it). The suggested word must be
    read by bash (the reference) as the folder's exact name, and every line of the output must
    be one line."""
    meshes = tmp_path / "m" / "c"
    _vertex_coloured_obj(meshes / "good", (1, 0, 0))
    (meshes / "broken").mkdir()
    (meshes / "broken" / "m.obj").write_text("this is no mesh\n")
    for name in ("my out", "new\nline 'quoted'", "tab\tand \\ slash"):
        out = tmp_path / name
        res = run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
        suggestion = next(line for line in res.output.splitlines() if "listed with reasons by" in line)
        word = re.fullmatch(r".*`sc3d-data info (.+)`", suggestion).group(1)
        assert _pasted(word) == os.fsencode(str(out)), (name, suggestion)
        summary = next(line for line in res.output.splitlines() if line.startswith("done 1,"))
        assert summary.endswith("index.json"), (name, res.output)
        assert index_of(out)["objects"][0]["model_id"] == "good/m"


# ----------------------------------------------------------------------------- the twenty-fourth attack: real files
def _cube_gltf(path, version: str = "2.0", material: dict | None = None, texcoord: bool = False,
               position_view: bool = True) -> None:
    """The unit cube as a .gltf with its buffer as a data URI; ``material`` on its primitive (with
    an 8 x 8 red PNG as image 0 where it names a texture), ``texcoord``: a TEXCOORD_0 of its corners'
    x and y; ``position_view=False``: POSITION without its bufferView."""
    import base64
    import io
    import json

    from PIL import Image

    from test_gltf_primitives import _cube, _gltf_doc

    vertices, indices = _cube()
    doc, buf = _gltf_doc([(vertices, indices, 4)])
    doc["asset"]["version"] = version
    if texcoord:
        uv = (vertices[:, :2] + 0.5).astype(np.float32).tobytes()
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(buf), "byteLength": len(uv)})
        doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "componentType": 5126,
                                 "count": len(vertices), "type": "VEC2"})
        doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = len(doc["accessors"]) - 1
        buf += uv
    if material is not None:
        png = io.BytesIO()
        Image.new("RGB", (8, 8), (255, 0, 0)).save(png, "PNG")
        doc.update(materials=[material], textures=[{"source": 0}],
                   images=[{"uri": "data:image/png;base64," + base64.b64encode(png.getvalue()).decode()}])
        doc["meshes"][0]["primitives"][0]["material"] = 0
    if not position_view:
        del doc["accessors"][0]["bufferView"]
    doc["buffers"] = [{"byteLength": len(buf),
                       "uri": "data:application/octet-stream;base64," + base64.b64encode(buf).decode()}]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))


def test_gltf_1_documents_and_positions_without_data_are_refused_in_one_line_that_says_so(tmp_path):
    """assimp's glTF 1.0 test models failed "AttributeError: 'str' object has no attribute 'get'"
    (.gltf) or "not a GLB file" (a binary glTF 1.0, whose header says version 1); a POSITION
    accessor without a bufferView (36 files of the glTF validator's tests) failed with trimesh's
    "UnboundLocalError". Each is refused in one line naming the cause; the same cube as glTF 2.0
    with its data renders (the control), also with ``asset.version`` "2"."""
    import struct

    meshes = tmp_path / "m" / "c"
    _cube_gltf(meshes / "v2.gltf")
    _cube_gltf(meshes / "v2_short.gltf", version="2")  # trimesh and three.js read it (a review found it refused)
    _cube_gltf(meshes / "v1.gltf", version="1.0")
    _cube_gltf(meshes / "zeros.gltf", position_view=False)
    body = b'{"asset": {"version": "1.0"}}'
    (meshes / "v1_binary.glb").write_bytes(b"glTF" + struct.pack("<IIII", 1, 20 + len(body), len(body), 0) + body)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    index = index_of(out)
    assert sorted(o["model_id"] for o in index["objects"]) == ["v2", "v2_short"]
    reasons = {f["model_id"]: f["reason"] for f in index["failures"]}
    assert reasons["v1"] == f"{meshes / 'v1.gltf'}: a glTF 1.0 document: sc3d reads glTF 2.0 (convert the file, " \
                            "e.g. with Blender or gltf-pipeline); not read"
    assert reasons["v1_binary"].startswith(f"{meshes / 'v1_binary.glb'}: a binary glTF of version 1 ")
    assert reasons["zeros"] == f"{meshes / 'zeros.gltf'}: accessor 0 (POSITION of mesh 0) has no bufferView, so its " \
                               "positions are all zeros (nothing to draw); not read"


def test_a_gltf_texture_with_no_texcoord_0_to_place_it_is_warned_of(tmp_path):
    """assimp's ``texcoord_crash.gltf``: a material with a base colour texture on a primitive
    without ``TEXCOORD_0`` was drawn in the material's colour without a word (the OBJ analogue,
    faces without ``vt``, is warned of). Now warned of, naming the primitive; the same cube with
    its TEXCOORD_0 draws the red texture without a warning (the control), and so does one whose
    document holds an untextured primitive in a mesh no node draws."""
    material = {"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "baseColorFactor": [0.2, 0.2, 1, 1]}}
    meshes = tmp_path / "m" / "c"
    _cube_gltf(meshes / "placed.gltf", material=material, texcoord=True)
    _cube_gltf(meshes / "unplaced.gltf", material=material)
    _cube_gltf(meshes / "unplaced_undrawn.gltf", material=material, texcoord=True)
    undrawn = json.loads((meshes / "unplaced_undrawn.gltf").read_text())  # a second mesh no node draws
    undrawn["meshes"].append({"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]})
    (meshes / "unplaced_undrawn.gltf").write_text(json.dumps(undrawn))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == []
    assert [w["warning"] for w in index_of(out)["warnings"]] == [
        f"{meshes / 'unplaced.gltf'}: mesh 0 primitive 0 has no TEXCOORD_0 to place its material's texture, so it is "
        "drawn in the material's colour without it"]
    objects = _objects(out)
    placed = objects["placed"]["images"][objects["placed"]["masks"] > 0].astype(int)
    assert (placed[:, 0] > 3 * placed[:, 2]).all()  # red x (0.2, 0.2, 1): the texture drawn


def _cube_stl(path, count: int | None = None, ascii_end: str | None = "endsolid cube\n") -> None:
    """The unit cube (trimesh's box) as a binary STL whose header says ``count`` triangles, or
    (``count`` None) as an ASCII STL whose facets are followed by ``ascii_end``."""
    import struct

    import trimesh

    box = trimesh.creation.box()
    triangles = box.vertices[box.faces]
    path.parent.mkdir(parents=True, exist_ok=True)
    if count is not None:
        body = b"".join(struct.pack("<3f", 0, 0, 0) + t.astype("<f4").tobytes() + b"\0\0" for t in triangles)
        path.write_bytes(b"binary stl".ljust(80, b" ") + struct.pack("<I", count) + body)
        return
    facets = "".join(" facet normal 0 0 0\n  outer loop\n" + "".join("   vertex %r %r %r\n" % tuple(map(float, p)) for p in t)
                     + "  endloop\n endfacet\n" for t in triangles)
    path.write_text("solid cube\n" + facets + (ascii_end or ""))


def test_stl_files_whose_triangle_count_cannot_be_trusted(tmp_path):
    """STLs that failed "empty mesh (no triangles)", naming neither cause: a binary STL whose header
    count is 0 (writers that stream triangles) is read by its size, as assimp and numpy-stl do,
    and draws the pixels of the same file with its count (the reference), as does one padded
    with two bytes after its counted triangles; one whose count says more than it holds (cut
    short) and an ASCII STL without its closing ``endsolid`` (cut short) are refused in one line
    saying so. The ASCII cube with its end (control) draws as the binary, and so do the ASCII
    variants the first version of the check refused (upper-case keywords, a byte-order mark, a
    Latin-1 name, NUL and ^Z after ``endsolid``)."""
    meshes = tmp_path / "m" / "c"
    _cube_stl(meshes / "counted.stl", count=12)
    _cube_stl(meshes / "count_zero.stl", count=0)
    _cube_stl(meshes / "count_100.stl", count=100)
    _cube_stl(meshes / "ascii.stl")
    _cube_stl(meshes / "ascii_cut.stl", ascii_end="")
    text = (meshes / "ascii.stl").read_bytes()  # ASCII STLs as other tools write them (read before; kept so)
    variants = {"upper": text.upper(), "bom": b"\xef\xbb\xbf" + text, "nul_after_end": text + b"\0\x1a",
                "latin1_name": text.replace(b" cube\n", " W\xfcrfel\n".encode("latin-1"))}
    for name, data in variants.items():
        (meshes / f"ascii_{name}.stl").write_bytes(data)
    (meshes / "padded.stl").write_bytes((meshes / "counted.stl").read_bytes() + b"\0\0")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    objects = _objects(out)
    assert sorted(objects) == sorted(["ascii", "count_zero", "counted", "padded"] + [f"ascii_{n}" for n in variants])
    for name in ["count_zero", "ascii", "padded"] + [f"ascii_{n}" for n in variants]:
        np.testing.assert_array_equal(objects[name]["images"], objects["counted"]["images"], err_msg=name)
    reasons = {f["model_id"]: f["reason"] for f in index_of(out)["failures"]}
    assert reasons["count_100"] == f"{meshes / 'count_100.stl'}: a binary STL whose header says 100 triangles while " \
                                   "its size (684 bytes) holds 12 triangles: cut short, or data after its triangles?; " \
                                   "not read"
    assert reasons["ascii_cut"].startswith(f"{meshes / 'ascii_cut.stl'}: an ASCII STL that does not end with an "
                                           "`endsolid` line: cut short?")


def test_a_ply_of_triangle_strips_draws_its_surface(tmp_path):
    """The Stanford/Cyberware scans (``igea.ply``) store their surface as ``element tristrips``
    (strips separated by -1), which trimesh's reader skips: "empty mesh (no triangles)". A cube
    written as two strips, by hand, as ASCII and as binary, must draw the masks and voxels of the
    same cube written as ``element face`` triangles (trimesh's box, the reference)."""
    import struct

    import trimesh

    box = trimesh.creation.box()
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    # the 8 corners of trimesh's box in its own order; strips written by hand around the cube
    corners = box.vertices.astype(np.float32)
    at = {tuple(np.sign(p).astype(int)): i for i, p in enumerate(corners)}
    c = lambda x, y, z: at[(x, y, z)]  # noqa: E731
    # strip 1: the four side faces (a band around z); strip 2: bottom and top through the sides
    band = [c(-1, -1, -1), c(-1, -1, 1), c(1, -1, -1), c(1, -1, 1), c(1, 1, -1), c(1, 1, 1), c(-1, 1, -1),
            c(-1, 1, 1), c(-1, -1, -1), c(-1, -1, 1)]
    caps = [c(-1, -1, -1), c(-1, 1, -1), c(1, -1, -1), c(1, 1, -1), c(1, 1, -1), c(1, 1, 1), c(1, 1, 1),
            c(1, -1, 1), c(-1, 1, 1), c(-1, -1, 1)]
    strips = band + [-1] + caps
    head = "ply\nformat {}\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\n"
    ascii_head = head.format("ascii 1.0") + "element tristrips 1\nproperty list int int vertex_indices\nend_header\n"
    (meshes / "strips.ply").write_text(ascii_head + "".join("%r %r %r\n" % tuple(map(float, p)) for p in corners)
                                       + " ".join(map(str, [len(strips)] + strips)) + "\n")
    binary_head = head.format("binary_little_endian 1.0") + \
        "element tristrips 1\nproperty list int int vertex_indices\nend_header\n"
    (meshes / "strips_binary.ply").write_bytes(binary_head.encode() + corners.astype("<f4").tobytes()
                                               + struct.pack("<i", len(strips)) + np.int32(strips).tobytes())
    face_head = head.format("ascii 1.0") + "element face 12\nproperty list uchar int vertex_indices\nend_header\n"
    (meshes / "faces.ply").write_text(face_head + "".join("%r %r %r\n" % tuple(map(float, p)) for p in corners)
                                      + "".join("3 %d %d %d\n" % tuple(f) for f in box.faces))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST, "--voxelize"])
    assert index_of(out)["failures"] == []
    objects = _objects(out)
    for name in ("strips", "strips_binary"):
        np.testing.assert_array_equal(objects[name]["masks"], objects["faces"]["masks"], err_msg=name)
        np.testing.assert_array_equal(objects[name]["voxels"], objects["faces"]["voxels"], err_msg=name)
