"""Hostile inputs, round ten (the data commands): a merge run again over a voxelized dataset,
someone's ``*.tmp`` files in the output folder, a rerun after ``voxelize --resolution``, ``info``
on voxelized shards, Ctrl-C while the worker server imports, flat objects seen edge-on in
``check``, stepped SLURM arrays, new meshes counted as retries, extra meshes in a ShapeNet model
folder, axes spelt in lower case. Real renderer, real HDF5, real worker processes; expected values
are derived by hand from the inputs."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from sc3d_cli.data import main as data_main
from conftest import SAMPLE_MESHES, one_error, run_cli, error_lines
from test_faults import FAST, index_of
from test_faults_round8_data import flip_bytes_in_a_chunk
from test_import_r2n2 import fake_r2n2  # noqa: F401 - the fixture (fake 3D-R2N2 folders)


def _voxel_shapes(out: Path) -> list[tuple | None]:
    shapes = []
    for shard in sorted(out.glob("shard-*.h5")):
        with h5py.File(shard, "r") as f:
            shapes.append(f["voxels"].shape[1:] if "voxels" in f else None)
    return shapes


def _dataset_bytes(folder: Path) -> dict[str, bytes]:
    """The shards' and the index's bytes (not the lock file, which names its last holder)."""
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file() and p.name != ".sc3d.lock"}


def _two_chairs(tmp_path: Path) -> Path:
    meshes = tmp_path / "m" / "chair"
    meshes.mkdir(parents=True)
    for name in ("chair2_blendswap.glb", "silla_blanca_blendswap.glb"):
        shutil.copy(SAMPLE_MESHES / "chair" / name, meshes / name)
    return meshes.parent


def test_merge_run_again_after_voxelize_keeps_the_voxels(tmp_path):
    """A merge run again into a folder that ``voxelize`` had given voxels replaced every shard
    with the parts' (no voxels) and wrote the parts' index: the voxelization was lost without a
    word. Now the same merge again keeps the dataset as it is; a merge of other part folders
    into it is refused in one line, and the folder is left untouched."""
    meshes = _two_chairs(tmp_path)
    parts = [tmp_path / f"p{i}" for i in range(2)]
    for i, part in enumerate(parts):
        run_cli(data_main, ["render", "--meshes", meshes, "--out", part, "--part", f"{i}/2", *FAST])
    merged = tmp_path / "merged"
    run_cli(data_main, ["merge", merged, *parts])
    run_cli(data_main, ["voxelize", merged, "--no-progress"])
    voxelized = _dataset_bytes(merged)
    assert _voxel_shapes(merged) and set(_voxel_shapes(merged)) == {(32, 32, 32)}

    res = run_cli(data_main, ["merge", merged, *parts])
    assert "(0 linked, 0 copied, 1 already there)" in res.output, res.output  # both chairs fall in one part
    assert _dataset_bytes(merged) == voxelized
    assert index_of(merged)["voxels"]["resolution"] == 32

    index = json.loads((merged / "index.json").read_text())  # a merge of an earlier version: no record of
    del index["merged"]["sources_sha256"]                      # which part shards it took
    (merged / "index.json").write_text(json.dumps(index))
    voxelized = _dataset_bytes(merged)
    res = run_cli(data_main, ["merge", merged, *parts], expect_exit=1)
    assert "given voxels by `sc3d-data voxelize` after the merge" in one_error(res.output)
    assert _dataset_bytes(merged) == voxelized

    copies = [shutil.copytree(p, tmp_path / f"q{i}") for i, p in enumerate(parts)]
    res = run_cli(data_main, ["merge", merged, *copies], expect_exit=1)
    errors = error_lines(res.output)
    assert len(errors) == 1 and "given voxels by `sc3d-data voxelize` after the merge" in errors[0], res.output
    assert _dataset_bytes(merged) == voxelized


def test_render_and_merge_delete_only_their_own_tmp_files(tmp_path):
    """``render`` and ``merge`` deleted every ``*.tmp`` in the output folder (a user's notes
    too). Now only the names sc3d's writers use go: a shard's or the index's ``.tmp`` and
    ``.PID.tmp``."""
    out, merged = tmp_path / "out", tmp_path / "merged"
    out.mkdir()
    merged.mkdir()
    for folder in (out, merged):
        (folder / "experiment-notes.tmp").write_text("mine")
        (folder / "shard-00000.h5.tmp").write_bytes(b"left by a killed run")
        (folder / "index.json.4242.tmp").write_bytes(b"left by a killed --part job")
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "table", "--out", out, *FAST])
    part = tmp_path / "part"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "table", "--out", part, "--part", "0/1", *FAST])
    run_cli(data_main, ["merge", merged, part])
    for folder in (out, merged):
        assert (folder / "experiment-notes.tmp").read_text() == "mine"
        assert not (folder / "shard-00000.h5.tmp").exists() and not (folder / "index.json.4242.tmp").exists()


def test_rerender_keeps_the_resolution_that_voxelize_gave_the_dataset(tmp_path):
    """After ``voxelize out --resolution 16``, a rerun that rendered a changed mesh again wrote
    its shard with 32^3 grids (``render --voxelize``'s own resolution), dropped the index's
    record and said the shard had been written *without* voxels: a mixed 16^3 / 32^3 dataset
    that ``check`` passed. Now the object rendered again gets 16^3 grids like the rest, the
    record stays, and ``info`` says what the shards hold."""
    meshes = _two_chairs(tmp_path)
    out = tmp_path / "out"
    render = ["render", "--meshes", meshes, "--out", out, "--voxelize", "--objects-per-shard", "1", *FAST]
    run_cli(data_main, render)
    run_cli(data_main, ["voxelize", out, "--resolution", "16", "--no-progress"])
    assert _voxel_shapes(out) == [(16, 16, 16)] * 2
    changed = meshes / "chair" / "chair2_blendswap.glb"
    trimesh.load(changed).export(changed)  # the same shape, other bytes: its chunk is rendered again
    res = run_cli(data_main, render)
    assert "rendering its chunk again" in res.output and "written without" not in res.output, res.output
    assert _voxel_shapes(out) == [(16, 16, 16)] * 2
    assert index_of(out)["voxels"]["resolution"] == 16
    info = run_cli(data_main, ["info", out]).output
    assert "voxels: 16^3, added by `sc3d-data voxelize`" in info, info


def test_a_shard_rewritten_with_grids_of_another_resolution_drops_them_and_says_so(tmp_path):
    """Where the objects rendered again still come with grids of another resolution than the
    index's record (an executor started before the run read the record), the shard is written
    without voxels (not mixed) and the note says so, naming the resolution to voxelize at."""
    from sc3d_data.io.shards import ObjectRecord
    from sc3d_data.pipeline.jobs.shard_output import ShardIndex
    from sc3d_data.pipeline.run.resume_voxels import voxels_after_rewrite

    index = ShardIndex(tmp_path, {}, {}, extra={"voxels": {"resolution": 16}})
    records = [ObjectRecord("a", "03001627", "train", "a.glb", {"voxels": np.zeros((16,) * 3, np.uint8)}),
               ObjectRecord("b", "03001627", "train", "b.glb", {"voxels": np.zeros((32,) * 3, np.uint8)})]
    notes: list[str] = []
    voxels_after_rewrite(index, "shard-00000.h5", records, notes)
    assert all("voxels" not in r.arrays for r in records) and "voxels" not in index.extra
    assert len(notes) == 1 and "written without the 16^3 voxels" in notes[0] and "--resolution 16" in notes[0]


def test_info_says_which_voxels_the_shards_hold(tmp_path):
    """``info`` printed only the render's settings (``voxelize: False``, ``voxel_resolution:
    32``) after ``voxelize --resolution 8`` had given the shards 8^3 grids."""
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES / "table", "--out", out, *FAST])
    assert "voxels: none" in run_cli(data_main, ["info", out]).output
    run_cli(data_main, ["voxelize", out, "--resolution", "8", "--no-progress"])
    assert _voxel_shapes(out) == [(8, 8, 8)]
    assert "voxels: 8^3, added by `sc3d-data voxelize` (0 failed" in run_cli(data_main, ["info", out]).output


PROBE = '''
"""Imported by the forkserver after sc3d's preload: slow, so that the test finds it importing."""
import signal
import time

