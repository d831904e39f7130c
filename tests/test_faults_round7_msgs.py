"""Hostile inputs to `sc3d-data`, round seven: what the messages say. A refused resume names
the meshes that went or came, render's summary mentions warnings, check and preview name an
object whose voxels lie behind a camera, a read-only dataset still gets its verdict, a SLURM
part says it is a part, and names in pictures are printable. Real renders, real HDF5."""
from __future__ import annotations

import json
from pathlib import Path

import trimesh

from sc3d_cli.data import main
from conftest import run_cli

FAST = ["--views", "2", "--image-size", "32", "--no-progress", "--workers", "1"]


def _boxes(root: Path, names: list[str]) -> Path:
    """Small boxes ``root/chair/NAME.obj``, one per name (model id = name)."""
    (root / "chair").mkdir(parents=True, exist_ok=True)
    for k, name in enumerate(names):
        trimesh.creation.box(extents=(0.6, 0.4 + 0.05 * k, 0.5)).export(root / "chair" / f"{name}.obj")
    return root


def test_r7_a_refused_resume_names_the_meshes_gone_and_new(tmp_path):
    """A broken mesh deleted after a run (it had failed) and, separately, a mesh added: the
    refusal named neither; now it names each (path, count) and says to restore or move them."""
    meshes = _boxes(tmp_path / "m", ["a", "c", "d"])
    broken = meshes / "chair" / "b_broken.obj"
    broken.write_text("garbage\n")
    out = tmp_path / "out"
    args = ["render", "--meshes", meshes, "--out", out, "--objects-per-shard", "1", *FAST]
    run_cli(main, args)
    broken.unlink()
    res = run_cli(main, args, expect_exit=1)
    assert len(res.output.strip().splitlines()) == 1, res.output
    assert f"1 mesh(es) it lists are gone ({broken})" in res.output and "restore them" in res.output
    broken.write_text("garbage\n")
    _boxes(meshes, ["a0"])  # sorts before every other: all move one chunk on
    res = run_cli(main, args, expect_exit=1)
    new = meshes / "chair" / "a0.obj"
    assert f"1 mesh(es) are new ({new})" in res.output and "move the new ones away" in res.output
    assert "gone" not in res.output


