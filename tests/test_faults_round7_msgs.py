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
