"""Data-half defects of the twenty-seventh round (OFF files as Geomview's own examples and
ModelNet write them). Real loader, renderer and command; references are the same shapes written
by hand in the form the loader always read."""
from __future__ import annotations

import numpy as np

from sc3d_cli.data import main as data_main
from conftest import objects_by_id, run_cli
from test_faults import FAST, index_of

CUBE_V = ["-1 -1 -1", "1 -1 -1", "1 1 -1", "-1 1 -1", "-1 -1 1", "1 -1 1", "1 1 1", "-1 1 1"]
CUBE_QUADS = ["4 0 3 2 1", "4 4 5 6 7", "4 0 1 5 4", "4 2 3 7 6", "4 1 2 6 5", "4 0 4 7 3"]


def test_off_headers_without_keyword_glued_to_counts_and_of_four_dimensions(tmp_path):
    """Geomview's OFF keyword is optional (its example ``pieces/cube1.off`` starts with its
    counts): such a file failed "cannot parse mesh file (ValueError: not enough values to
    unpack...)"; it must draw the pixels of the same cube with an ``OFF`` line. ModelNet's files
    glue the counts to the keyword (``OFF8 6 0``): drawn as the reference too (control of a form
    that already worked). A ``4OFF`` file (points of four coordinates: Geomview's hypercubes) was
    drawn from its first three coordinates, or failed "zero surface area": it must be refused
    saying what its header means."""
    meshes = tmp_path / "m" / "c"
    meshes.mkdir(parents=True)
    (meshes / "reference.off").write_text("\n".join(["OFF", "8 6 12", *CUBE_V, *CUBE_QUADS]) + "\n")
    (meshes / "headless.off").write_text("\n".join(["# a cube", "8 6 12", *CUBE_V, *CUBE_QUADS]) + "\n")
    (meshes / "glued.off").write_text("\n".join(["OFF8 6 0", *CUBE_V, *CUBE_QUADS]) + "\n")
    (meshes / "tesseract_slice.off").write_text(
        "\n".join(["4OFF", "8 6 12", *(v + " 0.5" for v in CUBE_V), *CUBE_QUADS]) + "\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert [f["reason"] for f in index_of(out)["failures"]] == [
        f"{meshes / 'tesseract_slice.off'}: its header 4OFF says its points have 4 coordinates: not a 3D mesh; "
        "not read"]
    assert index_of(out)["warnings"] == []
    objects = {name[1]: obj for name, obj in objects_by_id(out).items()}
    assert set(objects) == {"reference", "headless", "glued"}
    assert objects["reference"]["masks"].mean() > 0.1
    for name in ("headless", "glued"):
        np.testing.assert_array_equal(objects[name]["masks"], objects["reference"]["masks"], err_msg=name)
        np.testing.assert_array_equal(objects[name]["images"], objects["reference"]["images"], err_msg=name)


def test_check_leaves_out_objects_whose_voxelization_failed(tmp_path):
    """After ``voxelize SHARDS`` could not voxelize an object (its mesh moved away), the object
    keeps an empty placeholder grid and a ``stage: voxelize`` failure in the index; ``check``
    scored that grid (coverage 0) and failed the dataset (exit 1) without saying it was that
    known failure. It must leave the object out, say so in a note naming it, list it in
    ``--json``, and judge the others (which pass: exit 0)."""
    import json

    meshes = tmp_path / "m" / "box"
    meshes.mkdir(parents=True)
    cube = "".join(f"v {v}\n" for v in CUBE_V) + "".join(
        "f " + " ".join(str(int(c) + 1) for c in q.split()[1:]) + "\n" for q in CUBE_QUADS)
    for name in ("kept", "moved"):
        (meshes / f"{name}.obj").write_text(cube)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    (meshes / "moved.obj").rename(tmp_path / "moved.obj")
    run_cli(data_main, ["voxelize", out, "--no-progress"], expect_exit=None)
    assert [f["model_id"] for f in index_of(out)["failures"] if f.get("stage") == "voxelize"] == ["moved"]
    res = run_cli(data_main, ["check", out, "--no-progress", "--json", tmp_path / "check.json"])
    assert "note: 1 object(s) left out, their voxelization failed" in res.output and "box/moved" in res.output
    report = json.loads((tmp_path / "check.json").read_text())
    assert report["left_out_voxelize_failed"] == ["box/moved"]
    assert [o["model_id"] for o in report["objects"]] == ["kept"] and report["passed"]
    assert report["objects"][0]["mean_coverage"] > 0.98


