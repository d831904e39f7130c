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
