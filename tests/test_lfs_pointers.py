"""A repository cloned without Git LFS holds small pointer files in place of its meshes,
textures and glTF buffers. Each is named as a Git LFS pointer, with what to do, in one line
(before: "Not a ply file!", "empty mesh (no triangles)", "not an image format Pillow reads", a
buffer that "holds 130 bytes"). The pointers are written as the Git LFS specification gives
them (docs/spec.md of git-lfs: version line, oid, size)."""
from __future__ import annotations

import json
from pathlib import Path

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST, index_of
from test_gltf_accessors import CUBE
from test_gltf_primitives import _gltf_doc

POINTER = ("version https://git-lfs.github.com/spec/v1\n"
           "oid sha256:4d7a214614ab2935c943f9e0ff69d22eadbb8f32b1258daaa5e2ca24d17e2393\n"
           "size 12345\n").encode()
SAYS = "a Git LFS pointer to a file of 12,345 bytes, not the file itself: fetch it with `git lfs pull` in its repository"


def test_git_lfs_pointers_in_place_of_meshes_textures_and_buffers_are_named_so(tmp_path):
    folder = tmp_path / "m" / "c"
    folder.mkdir(parents=True)
    for name in ("bunny.ply", "chair.obj", "car.glb", "lamp.stl", "table.off"):
        (folder / name).write_bytes(POINTER)
    textured = folder / "textured"
    textured.mkdir()
    (textured / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\nusemtl mat\n"
                                    "f 1/1 2/1 3/1\nf 1/1 2/1 4/1\nf 1/1 3/1 4/1\nf 2/1 3/1 4/1\n")
    (textured / "m.mtl").write_text("newmtl mat\nKd 1 1 1\nmap_Kd t.png\n")
    (textured / "t.png").write_bytes(POINTER)
    pointed = folder / "pointed"
    pointed.mkdir()
    (pointed / "m.obj").write_text((textured / "m.obj").read_text())
    (pointed / "m.mtl").write_bytes(POINTER)
    doc, buf = _gltf_doc(CUBE)
    doc["buffers"] = [{"byteLength": len(buf), "uri": "cube.bin"}]
    (folder / "cube.gltf").write_text(json.dumps(doc))
    (folder / "cube.bin").write_bytes(POINTER)
    (folder / "good.gltf").write_text(json.dumps({**doc, "buffers": [{"byteLength": len(buf), "uri": "good.bin"}]}))
    (folder / "good.bin").write_bytes(buf)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    reasons = {Path(f["source"]).relative_to(folder).as_posix(): f["reason"] for f in index_of(out)["failures"]}
    for name in ("bunny.ply", "chair.obj", "car.glb", "lamp.stl", "table.off"):
        assert reasons.pop(name) == f"{folder / name}: {SAYS}; not read"
    assert f"texture t.png (from m.mtl) unreadable ({SAYS})" in reasons.pop("textured/m.obj")
    assert f"buffer 0, whose file cube.bin holds {len(POINTER)} bytes ({SAYS})" in reasons.pop("cube.gltf")
    assert reasons == {}
    assert sorted(objects_by_id(out)) == [("c", "good"), ("c", "pointed/m")]
    assert [w["warning"].split(": ", 1)[1] for w in index_of(out)["warnings"]] == [
        f"material file m.mtl is {SAYS}; rendered with the default material"]


def test_a_file_that_only_starts_like_a_pointer_is_read_as_what_it_is(tmp_path):
    """An OBJ whose first comment quotes the pointer line is an OBJ (pointers are under 1024
    bytes and have no other lines): it renders."""
    from sc3d_data.io.lfs_pointers import lfs_pointer

    obj = POINTER.replace(b"version", b"# version", 1) + b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n" \
        + b"f 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n" + b"# padding\n" * 120
    assert lfs_pointer(POINTER) == SAYS and lfs_pointer(obj) is None and lfs_pointer(POINTER + b" " * 1024) is None
    folder = tmp_path / "m" / "c"
    folder.mkdir(parents=True)
    (folder / "quoted.obj").write_bytes(obj)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == [] and list(objects_by_id(out)) == [("c", "quoted")]
