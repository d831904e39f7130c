"""Defects of the data half found by the fourteenth attack on the commands (2026-11-28), each test
failing without its fix."""
from __future__ import annotations

import os
import signal

import pytest

from sc3d_data.pipeline.executors.job import ExecOptions, Job
from sc3d_data.pipeline.executors.local_pool import start_pool
from sc3d_data.pipeline.run.plan import Task
from sc3d_cli.data import main as data_main
from conftest import SAMPLE_MESHES, error_lines, run_cli


def interrupted_at_task_2(config, backend: str, task) -> tuple:
    """The worker's Ctrl-C arrives while it works on task 2 (the terminal sends SIGINT to the whole
    process group; here to the worker alone, as when the main process's KeyboardInterrupt is lost
    in a weakref callback, which the attack saw: 'Exception ignored in: ... KeyboardInterrupt')."""
    if task.pos == 2:
        os.kill(os.getpid(), signal.SIGINT)
    return task.pos, "ok", None


# ----------------------------------------------------------------------------- Ctrl-C lost
def test_a_worker_stopped_by_ctrl_c_stops_the_run_instead_of_failing_its_object():
    """``voxelize`` went on after Ctrl-C: its worker stopped (exit code 0), the object was recorded
    as a failure of its mesh ('worker exited with code 0 while working on it'), the run exited 0.
    A worker that exits 0 in a task stopped on Ctrl-C: the pool raises KeyboardInterrupt."""
    tasks = [Task(pos=i, path=f"object{i}", category="c", model_id=str(i), split="train") for i in range(5)]
    pool = start_pool(1, ExecOptions(workers=1, timeout_s=120.0), Job("ctrl-c test", interrupted_at_task_2))
    results = []
    try:
        with pytest.raises(KeyboardInterrupt):
            for r in pool.run(tasks):
                results.append(r)
    finally:
        pool.close()
    assert [(pos, status) for pos, status, _ in results] == [(0, "ok"), (1, "ok")]


# ----------------------------------------------------------------------------- options
CHAIR = SAMPLE_MESHES / "chair"


@pytest.mark.parametrize("args,message", [
    (["render", "--meshes", CHAIR, "--out", ""], "Invalid value for '--out': is empty: give a folder"),
    (["import-r2n2", "--renderings", ".", "--voxels", ".", "--out", " "], "Invalid value for '--out': is empty"),
    (["voxelize", "--meshes", CHAIR, "--out", ""], "Invalid value for '--out': is empty"),
    (["merge", "", "."], "Invalid value for 'OUT': is empty"),
    (["render", "--meshes", CHAIR, "--out", "o", "--category", ""], "Invalid value for '--category': is empty"),
], ids=["render-out", "import-out", "voxelize-out", "merge-out", "category"])
def test_an_empty_out_or_category_is_refused(tmp_path, monkeypatch, args, message):
    """``--out "$OUT"`` with OUT unset wrote a dataset into the current folder (render,
    import-r2n2), exit 0; ``--category ""`` was ignored (the folder's category kept)."""
    monkeypatch.chdir(tmp_path)
    res = run_cli(data_main, args, expect_exit=2)
    assert message in res.output and list(tmp_path.iterdir()) == [], res.output


def test_gpus_with_the_cpu_backend_is_refused_in_one_line(tmp_path):
    """``--backend osmesa --gpus 0``: --gpus kept EGL alone, no backend was left, and the error was
    'no headless OpenGL backend works:' with no reason and apt-get advice."""
    res = run_cli(data_main, ["render", "--meshes", CHAIR, "--out", tmp_path / "o", "--backend", "osmesa",
                              "--gpus", "0", "--workers", 1, "--no-progress"], expect_exit=1)
    assert error_lines(res.output) == ["Error: --gpus names EGL devices and --backend osmesa renders on the CPU: "
                                       "give one of them"], res.output


@pytest.mark.parametrize("args,names,executor", [
    (["--slurm-parts", 16, "--slurm-partition", "gpu"], "--slurm-partition, --slurm-parts", "slurm"),
    (["--address", "10.0.0.1:6379"], "--address", "ray"),
], ids=["slurm", "ray"])
def test_options_of_another_executor_are_refused(tmp_path, args, names, executor):
    """``render --slurm-parts 16`` without ``--executor slurm`` rendered the whole dataset here and
    exited 0, the options ignored without a word."""
    res = run_cli(data_main, ["render", "--meshes", CHAIR, "--out", tmp_path / "o", *args, "--workers", 1,
                              "--no-progress"], expect_exit=2)
    assert f"Error: {names}: not read by --executor local (only by --executor {executor})" in res.output
    assert not (tmp_path / "o").exists()


