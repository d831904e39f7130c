"""Hostile inputs, round four: one test per defect found by the fourth attack on the ``sc3d-data``
command line (D1: ``merge`` of parts that ``voxelize`` ran on, one mesh failing; D2: a rerun
after a retry run was stopped; D3: a rerun of ``render`` on shards that ``voxelize`` completed). Real renderer,
HDF5 and worker processes; every fixture is built here. Expected values come from the fixtures
(which mesh was moved away, the shard bytes, the part a hash gives), never from the code under
test."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np

from sc3d_cli.data import main as data_main
from conftest import REPO, run_cli, write_hanging_gltf
from test_faults import CUBE_F, CUBE_V, FAST, obj_text


def _cubes(folder: Path, names: str) -> Path:
    """``folder/chair/N.obj`` for each letter of ``names``: unit cubes; returns ``folder``."""
    (folder / "chair").mkdir(parents=True)
    for name in names:
        (folder / "chair" / f"{name}.obj").write_text(obj_text(CUBE_V, CUBE_F))
    return folder


# ----------------------------------------------------------------------------- D1
def test_d1_merge_takes_parts_whose_voxelize_failed_on_one_mesh(tmp_path):
    """Parts rendered without voxels, then ``sc3d-data voxelize PART`` on each (the workflow
    docs/scale.md gives), one mesh of part 0 missing by then: that object keeps its row with an
    empty grid and gets a ``"stage": "voxelize"`` failure. ``merge`` counted that failure as one
    more object and refused for good ("part 0/2 accounts for 3 of its 2 objects"). Now it merges:
    all objects, the voxelize failure kept and pointing at the merged shard that holds the
    object (the part's shard name would name another part's shard)."""
    meshes = _cubes(tmp_path / "m", "abch")     # part_of(chair, id, 2): b, h -> 0; a, c -> 1
    parts = [tmp_path / "p0", tmp_path / "p1"]
    for i, p in enumerate(parts):
        run_cli(data_main, ["render", "--meshes", meshes, "--out", p, "--part", f"{i}/2", *FAST])
    assert [o["model_id"] for o in json.loads((parts[0] / "index.json").read_text())["objects"]] == ["b", "h"]
    (meshes / "chair" / "b.obj").rename(tmp_path / "b.obj")
    for p in parts:
        run_cli(data_main, ["voxelize", p, "--no-progress"])

    out = tmp_path / "merged"
    res = run_cli(data_main, ["merge", out, *parts])
    assert "4 objects in 2 shards" in res.output
    index = json.loads((out / "index.json").read_text())
    assert sorted(o["model_id"] for o in index["objects"]) == ["a", "b", "c", "h"]
    (fail,) = index["failures"]
    assert fail["stage"] == "voxelize" and fail["model_id"] == "b"
    with h5py.File(out / fail["shard"]) as f:
        ids = [m.decode() for m in f["model_id"][()]]
        grids = f["voxels"][()]
    assert ids[fail["row"]] == "b" and not grids[fail["row"]].any()
    assert all(grids[r].any() for r, m in enumerate(ids) if m != "b")


# ----------------------------------------------------------------------------- D2
def test_d2_a_rerun_after_a_stopped_retry_renders_the_object_again_instead_of_losing_it(tmp_path):
    """A mesh that hangs failed (``--timeout 1``); the rerun, which retries recorded failures,
    writes its index without that failure before it starts and was killed while retrying (a
    kill or Ctrl-C). The next rerun counted the object as resumed: exit 0, index complete, the
    object in neither ``objects`` nor ``failures`` (silently gone). Now an object of a kept
    chunk that the index does not name is done again and recorded."""
    meshes = _cubes(tmp_path / "m", "ab")
    write_hanging_gltf(meshes / "chair")
    out = tmp_path / "out"
    args = ["render", "--meshes", meshes, "--out", out, *FAST]
    run_cli(data_main, [*args, "--timeout", "1"])
    assert [f["model_id"] for f in json.loads((out / "index.json").read_text())["failures"]] == ["hang"]

    proc = subprocess.Popen([sys.executable, "-c", "from sc3d_cli.data import main; main()", *map(str, args),
                             "--timeout", "60"], cwd=REPO, env=dict(os.environ, PYTHONPATH=str(REPO)),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 50
        while json.loads((out / "index.json").read_text())["failures"] and time.monotonic() < deadline:
            time.sleep(0.05)    # the retry run has written its index; it now waits on the hanging mesh
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    stopped = json.loads((out / "index.json").read_text())
    assert not stopped["failures"] and not stopped["complete"]

    res = run_cli(data_main, [*args, "--timeout", "1"])
    assert "resumed 2" in res.output and "failed 1" in res.output
    index = json.loads((out / "index.json").read_text())
    assert sorted(o["model_id"] for o in index["objects"]) == ["a", "b"]
    assert [f["model_id"] for f in index["failures"]] == ["hang"] and index["complete"]


# ----------------------------------------------------------------------------- D3
def _shard_voxels(out: Path) -> dict:
    """``{model_id: voxels or None}`` over the shard files of ``out``."""
    got = {}
    for p in sorted(out.glob("shard-*.h5")):
        with h5py.File(p) as f:
            ids = [m.decode() for m in f["model_id"][()]]
            grids = f["voxels"][()] if "voxels" in f else [None] * len(ids)
        got.update(zip(ids, grids))
    return got


def test_d3_render_rerun_on_voxelized_shards_keeps_their_voxel_record_or_says_it_is_gone(tmp_path):
    """``render`` (a and d fail), ``voxelize OUT`` (b's mesh missing: empty grid, a voxelize
    failure), then the same ``render`` again. Before: a plain rerun dropped the index's
    ``voxels`` record and b's failure (the empty grid no longer recorded); once a and d were
    fixed, the rerun rewrote shard 0 with the retried a first and silently without the voxels of
    b, then died on shard 1 with a ``KeyError: 'voxels'`` traceback (d last). Now the plain
    rerun keeps both; the retry voxelizes a and d at the record's resolution (round ten: it wrote
    the shards without voxels and asked for ``voxelize`` again), keeps b's failure, and
    ``voxelize`` then retries b."""
    meshes = _cubes(tmp_path / "m", "bc")
    for name in "ad":
        (meshes / "chair" / f"{name}.obj").write_text("not a mesh\n")
    out = tmp_path / "out"
    args = ["render", "--meshes", meshes, "--out", out, "--objects-per-shard", "2", *FAST]
    run_cli(data_main, args)
    (meshes / "chair" / "b.obj").rename(tmp_path / "b.obj")
    run_cli(data_main, ["voxelize", out, "--no-progress"])
    (tmp_path / "b.obj").rename(meshes / "chair" / "b.obj")
    grids = _shard_voxels(out)
    assert sorted(grids) == ["b", "c"] and not grids["b"].any() and grids["c"].any()

    run_cli(data_main, args)                                       # a and d fail again
    index = json.loads((out / "index.json").read_text())
    assert index["voxels"]["resolution"] == 32
    assert sorted((f.get("stage", "render"), f["model_id"]) for f in index["failures"]) == [
        ("render", "a"), ("render", "d"), ("voxelize", "b")]

    for name in "ad":
        (meshes / "chair" / f"{name}.obj").write_text(obj_text(CUBE_V, CUBE_F))
    res = run_cli(data_main, args)
    assert "written without" not in res.output, res.output     # a and d get grids like the rest (32^3)
    index = json.loads((out / "index.json").read_text())
    assert index["voxels"]["resolution"] == 32 and index["complete"]
    assert [(f.get("stage"), f["model_id"]) for f in index["failures"]] == [("voxelize", "b")]
    grids = _shard_voxels(out)
    assert sorted(grids) == ["a", "b", "c", "d"] and not grids["b"].any()
    assert all(grids[k].any() for k in "acd")

    run_cli(data_main, ["voxelize", out, "--no-progress"])        # retries b's recorded failure
    grids = _shard_voxels(out)
    assert sorted(grids) == ["a", "b", "c", "d"] and all(g.any() for g in grids.values())