def _textured_box_gltf(folder, extra_images: dict[str, bytes | None]) -> None:
    """``folder/model.gltf``: a box drawn with an 8 px red base colour texture (trimesh's export),
    whose material also reads, for each ``extra_images`` slot (``metallicRoughnessTexture``,
    ``normalTexture``, ``baseColorTexture``...), an image file ``SLOT.png`` holding the given bytes
    (None: the file is missing)."""
    import json

    import trimesh
    from PIL import Image

    folder.mkdir(parents=True)
    box = trimesh.creation.box()
    box.visual = trimesh.visual.TextureVisuals(uv=box.vertices[:, :2] + 0.5, material=trimesh.visual.material.PBRMaterial(
        baseColorTexture=Image.new("RGB", (8, 8), (200, 40, 40))))
    files = trimesh.exchange.gltf.export_gltf(trimesh.Scene(box))
    doc = json.loads(files.pop("model.gltf"))
    for name, data in files.items():
        (folder / name).write_bytes(data)
    material = doc["materials"][0]
    for slot, data in extra_images.items():
        doc["images"].append({"uri": f"{slot}.png"})
        doc["textures"].append({"source": len(doc["images"]) - 1})
        where = material if slot in ("normalTexture", "occlusionTexture", "emissiveTexture") \
            else material["pbrMetallicRoughness"]
        where[slot] = {"index": len(doc["textures"]) - 1}
        if data is not None:
            (folder / f"{slot}.png").write_bytes(data)
    (folder / "model.gltf").write_text(json.dumps(doc))


def test_a_gltf_image_the_renderer_does_not_draw_is_not_a_failure(tmp_path):
    """The renderer draws base colour textures only. A glTF whose metallic-roughness or normal
    texture image is missing or does not decode (the glTF samples' ``Avocado.gltf`` as a viewer
    repository ships it, without its metallic-roughness PNG) failed "texture image 1 ... not
    found", and with ``--bad-texture fallback`` was said to be "rendered with material colours"
    while its base colour texture was drawn. It must render as the same box without those
    textures, with a warning naming the image and saying nothing drawn changes. Control: a base
    colour texture that is missing still fails the object."""
    meshes = tmp_path / "m" / "box"
    _textured_box_gltf(meshes / "reference", {})
    _textured_box_gltf(meshes / "missing_mr", {"metallicRoughnessTexture": None})
    _textured_box_gltf(meshes / "broken_normal", {"normalTexture": b"not a png"})
    _textured_box_gltf(meshes / "missing_base", {"baseColorTexture": None})
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    index = index_of(out)
    assert [f["reason"].split(": ", 1)[1] for f in index["failures"]] == [
        "texture image 1 (baseColorTexture.png) not found (use --bad-texture fallback to render with material "
        "colours)"]
    warnings = sorted(w["warning"].split(": ", 1)[1] for w in index["warnings"])
    moot = "; sc3d draws base colour textures only, so the object renders the same without it"
    assert warnings == [
        "texture image 1 (metallicRoughnessTexture.png) (read by no base colour texture) not found" + moot,
        "texture image 1 (normalTexture.png) (read by no base colour texture) unreadable (not an image format Pillow "
        "reads)" + moot], warnings
    objects = {name[1].split("/")[0]: obj for name, obj in objects_by_id(out).items()}  # model_id: folder/file
    assert sorted(objects) == ["broken_normal", "missing_mr", "reference"], sorted(objects)
    reference = objects["reference"]["images"][objects["reference"]["masks"] > 0].astype(int)
    assert (reference[:, 0] - reference[:, 1]).min() > 50  # the red texture is drawn
    for name in ("missing_mr", "broken_normal"):
        np.testing.assert_array_equal(objects[name]["images"], objects["reference"]["images"], err_msg=name)


#: a 12 x 4 texture: columns 0-3 red, 4-7 green, 8-11 red (the same colour at both edges, so a
#: repeated texture and a clamped one agree at u = 0 and u = 1, and differ beyond)
def _stripes():
    from PIL import Image

    image = Image.new("RGB", (12, 4), (220, 30, 30))
    image.paste((30, 200, 40), (4, 0, 8, 4))
    return image


def _quad_parts(spans: list[tuple[float, float, float, float]]) -> tuple[list, list, list]:
    """Vertices, texture coordinates and faces of quads side by side along x, one per
    ``(x0, x1, u0, u1)``: x from x0 to x1 mapped to u from u0 to u1, y -0.5..0.5 to v 0..1."""
    vertices, uv, faces = [], [], []
    for x0, x1, u0, u1 in spans:
        k = len(vertices)
        vertices += [(x0, -0.5, 0), (x1, -0.5, 0), (x1, 0.5, 0), (x0, 0.5, 0)]
        uv += [(u0, 0), (u1, 0), (u1, 1), (u0, 1)]
        faces += [(k, k + 1, k + 2), (k, k + 2, k + 3)]
    return vertices, uv, faces