# ----------------------------------------------------------------------------- settings by meaning
@pytest.mark.parametrize("old,new,differ", [
    ({"categories": "chair,car"}, {"categories": "car,chair"}, []),
    ({"categories": "chair,car"}, {"categories": "03001627,02958343"}, []),   # ShapeNet's synset ids
    ({"categories": "chair,car"}, {"categories": "chair"}, ["categories"]),
    ({"split": "random:0.7,0.3"}, {"split": "random:0.7,0,0.3"}, []),        # an empty val split
    ({"split": "random:0.7,0.3"}, {"split": "random:0.70,0.30"}, []),
    ({"split": "random:0.7,0.3"}, {"split": "random:0.6,0.4"}, ["split"]),
    ({"split": "random:0.7,0.3"}, {"split": "random:0.7,0.2,0.1"}, ["split"]),
    ({"split": "R2N2"}, {"split": "r2n2"}, []),
    ({"split_file": "sp.txt"}, {"split_file": ["./sp.txt"]}, []),
    ({"split_file": "sp.txt"}, {"split_file": "other/sp.txt"}, ["split_file"]),
    ({"split_file": ["a.txt", "b.txt"]}, {"split_file": ["b.txt", "a.txt"]}, ["split_file"]),  # first file wins
    ({"up": "+z"}, {"up": "+Z"}, []),
])
def test_settings_compare_by_meaning(old, new, differ, tmp_path, monkeypatch):
    """A rerun of the same selection and split typed otherwise was refused as 'other settings',
    leaving --overwrite (the finished shards lost) or guessing the first spelling; the controls
    (other categories, other fractions, another file) still differ."""
    from sc3d_data.pipeline.run.resume import settings_differ

    monkeypatch.chdir(tmp_path)
    assert settings_differ(old, new) == differ


def test_a_rerun_with_the_categories_in_another_order_resumes(tmp_path):
    meshes = tmp_path / "m"
    for cat, name in (("chair", "chair2_blendswap"), ("car", "jeep_psionic")):
        (meshes / cat).mkdir(parents=True)
        (meshes / cat / f"{name}.glb").write_bytes((SAMPLE_MESHES / cat / f"{name}.glb").read_bytes())
    common = ["render", "--meshes", meshes, "--out", tmp_path / "o", "--views", 2, "--workers", 1, "--no-progress"]
    run_cli(data_main, [*common, "--categories", "chair,car", "--split", "random:0.7,0.3"])
    res = run_cli(data_main, [*common, "--categories", "02958343,chair", "--split", "random:0.7,0,0.3"])
    assert "done 0, resumed 2" in res.output


# ----------------------------------------------------------------------------- voxelize --meshes
def test_voxelize_meshes_removes_the_old_grid_of_an_edited_mesh_that_now_fails(tmp_path):
    """An edited mesh that now fails (a broken re-export) kept the ``.binvox`` of its earlier
    geometry, unmarked, and the summary said '1 of them again'. Now the old grid is removed, its
    failure names it, and the summary counts no redone file; the untouched mesh keeps its grid."""
    import json

    import trimesh

    (tmp_path / "m" / "x").mkdir(parents=True)
    mesh, other = tmp_path / "m" / "x" / "a.obj", tmp_path / "m" / "x" / "b.obj"
    trimesh.creation.box([1, 0.2, 0.2]).export(mesh)
    trimesh.creation.icosphere().export(other)
    args = ["voxelize", "--meshes", tmp_path / "m", "--out", tmp_path / "vo", "--no-progress", "--workers", "1"]
    run_cli(data_main, args)
    binvox = tmp_path / "vo" / "x" / "a.binvox"
    mesh.write_text("v 0 0 0\nf 1 2 3\n")  # a face naming vertices the file does not have
    now = binvox.stat().st_mtime_ns
    os.utime(binvox, ns=(now - 10 * 10**9,) * 2)  # grid older than the edit (clear of time resolution)
    res = run_cli(data_main, args)
    assert "1 failed" in res.output and "again" not in res.output, res.output
    assert not binvox.exists() and (tmp_path / "vo" / "x" / "b.binvox").is_file()
    failures = json.loads((tmp_path / "vo" / "failures.json").read_text())
    assert [f["source"] for f in failures] == [str(mesh)] and failures[0]["removed"].startswith(str(binvox))


