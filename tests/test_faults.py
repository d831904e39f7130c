"""Fault injection, one regression test per defect D1-D11 of issue 11 (the larger study is
``benchmarks/faults.py``). Real renderer, real HDF5, real worker processes, real ENOSPC (a
tmpfs in a user+mount namespace; skipped where the kernel does not allow one).

Every failure must name the file and the reason in one line; nothing may be lost; nothing from
a checkpoint or an index may run or reach outside its folder."""
from __future__ import annotations

import json
import os
import pickle
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

from sc3d_cli.data import main as data_main
from conftest import REPO, SAMPLE_MESHES, run_cli, error_lines

FAST = ["--views", "4", "--no-progress", "--workers", "1"]
CUBE_V = [[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)]
CUBE_F = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
          [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]


def obj_text(vertices, faces, header: str = "") -> str:
    lines = [header] if header else []
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in vertices]
    lines += ["f " + " ".join(str(i + 1) for i in f) for f in faces]
    return "\n".join(lines) + "\n"


def by_source(entries: list[dict]) -> dict[str, dict]:
    return {Path(e["source"]).name: e for e in entries}


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    """Good meshes beside one bad input per mesh-level defect (D1-D4)."""
    root = tmp_path_factory.mktemp("corpus")
    d = root / "meshes" / "chair"
    d.mkdir(parents=True)
    (d / "cube.obj").write_text(obj_text(CUBE_V, CUBE_F))
    # D1: far beyond float32, and one outlier at 1e9 that collapses the cube below a pixel
    (d / "huge.obj").write_text("v 1e300 0 0\nv 0 1e300 0\nv 0 0 1e300\nv 0 0 0\n"
                                "f 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    (d / "outlier.obj").write_text(obj_text(CUBE_V + [[1e9, 0, 0]], CUBE_F + [[0, 1, 8]]))
    # D2: a valid OBJ with a Latin-1 comment; random bytes named like meshes
    (d / "latin1.obj").write_bytes("# chaise en rotin, fa\xe7on caf\xe9\n".encode("latin-1")
                                   + obj_text(CUBE_V, CUBE_F).encode())
    rng = np.random.default_rng(11)
    for ext in ("off", "stl", "ply"):
        (d / f"random_{ext}.{ext}").write_bytes(rng.integers(0, 256, 2000, dtype=np.uint8).tobytes())
    # D3: missing .mtl; a texture read by absolute path from outside the dataset folder
    (d / "no_mtl.obj").write_text(obj_text(CUBE_V, CUBE_F, "mtllib gone.mtl\nusemtl m"))
    outside = root / "elsewhere"
    outside.mkdir()
    from PIL import Image

    Image.new("RGB", (8, 8), (200, 30, 30)).save(outside / "secret.png")
    (d / "abs_tex.mtl").write_text(f"newmtl m\nKd 1 1 1\nmap_Kd {outside / 'secret.png'}\n")
    (d / "abs_tex.obj").write_text(obj_text(CUBE_V, CUBE_F, "mtllib abs_tex.mtl\nusemtl m"))
    # D4: a folder named like a mesh
    (d / "folder.obj").mkdir()
    return root / "meshes"


@pytest.fixture(scope="module")
def corpus_run(corpus, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("corpus_out") / "out"
    res = run_cli(data_main, ["render", "--meshes", corpus, "--out", out, "--voxelize", *FAST])
    assert "Traceback" not in res.output
    return out


def index_of(out: Path) -> dict:
    return json.loads((out / "index.json").read_text())


# ----------------------------------------------------------------------------- D1
def test_d1_nonfinite_or_outlier_geometry_is_a_failure_not_a_blank_object(corpus_run):
    index = index_of(corpus_run)
    failed, done = by_source(index["failures"]), by_source(index["objects"])
    assert "huge.obj" in failed and "float32" in failed["huge.obj"]["reason"]
    assert "outlier.obj" in failed and "silhouette is empty" in failed["outlier.obj"]["reason"]
    assert "huge.obj" not in done and "outlier.obj" not in done
    # every object counted as done has a visible silhouette in every view (not an empty render)
    with h5py.File(corpus_run / "shard-00000.h5") as f:
        assert (f["masks"][()].sum(axis=(2, 3)) > 0).all()
        # the unit cube fills [-0.5, 0.5]^3 after normalisation: all 32^3 voxels solid
        row = [s.decode() for s in f["source"][()]].index(str(Path(done["cube.obj"]["source"])))
        assert int(f["voxels"][row].sum()) == 32 ** 3


# ----------------------------------------------------------------------------- D2
def test_d2_non_utf8_obj_renders_and_garbage_gets_a_clear_reason(corpus_run):
    index = index_of(corpus_run)
    assert "latin1.obj" in by_source(index["objects"])
    failed = by_source(index["failures"])
    for ext in ("off", "stl", "ply"):
        reason = failed[f"random_{ext}.{ext}"]["reason"]
        assert f"random_{ext}.{ext}: " in reason and "ModuleNotFoundError" not in reason


# ----------------------------------------------------------------------------- D3
def test_d3_missing_mtl_and_outside_texture_are_warned_and_can_be_refused(corpus_run, corpus):
    warnings = [w["warning"] for w in index_of(corpus_run)["warnings"]]
    assert any("no_mtl.obj" in w and "gone.mtl not found" in w for w in warnings)
    assert any("abs_tex.obj" in w and "secret.png" in w and "outside the dataset folder" in w
               for w in warnings)
    assert not any("cube.obj" in w for w in warnings)
    from sc3d_data.io.meshes import MeshError, load_mesh

    with pytest.raises(MeshError, match="abs_tex.obj: .*secret.png.*refused by --outside-textures refuse"):
        load_mesh(corpus / "chair" / "abs_tex.obj", root=corpus, outside_textures="refuse")
    load_mesh(corpus / "chair" / "cube.obj", root=corpus, outside_textures="refuse")


# ----------------------------------------------------------------------------- D4
def test_d4_folder_named_like_a_mesh_is_listed_as_skipped(corpus_run):
    skipped = by_source(index_of(corpus_run)["skipped"])
    assert "folder named like a mesh" in skipped["folder.obj"]["reason"]
    report = run_cli(data_main, ["info", corpus_run]).output
    assert "folder.obj: a folder named like a mesh file" in report


# ----------------------------------------------------------------------------- D5
def test_d5_failures_are_retried_on_rerun_and_the_shard_is_rewritten_in_plan_order(tmp_path):
    d = tmp_path / "m" / "chair"
    d.mkdir(parents=True)
    (d / "a.obj").write_text(obj_text(CUBE_V, CUBE_F))
    (d / "b.obj").write_text("not a mesh\n")        # fails now; fixed below
    (d / "c.obj").write_text(obj_text([[0, 0, 0], [2, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]))
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--split", "random:1,0,0", *FAST])
    assert by_source(index_of(out)["failures"])["b.obj"]["attempts"] == 1
    # rerun without retry keeps the failure as it is
    res = run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--split", "random:1,0,0",
                              "--no-retry-failed", *FAST])
    assert "done 0, resumed 2, skipped 0, failed 1" in res.output and by_source(index_of(out)["failures"])["b.obj"]["attempts"] == 1
    # still broken: retried once more, attempts counted, shard left as it was
    res = run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--split", "random:1,0,0", *FAST])
    assert "retried 1" in res.output and by_source(index_of(out)["failures"])["b.obj"]["attempts"] == 2
    # fixed (as after an OOM kill): the rerun renders it and rewrites the shard a, b, c
    (d / "b.obj").write_text(obj_text(CUBE_V, CUBE_F))
    res = run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--split", "random:1,0,0", *FAST])
    assert "done 1, resumed 2, retried 1" in res.output
    index = index_of(out)
    assert index["failures"] == [] and index["complete"]
    assert [Path(o["source"]).name for o in index["objects"]] == ["a.obj", "b.obj", "c.obj"]
    assert [o["row"] for o in index["objects"]] == [0, 1, 2]
    with h5py.File(out / "shard-00000.h5") as f:
        assert [Path(s.decode()).name for s in f["source"][()]] == ["a.obj", "b.obj", "c.obj"]
    assert run_cli(data_main, ["info", out, "--verify"]).exit_code == 0


def test_d5_a_killed_worker_costs_one_attempt_not_the_object(tmp_path):
    """A per-object time limit kills the worker with SIGKILL (the OOM killer's signal); the
    object is failed with the reason, and the next run renders it."""
    d = tmp_path / "m" / "chair"
    d.mkdir(parents=True)
    shutil.copy(SAMPLE_MESHES / "chair" / "chair2_blendswap.glb", d)
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, "--timeout", "0.001",
                        *FAST], expect_exit=1)
    (failure,) = index_of(out)["failures"]
    assert "chair2_blendswap.glb: timed out" in failure["reason"]
    res = run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", out, *FAST])
    assert "done 1, resumed 0, retried 1" in res.output and index_of(out)["counts"]["total"] == 1


