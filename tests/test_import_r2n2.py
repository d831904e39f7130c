"""``sc3d-data import-r2n2`` on a fake ShapeNetRendering/ShapeNetVox32 pair rendered with known
cameras (sc3d_data.r2n2_synth, run in a subprocess so no GL context lives in the test process):
the import must recover those cameras, ``sc3d-data check`` must pass on the result, and bad
input must be reported per model while the rest is imported."""
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

from sc3d_data import camera
from sc3d_data.binvox import write_binvox
from sc3d_data.r2n2_import import (R2N2_FOV_DEG, parse_metadata_line, r2n2_to_sc3d_azimuth,
                                   voxel_grid_to_canonical)
from sc3d_data.shards import iter_objects, load_index

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "assets" / "sample_meshes"
PICK = ["airplane/c182_fgai.glb", "chair/chair2_blendswap.glb", "chair/dining_chair_katorlegaz.glb"]
AIRPLANE, CHAIR = "02691156", "03001627"


def cli(args, expect=0):
    from cli.data import main

    res = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    assert res.exit_code == expect, f"{args} exited {res.exit_code}:\n{res.output}"
    return res


@pytest.fixture(scope="session")
def fake_r2n2(tmp_path_factory):
    """``(renderings, voxels, truth)`` for 3 sample meshes (1 airplane, 2 chairs)."""
    root = tmp_path_factory.mktemp("r2n2")
    for rel in PICK:
        (root / "meshes" / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(SAMPLES / rel, root / "meshes" / rel)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    env.setdefault("PYOPENGL_PLATFORM", "egl")
    proc = subprocess.run([sys.executable, "-m", "sc3d_data.r2n2_synth", root / "meshes",
                           root / "ShapeNetRendering", root / "ShapeNetVox32", root / "truth.json", "7"],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return root / "ShapeNetRendering", root / "ShapeNetVox32", json.loads((root / "truth.json").read_text())


@pytest.fixture(scope="session")
def imported(fake_r2n2, tmp_path_factory):
    renderings, voxels, _ = fake_r2n2
    out = tmp_path_factory.mktemp("r2n2_shards")
    res = cli(["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out", out, "--no-progress"])
    assert "imported 3 of 3 models" in res.output
    return out


def test_metadata_line_and_conventions():
    v = parse_metadata_line("293.65 26.88 0 0.7237 25\n")
    assert (v.azimuth, v.elevation, v.in_plane, v.distance_ratio, v.fov) == (293.65, 26.88, 0, 0.7237, 25)
    for bad in ["1 2 3 4", "a b c d e", "1 2 3 -1 25", "1 2 3 nan 25"]:
        with pytest.raises(ValueError):
            parse_metadata_line(bad)
    # R2N2 azimuth 90 looks at the front (+Z); R2N2 azimuth 0 puts the camera on +X
    assert r2n2_to_sc3d_azimuth([90.0, 0.0, 180.0]).tolist() == [0.0, 90.0, 270.0]
    # Blender's default 35 mm lens on a 32 mm sensor: f = 35/32 * W
    assert np.isclose(camera.intrinsics(137, R2N2_FOV_DEG)[0, 0], 35 / 32 * 137)
    M = voxel_grid_to_canonical((-0.35, -0.35, -0.35), 0.7)
    assert np.allclose(M @ [0.35, -0.35, 0, 1], [0.5, -0.5, 0, 1])


def test_import_recovers_known_cameras(fake_r2n2, imported):
    _, _, truth = fake_r2n2
    objects = list(iter_objects(imported))
    assert [(o["category"], o["model_id"]) for o in objects] == [
        (AIRPLANE, "c182_fgai"), (CHAIR, "chair2_blendswap"), (CHAIR, "dining_chair_katorlegaz")]
    for o in objects:
        t = truth[f"{o['category']}/{o['model_id']}"]
        s = t["obj_scale"]
        meta = np.array(t["metadata"])
        assert o["images"].shape == (24, 64, 64, 3) and o["masks"].shape == (24, 64, 64)
        assert o["voxels"].shape == (32, 32, 32) and o["voxels"].sum() > 50
        np.testing.assert_allclose(o["K"], np.broadcast_to([[70, 0, 32], [0, 70, 32], [0, 0, 1]], (24, 3, 3)),
                                   atol=1e-4)
        np.testing.assert_allclose(o["R"], np.array(t["R"]), atol=1e-5)
        np.testing.assert_allclose(o["t"], np.array(t["t"]) / s, atol=1e-4)   # OBJ frame -> canonical
        np.testing.assert_allclose(o["azimuth"], np.mod(90 - meta[:, 0], 360), atol=1e-3)
        np.testing.assert_allclose(o["elevation"], meta[:, 1], atol=1e-4)
        np.testing.assert_allclose(o["distance"], meta[:, 3] * 1.75 / s, rtol=1e-5)
        np.testing.assert_allclose(o["to_canonical"], np.diag([1 / s, 1 / s, 1 / s, 1]), atol=1e-9)
        assert 0.02 < o["masks"].mean() < 0.6
        # background composited to white outside the mask
        assert (o["images"][o["masks"] == 0] > 200).mean() > 0.95
    index = load_index(imported)
    assert index["split"]["method"] == "r2n2" and index["complete"]
    # r2n2 rule: 1 airplane -> int(0.8) = 0 train; 2 chairs -> 1 train, 1 test
    assert index["counts"]["by_category"] == {AIRPLANE: {"test": 1}, CHAIR: {"test": 1, "train": 1}}
    assert index["failures"] == []


def test_check_passes_on_imported_shards(imported, fake_r2n2, tmp_path):
    res = cli(["check", "--shards", imported, "--no-progress", "--min-iou", "0.6",
               "--json", tmp_path / "check.json"])
    report = json.loads((tmp_path / "check.json").read_text())
    assert report["passed"] and min(o["mean_iou"] for o in report["objects"]) > 0.6
    assert min(min(o["coverage"]) for o in report["objects"]) > 0.9
    # negative control: ignoring the binvox header (wrong frame) must fail the check
    renderings, voxels, _ = fake_r2n2
    wrong = tmp_path / "wrong"
    cli(["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out", wrong,
         "--voxel-frame", "centered", "--no-progress"])
    res = cli(["check", "--shards", wrong, "--no-progress", "--min-iou", "0.6"], expect=1)
    assert "FAIL" in res.output or "below" in res.output


def _copy_model(renderings, voxels, src, dst_id, root):
    syn, mid = src.split("/")
    shutil.copytree(renderings / syn / mid, root / "R" / syn / dst_id)
    (root / "V" / syn / dst_id).mkdir(parents=True)
    shutil.copy(voxels / syn / mid / "model.binvox", root / "V" / syn / dst_id / "model.binvox")
    return root / "R" / syn / dst_id / "rendering", root / "V" / syn / dst_id / "model.binvox"


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
    out = tmp_path / "out"
    res = cli(["import-r2n2", "--renderings", tmp_path / "R", "--voxels", tmp_path / "V", "--out", out,
               "--split-file", split, "--no-progress"])
    assert "imported 1 of 6 models" in res.output
    index = load_index(out)
    assert [o["model_id"] for o in index["objects"]] == ["good"]
    reasons = {Path(f["source"]).name: f["reason"] for f in index["failures"]}
    assert "rendering_metadata.txt:5: not numbers" in reasons["badmeta"]
    assert "20 metadata lines, expected 24" in reasons["shortmeta"]
    assert "07.png: missing rendering" in reasons["nopng"]
    assert "rendering_metadata.txt: missing" in reasons["nometa"]
    assert "voxel grid 16x16x16, expected 32^3" in reasons["vox16"]
    assert "missing binvox" in reasons["model.binvox"]
    assert "without rendering/" in reasons["emptyfolder"]
    assert any("'03001627/ghost'" in p["reason"] for p in index["skipped"])
    for name in ("badmeta", "shortmeta", "nopng", "nometa", "vox16"):
        assert "failed: " in res.output and name in res.output
    # a second run into the same folder refuses without --overwrite
    res = cli(["import-r2n2", "--renderings", tmp_path / "R", "--voxels", tmp_path / "V", "--out", out,
               "--no-progress"], expect=1)
    assert "--overwrite" in res.output
