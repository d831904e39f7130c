"""``sc3d-data import-r2n2`` against an independent statement of 3D-R2N2's conventions.

* Pinned numbers (issue 10, computed from 3D-R2N2's Blender script and PyTorch3D's
  ``compute_extrinsic_matrix``) for one real metadata line and one real binvox header.
* Fake ``ShapeNetRendering``/``ShapeNetVox32`` written by ``tests/r2n2_synth.py`` (run in a
  subprocess so no GL context lives in the test process), which builds the cameras from the
  Blender rig, stores the meshes facing +X as ShapeNetCore v1 does and writes the binvox files
  the way ``binvox -cb`` does, without calling importer code: the import must recover the
  cameras, put the front at +Z and pass ``check``; the wrong conventions must fail.
* Real release files when ``SC3D_R2N2_ROOT`` names a folder holding ``ShapeNetRendering/`` and
  ``ShapeNetVox32/`` (skipped otherwise).
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from sc3d_data.io.binvox import read_binvox, write_binvox
from sc3d_data.geometry.normalize import apply_transform
from sc3d_data.formats.r2n2 import (grid_placement, obj_to_canonical, parse_metadata_line,
                                    r2n2_cameras, rotate_grid)
from r2n2_synth import blender_camera
from sc3d_data.io.shards import load_index
from sc3d_data.io.shard_reader import iter_objects

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "assets" / "sample_meshes"
PICK = ["airplane/c182_fgai.glb", "chair/chair2_blendswap.glb", "chair/dining_chair_katorlegaz.glb"]
AIRPLANE, CHAIR = "02691156", "03001627"

# issue 10: a real rendering_metadata.txt line and its camera in the OBJ frame (OpenCV, 137 px)
REAL_LINE = "23.1629952007 27.4774853872 0 0.844757211654 25"
PINNED_R = [[0.393348, 0, -0.91939], [0.424206, -0.887192, 0.181491], [-0.815675, -0.4614, -0.348975]]
PINNED_T = [0, 0, 1.478325]
PINNED_CENTRE = [1.205833, 0.682099, 0.515899]
PINNED_PIXELS = {(0, 0.3, 0): (68.5, 38.735), (0.3, 0, 0): (82.834, 83.958), (0, 0, 0.3): (38.412, 74.439)}
# issue 10: a real ShapeNetVox32 header and the OBJ-frame centre of its voxel (0, 0, 0)
REAL_HEADER = ((-0.166964, -0.154552, -0.445238), 0.890476)
PINNED_VOXEL0 = (-0.431324, -0.431324, -0.431324)


def cli(args, expect=0):
    from sc3d_cli.data import main

    res = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    assert res.exit_code == expect, f"{args} exited {res.exit_code}:\n{res.output}"
    return res


def synthesize(root: Path, seed: int, in_plane_max: float = 0.0):
    for rel in PICK:
        (root / "meshes" / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(SAMPLES / rel, root / "meshes" / rel)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    env.setdefault("PYOPENGL_PLATFORM", "egl")
    proc = subprocess.run([sys.executable, str(Path(__file__).with_name("r2n2_synth.py")), root / "meshes",
                           root / "ShapeNetRendering", root / "ShapeNetVox32", root / "truth.json",
                           str(seed), str(in_plane_max)],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"r2n2_synth.py: exit status {proc.returncode}\n{proc.stderr[-3000:]}"
    return root / "ShapeNetRendering", root / "ShapeNetVox32", json.loads((root / "truth.json").read_text())


@pytest.fixture(scope="session")
def fake_r2n2(tmp_path_factory):
    """``(renderings, voxels, truth)`` for 3 sample meshes (1 airplane, 2 chairs); in-plane
    angles up to 20 degrees so that its sign matters."""
    return synthesize(tmp_path_factory.mktemp("r2n2"), seed=7, in_plane_max=20.0)


@pytest.fixture(scope="session")
def imported(fake_r2n2, tmp_path_factory):
    renderings, voxels, _ = fake_r2n2
    out = tmp_path_factory.mktemp("r2n2_shards")
    res = cli(["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out", out, "--no-progress"])
    assert "imported 3 of 3 models" in res.output
    return out


def check_json(shards, tmp_path, expect, *extra):
    js = tmp_path / f"check_{Path(shards).name}.json"
    cli(["check", "--shards", shards, "--no-progress", "--json", js, *extra], expect=expect)
    return json.loads(js.read_text())


def project(R, t, f, c, point):
    x = np.asarray(R) @ point + np.asarray(t)
    return f * x[0] / x[2] + c, f * x[1] / x[2] + c


def test_metadata_line():
    v = parse_metadata_line("293.65 26.88 0 0.7237 25\n")
    assert (v.azimuth, v.elevation, v.in_plane, v.distance_ratio, v.fov) == (293.65, 26.88, 0, 0.7237, 25)
    for bad in ["1 2 3 4", "a b c d e", "1 2 3 -1 25", "1 2 3 nan 25"]:
        with pytest.raises(ValueError):
            parse_metadata_line(bad)


def test_synth_blender_rig_matches_pinned_camera():
    """The test data's camera (Blender rig) reproduces the issue's numbers."""
    az, el, ip, ratio, _ = map(float, REAL_LINE.split())
    R, t = blender_camera(az, el, ip, ratio)
    np.testing.assert_allclose(R, PINNED_R, atol=2e-6)
    np.testing.assert_allclose(t, PINNED_T, atol=2e-6)
    np.testing.assert_allclose(-R.T @ t, PINNED_CENTRE, atol=2e-6)
    for p, uv in PINNED_PIXELS.items():
        np.testing.assert_allclose(project(R, t, 35 / 32 * 137, 68.5, p), uv, atol=2e-3)


def test_importer_camera_matches_pinned_camera_in_both_frames():
    view = parse_metadata_line(REAL_LINE)
    cams = r2n2_cameras([view], 137)                              # OBJ frame
    np.testing.assert_allclose(cams["K"][0], [[149.84375, 0, 68.5], [0, 149.84375, 68.5], [0, 0, 1]])
    np.testing.assert_allclose(cams["R"][0], PINNED_R, atol=2e-6)
    np.testing.assert_allclose(cams["t"][0], PINNED_T, atol=2e-6)
    # canonical frame of a real header: the same OBJ points land on the same pixels
    M = obj_to_canonical(*grid_placement(*REAL_HEADER, "cube"))
    cams = r2n2_cameras([view], 137, M)
    for p, uv in PINNED_PIXELS.items():
        q = apply_transform(np.array([p]), M)[0]
        np.testing.assert_allclose(project(cams["R"][0], cams["t"][0], 149.84375, 68.5, q), uv, atol=2e-3)
    # sc3d pose of the canonical camera: front (+X in the OBJ) -> +Z: azimuth = -R2N2 azimuth
    assert np.isclose(cams["azimuth"][0], 360 - 23.1629952007, atol=1e-6)
    assert np.isclose(cams["elevation"][0], 27.4774853872, atol=1e-6)
    assert np.isclose(cams["distance"][0], 0.844757211654 * 1.75 / REAL_HEADER[1])


def test_in_plane_sign_matches_blender_and_not_its_mirror():
    line = "123.4 28.1 17.5 0.77 25"
    R_true, t_true = blender_camera(*[float(x) for x in line.split()[:4]])
    cams = r2n2_cameras([parse_metadata_line(line)], 137)
    np.testing.assert_allclose(cams["R"][0], R_true, atol=1e-9)
    np.testing.assert_allclose(cams["t"][0], t_true, atol=1e-9)
    mirrored = r2n2_cameras([parse_metadata_line("123.4 28.1 -17.5 0.77 25")], 137)
    assert np.abs(mirrored["R"][0] - R_true).max() > 0.1       # negative control: +in_plane is wrong


def test_binvox_cb_placement_matches_pinned_voxel_centre():
    """Voxel (0, 0, 0) of the real header lies at the pinned OBJ point; the literal header
    reading (translate = grid corner) puts it elsewhere."""
    centre, size = grid_placement(*REAL_HEADER, "cube")
    M = obj_to_canonical(centre, size, front="+Z")                # no rotation: index axes = OBJ axes
    np.testing.assert_allclose(apply_transform(np.array([PINNED_VOXEL0]), M)[0], [-0.5 + 1 / 64] * 3, atol=2e-6)
    literal = obj_to_canonical(*grid_placement(*REAL_HEADER, "header"), front="+Z")
    assert np.abs(apply_transform(np.array([PINNED_VOXEL0]), literal)[0] + 0.5 - 1 / 64).max() > 0.1
    # default front +X: the OBJ point (x, y, z) is canonical (-z, y, x); voxels re-indexed alike
    M = obj_to_canonical(centre, size)
    np.testing.assert_allclose(apply_transform(np.array([[0.2, 0.1, -0.3]]), M)[0],
                               np.array([0.3, 0.1, 0.2]) / size, atol=1e-12)
    g = np.zeros((32, 32, 32), bool)
    g[31, 5, 2] = True                                            # OBJ-frame indices (x, y, z)
    assert np.argwhere(rotate_grid(g, M[:3, :3] * size)).tolist() == [[29, 5, 31]]


def test_import_recovers_known_cameras(fake_r2n2, imported):
    _, _, truth = fake_r2n2
    objects = list(iter_objects(imported))
    assert [(o["category"], o["model_id"]) for o in objects] == [
        (AIRPLANE, "c182_fgai"), (CHAIR, "chair2_blendswap"), (CHAIR, "dining_chair_katorlegaz")]
    A = np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]])              # OBJ front +X -> canonical +Z
    for o in objects:
        tr = truth[f"{o['category']}/{o['model_id']}"]
        s = tr["obj_scale"]
        meta = np.array(tr["metadata"])
        assert o["images"].shape == (24, 64, 64, 3) and o["masks"].shape == (24, 64, 64)
        assert o["voxels"].shape == (32, 32, 32) and o["voxels"].sum() > 50
        np.testing.assert_allclose(o["K"], np.broadcast_to([[70, 0, 32], [0, 70, 32], [0, 0, 1]], (24, 3, 3)),
                                   atol=1e-4)
        np.testing.assert_allclose(o["R"], np.array(tr["R"]) @ A.T, atol=1e-5)
        np.testing.assert_allclose(o["t"], np.array(tr["t"]) / s, atol=1e-4)   # OBJ units -> canonical
        np.testing.assert_allclose(o["azimuth"], np.mod(-meta[:, 0], 360), atol=1e-3)
        np.testing.assert_allclose(o["elevation"], meta[:, 1], atol=1e-4)
        np.testing.assert_allclose(o["distance"], meta[:, 3] * 1.75 / s, rtol=1e-5)
        np.testing.assert_allclose(o["to_canonical"][:3, :3], A / s, atol=1e-9)
        assert 0.02 < o["masks"].mean() < 0.6
        assert (o["images"][o["masks"] == 0] > 200).mean() > 0.95   # background composited to white
    index = load_index(imported)
    assert index["split"]["method"] == "r2n2" and index["complete"]
    # r2n2 rule: 1 airplane -> int(0.8) = 0 train; 2 chairs -> 1 train, 1 test
    assert index["counts"]["by_category"] == {AIRPLANE: {"test": 1}, CHAIR: {"test": 1, "train": 1}}
    assert index["failures"] == []


def test_imported_front_is_plus_z(imported):
    """The sample meshes face +Z in their own files; after the round trip through a v1-style
    OBJ frame (front +X) the imported voxels must match sc3d's voxels of the original mesh.
    Negative control: --front +Z (taking the v1 files as canonical) does not."""
    from sc3d_data.io.meshes import load_mesh_triangles
    from sc3d_data.geometry.normalize import to_canonical_transform
    from sc3d_data.voxel.voxelize import voxelize_triangles

    def iou(a, b):
        return (a & b).sum() / (a | b).sum()

    ref = {}
    for rel in PICK:
        v, f = load_mesh_triangles(SAMPLES / rel)
        ref[Path(rel).stem] = voxelize_triangles(apply_transform(v, to_canonical_transform(v, f)), f, 32)
    for o in iter_objects(imported, ("voxels",)):
        assert iou(o["voxels"].astype(bool), ref[o["model_id"]]) > 0.8, o["model_id"]


def test_check_passes_and_wrong_conventions_fail(imported, fake_r2n2, tmp_path):
    report = check_json(imported, tmp_path, 0)
    assert report["passed"]
    assert min(o["mean_coverage"] for o in report["objects"]) >= 0.99
    assert min(o["mean_near"] for o in report["objects"]) >= 0.98
    assert min(o["mean_iou"] for o in report["objects"]) >= 0.6
    renderings, voxels, _ = fake_r2n2
    # negative control 1: the binvox header read literally (translate = grid corner)
    literal = tmp_path / "literal"
    cli(["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out", literal,
         "--voxel-frame", "header", "--no-progress"])
    assert not check_json(literal, tmp_path, 1)["passed"]
    # negative control 2: mirrored azimuth (camera on +Z of the OBJ at azimuth 90, not -Z)
    mirror = tmp_path / "mirror"
    shutil.copytree(renderings, mirror / "R")
    for meta in (mirror / "R").rglob("rendering_metadata.txt"):
        rows = [ln.split() for ln in meta.read_text().splitlines()]
        meta.write_text("".join(" ".join([repr(-float(r[0]) % 360)] + r[1:]) + "\n" for r in rows))
    cli(["import-r2n2", "--renderings", mirror / "R", "--voxels", voxels, "--out", mirror / "out",
         "--no-progress"])
    assert not check_json(mirror / "out", tmp_path, 1)["passed"]


def test_wrong_front_is_caught_by_voxels(fake_r2n2, tmp_path):
    """--front +Z leaves the v1 files' front at +X: cameras and voxels stay consistent (check
    cannot see it) but the voxels no longer match the canonical mesh."""
    from sc3d_data.io.meshes import load_mesh_triangles
    from sc3d_data.geometry.normalize import to_canonical_transform
    from sc3d_data.voxel.voxelize import voxelize_triangles

    renderings, voxels, _ = fake_r2n2
    out = tmp_path / "front_z"
    cli(["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out", out, "--front", "+Z",
         "--no-progress"])
    v, f = load_mesh_triangles(SAMPLES / PICK[1])
    ref = voxelize_triangles(apply_transform(v, to_canonical_transform(v, f)), f, 32)
    got = next(o["voxels"] for o in iter_objects(out, ("voxels",)) if o["model_id"] == "chair2_blendswap")
    assert (ref & got.astype(bool)).sum() / (ref | got.astype(bool)).sum() < 0.7


R2N2_ROOT = os.environ.get("SC3D_R2N2_ROOT")


@pytest.mark.skipif(not R2N2_ROOT, reason="set SC3D_R2N2_ROOT to a folder with ShapeNetRendering/ and "
                                          "ShapeNetVox32/ of the 3D-R2N2 release")
def test_real_release_files(tmp_path):
    """Opt-in (as PyTorch3D's R2N2 tests): the released files imported with defaults pass
    ``check`` (coverage >= 0.99, IoU >= 0.6 at 64 px); every binvox's occupancy is centred in
    its grid (binvox -cb); chairs have their backrest (the tallest end) at -Z."""
    root = Path(R2N2_ROOT)
    renderings, voxels = root / "ShapeNetRendering", root / "ShapeNetVox32"
    for bv in list(voxels.rglob("model.binvox"))[:50]:
        idx = np.argwhere(read_binvox(bv).voxels)
        assert np.abs((idx.min(0) + idx.max(0)) / 2 - 15.5).max() <= 0.5, bv
    out = tmp_path / "real"
    cli(["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out", out, "--no-progress",
         "--split", "random:1,0,0"])
    report = check_json(out, tmp_path, 0)
    assert min(o["mean_coverage"] for o in report["objects"]) >= 0.99
    assert min(o["mean_iou"] for o in report["objects"]) >= 0.6
    for o in iter_objects(out, ("voxels",)):
        if o["category"] == CHAIR:
            idx = np.argwhere(o["voxels"])
            z = idx[:, 2]
            assert idx[z == z.min(), 1].max() >= idx[z == z.max(), 1].max(), o["model_id"]


def _copy_model(renderings, voxels, src, dst_id, root):
    syn, mid = src.split("/")
    shutil.copytree(renderings / syn / mid, root / "R" / syn / dst_id)
    (root / "V" / syn / dst_id).mkdir(parents=True)
    shutil.copy(voxels / syn / mid / "model.binvox", root / "V" / syn / dst_id / "model.binvox")
    return root / "R" / syn / dst_id / "rendering", root / "V" / syn / dst_id / "model.binvox"


def _import_copies(root: Path, *extra) -> tuple[str, dict, dict]:
    """``import-r2n2`` of the models :func:`_copy_model` put under ``root`` into ``root/out``:
    ``(output, index, {model folder or file name: failure reason})``."""
    out = root / "out"
    res = cli(["import-r2n2", "--renderings", root / "R", "--voxels", root / "V", "--out", out, *extra,
               "--no-progress"])
    index = load_index(out)
    return res.output, index, {Path(f["source"]).name: f["reason"] for f in index["failures"]}


def test_extreme_distance_ratios_fail_their_model_in_one_line(fake_r2n2, tmp_path):
    """A distance ratio of 1e300 overflowed into cameras of inf and one of 1e-300 into a camera at
    the object's centre (elevation 90), both imported with numpy warnings. Each now fails its
    model, naming the metadata file and the view; the good model is imported."""
    renderings, voxels, _ = fake_r2n2
    src = f"{CHAIR}/chair2_blendswap"
    _copy_model(renderings, voxels, src, "good", tmp_path)
    for name, view, ratio in (("far", 3, "1e300"), ("near", 0, "1e-300")):
        rdir, _ = _copy_model(renderings, voxels, src, name, tmp_path)
        lines = (rdir / "rendering_metadata.txt").read_text().splitlines()
        fields = lines[view].split()
        lines[view] = " ".join(fields[:3] + [ratio] + fields[4:])
        (rdir / "rendering_metadata.txt").write_text("\n".join(lines) + "\n")
    output, index, reasons = _import_copies(tmp_path)
    assert "imported 1 of 3 models" in output
    assert [o["model_id"] for o in index["objects"]] == ["good"]
    assert "rendering_metadata.txt: view 3 (distance ratio 1e+300)" in reasons["far"]
    assert "rendering_metadata.txt: view 0 (distance ratio 1e-300)" in reasons["near"]
    assert all("must be finite and more than 0.866" in r for r in reasons.values())


def test_files_linked_out_of_their_model_folder_are_not_read(fake_r2n2, tmp_path):
    """A rendering PNG (or a binvox) that is a symbolic link to a file outside its model's folder
    was read (render treats a texture linked out of its folder as outside and never opens it).
    Such a model now fails in one line naming the link; a model whose whole folder is a link (a
    dataset on another disk) is imported."""
    renderings, voxels, _ = fake_r2n2
    src = f"{CHAIR}/chair2_blendswap"
    _copy_model(renderings, voxels, src, "good", tmp_path)
    rdir, _ = _copy_model(renderings, voxels, src, "pnglink", tmp_path)
    outside = tmp_path / "outside.png"
    shutil.copy(rdir / "05.png", outside)
    (rdir / "05.png").unlink()
    (rdir / "05.png").symlink_to(outside)
    _, bv = _copy_model(renderings, voxels, src, "voxlink", tmp_path)
    shutil.move(bv, tmp_path / "outside.binvox")
    bv.symlink_to(tmp_path / "outside.binvox")
    elsewhere = tmp_path / "disk2"
    rdir, _ = _copy_model(renderings, voxels, src, "linkedfolder", tmp_path)
    shutil.move(rdir.parent, elsewhere)
    rdir.parent.symlink_to(elsewhere, target_is_directory=True)
    output, index, reasons = _import_copies(tmp_path)
    assert "imported 2 of 4 models" in output
    assert sorted(o["model_id"] for o in index["objects"]) == ["good", "linkedfolder"]
    text = " ".join(reasons.values())
    assert f"05.png: a link to {outside}, outside" in text and "refused (not read)" in text
    assert f"model.binvox: a link to {tmp_path / 'outside.binvox'}, outside" in text


def test_bad_input_reported_rest_imported(fake_r2n2, tmp_path):
    renderings, voxels, _ = fake_r2n2
    src = f"{CHAIR}/chair2_blendswap"
    _copy_model(renderings, voxels, src, "good", tmp_path)
    rdir, _ = _copy_model(renderings, voxels, src, "badmeta", tmp_path)
    lines = (rdir / "rendering_metadata.txt").read_text().splitlines()
    broken = lines[:4] + ["12.5 30 0 oops 25"] + lines[5:]
    (rdir / "rendering_metadata.txt").write_text("\n".join(broken) + "\n")
    rdir, _ = _copy_model(renderings, voxels, src, "shortmeta", tmp_path)
    (rdir / "rendering_metadata.txt").write_text("\n".join(lines[:20]) + "\n")
    rdir, _ = _copy_model(renderings, voxels, src, "nopng", tmp_path)
    (rdir / "07.png").unlink()
    rdir, _ = _copy_model(renderings, voxels, src, "nometa", tmp_path)
    (rdir / "rendering_metadata.txt").unlink()
    _, bv = _copy_model(renderings, voxels, src, "vox16", tmp_path)
    write_binvox(bv, np.ones((16, 16, 16), bool))
    _, bv = _copy_model(renderings, voxels, src, "novox", tmp_path)
    bv.unlink()
    (tmp_path / "R" / CHAIR / "emptyfolder").mkdir()
    split = tmp_path / "split.txt"
    split.write_text("".join(f"train {CHAIR}/{m}\n" for m in
                             ["good", "badmeta", "shortmeta", "nopng", "nometa", "vox16", "ghost"]))
    output, index, reasons = _import_copies(tmp_path, "--split-file", split)
    assert "imported 1 of 6 models" in output
    assert [o["model_id"] for o in index["objects"]] == ["good"]
    assert "rendering_metadata.txt:5: not numbers" in reasons["badmeta"]
    assert "20 metadata lines, expected 24" in reasons["shortmeta"]
    assert "07.png: missing rendering" in reasons["nopng"]
    assert "rendering_metadata.txt: missing" in reasons["nometa"]
    assert "voxel grid 16x16x16, expected 32^3" in reasons["vox16"]
    assert "missing binvox" in reasons["model.binvox"]
    assert "without rendering/" in reasons["emptyfolder"]
    assert any("'03001627/ghost'" in p["reason"] for p in index["skipped"])
    for name in ("badmeta", "shortmeta", "nopng", "nometa", "vox16"):
        assert "failed: " in output and name in output
    # a second run into the same folder resumes (nothing to do); with other settings it is refused
    out = tmp_path / "out"
    res = cli(["import-r2n2", "--renderings", tmp_path / "R", "--voxels", tmp_path / "V", "--out", out,
               "--split-file", split, "--no-progress"])
    assert "imported 0 of 6 models" in res.output and "(1 already there, 7 failed" in res.output
    assert load_index(out)["objects"] == index["objects"] and load_index(out)["failures"] == index["failures"]
    res = cli(["import-r2n2", "--renderings", tmp_path / "R", "--voxels", tmp_path / "V", "--out", out,
               "--no-progress"], expect=1)
    assert "other settings (split_file differ)" in res.output and "--overwrite" in res.output


def test_import_in_parts_then_merge_equals_one_import(fake_r2n2, imported, tmp_path):
    """issue 13: `import-r2n2 --part I/2` twice + `merge` == one import, object by object."""
    from conftest import assert_same_dataset

    renderings, voxels, _ = fake_r2n2
    parts = [tmp_path / f"p{i}" for i in range(2)]
    for i, out in enumerate(parts):
        cli(["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out", out, "--part", f"{i}/2",
             "--no-progress"])
    assigned = [json.loads((p / "index.json").read_text())["part"]["assigned"] for p in parts]
    assert sum(assigned) == 3
    cli(["merge", tmp_path / "merged", *parts])
    assert_same_dataset(tmp_path / "merged", imported)


def test_import_killed_mid_run_resumes_and_equals_an_uninterrupted_import(fake_r2n2, tmp_path):
    """The import process (9 models, one per shard, one worker) is SIGKILLed by its own progress
    callback when the 5th result arrives, so at a known point mid-run: shards 0-3 are written
    and listed. With one of them truncated, a rerun keeps the intact ones (same files, not
    rewritten), imports the rest and equals an import that was never interrupted, object by
    object."""
    from conftest import assert_same_dataset

    renderings, voxels, _ = fake_r2n2
    R, V = tmp_path / "R", tmp_path / "V"
    shutil.copytree(renderings, R)
    shutil.copytree(voxels, V)
    src = f"{CHAIR}/chair2_blendswap"
    for k in range(6):
        shutil.copytree(R / src, R / CHAIR / f"copy{k}")
        shutil.copytree(V / src, V / CHAIR / f"copy{k}")
    out = tmp_path / "out"
    script = ("import os, signal\n"
              "from sc3d_data.pipeline.jobs.r2n2_job import ImportConfig, import_r2n2\n"
              "seen = []\n"
              "def progress(n):\n"
              "    seen.append(n)\n"
              "    if len(seen) == 5:\n"
              "        os.kill(os.getpid(), signal.SIGKILL)\n"
              f"import_r2n2(ImportConfig(renderings={str(R)!r}, voxels={str(V)!r}, out={str(out)!r}, "
              "objects_per_shard=1, workers=1), progress=progress)\n")
    env = dict(os.environ, PYTHONPATH=f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    proc = subprocess.run([sys.executable, "-c", script], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == -9, proc.stderr
    index = load_index(out)
    assert not index["complete"] and [e["file"] for e in index["shards"]] == [f"shard-0000{i}.h5" for i in range(4)]
    kept = (out / "shard-00000.h5").stat()
    broken = out / "shard-00001.h5"
    broken.write_bytes(broken.read_bytes()[: broken.stat().st_size // 2])
    args = ["import-r2n2", "--renderings", R, "--voxels", V, "--objects-per-shard", "1", "--no-progress"]
    res = cli([*args, "--out", out])
    assert "imported 6 of 9 models" in res.output and "(3 already there, 0 failed" in res.output
    again = (out / "shard-00000.h5").stat()
    assert (again.st_ino, again.st_mtime_ns) == (kept.st_ino, kept.st_mtime_ns)   # kept, not rewritten
    cli([*args, "--out", tmp_path / "whole"])
    assert_same_dataset(out, tmp_path / "whole")
