"""Hostile inputs, round three: one test per defect found by the third attack on ``sc3d-data`` (F1:
a 16-bit grey texture; F2: camera and axis options; F3: ``voxelize --meshes`` when nothing was
voxelized; F4: ``voxelize SHARDS`` without the meshes; F5: a warning naming no file; F6:
``renderings.txt`` naming images outside the model; F7: a binvox header scale; F8:
``import-r2n2`` when every model failed; F9: report files of ``check``/``preview`` over the
dataset). Real renderer, HDF5 and worker processes; every fixture is built here. Expected values
come from the fixtures (an 8-bit twin of a texture, the option given, a red image), never from
the code under test."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
from PIL import Image

from sc3d_cli.data import main as data_main
from conftest import run_cli
from test_faults import CUBE_F, CUBE_V, FAST, obj_text


def _textured_cube(folder: Path, name: str, texture: Image.Image) -> None:
    """``folder/name.obj`` (+ ``.mtl``, ``.png``): the unit cube, white material, ``texture``."""
    texture.save(folder / f"{name}.png")
    lines = [f"mtllib {name}.mtl", "usemtl m"] + [f"v {x} {y} {z}" for x, y, z in CUBE_V]
    lines += [f"vt {x} {y}" for x, y, _ in CUBE_V] + ["f " + " ".join(f"{i + 1}/{i + 1}" for i in f) for f in CUBE_F]
    (folder / f"{name}.obj").write_text("\n".join(lines) + "\n")
    (folder / f"{name}.mtl").write_text(f"newmtl m\nKd 1 1 1\nmap_Kd {name}.png\n")


# ----------------------------------------------------------------------------- F1
def test_f1_a_16_bit_grey_texture_renders_as_its_8_bit_twin(tmp_path):
    """A 16-bit grey PNG (PIL mode I;16, values 0-65535) was clipped to 255 by PIL's convert:
    a dark texture rendered white with exit 0. Its 8-bit twin (value / 257) is the reference."""
    folder = tmp_path / "m" / "chair"
    folder.mkdir(parents=True)
    wide = Image.fromarray(np.full((16, 16), 20000, np.uint16))
    assert wide.mode == "I;16"
    _textured_cube(folder, "grey16", wide)
    _textured_cube(folder, "grey8", Image.new("L", (16, 16), round(20000 / 257)))   # 78
    _textured_cube(folder, "white", Image.new("L", (16, 16), 255))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    with h5py.File(out / "shard-00000.h5") as f:
        images = dict(zip([m.decode() for m in f["model_id"][()]], f["images"][()]))
    assert not np.array_equal(images["grey8"], images["white"])     # the fixture can tell them apart
    np.testing.assert_array_equal(images["grey16"], images["grey8"])


# ----------------------------------------------------------------------------- F2
def test_f2_camera_and_axis_options_that_cannot_work_are_refused_once_naming_the_option(tmp_path):
    """``--fov 0``, ``--distance -2``, ``--up +Y --front +Y``... were accepted and every mesh then
    failed, blamed on itself ("silhouette is empty ... outlier vertex"); ``--distance 0`` rendered
    from inside the object with exit 0. Now one line naming the option, before any work."""
    meshes = tmp_path / "m" / "chair"
    meshes.mkdir(parents=True)
    (meshes / "cube.obj").write_text(obj_text(CUBE_V, CUBE_F))
    cases = {("--fov", "0"): "--fov 0.0: must be between 0 and 180",
             ("--fov", "180"): "--fov 180.0: must be between",
             ("--fov", "nan"): "--fov nan: must be",
             ("--distance", "0"): "--distance 0.0: must be a positive",
             ("--distance", "-2"): "--distance -2.0: must be",
             ("--elevations", "30,nan"): "--elevations 30.0,nan: must be",
             ("--up", "Q"): "--up Q: axis must be one of",
             ("--front", "+Y"): "--up +Y and --front +Y must be perpendicular",
             ("--up", "+Z"): "--up +Z with --front auto: auto takes +Z as the front"}
    for (option, value), message in cases.items():
        out = tmp_path / f"out{option}{value}"
        res = run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST, option, value],
                      expect_exit=1)
        lines = res.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"Error: {message}"), res.output
        assert not (out / "index.json").exists()                    # refused before any mesh was tried
    vox = tmp_path / "vox"
    res = run_cli(data_main, ["voxelize", "--meshes", tmp_path / "m", "--out", vox, "--no-progress", "--up", "+X",
                              "--front", "-X"], expect_exit=1)
    assert "--up +X and --front -X must be perpendicular axes" in res.output
    assert not (vox / "failures.json").exists()
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", tmp_path / "zup", *FAST, "--up", "+Z",
                        "--front", "-Y"])                              # a Z-up export with its front given


# ----------------------------------------------------------------------------- F3
def test_f3_voxelize_meshes_fails_when_nothing_was_voxelized_and_counts_every_failure(tmp_path):
    """``voxelize --meshes`` on an empty folder, or on one whose every mesh failed, said "wrote 0
    .binvox files ... 0 failed" or "1 failed" with exit 0 (a script went on with no voxels), and
    its count left out what discovery found wrong (a ShapeNet model folder without its mesh),
    which ``failures.json`` lists and ``render`` counts."""
    empty = tmp_path / "empty"
    empty.mkdir()
    res = run_cli(data_main, ["voxelize", "--meshes", empty, "--out", tmp_path / "v0", "--no-progress"], expect_exit=1)
    assert res.output.strip() == f"Error: --meshes {empty}: no mesh files found (looked for .obj, .glb, .gltf, .ply, .off, .stl)"

    meshes = tmp_path / "m"
    (meshes / "chair").mkdir(parents=True)
    (meshes / "chair" / "garbage.obj").write_text("not a mesh\n")
    (meshes / "02691156" / "model_without_mesh").mkdir(parents=True)
    vox = tmp_path / "v1"
    res = run_cli(data_main, ["voxelize", "--meshes", meshes, "--out", vox, "--no-progress"], expect_exit=1)
    assert "wrote 0 .binvox files" in res.output and "2 failed" in res.output
    assert res.output.strip().splitlines()[-1] == f"Error: no .binvox was written: all 2 failed (reasons in {vox}/failures.json)"
    assert len(json.loads((vox / "failures.json").read_text())) == 2

    (meshes / "chair" / "cube.obj").write_text(obj_text(CUBE_V, CUBE_F))
    res = run_cli(data_main, ["voxelize", "--meshes", meshes, "--out", vox, "--no-progress"])
    assert "wrote 1 .binvox files" in res.output and "2 failed" in res.output
    assert (vox / "chair" / "cube.binvox").is_file()


# ----------------------------------------------------------------------------- F4
def test_f4_voxelize_shards_without_their_meshes_changes_nothing_and_fails(tmp_path):
    """Shards copied without their meshes (or meshes moved): ``voxelize OUT --resolution 16``
    replaced every object's good grid by an empty one and exited 0 ("voxelized 2 objects ...,
    2 failed"). Now it refuses in one line and the shards keep their bytes; when the meshes are
    there but every one fails, the grids are empty as documented and the exit is 1."""
    meshes = tmp_path / "m" / "chair"
    meshes.mkdir(parents=True)
    for name in ("a", "b"):
        (meshes / f"{name}.obj").write_text(obj_text(CUBE_V, CUBE_F))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST, "--voxelize"])
    shard = out / "shard-00000.h5"
    before = shard.read_bytes()
    with h5py.File(shard) as f:
        assert f["voxels"].shape == (2, 32, 32, 32)
        assert f["voxels"][()].any(axis=(1, 2, 3)).all()              # both cubes have solid grids

    (tmp_path / "m").rename(tmp_path / "elsewhere")
    res = run_cli(data_main, ["voxelize", out, "--resolution", "16", "--no-progress"], expect_exit=1)
    assert res.output.strip().splitlines() == [
        f"Error: {out}: none of the 2 source meshes its shards record exists (first: {meshes / 'a.obj'}, also looked "
        f"for under {tmp_path / 'm'}); no shard was changed: voxelize where the meshes are"]
    assert shard.read_bytes() == before

    (tmp_path / "elsewhere").rename(tmp_path / "m")
    (meshes / "a.obj").write_text("not a mesh\n")       # one of two fails: the count says 1 voxelized, not 2
    res = run_cli(data_main, ["voxelize", out, "--resolution", "8", "--no-progress"])
    assert "voxelized 1 objects in 1 shards" in res.output and "1 failed" in res.output
    (meshes / "b.obj").write_text("not a mesh\n")
    res = run_cli(data_main, ["voxelize", out, "--resolution", "16", "--no-progress"], expect_exit=1)
    assert res.output.strip().splitlines()[-1] == (f"Error: no object was voxelized: all 2 failed (their grids are "
                                                   f"empty; reasons: `sc3d-data info {out}`)")


# ----------------------------------------------------------------------------- F5
def test_f5_an_inf_vertex_prints_no_stray_warning_only_the_failure_naming_the_file(tmp_path):
    """A mesh with an infinite coordinate made every worker print numpy's two-line
    ``RuntimeWarning: invalid value encountered in matmul`` (``meshes.py:78``, inf x 0), naming
    no file, into the output of ``render`` and ``voxelize --meshes``. The failure (a used inf
    vertex) is recorded naming the file, an unused one renders; nothing else is printed."""
    chair = tmp_path / "m" / "chair"
    chair.mkdir(parents=True)
    (chair / "cube.obj").write_text(obj_text(CUBE_V, CUBE_F))
    (chair / "unused_inf.obj").write_text(obj_text(CUBE_V + [[float("inf")] * 3], CUBE_F))
    (chair / "used_inf.obj").write_text(obj_text(CUBE_V + [[float("inf"), 0, 0]], CUBE_F + [[8, 0, 1]]))
    cli = [sys.executable, "-c", "import sc3d_cli.data as d; d.main()"]
    for args, done in ((["render", "--meshes", tmp_path / "m", "--out", tmp_path / "out", *FAST], "done 2,"),
                       (["voxelize", "--meshes", tmp_path / "m", "--out", tmp_path / "vox", "--no-progress"],
                        "wrote 2 .binvox")):
        res = subprocess.run(cli + [str(a) for a in args], capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        assert res.stderr == "", res.stderr
        assert done in res.stdout, res.stdout
    (failure,) = json.loads((tmp_path / "out" / "index.json").read_text())["failures"]
    assert failure["reason"] == f"{chair / 'used_inf.obj'}: 1 vertices with NaN/inf coordinates"


# ----------------------------------------------------------------------------- F6
def test_f6_import_r2n2_refuses_a_renderings_list_naming_images_outside_the_model(tmp_path):
    """``renderings.txt`` names the view PNGs; a line ``/elsewhere/secret.png`` or
    ``../../../secret.png`` was joined to the model's folder as it stood, so the import read
    any PNG on the machine into the shards, with exit 0. Now that model fails naming the file
    and line, and the other models are imported."""
    from test_import_r2n2 import synthesize

    renderings, voxels, _ = synthesize(tmp_path / "r2n2", seed=3)
    secret = tmp_path / "elsewhere" / "secret.png"
    secret.parent.mkdir()
    Image.new("RGBA", (137, 137), (255, 0, 0, 255)).save(secret)
    models = sorted(p for p in renderings.glob("*/*") if p.is_dir())
    lists = [m / "rendering" / "renderings.txt" for m in models[:2]]
    for lst, bad in zip(lists, (str(secret), os.path.relpath(secret, lists[1].parent))):
        lines = lst.read_text().splitlines()
        lst.write_text("\n".join([lines[0], bad] + lines[2:]) + "\n")
    out = tmp_path / "out"
    res = run_cli(data_main, ["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out", out,
                              "--no-progress"])
    assert f"imported {len(models) - 2} of {len(models)} models" in res.output and "2 failed" in res.output
    reasons = sorted(f["reason"] for f in json.loads((out / "index.json").read_text())["failures"])
    assert [r.split(": line 2: ")[0] for r in reasons] == [str(lst) for lst in lists]
    assert all("is a path, not a file name in" in r and r.endswith("; refused") for r in reasons)
    with h5py.File(out / "shard-00000.h5") as f:
        red = (f["images"][()] == [255, 0, 0]).all(-1).all((-1, -2))     # [N, V]: a view that is all red
    assert not red.any()


# ----------------------------------------------------------------------------- F7
def test_f7_import_r2n2_refuses_a_binvox_header_with_a_scale_that_places_no_grid(tmp_path):
    """A ``model.binvox`` whose header says ``scale -0.9`` (or nan, 0) was imported with exit 0:
    the grid size became the divisor of ``to_canonical`` and of every camera distance, so the
    object was mirrored and its cameras stood behind it (``check`` then failed with "part of
    the voxel grid is behind the camera", naming no object). Now that model fails naming the
    file and its header values; the others are imported."""
    import re

    from test_import_r2n2 import synthesize

    renderings, voxels, _ = synthesize(tmp_path / "r2n2", seed=3)
    files = sorted(voxels.glob("*/*/model.binvox"))[:2]
    for path, bad in zip(files, ("-0.9", "nan")):
        raw = path.read_bytes()
        header, data = raw.split(b"\ndata\n", 1)
        path.write_bytes(re.sub(rb"scale \S+", b"scale " + bad.encode(), header) + b"\ndata\n" + data)
    out = tmp_path / "out"
    res = run_cli(data_main, ["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out", out,
                              "--no-progress"])
    assert "imported 1 of 3 models" in res.output and "2 failed" in res.output
    reasons = sorted(f["reason"] for f in json.loads((out / "index.json").read_text())["failures"])
    assert [r.split(": header scale ")[0] for r in reasons] == [str(p) for p in files]
    assert [r.split(": header scale ")[1].split(" ")[0] for r in reasons] == ["-0.9", "nan"]


# ----------------------------------------------------------------------------- F8
def test_f8_import_r2n2_exits_1_when_every_model_failed(tmp_path):
    """``import-r2n2`` whose every model failed (here: each ``rendering_metadata.txt`` emptied)
    printed "imported 0 of 3 models ... 3 failed" and exited 0, where ``render`` exits 1 ("no
    object was rendered: all N failed"); a script went on with an empty dataset."""
    from test_import_r2n2 import synthesize

    renderings, voxels, _ = synthesize(tmp_path / "r2n2", seed=3)
    for meta in renderings.glob("*/*/rendering/rendering_metadata.txt"):
        meta.write_text("")
    res = run_cli(data_main, ["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out",
                              tmp_path / "out", "--no-progress"], expect_exit=1)
    assert "imported 0 of 3 models" in res.output
    assert res.output.strip().splitlines()[-1] == "Error: no model was imported: all 3 failed"


# ----------------------------------------------------------------------------- F9
def test_f9_reports_of_check_and_preview_never_overwrite_the_dataset_they_read(tmp_path):
    """``check OUT --json OUT/index.json`` replaced the index by the report (exit 0; the dataset
    then read as empty and INCOMPLETE), ``preview OUT --out OUT/shard-00000.h5`` truncated the
    shard to 0 bytes (PIL opens the file before finding no HDF5 writer) and printed a
    traceback, as did any extension PIL or matplotlib cannot write. Now each is one line and
    the dataset keeps its bytes."""
    meshes = tmp_path / "m" / "chair"
    meshes.mkdir(parents=True)
    (meshes / "cube.obj").write_text(obj_text(CUBE_V, CUBE_F))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST, "--voxelize"])
    index, shard = out / "index.json", out / "shard-00000.h5"
    before = {p: p.read_bytes() for p in (index, shard)}
    for args, message in (
            (["check", out, "--json", index], f"Error: --json {index}: that is the dataset's own index.json"),
            (["check", out, "--png", shard], f"Error: --png {shard}: that is the dataset's own shard-00000.h5"),
            (["preview", out, "--out", shard], f"Error: --out {shard}: that is the dataset's own shard-00000.h5"),
            (["preview", out, "--out", out / ".." / out.name / "index.json"], "Error: --out"),
            (["preview", out, "--out", tmp_path / "sheet.txt"], f"Error: --out {tmp_path / 'sheet.txt'}: unknown file"),
            (["check", out, "--png", tmp_path / "worst.txt"], f"Error: --png {tmp_path / 'worst.txt'}: Format 'txt'")):
        res = run_cli(data_main, [*args, "--no-progress"] if args[0] == "check" else args, expect_exit=1)
        assert res.output.strip().splitlines()[-1].startswith(message), res.output
        assert "Traceback" not in res.output
    assert {p: p.read_bytes() for p in before} == before
    run_cli(data_main, ["check", out, "--json", out / "check.json", "--no-progress"])   # beside the data: fine
    assert json.loads((out / "check.json").read_text())["passed"]