def test_a_legal_255_byte_output_name_is_written(tmp_path):
    """A mesh of a 248-character stem needs a 255-byte ``.binvox`` name (the most a name may have):
    the write failed with 'File name too long' for its temporary ``NAME.binvox.tmp`` (259)."""
    import trimesh

    from sc3d_data.io.binvox import read_binvox

    stem = "a" * 248
    (tmp_path / "m" / "x").mkdir(parents=True)
    trimesh.creation.box([1, 0.5, 0.5]).export(tmp_path / "m" / "x" / f"{stem}.obj")
    res = run_cli(data_main, ["voxelize", "--meshes", tmp_path / "m", "--out", tmp_path / "vo", "--no-progress",
                              "--workers", "1"])
    assert "wrote 1 .binvox files" in res.output and "0 failed" in res.output, res.output
    assert os.listdir(tmp_path / "vo" / "x") == [f"{stem}.binvox"]
    assert read_binvox(tmp_path / "vo" / "x" / f"{stem}.binvox").voxels.any()


def test_a_whole_voxelize_meshes_run_drops_the_parts_failure_lists(tmp_path):
    """After ``--part 0/2`` and ``1/2`` runs with a broken mesh, the mesh removed and a whole run
    done, ``failures.json`` was [] but ``failures.part-*.json`` still listed the failure."""
    import json

    import trimesh

    (tmp_path / "m" / "x").mkdir(parents=True)
    for i in range(4):
        trimesh.creation.box([1, 0.5, 0.5]).export(tmp_path / "m" / "x" / f"good{i}.obj")
    for i in range(4):
        (tmp_path / "m" / "x" / f"bad{i}.obj").write_text("v 0 0 0\nf 1 2 3\n")
    args = ["voxelize", "--meshes", tmp_path / "m", "--out", tmp_path / "vo", "--no-progress", "--workers", "1"]
    for part in ("0/2", "1/2"):
        run_cli(data_main, [*args, "--part", part])
    listed = [json.loads(p.read_text()) for p in sorted((tmp_path / "vo").glob("failures.part-*.json"))]
    assert sum(len(f) for f in listed) == 4  # each part lists its own bad meshes
    for i in range(4):
        (tmp_path / "m" / "x" / f"bad{i}.obj").unlink()
    run_cli(data_main, args)
    assert json.loads((tmp_path / "vo" / "failures.json").read_text()) == []
    assert sorted(p.name for p in (tmp_path / "vo").glob("failures*.json")) == ["failures.json"]


def test_voxelize_shards_refuses_options_of_another_executor(tmp_path):
    """The review: ``voxelize SHARDS --slurm-parts 4`` (or ``--address``) was still ignored."""
    res = run_cli(data_main, ["voxelize", tmp_path, "--slurm-parts", 4, "--no-progress"], expect_exit=2)
    assert ("Error: --slurm-parts: not read by --executor local (only by --executor slurm); shards are voxelized "
            "by a local pool (--workers): leave them out") in res.output


@pytest.mark.parametrize("executor", ["ray", "slurm"])
def test_gpus_with_the_cpu_backend_is_refused_before_any_executor_starts(tmp_path, executor):
    """The review: the refusal lived in the local pool, so a slurm array submitted its tasks
    (each failing) and Ray never checked; now the render's settings check refuses it."""
    res = run_cli(data_main, ["render", "--meshes", CHAIR, "--out", tmp_path / "o", "--backend", "osmesa",
                              "--gpus", "0", "--executor", executor, "--slurm-cluster", "local", "--no-progress"]
                  if executor == "slurm" else
                  ["render", "--meshes", CHAIR, "--out", tmp_path / "o", "--backend", "osmesa", "--gpus", "0",
                   "--executor", executor, "--no-progress"], expect_exit=1)
    assert error_lines(res.output) == ["Error: --gpus names EGL devices and --backend osmesa renders on the CPU: "
                                       "give one of them"], res.output
