"""Loader defects of the twenty-fifth round (items of the left-alone list), each with real files
written byte by byte, the real loader, renderer and command; expected values come from the same
shape written another way (plain faces, a file with a scene) or from bash itself, never from the
code under test."""
from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import FAST, index_of
from test_faults_round19_data import _objects


def _ply(path, corners, colours=None, faces=None, strips=None, binary=False) -> None:
    """A PLY of ``corners`` (with per-vertex ``colours`` where given), an ``element face`` of
    ``faces`` (triangles) and an ``element tristrips`` of the one index list ``strips``, where
    given; ASCII, or binary little-endian."""
    head = ["ply", "format " + ("binary_little_endian 1.0" if binary else "ascii 1.0"),
            f"element vertex {len(corners)}", "property float x", "property float y", "property float z"]
    head += ["property uchar red", "property uchar green", "property uchar blue"] if colours is not None else []
    head += [f"element face {len(faces)}", "property list uchar int vertex_indices"] if faces is not None else []
    head += ["element tristrips 1", "property list int int vertex_indices"] if strips is not None else []
    head = ("\n".join(head + ["end_header"]) + "\n").encode()
    rows = [list(map(float, p)) + ([] if colours is None else list(map(int, c)))
            for p, c in zip(corners, colours if colours is not None else [None] * len(corners))]
    if binary:
        vertex = b"".join(struct.pack("<3f" + "3B" * (colours is not None), *r) for r in rows)
        body = b"".join(struct.pack("<B3i", 3, *map(int, f)) for f in (faces if faces is not None else []))
        body += b"" if strips is None else struct.pack("<i", len(strips)) + np.int32(strips).astype("<i4").tobytes()
    else:
        vertex = "".join(" ".join(map(repr, r)) + "\n" for r in rows).encode()
        body = "".join("3 %d %d %d\n" % tuple(f) for f in (faces if faces is not None else [])).encode()
        body += b"" if strips is None else (" ".join(map(str, [len(strips), *strips])) + "\n").encode()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(head + vertex + body)


def test_a_ply_with_both_faces_and_triangle_strips_draws_both(tmp_path):
    """A PLY with an ``element face`` and an ``element tristrips`` kept the faces alone: trimesh
    reads ``face`` and the strips were read only where there were no faces, so half the cube
    below was dropped, exit 0. Its first six triangles as faces and the other six as strips
    (ASCII, binary, and with vertex colours) must draw the masks, voxels and pixels of the same
    cube written as twelve plain faces (trimesh's box, the reference)."""
    import trimesh

    box = trimesh.creation.box()
    corners, faces = box.vertices, box.faces
    colours = np.where(corners[:, :1] > 0, [200, 40, 40], [40, 40, 200])  # red at +x, blue at -x
    strips = sum(([*map(int, f), -1] for f in faces[6:]), [])[:-1]  # a strip of 3 corners per triangle
    meshes = tmp_path / "m" / "c"
    _ply(meshes / "faces" / "m.ply", corners, faces=faces)
    _ply(meshes / "both" / "m.ply", corners, faces=faces[:6], strips=strips)
    _ply(meshes / "both_binary" / "m.ply", corners, faces=faces[:6], strips=strips, binary=True)
    _ply(meshes / "faces_coloured" / "m.ply", corners, colours, faces=faces)
    _ply(meshes / "both_coloured" / "m.ply", corners, colours, faces=faces[:6], strips=strips)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST, "--voxelize"])
    assert index_of(out)["failures"] == []
    objects = _objects(out)
    for name, reference in (("both", "faces"), ("both_binary", "faces"), ("both_coloured", "faces_coloured")):
        for key in ("masks", "voxels", "images"):
            np.testing.assert_array_equal(objects[name][key], objects[reference][key], err_msg=f"{name} {key}")


#: a unit cube's corners and its six sides (quads), for the test below
CUBE = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
SIDES = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]


def _listed(word: str, cwd) -> bytes:
    """What ``ls -d WORD`` prints, run by bash in ``cwd`` (``WORD`` as printed in a message, after
    a command's name: a word that starts with ``-`` is read as options)."""
    import subprocess

    return subprocess.run(["bash", "-c", f"ls -d {word}"], cwd=cwd, capture_output=True, check=True).stdout