# ----------------------------------------------------------------------------- D6
def _flip_byte_in_chunk(path: Path, dataset: str, row: int) -> None:
    with h5py.File(path) as f:
        info = f[dataset].id.get_chunk_info(row)
    with open(path, "r+b") as fh:
        fh.seek(info.byte_offset + info.size // 2)
        b = fh.read(1)
        fh.seek(-1, 1)
        fh.write(bytes([b[0] ^ 0xFF]))


def test_d6_truncated_or_flipped_shards_are_detected_named_and_re_rendered(corpus_run, tmp_path):
    from sc3d_data.io.shards import ShardError
    from sc3d_data.io.shard_reader import iter_objects
    from sc3d_train.data.dataset import DataError, scan_objects

    out = tmp_path / "out"
    shutil.copytree(corpus_run, out)
    shard = out / "shard-00000.h5"
    original = shard.read_bytes()
    n_objects = index_of(out)["counts"]["total"]
    # flipped bytes in image data: info --verify, check and reading the object all name the file
    _flip_byte_in_chunk(shard, "images", 0)
    assert run_cli(data_main, ["info", out]).exit_code == 0          # size unchanged: cheap check passes
    res = run_cli(data_main, ["info", out, "--verify"], expect_exit=1)
    assert f"{shard}: SHA-256 differs" in res.output
    res = run_cli(data_main, ["check", out, "--no-progress"], expect_exit=1)
    assert f"Error: {shard}: SHA-256 differs" in res.output and "Traceback" not in res.output
    with pytest.raises(ShardError, match="shard-00000.h5: row 0 cannot be read"):
        list(iter_objects(out, fields=("images",)))                   # HDF5 Fletcher-32 per chunk
    # truncated: even plain info notices; training names the file
    shard.write_bytes(original[:len(original) // 2])
    res = run_cli(data_main, ["info", out], expect_exit=1)
    assert f"{shard}: {len(original) // 2} bytes, the index says {len(original)}" in res.output
    with pytest.raises(DataError, match="shard-00000.h5: cannot open shard .*info --verify"):
        scan_objects(out)
    # a render rerun re-renders the broken shard instead of resuming it
    res = run_cli(data_main, ["render", "--meshes", index_of(out)["settings"]["meshes"], "--out", out,
                              "--voxelize", *FAST])
    assert "shard-00000.h5" in res.output and "rendering its objects again" in res.output
    assert index_of(out)["counts"]["total"] == n_objects
    assert run_cli(data_main, ["info", out, "--verify"]).exit_code == 0


# ----------------------------------------------------------------------------- D7
def test_d7_bad_option_values_get_one_line_naming_the_option(tmp_path, corpus):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    empty = tmp_path / "empty"
    empty.mkdir()
    cases = [(["--meshes", corpus, "--out", a_file], f"--out {a_file}: exists and is not a folder"),
             (["--meshes", corpus, "--out", tmp_path / "o1", "--image-size", "100000"], "--image-size 100000"),
             (["--meshes", corpus, "--out", tmp_path / "o2", "--voxel-resolution", "100000"], "--voxel-resolution"),
             (["--meshes", empty, "--out", tmp_path / "o3"], f"--meshes {empty}: no mesh files found")]
    for args, expected in cases:
        res = run_cli(data_main, ["render", *args, *FAST], expect_exit=None)
        assert res.exit_code != 0 and expected in res.output, res.output
        assert "Traceback" not in res.output and sum(ln.startswith("Error") for ln in res.output.splitlines()) == 1
    assert not (tmp_path / "o1" / "index.json").exists()


# ----------------------------------------------------------------------------- D8
def _in_tmpfs(script: str, size: str) -> subprocess.CompletedProcess:
    """Run a bash ``script`` with ``$T`` a fresh tmpfs of ``size`` (user + mount namespace)."""
    if shutil.which("unshare") is None:
        pytest.skip("no unshare(1)")
    probe = subprocess.run(["unshare", "-rm", "sh", "-c", "mount -t tmpfs -o size=1m tmpfs /mnt"],
                           capture_output=True)
    if probe.returncode != 0:
        pytest.skip("this kernel does not allow a tmpfs in a user namespace")
    env = dict(os.environ, PYTHONPATH=f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    full = f"set -u; T=$(mktemp -d); mount -t tmpfs -o size={size} tmpfs $T; cd {REPO}\n{script}"
    return subprocess.run(["unshare", "-rm", "bash", "-c", full], stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, env=env, timeout=240)


def test_d8_render_on_a_full_disk_fails_in_one_line_and_resumes(tmp_path):
    d = tmp_path / "m" / "chair"
    d.mkdir(parents=True)
    for name in ("chair2_blendswap.glb", "dining_chair_katorlegaz.glb", "rattan_armchair_scopia.glb"):
        shutil.copy(SAMPLE_MESHES / "chair" / name, d)
    cmd = (f"{sys.executable} -c 'import sc3d_cli.data as d; d.main()' render --meshes {tmp_path / 'm'} --out $T/out "
           "--objects-per-shard 1 --views 4 --no-progress --workers 1 --split random:1,0,0")
    r = _in_tmpfs(textwrap.dedent(f"""
        {cmd}; echo "rc=$?"
        echo "tmp_left=$(ls $T/out | grep -c '\\.tmp$')"
        mount -o remount,size=20m $T
        {cmd}; echo "rc2=$?"
        {sys.executable} -c 'import sc3d_cli.data as d; d.main()' info --verify $T/out > /dev/null; echo "verify=$?"
        """), size="100k")  # a shard of 4 views is ~47 kB: the second or third does not fit
    out = r.stdout
    first = out.split("rc=")[0]
    assert "rc=1\n" in out and "No space left on device" in first, out
    assert "Traceback" not in out and "Segmentation" not in out
    assert len(error_lines(first)) == 1
    assert "tmp_left=0" in out and "rc2=0" in out and "verify=0" in out, out
    second = out.split("tmp_left=0")[1]
    assert "resumed 0" not in second and "failed 0" in second  # shards written before the disk filled are kept


def test_d8_checkpoint_on_a_full_disk_removes_its_temp_and_resume_finds_the_newest(tmp_path):
    script = textwrap.dedent(f"""
        {sys.executable} - <<'EOF'
        import os, torch
        from pathlib import Path
        from sc3d_train.loop.checkpoint import CheckpointError, save_checkpoint
        from sc3d_train.loop.checkpoint_resume import resume_checkpoint
        run = Path(os.environ["T"]) / "run"
        def payload(step, mb):
            return {{"model": {{"w": torch.ones(mb * 2**18)}}, "config": {{}}, "step": step, "optimizer": {{}},
                    "rng": [], "data_position": {{}}}}
        save_checkpoint(run, payload(1, 1))          # step_000001.pt + last.pt: 2 MiB of 3
        try:
            save_checkpoint(run, payload(2, 1))      # step_000002.pt fits, last.pt copy does not
        except CheckpointError as e:
            print("error:", e)
        print("files:", sorted(p.name for p in (run / "checkpoints").iterdir()))
        path, ckpt = resume_checkpoint(run)
        print("resume:", path.name, ckpt["step"])
        try:
            save_checkpoint(run, payload(3, 1))      # the step file itself does not fit
        except CheckpointError as e:
            print("error 3:", e)
        print("files 3:", sorted(p.name for p in (run / "checkpoints").iterdir()))
        EOF
        """)
    r = _in_tmpfs(f"export T\n{script}", size="3200k")
    assert "No space left on device" in r.stdout and "step_000002.pt is complete" in r.stdout, r.stdout
    assert "files: ['last.pt', 'step_000001.pt', 'step_000002.pt']" in r.stdout
    assert "resume: step_000002.pt 2" in r.stdout
    # torch.save's own message for a failed write is "unexpected pos 704 vs 598": the write's error is named
    assert "step_000003.pt: cannot write checkpoint (No space left on device); free space and rerun with --resume" \
        in r.stdout, r.stdout
    assert "files 3: ['last.pt', 'step_000001.pt', 'step_000002.pt']" in r.stdout


# ----------------------------------------------------------------------------- D9
def test_d9_a_second_writer_is_refused_and_the_first_unaffected(tmp_path, corpus):
    out = tmp_path / "out"
    out.mkdir()
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys; from sc3d_data.io.outlock import exclusive_lock\n"
         f"with exclusive_lock({str(out)!r}):\n print('locked', flush=True); sys.stdin.read()"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
        env=dict(os.environ, PYTHONPATH=str(REPO)))
    try:
        assert holder.stdout.readline().strip() == "locked"
        for cmd in (["render", "--meshes", corpus, "--out", out, *FAST], ["voxelize", out, "--no-progress"]):
            res = run_cli(data_main, cmd, expect_exit=1)
            assert f"{out}: another process (PID {holder.pid}: " in res.output and "is writing to this folder" in res.output
        assert sorted(p.name for p in out.iterdir()) == [".sc3d.lock"]
    finally:
        holder.kill()  # SIGKILL: the kernel drops the lock, a stale lock file blocks nothing
        holder.wait()
    run_cli(data_main, ["render", "--meshes", corpus, "--out", out, *FAST])
    assert index_of(out)["complete"]


# ----------------------------------------------------------------------------- D10
class _Payload:
    """A pickle that would create a file when unpickled without weights_only."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (Path(self.marker),))


def test_d10_a_crafted_checkpoint_runs_nothing_and_a_real_one_loads(tmp_path, corpus_run):
    import torch

    from sc3d_cli.train import main as train_main
    from sc3d_train.loop.checkpoint import CheckpointError, load_checkpoint, rng_state, save_checkpoint
    from sc3d_train.loop.checkpoint_resume import resume_checkpoint

    marker = tmp_path / "pwned"
    evil = tmp_path / "evil.pt"
    torch.save({"model": {}, "config": {}, "x": _Payload(str(marker))}, evil)
    # control: the payload really runs when unpickled the unsafe way
    pickle.loads(pickle.dumps(_Payload(str(tmp_path / "control"))))
    assert (tmp_path / "control").exists()
    from PIL import Image

    Image.new("RGB", (64, 64), (255, 255, 255)).save(tmp_path / "view.png")
    for cmd in (["eval", "--checkpoint", evil, "--shards", corpus_run, "--out", tmp_path / "ev"],
                ["predict", "--checkpoint", evil, tmp_path / "view.png", "--out", tmp_path / "pr"]):
        res = run_cli(train_main, cmd, expect_exit=1)
        assert f"{evil}: refused" in res.output and "Traceback" not in res.output
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    shutil.copy(evil, run / "checkpoints" / "last.pt")
    with pytest.raises(CheckpointError, match="last.pt: refused"):
        resume_checkpoint(run)  # what `fit --resume` loads
    assert not marker.exists()
    # a checkpoint with every type sc3d-train stores (numpy and python RNG states, optimiser) loads
    net = torch.nn.Linear(3, 2)
    opt = torch.optim.Adam(net.parameters())
    net(torch.ones(1, 3)).sum().backward()
    opt.step()
    np.random.seed(5)
    state = rng_state()
    path = save_checkpoint(tmp_path / "good", {"model": net.state_dict(), "optimizer": opt.state_dict(),
                                               "scaler": None, "rng": [state], "step": 3, "config": {"a": 1},
                                               "data_position": {"phase": "supervised"}})
    ckpt = load_checkpoint(path)
    assert ckpt["step"] == 3 and np.array_equal(ckpt["rng"][0]["numpy"][1], state["numpy"][1])
    assert ckpt["rng"][0]["python"] == state["python"]


# ----------------------------------------------------------------------------- D11
def test_d11_index_paths_outside_the_dataset_are_refused(tmp_path, corpus_run):
    from sc3d_train.data.dataset import scan_objects

    victim_dir = tmp_path / "victim"
    victim_dir.mkdir()
    out = tmp_path / "out"
    shutil.copytree(corpus_run, out)
    shutil.copy(out / "shard-00000.h5", victim_dir / "shard-00000.h5")
    victim_bytes = (victim_dir / "shard-00000.h5").read_bytes()
    index = index_of(out)
    index["shards"][0]["file"] = "../victim/shard-00000.h5"
    (out / "index.json").write_text(json.dumps(index))
    res = run_cli(data_main, ["voxelize", out, "--overwrite", "--no-progress"], expect_exit=1)
    assert "'../victim/shard-00000.h5' is not a plain file name inside the dataset folder" in res.output
    assert run_cli(data_main, ["info", out, "--verify"], expect_exit=1).exit_code == 1
    with pytest.raises(ValueError, match="not a plain file name"):
        scan_objects(out)
    # a symlink inside the folder that leads out is refused too
    index["shards"][0]["file"] = "shard-00000.h5"
    (out / "index.json").write_text(json.dumps(index))
    (out / "shard-00000.h5").unlink()
    (out / "shard-00000.h5").symlink_to(victim_dir / "shard-00000.h5")
    res = run_cli(data_main, ["voxelize", out, "--overwrite", "--no-progress"], expect_exit=1)
    assert "leads outside the dataset folder" in res.output
    assert (victim_dir / "shard-00000.h5").read_bytes() == victim_bytes