def _far_apart(a, b, mask) -> float:
    """The share of the pixels of ``mask`` where two renders differ by more than 40 in a channel."""
    return float((np.abs(a.astype(int) - b.astype(int)).max(axis=-1) > 40)[mask > 0].mean())


def test_texture_wrap_modes_of_gltf_samplers_and_mtl_clamp_are_drawn(tmp_path):
    """A texture whose coordinates leave [0, 1] was drawn repeated whatever the file said: a glTF
    sampler's CLAMP_TO_EDGE, and an MTL ``map_Kd -clamp on`` (warned of). A quad whose u runs from
    -1 to 2 over a red | green | red texture must draw as the same quad cut in three by hand: the
    outer thirds in the texture's edge colour (glTF: u held at 0 and 1, read with REPEAT) or in the
    material's colour alone (MTL: Wavefront's "outside of the origin texture, the underlying
    material is unchanged"), the middle third the texture once; the linear filter may differ on the
    texels at a cut. Control: the same quad with REPEAT (no sampler; no -clamp) draws green stripes
    in the outer thirds, far from the reference."""
    import json

    import trimesh

    meshes = tmp_path / "m"
    whole, cut = _quad_parts([(-1.5, 1.5, -1, 2)]), _quad_parts([(-1.5, -0.5, 0, 0), (-0.5, 0.5, 0, 1), (0.5, 1.5, 1, 1)])

    def gltf(name, parts, sampler):
        (meshes / "gltf" / name).mkdir(parents=True)
        vertices, uv, faces = parts
        mesh = trimesh.Trimesh(vertices, faces, process=False, visual=trimesh.visual.TextureVisuals(
            uv=np.array(uv, float), material=trimesh.visual.material.PBRMaterial(baseColorTexture=_stripes())))
        files = trimesh.exchange.gltf.export_gltf(trimesh.Scene(mesh))
        doc = json.loads(files.pop("model.gltf"))
        doc["samplers"] = [sampler]
        for texture in doc["textures"]:
            texture["sampler"] = 0
        for file, data in files.items():
            (meshes / "gltf" / name / file).write_bytes(data)
        (meshes / "gltf" / name / "model.gltf").write_text(json.dumps(doc))

    repeat, clamp = {"wrapS": 10497, "wrapT": 10497}, {"wrapS": 33071, "wrapT": 33071}
    gltf("clamped", whole, clamp)
    gltf("repeated", whole, repeat)
    gltf("reference", cut, repeat)

    def obj(name, parts, materials):
        folder = meshes / "obj" / name
        folder.mkdir(parents=True)
        vertices, uv, faces = parts
        lines = ["mtllib m.mtl", *("v %g %g %g" % v for v in vertices), *("vt %g %g" % t for t in uv)]
        for j, material in enumerate(materials):
            lines += [f"usemtl {material}"] + ["f " + " ".join(f"{i + 1}/{i + 1}" for i in f)
                                               for f in faces[2 * j:2 * j + 2]]
        (folder / "m.obj").write_text("\n".join(lines) + "\n")
        (folder / "m.mtl").write_text("newmtl clamped\nKd 0.3 0.5 0.9\nmap_Kd -clamp on t.png\n"
                                      "newmtl repeated\nKd 0.3 0.5 0.9\nmap_Kd t.png\nnewmtl plain\nKd 0.3 0.5 0.9\n")
        _stripes().save(folder / "t.png")

    obj("clamped", whole, ["clamped"])
    obj("repeated", whole, ["repeated"])
    obj("reference", cut, ["plain", "repeated", "plain"])
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", meshes, "--out", out, *FAST])
    assert index_of(out)["failures"] == [] and index_of(out)["warnings"] == []
    objects = {(c, m.split("/")[0]): o for (c, m), o in objects_by_id(out).items()}
    # measured (2-core CPU box, llvmpipe): glTF 0.0 against 0.25 repeated; MTL 0.046 (the texel at
    # each cut blends the texture with the white border: one column of pixels) against 0.66
    for kind, bound in (("gltf", 0.02), ("obj", 0.1)):
        reference, mask = objects[kind, "reference"]["images"], objects[kind, "reference"]["masks"]
        assert (objects[kind, "clamped"]["masks"] == mask).all(), kind
        assert _far_apart(objects[kind, "clamped"]["images"], reference, mask) < bound, kind
        assert _far_apart(objects[kind, "repeated"]["images"], reference, mask) > 0.2, kind