def test_a_suggested_folder_whose_name_starts_with_a_dash_is_read_as_a_path(tmp_path, monkeypatch):
    """``shell_word`` printed a relative folder named ``-out`` as ``-out``: pasted after a command,
    ``ls -d -out`` lists ``.`` (options ``-o -u -t``), ``ls -d '-my out'`` fails "invalid option".
    Each such name (plain, quoted, ANSI-C quoted, ``--help``) must now be a word after which
    ``ls -d`` lists that very folder (bash the reference); render's suggestion ``sc3d-data info
    WORD`` for a run with ``--out=-out`` given relative names it so too, and names that start
    otherwise print as before."""
    import os

    from sc3d_data.io.names import shell_word

    monkeypatch.chdir(tmp_path)
    for name in ("-out", "-my out", "-new\nline", "--help"):
        os.mkdir(name)
        assert _listed(shell_word(name), tmp_path) == b"./" + os.fsencode(name) + b"\n", name
    assert [shell_word(n) for n in ("out", "my out", "/abs/-x", "a-b")] == ["out", "'my out'", "/abs/-x", "a-b"]
    meshes = tmp_path / "m" / "c"
    _ply(meshes / "good" / "m.ply", CUBE, faces=[f for q in SIDES for f in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))])
    (meshes / "broken").mkdir()
    (meshes / "broken" / "m.ply").write_text("this is no mesh\n")
    res = run_cli(data_main, ["render", "--meshes", "m", "--out=-run", *FAST])
    suggestion = next(line for line in res.output.splitlines() if "listed with reasons by" in line)
    word = suggestion.rsplit("`sc3d-data info ", 1)[1].rstrip("`")
    assert _listed(word, tmp_path) == b"./-run\n", suggestion
    assert (tmp_path / "-run" / "index.json").is_file()


def test_a_skinned_gltf_without_scenes_is_posed_as_its_twin_with_a_scene(tmp_path):
    """A document without ``scenes`` draws its root nodes (``gltf_check.scene_roots``, as Blender
    and trimesh's scene-less reading do; an unskinned one since 961e6fe). A skinned one must be
    posed by its joints the same way: the bent bar of ``test_gltf_skins`` without ``scenes`` (.gltf
    and .glb), and its unskinned reference posed by hand without ``scenes``, draw the masks and
    pixels of the reference with its scene. (Passed before this round too: a regression test, the
    left-alone list's entry was older than 961e6fe.)"""
    from test_gltf_skins import BAR, BENT, S, _reference, _skinned_bar

    def sceneless(d):
        for key in ("scenes", "scene"):
            d.doc.pop(key)
        return d

    folder = tmp_path / "m" / "bar"
    folder.mkdir(parents=True)
    _reference((BENT, [0, 0, 0])).write(folder / "ref_bent.gltf")
    _reference((BAR, [0, 0, 0])).write(folder / "ref_straight.gltf")  # the bind pose: what an unposed skin draws
    sceneless(_reference((BENT, [0, 0, 0]))).write(folder / "ref_bent_no_scenes.gltf")
    sceneless(_skinned_bar([0, 0, S, S])).write(folder / "bent_no_scenes.gltf")
    sceneless(_skinned_bar([0, 0, S, S], packed=True)).write(folder / "packed_no_scenes.glb")
    assert "scenes" not in json.loads((folder / "bent_no_scenes.gltf").read_text())
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert index_of(out)["failures"] == []
    objects = _objects(out)
    assert not np.array_equal(objects["ref_bent"]["masks"], objects["ref_straight"]["masks"])  # unposed would show
    for name in ("ref_bent_no_scenes", "bent_no_scenes", "packed_no_scenes"):
        for key in ("masks", "images"):
            np.testing.assert_array_equal(objects[name][key], objects["ref_bent"][key], err_msg=f"{name} {key}")


def _meshlab_ply(path, corners, faces, uv, binary: bool = False) -> None:
    """``faces`` (lists of corners) with per-face texture coordinates ``uv(corner)``, textured
    with ``tex.png`` beside it, as vcglib's ``ExporterPLY`` (MeshLab) writes them: the comments,
    properties and ASCII number formats of its source (``%g`` positions and ``%f`` coordinates,
    each followed by a space), or binary little-endian (``uchar`` counts, ``int`` corners,
    ``float`` coordinates)."""
    head = ("ply\nformat %s 1.0\ncomment VCGLIB generated\ncomment TextureFile tex.png\nelement vertex %d\n"
            "property float x\nproperty float y\nproperty float z\nelement face %d\n"
            "property list uchar int vertex_indices\nproperty list uchar float texcoord\nend_header\n"
            % ("binary_little_endian" if binary else "ascii", len(corners), len(faces))).encode()
    if binary:
        body = b"".join(struct.pack("<3f", *p) for p in corners) + b"".join(
            struct.pack(f"<B{len(f)}iB{2 * len(f)}f", len(f), *f, 2 * len(f), *sum((uv(i) for i in f), ()))
            for f in faces)
    else:
        body = ("".join("%g %g %g \n" % tuple(p) for p in corners) + "".join(
            "%d " % len(f) + "".join("%d " % i for i in f) + "%d " % (2 * len(f)) + "".join("%f %f " % uv(i) for i in f)
            + "\n" for f in faces)).encode()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(head + body)