time.sleep(1.5)


def run(config, backend, task):
    return task, "ok", signal.getsignal(signal.SIGINT) is signal.default_int_handler
'''

SERVER_CHECK = '''
import os, signal, sys, time
from multiprocessing import forkserver
from sc3d_data.pipeline.executors import local_pool
from sc3d_data.pipeline.executors.job import Job
import probe

local_pool.PRELOAD_EXTRA.append("probe")
ctx = local_pool.worker_context(None)
local_pool.start_server_early(None, Job("probe", probe.run))
server = forkserver._forkserver._forkserver_pid
time.sleep(0.5)  # the server is in its preload (sc3d's modules, then the probe's 1.5 s)
status = open(f"/proc/{server}/status").read()
ignored = int([ln for ln in status.splitlines() if ln.startswith("SigIgn:")][0].split()[1], 16)
print("server ignores SIGINT:", bool(ignored & (1 << (signal.SIGINT - 1))))
os.kill(server, signal.SIGINT)
pool = local_pool.WorkerPool(1, None, "cpu", Job("probe", probe.run))
assert pool.wait_ready() is None
worker = pool.workers[0]
worker.conn.send(7)
print("worker reply:", worker.receive())
pool.close()
'''


def test_ctrl_c_while_the_worker_server_imports_prints_no_traceback(tmp_path):
    """Ctrl-C in the first second of a render printed a 20-line traceback of the forkserver's
    imports (multiprocessing ignores SIGINT in the server only after its preload). Now the
    server ignores it from its start, survives it, and its workers take Python's handler back
    (Ctrl-C still stops them as before)."""
    (tmp_path / "probe.py").write_text(textwrap.dedent(PROBE))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    res = subprocess.run([sys.executable, "-c", SERVER_CHECK], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0 and "Traceback" not in res.stderr, res.stdout + res.stderr
    assert "server ignores SIGINT: True" in res.stdout, res.stdout
    assert "worker reply: ('ok', 7, True)" in res.stdout, res.stdout


def test_check_passes_a_flat_object_whose_edge_on_views_have_an_empty_mask(tmp_path):
    """A plate seen edge-on has an empty (point-sampled) mask while its voxels are a slab one
    voxel thick; ``near`` scored such a view 0 and ``check`` failed a correct render. Hand-made
    cases of ``near_score`` and the real command on a real plate."""
    from sc3d_data.qa.check import near_score

    empty = np.zeros((64, 64), bool)
    line, block = empty.copy(), empty.copy()
    line[10:50, 32] = True         # one pixel wide: the excess a thin structure leaves
    block[10:30, 10:30] = True     # 20 x 20 pixels where the mask has nothing: wrong voxels
    assert near_score(empty, line, footprint=1.0) == 1.0
    assert near_score(empty, block, footprint=1.0) == 0.0

    plate = tmp_path / "m" / "sign" / "plate.obj"
    plate.parent.mkdir(parents=True)
    plate.write_text("v -1 0 0\nv 1 0 0\nv 1 1 0\nv -1 1 0\nf 1 2 3\nf 1 3 4\n")
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", plate.parent.parent, "--out", out, "--voxelize", "--no-progress",
                        "--workers", "1"])
    with h5py.File(next(out.glob("shard-*.h5")), "r") as f:
        assert (f["masks"][0].reshape(24, -1).sum(1) == 0).sum() == 2  # azimuths 90 and 270: edge-on
    res = run_cli(data_main, ["check", out, "--no-progress"])
    assert "PASS" in res.output, res.output


def test_parts_of_stepped_slurm_arrays(tmp_path):
    """``--array=0-4:2`` gives ids 0, 2, 4 (count 3): they were taken as parts 0/3, 2/3 and an
    error about a ``--part`` nobody gave. Now ids map to parts 0, 1, 2; an array that is not
    evenly spaced (``--array=1,5,7``) is refused naming the array."""
    from sc3d_data.pipeline.run.partition import Part, part_from_env

    stepped = {"SLURM_ARRAY_TASK_COUNT": "3", "SLURM_ARRAY_TASK_MIN": "0", "SLURM_ARRAY_TASK_MAX": "4",
               "SLURM_ARRAY_TASK_STEP": "2"}
    assert [part_from_env(dict(stepped, SLURM_ARRAY_TASK_ID=i)) for i in ("0", "2", "4")] == \
        [Part(0, 3), Part(1, 3), Part(2, 3)]
    listed = {"SLURM_ARRAY_TASK_ID": "5", "SLURM_ARRAY_TASK_COUNT": "3", "SLURM_ARRAY_TASK_MIN": "1",
              "SLURM_ARRAY_TASK_MAX": "7", "SLURM_ARRAY_TASK_STEP": "1"}
    with pytest.raises(ValueError, match="evenly spaced"):
        part_from_env(listed)
    res = CliRunner().invoke(data_main, ["render", "--meshes", str(SAMPLE_MESHES / "table"), "--out",
                                         str(tmp_path / "out"), "--no-progress"], env=listed)
    assert res.exit_code == 2 and "SLURM array task 5 of 3" in res.output and "'--part'" not in res.output, res.output


def test_a_rerun_counts_new_meshes_as_added_not_retried(tmp_path):
    """A mesh added to the collection was reported as ``retried`` on the rerun (a user reads
    a failure that never happened)."""
    meshes = tmp_path / "m" / "chair"
    meshes.mkdir(parents=True)
    shutil.copy(SAMPLE_MESHES / "chair" / "chair2_blendswap.glb", meshes)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", meshes.parent, "--out", out, *FAST])
    shutil.copy(SAMPLE_MESHES / "chair" / "silla_blanca_blendswap.glb", meshes)
    res = run_cli(data_main, ["render", "--meshes", meshes.parent, "--out", out, *FAST])
    assert "done 1, resumed 1, added 1," in res.output and "retried" not in res.output, res.output


def test_extra_meshes_in_a_shapenet_model_folder_are_listed_as_skipped(tmp_path):
    """Inside ``SYNSET/MODEL/`` only ``model.obj`` is read; another mesh there was dropped
    without a word. Now it is listed under ``skipped`` with the reason."""
    from sc3d_data.formats.discover import discover_meshes

    model = tmp_path / "sn" / "03001627" / "abc"
    model.mkdir(parents=True)
    (model / "model.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    shutil.copy(SAMPLE_MESHES / "chair" / "chair2_blendswap.glb", model / "cushion.glb")
    entries, problems = discover_meshes(tmp_path / "sn")
    assert [(e.category, e.model_id, Path(e.path).name) for e in entries] == [("03001627", "abc", "model.obj")]
    assert [(Path(p["source"]).name, p.get("skipped")) for p in problems] == [("cushion.glb", True)]
    assert "not its mesh (only model.obj is read)" in problems[0]["reason"]


def test_axes_spelt_in_lower_case_resume_and_are_recorded_one_way(tmp_path):
    """``--up +z --front -y`` and ``--up +Z --front -Y`` mean the same axes, but a rerun with the
    other spelling was refused ("front, up differ"). Now the index records ``+Z``/``-Y`` and
    either spelling resumes; another axis is still refused (negative control)."""
    out = tmp_path / "out"
    base = ["render", "--meshes", SAMPLE_MESHES / "table", "--out", out, *FAST]
    run_cli(data_main, [*base, "--up", "+z", "--front", "-y"])
    settings = index_of(out)["settings"]
    assert (settings["up"], settings["front"]) == ("+Z", "-Y")
    assert "resumed 1" in run_cli(data_main, [*base, "--up", "+Z", "--front", "-Y"]).output
    assert "resumed 1" in run_cli(data_main, [*base, "--up", "z", "--front", "-y"]).output
    res = run_cli(data_main, [*base, "--up", "+Z", "--front", "+Y"], expect_exit=1)
    assert "front differ" in res.output, res.output


def test_settings_differ_reads_axes_of_older_indexes_by_meaning():
    """An index written before the spelling was fixed records ``+z``: a rerun spelling ``+Z``
    resumes it; ``+x`` against ``+Z`` still differs."""
    from sc3d_data.pipeline.run.resume import settings_differ

    assert settings_differ({"up": "+z", "front": "auto"}, {"up": "+Z", "front": "auto"}) == []
    assert settings_differ({"up": "+x"}, {"up": "+Z"}) == ["up"]
    assert json.loads(json.dumps({"up": "+Z"}))["up"] == "+Z"


def test_a_refused_overwrite_deletes_nothing(tmp_path):
    """``render --overwrite`` deleted the dataset in ``--out`` as soon as it held the lock, then
    refused an empty ``--meshes`` or a foreign shard-named file: the old dataset was gone and no
    new one written. Now the old outputs go only when the run starts, after its checks; an
    overwrite that runs still replaces them (a shard the old index listed and the new run does
    not write is deleted)."""
    meshes = _two_chairs(tmp_path)
    out = tmp_path / "out"

    def render(per_shard: str, *extra, expect_exit=0):
        return run_cli(data_main, ["render", "--meshes", meshes, "--out", out, "--objects-per-shard", per_shard,
                                   *extra, *FAST], expect_exit=expect_exit)

    render("2")
    before = _dataset_bytes(out)
    assert sorted(before) == ["index.json", "shard-00000.h5"]
    (tmp_path / "empty").mkdir()
    res = run_cli(data_main, ["render", "--meshes", tmp_path / "empty", "--out", out, "--overwrite", *FAST],
                  expect_exit=1)
    assert "no mesh files found" in one_error(res.output) and _dataset_bytes(out) == before
    (out / "shard-00001.h5").write_text("someone's")
    res = render("1", "--overwrite", expect_exit=1)
    assert "shard-00001.h5: named like a shard" in one_error(res.output)
    assert {k: v for k, v in _dataset_bytes(out).items() if k != "shard-00001.h5"} == before
    (out / "shard-00001.h5").unlink()
    render("1", "--overwrite")
    assert sorted(_dataset_bytes(out)) == ["index.json", "shard-00000.h5", "shard-00001.h5"]
    render("2", "--overwrite")  # shard-00001.h5, listed by the old index, is not written again: deleted
    assert sorted(_dataset_bytes(out)) == ["index.json", "shard-00000.h5"]
    assert index_of(out)["settings"]["objects_per_shard"] == 2


@pytest.mark.parametrize("damage", ["not square", "named twice"])
def test_import_r2n2_refuses_a_stretched_or_repeated_view(fake_r2n2, tmp_path, damage):
    """A rendering PNG of another aspect (137x90) was stretched to a square under a camera made
    for a square image, and a ``renderings.txt`` naming one PNG twice gave two views one picture
    under two cameras; both were imported without a word (``check`` passed one of them). Now the
    model is left out with its reason, as for any other bad view."""
    from PIL import Image

    renderings, voxels, _ = fake_r2n2
    copy = shutil.copytree(renderings, tmp_path / "ShapeNetRendering")
    rendering = sorted(copy.glob("*/*/rendering"))[0]
    if damage == "not square":
        with Image.open(rendering / "03.png") as im:
            im.crop((0, 0, im.width, 90)).save(rendering / "03.png")
        reason = "03.png: image is 137x90, not square"
    else:
        names = (rendering / "renderings.txt").read_text().splitlines()
        (rendering / "renderings.txt").write_text("\n".join([names[0], names[0], *names[2:]]) + "\n")
        reason = f"line 2: {names[0]!r} is named again (line 1)"
    out = tmp_path / "out"
    res = run_cli(data_main, ["import-r2n2", "--renderings", copy, "--voxels", voxels, "--out", out, "--no-progress"])
    assert "imported 2 of 3 models" in res.output, res.output
    failures = index_of(out)["failures"]
    assert len(failures) == 1 and reason in failures[0]["reason"], failures
    assert failures[0]["model_id"] == rendering.parent.name


def test_preview_reads_only_the_objects_it_draws(tmp_path):
    """``preview --objects 1`` read the images, masks and voxels of every object of the dataset
    before picking one (0.44 MB an object: gigabytes for ShapeNet). Now it picks from the index:
    shards of objects it does not draw are not read, so damage there does not even stop it."""
    meshes = _two_chairs(tmp_path)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", meshes, "--out", out, "--objects-per-shard", "1", "--voxelize", *FAST])
    flip_bytes_in_a_chunk(out / "shard-00001.h5")  # the second chair's images: a read fails its checksum
    res = run_cli(data_main, ["preview", out, "--objects", "1", "--out", tmp_path / "one.png"])
    assert (tmp_path / "one.png").is_file(), res.output
    res = run_cli(data_main, ["preview", out, "--objects", "2", "--out", tmp_path / "two.png"], expect_exit=1)
    assert "shard-00001.h5: row 0 cannot be read" in one_error(res.output)


def test_ray_with_gpus_on_a_cluster_without_gpus_is_refused_not_left_waiting(tmp_path):
    """``render --executor ray --gpus 0`` on a cluster without GPUs asked Ray for GPU shares
    that could never be granted and waited for ever, printing nothing."""
    pytest.importorskip("ray")
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU: Ray would grant the shares")
    res = subprocess.run([sys.executable, "-c", "from sc3d_cli.data import main; main()", "render", "--meshes",
                          str(SAMPLE_MESHES / "table"), "--out", str(tmp_path / "out"), "--executor", "ray",
                          "--gpus", "0", "--workers", "1", "--no-progress"],
                         capture_output=True, text=True, timeout=180)
    assert res.returncode == 1, res.stdout + res.stderr
    assert "--gpus 0: the Ray cluster has no GPU" in error_lines(res.stdout + res.stderr)[0]


def test_import_r2n2_skips_hidden_folders(fake_r2n2, tmp_path):
    """A hidden folder in a synset folder (``.ipynb_checkpoints``) was counted as a failed model
    with an empty category and id; ``render`` skips hidden folders, and so does the import now."""
    renderings, voxels, _ = fake_r2n2
    copy = shutil.copytree(renderings, tmp_path / "ShapeNetRendering")
    synset = sorted(p for p in copy.iterdir() if p.is_dir())[0]
    (synset / ".ipynb_checkpoints").mkdir()
    out = tmp_path / "out"
    res = run_cli(data_main, ["import-r2n2", "--renderings", copy, "--voxels", voxels, "--out", out, "--no-progress"])
    assert "imported 3 of 3 models" in res.output and index_of(out)["failures"] == [], res.output


def test_info_says_which_command_makes_a_broken_shard_again(tmp_path):
    """``info --verify`` told the user of a merged dataset to "rerun the render command", which a
    merged folder refuses; it names the command that made the dataset."""
    meshes = _two_chairs(tmp_path)
    parts = [tmp_path / f"p{i}" for i in range(2)]
    for i, part in enumerate(parts):
        run_cli(data_main, ["render", "--meshes", meshes, "--out", part, "--part", f"{i}/2", *FAST])
    merged = tmp_path / "merged"
    run_cli(data_main, ["merge", merged, *parts, "--copy"])
    flip_bytes_in_a_chunk(next(merged.glob("shard-*.h5")))
    res = run_cli(data_main, ["info", merged, "--verify"], expect_exit=1)
    assert "(rerun the merge command (same parts) to make them again)" in res.output, res.output
    run_cli(data_main, ["merge", merged, *parts, "--copy"])
    run_cli(data_main, ["info", merged, "--verify"])


def test_voxelize_meshes_redoes_a_binvox_cut_short(tmp_path):
    """A rerun of ``voxelize --meshes`` kept a ``.binvox`` cut to 100 bytes (its header intact)
    as "already there"; ``read_binvox`` then failed on it. A file whose voxels do not decode to
    the whole grid is done again."""
    from sc3d_data.io.binvox import read_binvox

    out = tmp_path / "vox"
    args = ["voxelize", "--meshes", SAMPLE_MESHES / "table", "--out", out, "--no-progress"]
    run_cli(data_main, args)
    target = next(out.rglob("*.binvox"))
    whole = target.read_bytes()
    target.write_bytes(whole[:100])
    with pytest.raises(ValueError):
        read_binvox(target)
    res = run_cli(data_main, args)
    assert "wrote 1 .binvox files" in res.output, res.output
    assert target.read_bytes() == whole


def test_import_r2n2_rerun_imports_a_model_whose_files_came_back(fake_r2n2, tmp_path):
    """A model that failed for a missing PNG (an incomplete extraction) stayed out on the rerun
    after the file was restored, and ``info`` still said the file was missing. The rerun tries the
    failures again, as ``render`` does."""
    renderings, voxels, _ = fake_r2n2
    copy = shutil.copytree(renderings, tmp_path / "ShapeNetRendering")
    png = sorted(copy.glob("*/*/rendering/05.png"))[0]
    png.rename(tmp_path / "05.png")
    out = tmp_path / "out"
    args = ["import-r2n2", "--renderings", copy, "--voxels", voxels, "--out", out, "--no-progress"]
    assert "imported 2 of 3 models" in run_cli(data_main, args).output
    (tmp_path / "05.png").rename(png)
    res = run_cli(data_main, args)
    assert "imported 1 of 3 models" in res.output and index_of(out)["failures"] == [], res.output
    assert len(index_of(out)["objects"]) == 3