def test_r7_render_summary_counts_objects_with_warnings(tmp_path):
    """An OBJ whose .mtl is missing renders with the default material and a recorded warning;
    the summary said only `failed 0`. Now it counts the object with warnings and says where
    they are listed."""
    meshes = tmp_path / "m" / "chair"
    meshes.mkdir(parents=True)
    (meshes / "t.obj").write_text("mtllib nothere.mtl\nusemtl a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                                  "f 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    out = tmp_path / "out"
    res = run_cli(main, ["render", "--meshes", meshes.parent, "--out", out, *FAST])
    assert "failed 0, 1 with warnings in" in res.output
    assert f"warnings are listed with reasons by `sc3d-data info {out}`" in res.output
    assert len(json.loads((out / "index.json").read_text())["warnings"]) == 1


def _older_near_camera_dataset(tmp_path: Path, distance: float = 0.7) -> Path:
    """A voxelized cube (8 views at elevation 30) whose stored cameras are moved to ``distance``
    from the origin, as an earlier sc3d that accepted ``--distance 0.7`` stored them (shard
    bytes and size recorded in the index again). Hand-derived: the cube's corner (0.5, 0.5, 0.5)
    has depth 0.7 - 0.5 * (cos30 (sin45 + cos45) + sin30) = -0.16 in the view at azimuth 45."""
    import h5py

    from sc3d_data.io.hashing import file_sha256

    meshes = tmp_path / "m" / "chair"
    meshes.mkdir(parents=True)
    trimesh.creation.box(extents=(1, 1, 1)).export(meshes / "cube.obj")
    out = tmp_path / "ds"
    run_cli(main, ["render", "--meshes", meshes.parent, "--out", out, "--views", "8", "--image-size", "32",
                   "--voxelize", "--voxel-resolution", "8", "--no-progress", "--workers", "1"])
    shard = out / "shard-00000.h5"
    with h5py.File(shard, "r+") as f:
        f["t"][...] = f["t"][...] * distance / 2.0  # t = (0, 0, d) for a camera looking at the origin
    index = json.loads((out / "index.json").read_text())
    index["shards"][0].update(sha256=file_sha256(shard), bytes=shard.stat().st_size)
    (out / "index.json").write_text(json.dumps(index))
    return out


def test_r7_render_refuses_a_camera_that_can_be_inside_the_unit_cube(tmp_path):
    """`--distance 0.7` was accepted; the unit cube's corner lies sqrt(3)/2 = 0.866 from the
    origin, so such a camera can be inside the object. Now one line names the minimum."""
    meshes = _boxes(tmp_path / "m", ["a"])
    res = run_cli(main, ["render", "--meshes", meshes, "--out", tmp_path / "o", "--distance", "0.7", *FAST],
                  expect_exit=None)
    assert res.exit_code != 0
    assert "--distance 0.7: must be more than 0.866" in res.output and len(res.output.strip().splitlines()) == 1
    run_cli(main, ["render", "--meshes", meshes, "--out", tmp_path / "o", "--distance", "0.87", *FAST])


def test_r7_check_and_preview_name_views_with_voxels_behind_the_camera(tmp_path):
    """check and preview aborted the whole dataset with 'project_voxels: part of the voxel grid
    is behind the camera'. Now check scores those views 0 (the object fails) and names the object
    and views; preview leaves their voxel tiles empty and names them."""
    out = _older_near_camera_dataset(tmp_path)
    res = run_cli(main, ["check", out, "--no-progress", "--png", tmp_path / "w.png",
                         "--json", tmp_path / "c.json"], expect_exit=1)
    assert "03001627/cube (shard-00000.h5 row 0): view(s) 1, 3, 5, 7 have voxels behind the camera" in res.output
    assert "FAIL: 1 of 1 objects" in res.output and (tmp_path / "w.png").is_file()
    report = json.loads((tmp_path / "c.json").read_text())
    assert report["objects"][0]["behind_camera_views"] == [1, 3, 5, 7]
    res = run_cli(main, ["preview", out, "--out", tmp_path / "s.png", "--views", "8"])
    assert "03001627/cube (shard-00000.h5 row 0): view(s) 1, 3, 5, 7 have voxels behind" in res.output
    assert (tmp_path / "s.png").is_file()


def test_r7_check_of_a_dataset_where_the_default_picture_cannot_be_written(sample_shards, tmp_path):
    """`check` of a read-only dataset printed PASS and then exited 1 on writing its default
    SHARDS/check_worst.png. Now one warning names the file and --png, and the exit is the
    verdict (0); an explicit --png that cannot be written stays an error. The unwritable file is
    a folder in its place (root writes into read-only modes, not into a folder as a file)."""
    import shutil

    ds = tmp_path / "ds"
    shutil.copytree(sample_shards, ds)
    (ds / "check_worst.png").mkdir()
    res = run_cli(main, ["check", ds, "--no-progress", "--json", tmp_path / "c.json"], expect_exit=0)
    assert "PASS" in res.output and "worst views:" not in res.output
    warning = [line for line in res.output.splitlines() if line.startswith("warning:")]
    assert len(warning) == 1 and str(ds / "check_worst.png") in warning[0] and "--png PATH" in warning[0]
    assert json.loads((tmp_path / "c.json").read_text())["passed"]
    res = run_cli(main, ["check", ds, "--no-progress", "--png", tmp_path / "c.json" / "w.png"], expect_exit=1)
    assert res.output.strip().splitlines()[-1].startswith(f"Error: {tmp_path / 'c.json'}")


def test_r7_a_slurm_array_part_says_it_is_a_part(tmp_path, monkeypatch):
    """Inside a SLURM job array render defaults to that task's part; render's summary did not
    say where the part came from and `info` called the part folder complete without naming the
    part. Now both do. Expected counts from the partition rule (sha256 of 'category/model_id'
    mod 3), computed here with hashlib, not with sc3d."""
    import hashlib

    names = ["a", "b", "c", "d", "e", "f"]
    meshes = _boxes(tmp_path / "m", names)
    mine = [n for n in names if int(hashlib.sha256(f"03001627/{n}".encode()).hexdigest()[:16], 16) % 3 == 2]
    assert 0 < len(mine) < len(names)
    monkeypatch.setenv("SLURM_ARRAY_TASK_ID", "2")
    monkeypatch.setenv("SLURM_ARRAY_TASK_COUNT", "3")
    out = tmp_path / "sl"
    res = run_cli(main, ["render", "--meshes", meshes, "--out", out, *FAST])
    assert f"part 2/3, done {len(mine)}," in res.output
    assert "part 2/3 taken from SLURM_ARRAY_TASK_ID/SLURM_ARRAY_TASK_COUNT" in res.output
    res = run_cli(main, ["info", out])
    assert f"part 2/3: {len(mine)} of {len(names)} planned objects; merge the parts" in res.output
    res = run_cli(main, ["render", "--meshes", meshes, "--out", tmp_path / "p", "--part", "2/3", *FAST])
    assert "taken from SLURM" not in res.output  # --part given: the user knows


def test_r7_names_in_pictures_are_printable(tmp_path, recwarn):
    """An object named with a tab: check's picture title made matplotlib warn 'Glyph 9 (\\t)
    missing from font(s)'. Now names in pictures are written in printable form (a tab as \\t),
    with no warning."""
    meshes = tmp_path / "m" / "chair"
    meshes.mkdir(parents=True)
    trimesh.creation.box(extents=(1, 0.8, 0.6)).export(meshes / "a\tb.obj")
    out = tmp_path / "ds"
    run_cli(main, ["render", "--meshes", meshes.parent, "--out", out, *FAST, "--voxelize", "--voxel-resolution", "8"])
    run_cli(main, ["check", out, "--no-progress", "--png", tmp_path / "w.png"], expect_exit=None)
    run_cli(main, ["preview", out, "--out", tmp_path / "s.png"])
    assert (tmp_path / "w.png").is_file() and (tmp_path / "s.png").is_file()
    assert not [w for w in recwarn if "Glyph" in str(w.message)], [str(w.message) for w in recwarn]