def test_meshlab_polygons_with_per_face_texture_coordinates_draw_their_texture(tmp_path):
    """MeshLab writes texture coordinates as a ``texcoord`` list on each face; trimesh read them
    only where every face has the same number of corners: a cube of quads beside triangles failed
    "cannot parse mesh file (ValueError: ...)" and a square of one quad "TypeError: object of type
    'numpy.int64' has no len()". Each must draw the pixels, masks and voxels of the same shape
    written with its polygons split by hand into the fans ``(0, k, k + 1)`` (all triangles, which
    trimesh reads: the reference), textured half red, half blue so that a texture coordinate
    misplaced shows; the all-quads cube (read before too) and a binary file of triangles stay as
    they were. A quad with texture coordinates for three corners is refused naming the face."""
    from PIL import Image

    uv = lambda i: (CUBE[i][0] * 0.5 + 0.25, CUBE[i][1] * 0.5 + 0.25)  # noqa: E731  x=0 red, x=1 blue
    fan = lambda faces: [(f[0], f[k], f[k + 1]) for f in faces for k in range(1, len(f) - 1)]  # noqa: E731
    texture = Image.new("RGB", (8, 8), (220, 30, 30))
    texture.paste((30, 30, 220), (4, 0, 8, 8))
    cube_mixed = SIDES[:3] + fan(SIDES[3:])
    files = {"mixed": (CUBE, cube_mixed), "mixed_ref": (CUBE, fan(cube_mixed)), "quads": (CUBE, SIDES),
             "quads_ref": (CUBE, fan(SIDES)), "square": (CUBE[:4], [(0, 1, 2, 3)]),
             "square_ref": (CUBE[:4], fan([(0, 1, 2, 3)]))}
    meshes = tmp_path / "m" / "c"
    for name, (corners, faces) in files.items():
        _meshlab_ply(meshes / name / "m.ply", corners, faces, uv)
        texture.save(meshes / name / "tex.png")
    _meshlab_ply(meshes / "binary" / "m.ply", CUBE, fan(SIDES), uv, binary=True)
    texture.save(meshes / "binary" / "tex.png")
    _meshlab_ply(meshes / "short_uv" / "m.ply", CUBE, SIDES, uv)
    lines = (meshes / "short_uv" / "m.ply").read_text().split("\n")
    first = lines.index("end_header") + 1 + len(CUBE)
    tokens = lines[first].split()  # 4 0 3 2 1 8 u v u v u v u v: the coordinates of three corners left
    lines[first] = " ".join(tokens[:5] + ["6"] + tokens[6:12]) + " "
    (meshes / "short_uv" / "m.ply").write_text("\n".join(lines))
    texture.save(meshes / "short_uv" / "tex.png")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST, "--voxelize"])
    reasons = {f["model_id"].split("/")[0]: f["reason"] for f in index_of(out)["failures"]}
    assert reasons == {"short_uv": f"{meshes / 'short_uv' / 'm.ply'}: face 0 has 4 corners and 6 texture coordinates "
                                   "(two per corner expected); not read"}
    objects = _objects(out)
    for name, reference in (("mixed", "mixed_ref"), ("quads", "quads_ref"), ("square", "square_ref"),
                            ("binary", "quads_ref")):
        for key in ("masks", "voxels", "images"):
            np.testing.assert_array_equal(objects[name][key], objects[reference][key], err_msg=f"{name} {key}")
    seen = objects["mixed"]["images"][objects["mixed"]["masks"] > 0].astype(int)
    assert (seen[:, 0] > 2 * seen[:, 2]).any() and (seen[:, 2] > 2 * seen[:, 0]).any()  # both halves drawn
    from sc3d_data.io.meshes import MeshError, load_mesh

    with pytest.raises(MeshError, match=r": 9 faces, more than the limit of 8 \(--max-faces\); not read$"):
        load_mesh(meshes / "mixed" / "m.ply", max_faces=8)  # refused before its rows are split


def test_drawn_nodes_and_drawn_meshes_share_one_reading_of_a_malformed_scene():
    """The errors that mark a malformed scene are one definition (``gltf_check.MALFORMED_SCENE``),
    used by ``drawn_nodes(safe=True)`` (the loader's copy of the document) and ``drawn_meshes(safe=True)``
    (the feature warnings): each returns nothing for such a document and raises without ``safe``;
    a well-formed one reads the same either way."""
    from sc3d_data.io.gltf_check import MALFORMED_SCENE, drawn_meshes, drawn_nodes

    malformed = [{"scenes": [{"nodes": [5]}], "nodes": []}, {"nodes": [1]}, {"scenes": [{"nodes": [0]}], "nodes": [
        {"children": 3}]}, {"scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, "children": [7]}]}]
    for doc in malformed:
        assert drawn_nodes(doc, safe=True) == [] and drawn_meshes(doc, safe=True) == set(), doc
        with pytest.raises(MALFORMED_SCENE):
            drawn_nodes(doc)
    good = {"scenes": [{"nodes": [0]}], "nodes": [{"children": [1]}, {"mesh": 0}]}
    assert drawn_nodes(good, safe=True) == drawn_nodes(good) == [0, 1] and drawn_meshes(good, safe=True) == {0}
