"""The one chunk loop and index writer of the jobs that write shards
(``sc3d_data.pipeline.jobs.shard_output``): every job holds the output lock, a run never replaces a
file it did not write, a rerun never mixes two plans, and an index write that was put off is
made when the run stops. Real commands, real worker pool, real HDF5."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import trimesh

from sc3d_cli.data import main
from conftest import run_cli

FAST = ["--views", "4", "--no-progress", "--workers", "1"]


def _meshes(root: Path, names: list[str]) -> Path:
    """Small boxes ``root/chair/NAME.obj``, one per name (model id = name)."""
    (root / "chair").mkdir(parents=True, exist_ok=True)
    for k, name in enumerate(names):
        trimesh.creation.box(extents=(0.6, 0.4 + 0.05 * k, 0.5)).export(root / "chair" / f"{name}.obj")
    return root


def _command(job: str, tmp_path: Path, out: Path) -> list:
    """The CLI arguments of ``job`` writing into ``out``."""
    if job == "render":
        return ["render", "--meshes", _meshes(tmp_path / "m", ["a"]), "--out", out, *FAST]
    if job == "import-r2n2":
        for d in ("R", "V"):
            (tmp_path / d).mkdir()
        return ["import-r2n2", "--renderings", tmp_path / "R", "--voxels", tmp_path / "V", "--out", out,
                "--no-progress"]
    return ["voxelize", out, "--no-progress"]


@pytest.mark.parametrize("job", ["render", "import-r2n2", "voxelize"])
def test_every_job_that_writes_shards_holds_the_output_lock(job, tmp_path):
    """While another writer holds ``out`` (here this process, through a second descriptor: flock
    locks conflict between open files, also in one process), each job stops at once with one
    line naming the folder and the holder, and writes nothing."""
    from sc3d_data.io.outlock import exclusive_lock

    out = tmp_path / "out"
    out.mkdir()
    args = _command(job, tmp_path, out)
    with exclusive_lock(out, "the first writer"):
        res = run_cli(main, args, expect_exit=1)
    line = f"{out}: another process (PID {os.getpid()}: the first writer) is writing to this folder"
    assert line in res.output and len(res.output.strip().splitlines()) == 1, res.output
    assert sorted(p.name for p in out.iterdir()) == [".sc3d.lock"]


def test_a_shard_named_file_the_run_did_not_write_is_refused_not_replaced(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    foreign = out / "shard-00000.h5"
    foreign.write_bytes(b"somebody else's file")
    args = ["render", "--meshes", _meshes(tmp_path / "m", ["a"]), "--out", out, *FAST]
    res = run_cli(main, args, expect_exit=1)
    assert f"{foreign}: named like a shard this run writes" in res.output
    assert len(res.output.strip().splitlines()) == 1, res.output
    assert foreign.read_bytes() == b"somebody else's file" and not (out / "index.json").exists()
    # a shard of this run's settings that the index does not list (a run killed before its
    # index listed it) is this run's own: a rerun writes it again
    foreign.unlink()
    run_cli(main, args)
    (out / "index.json").unlink()
    inode = foreign.stat().st_ino
    run_cli(main, args)
    index = json.loads((out / "index.json").read_text())
    assert index["complete"] and [s["file"] for s in index["shards"]] == ["shard-00000.h5"]
    assert foreign.stat().st_ino != inode


def test_a_rerun_refuses_an_index_of_another_plan(tmp_path):
    """A mesh added before the others moves every object to the next chunk: resuming would keep
    shards of the old plan beside shards of the new one (the same object twice)."""
    meshes = _meshes(tmp_path / "m", ["b", "c"])
    out = tmp_path / "out"
    args = ["render", "--meshes", meshes, "--out", out, "--objects-per-shard", "1", *FAST]
    run_cli(main, args)
    before = (out / "index.json").read_bytes()
    _meshes(meshes, ["a"])
    res = run_cli(main, args, expect_exit=1)
    assert f"{out}: its shards do not hold this plan's chunks" in res.output
    assert (out / "index.json").read_bytes() == before


def test_index_writes_put_off_when_large_and_made_when_the_run_stops(tmp_path, monkeypatch):
    """Every index counted as large: the writes after chunks 0 and 1 are put off; the run
    stopped by Ctrl-C in chunk 2 still leaves an index that lists chunks 0 and 1. Real local
    pool running the real ``voxelize --meshes`` job on three boxes."""
    from sc3d_data.pipeline.jobs import shard_output
    from sc3d_data.pipeline.executors.executor import start_executor
    from sc3d_data.pipeline.run.plan import Task
    from sc3d_data.pipeline.jobs.voxel_meshes import VOXELIZE_MESH, VoxelMeshesConfig

    meshes = _meshes(tmp_path / "m", ["a", "b", "c"])
    config = VoxelMeshesConfig(meshes=meshes, out=tmp_path / "vox", resolution=8, progress=False)
    todo = [Task(k, str(p), "chair", p.stem, "") for k, p in enumerate(sorted((meshes / "chair").iterdir()))]
    index = shard_output.ShardIndex(tmp_path, settings={}, split={})
    monkeypatch.setattr(shard_output, "LAZY_OBJECTS", -1)
    monkeypatch.setattr(shard_output, "LAZY_FACTOR", 1e9)
    on_disk = []

    def store(c, results, last):
        on_disk.append(json.loads((tmp_path / "index.json").read_text())["warnings"])
        if c == 2:
            raise KeyboardInterrupt
        index.warnings.append({"chunk": c, "status": results[0][1]})

    pool = start_executor(config, 1, VOXELIZE_MESH)
    try:
        with pytest.raises(KeyboardInterrupt):
            shard_output.write_chunks(index, pool, todo, 1, 1, store)
    finally:
        pool.close()
    assert on_disk == [[], [], []]  # only the first write was made while the chunks came in
    listed = json.loads((tmp_path / "index.json").read_text())["warnings"]
    assert listed == [{"chunk": 0, "status": "ok"}, {"chunk": 1, "status": "ok"}]
