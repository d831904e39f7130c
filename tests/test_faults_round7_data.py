"""Hostile inputs to `sc3d-data`, round seven: the ShapeNet layout read from how a path is
written (`--meshes .`, an 8-digit folder above plain meshes). Expected categories, ids and
fronts are stated by hand from the folder names."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from sc3d_data.formats.discover import discover_meshes
from sc3d_data.formats.shapenet import resolve_front
from test_import_r2n2 import fake_r2n2  # noqa: F401 - the fixture (fake 3D-R2N2 folders)

SAMPLES = Path(__file__).resolve().parents[1] / "assets" / "sample_meshes"
SYNSET = "03001627"
MODELS = ("1a38407b2b1f9ad8b6ed3b79bd59f70", "2b38407b2b1f9ad8b6ed3b79bd59f71")


def _shapenet_v1(root: Path) -> Path:
    """``root/SYNSET/MODEL_ID/model.obj`` for two models (tiny tetrahedra)."""
    for m in MODELS:
        d = root / SYNSET / m
        d.mkdir(parents=True)
        (d / "model.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    return root / SYNSET


@pytest.mark.parametrize("how", ["absolute", "dot", "relative"])
def test_r7_a_synset_folder_reads_the_same_however_it_is_written(tmp_path, monkeypatch, how):
    """`--meshes .` run inside the synset folder made each model its own category with model id
    'model' and gave it the front of a non-ShapeNet mesh; now the synset and model ids and the v1
    front (+X) are those of the absolute path."""
    synset_dir = _shapenet_v1(tmp_path / "sn")
    root = {"absolute": synset_dir, "dot": Path("."), "relative": Path(SYNSET)}[how]
    monkeypatch.chdir({"absolute": tmp_path, "dot": synset_dir, "relative": tmp_path / "sn"}[how])
    entries, problems = discover_meshes(root)
    assert not problems
    assert [(e.category, e.model_id) for e in entries] == [(SYNSET, m) for m in MODELS]
    assert {resolve_front("auto", e.path) for e in entries} == {"+X"}


@pytest.mark.parametrize("how", ["absolute", "relative"])
def test_r7_an_eight_digit_folder_above_plain_meshes_is_no_shapenet_synset(tmp_path, monkeypatch, how):
    """`/tmp/12345678/chairs` (a date or a SLURM job id above a folder of GLBs) was taken for a
    ShapeNet model folder without its mesh, and nothing rendered. Now the GLBs are the objects
    of category 'chairs', whichever way the path is written."""
    chairs = tmp_path / "12345678" / "chairs"
    chairs.mkdir(parents=True)
    for f in sorted((SAMPLES / "chair").glob("*.glb"))[:2]:
        shutil.copy(f, chairs / f.name)
    monkeypatch.chdir(tmp_path / "12345678")
    entries, problems = discover_meshes(chairs if how == "absolute" else Path("chairs"))
    assert not problems
    assert sorted((e.category, e.model_id) for e in entries) == sorted(
        ("chairs", f.stem) for f in (SAMPLES / "chair").glob("*.glb"))[:2]


def test_r7_control_a_model_folder_given_itself_is_still_shapenet(tmp_path):
    """`--meshes SYNSET/MODEL_ID` (one model's folder, which holds model.obj) keeps its ids; a
    model folder below --meshes without its mesh is still reported."""
    synset_dir = _shapenet_v1(tmp_path / "sn")
    entries, problems = discover_meshes(synset_dir / MODELS[0])
    assert [(e.category, e.model_id) for e in entries] == [(SYNSET, MODELS[0])] and not problems
    (synset_dir / MODELS[1] / "model.obj").unlink()
    (synset_dir / MODELS[1] / "notes.txt").write_text("no mesh here")
    entries, problems = discover_meshes(synset_dir)
    assert [(e.category, e.model_id) for e in entries] == [(SYNSET, MODELS[0])]
    assert [p["reason"] for p in problems] == [
        "ShapeNet model folder without its mesh (neither model.obj nor models/model_normalized.obj)"]


def _h5_voxels(out: Path, row: int):
    import h5py

    with h5py.File(next(out.glob("shard-*.h5")), "r") as f:
        return f["voxels"][row]


def test_r7_voxelize_finds_relative_sources_under_the_recorded_root_and_keeps_good_grids(tmp_path, monkeypatch):
    """Rendered from A with a relative --meshes, voxelized from B, where a different mesh has the
    same relative path: the mesh under A (the index's meshes root) is voxelized, not B's. When
    the recorded mesh has changed since rendering, the object fails but keeps the grid made from
    the mesh as rendered (it was replaced by an empty one before)."""
    from sc3d_cli.data import main as data_main
    from conftest import run_cli

    tetra = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n"
    for tree, text in (("A", tetra), ("B", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")):
        (tmp_path / tree / "meshes" / "chair").mkdir(parents=True)
        (tmp_path / tree / "meshes" / "chair" / "a.obj").write_text(text)
    out = tmp_path / "out"
    monkeypatch.chdir(tmp_path / "A")
    run_cli(data_main, ["render", "--meshes", "meshes", "--out", out, "--voxelize", "--views", "4", "--no-progress",
                        "--workers", "1"])
    rendered = _h5_voxels(out, 0)
    assert rendered.sum() > 100
    monkeypatch.chdir(tmp_path / "B")
    run_cli(data_main, ["voxelize", out, "--overwrite", "--no-progress"])
    assert (_h5_voxels(out, 0) == rendered).all()
    (tmp_path / "A" / "meshes" / "chair" / "a.obj").write_text(tetra + "v 2 2 2\nf 1 2 5\n")  # changed since
    res = run_cli(data_main, ["voxelize", out, "--overwrite", "--no-progress"], expect_exit=None)
    assert (_h5_voxels(out, 0) == rendered).all(), "the grid made from the mesh as rendered was replaced"
    import json

    failures = json.loads((out / "index.json").read_text())["failures"]
    assert [f.get("grid_kept") for f in failures] == [True], res.output


def test_r7_a_voxelize_rerun_retries_objects_that_failed(tmp_path):
    """A mesh missing during `voxelize SHARDS` failed; once it is back, a plain rerun (no
    --overwrite) voxelizes it (the shard was skipped as done before, keeping the empty grid)."""
    from sc3d_cli.data import main as data_main
    from conftest import run_cli

    m = tmp_path / "m" / "chair"
    m.mkdir(parents=True)
    glbs = sorted((SAMPLES / "chair").glob("*.glb"))[:2]
    for f in glbs:
        shutil.copy(f, m / f.name)
    out = tmp_path / "vr"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--views", "4", "--no-progress",
                        "--workers", "1"])
    (m / glbs[0].name).rename(tmp_path / "away.glb")
    run_cli(data_main, ["voxelize", out, "--no-progress"], expect_exit=None)
    assert _h5_voxels(out, 0).sum() == 0
    (tmp_path / "away.glb").rename(m / glbs[0].name)
    res = run_cli(data_main, ["voxelize", out, "--no-progress"])
    assert _h5_voxels(out, 0).sum() > 100, res.output
    import json

    assert json.loads((out / "index.json").read_text())["failures"] == []


def test_r7_a_slurm_array_task_is_told_for_voxelize_and_import(tmp_path, monkeypatch, fake_r2n2):
    """Inside a job array (SLURM_ARRAY_TASK_ID/COUNT set, no --part) `voxelize SHARDS` said
    '--part is for --meshes' though no --part was given; now it names the job array (and runs with
    --part 0/1). `voxelize --meshes` and `import-r2n2` take their part from the array as render
    does, and now say so, as render does."""
    from sc3d_cli.data import main as data_main
    from conftest import run_cli

    m = tmp_path / "m" / "chair"
    m.mkdir(parents=True)
    for f in sorted((SAMPLES / "chair").glob("*.glb"))[:2]:
        shutil.copy(f, m / f.name)
    out = tmp_path / "s"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--views", "4", "--no-progress",
                        "--workers", "1"])
    monkeypatch.setenv("SLURM_ARRAY_TASK_ID", "1")
    monkeypatch.setenv("SLURM_ARRAY_TASK_COUNT", "2")
    res = run_cli(data_main, ["voxelize", out, "--no-progress"], expect_exit=2)
    assert "SLURM job array task" in res.output and "--part 0/1" in res.output
    run_cli(data_main, ["voxelize", out, "--no-progress", "--part", "0/1"])
    res = run_cli(data_main, ["voxelize", "--meshes", tmp_path / "m", "--out", tmp_path / "bv", "--no-progress"])
    assert "part 1/2 taken from SLURM_ARRAY_TASK_ID" in res.output
    renderings, voxels, _ = fake_r2n2
    res = run_cli(data_main, ["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--out",
                              tmp_path / "r2", "--no-progress"])
    assert "part 1/2 taken from SLURM_ARRAY_TASK_ID" in res.output
