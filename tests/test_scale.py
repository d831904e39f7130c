"""Issue 13: partition (--part I/N), merge, and the Ray / SLURM (submitit local) executors, with
the real renderer, real HDF5, a real local Ray cluster and submitit's real LocalExecutor, for
`render`, `voxelize --meshes` and `import-r2n2`.

The reference of every equality test is an ordinary local run (`sc3d-data render`, local
pool) of the same meshes with the same settings; "equal" means: the same object ids, each
once, with identical arrays (images, masks, cameras, voxels, ...) and strings, and identical
shard settings attributes."""
from __future__ import annotations

import json
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from sc3d_cli.data import main
from conftest import SAMPLE_MESHES, assert_same_dataset, objects_by_id, run_cli, write_hanging_gltf
from sc3d_data.pipeline.run.partition import Part, parse_part, part_from_env, part_of

SETTINGS = ["--views", "4", "--voxelize", "--objects-per-shard", "2", "--no-progress"]


@pytest.fixture(scope="module")
def local_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("scale") / "local"
    run_cli(main, ["render", "--meshes", SAMPLE_MESHES, "--out", out, "--workers", "2", *SETTINGS])
    return out


def part_config(out: Path, part: Part):
    """``render --meshes SAMPLE_MESHES *SETTINGS --part I/N --out OUT`` as a library config."""
    from sc3d_data.pipeline.jobs.render_job import RenderConfig

    return RenderConfig(out=out, meshes=SAMPLE_MESHES, num_views=4, voxelize=True, objects_per_shard=2,
                        progress=False, part=part)


@pytest.fixture(scope="module")
def pool():
    """One local pool (2 workers) shared by the part runs of this module (``render_dataset(...,
    executor=pool)``: the parts differ only in their objects, the workers are reused)."""
    from sc3d_data.pipeline.executors.local_pool import start_pool
    from sc3d_data.pipeline.jobs.render_job import RENDER

    p = start_pool(2, part_config(Path("unused"), Part(0, 1)), RENDER)
    yield p
    p.close()


def render_parts(root: Path, n: int, pool) -> list[Path]:
    from sc3d_data.pipeline.jobs.render_run import render_dataset

    parts = [root / f"p{i}" for i in range(n)]
    for i, out in enumerate(parts):
        assert render_dataset(part_config(out, Part(i, n)), executor=pool)["failed"] == 0
    return parts


# ----------------------------------------------------------------------------- partition
def test_partition_rule_is_the_id_hash_not_the_order():
    # expected parts from `printf chair/abc | sha256sum` (50871c6746338957...) and
    # `printf airplane/x1 | sha256sum` (753d9a691c1b9834...), first 64 bits mod N by hand
    assert part_of("chair", "abc", 7) == 1 and part_of("chair", "abc", 3) == 1
    assert part_of("airplane", "x1", 7) == 4 and part_of("airplane", "x1", 3) == 0
    ids = [("c%d" % (i % 5), "m%04d" % i) for i in range(500)]
    for n in (1, 2, 3, 7):
        parts = [part_of(c, m, n) for c, m in ids]
        assert sorted(set(parts)) == list(range(n))                      # every part used
        assert all(0 <= p < n for p in parts)
        # another order of the collection, or more objects, leave every object where it was
        assert [part_of(c, m, n) for c, m in reversed(ids)] == parts[::-1]
    assert parse_part("2/7") == Part(2, 7)
    for bad in ("7/7", "-1/3", "3", "a/b"):
        with pytest.raises(ValueError, match="--part"):
            parse_part(bad)
    env = {"SLURM_ARRAY_TASK_ID": "5", "SLURM_ARRAY_TASK_MIN": "1", "SLURM_ARRAY_TASK_COUNT": "8"}
    assert part_from_env(env) == Part(4, 8) and part_from_env({}) is None


@pytest.mark.parametrize("n", [1, 2, 3, 7])
def test_n_parts_plus_merge_equal_one_local_run(local_run, pool, tmp_path, n):
    parts = render_parts(tmp_path, n, pool)
    ids = [{(o["category"], o["model_id"]) for o in json.loads((p / "index.json").read_text())["objects"]}
           for p in parts]
    assert sum(map(len, ids)) == 11 and len(set().union(*ids)) == 11      # each object in one part
    res = run_cli(main, ["merge", tmp_path / "merged", *parts[::-1]])     # any order of the folders
    assert f"merged {n} parts" in res.output and "11 objects" in res.output
    assert_same_dataset(tmp_path / "merged", local_run)
    assert not any((tmp_path / "merged" / f).is_symlink() for f in os.listdir(tmp_path / "merged"))


def test_merged_dataset_is_read_by_every_command_and_merge_resumes(local_run, pool, tmp_path):
    p0, p1 = render_parts(tmp_path, 2, pool)
    m = tmp_path / "m"
    res = run_cli(main, ["merge", m, p0, p1])
    n = len(list(m.glob("shard-*.h5")))
    assert f"({n} linked, 0 copied, 0 already there)" in res.output
    (m / "shard-00000.h5").unlink()                 # an interrupted merge: one shard placed, no index
    (m / "index.json").unlink()
    res = run_cli(main, ["merge", m, p0, p1])
    assert f"(1 linked, 0 copied, {n - 1} already there)" in res.output
    assert_same_dataset(m, local_run)
    shutil.rmtree(p0)                               # the merged folder holds its own files
    shutil.rmtree(p1)
    assert "objects: 11 in" in run_cli(main, ["info", m, "--verify"]).output
    run_cli(main, ["check", "--shards", m, "--no-progress", "--json", tmp_path / "check.json"])
    run_cli(main, ["preview", m, "--out", tmp_path / "sheet.png"])
    assert (tmp_path / "sheet.png").stat().st_size > 1000
    from sc3d_cli.train import main as train

    run_cli(train, ["fit", "--shards", m, "--out", tmp_path / "run", "--steps", 2, "--batch-size", 4, "--tiny",
                    "--base-channels", 4, "--no-progress"])
    # rendering into a merged folder is refused (its chunks are not a plan's)
    res = run_cli(main, ["render", "--meshes", SAMPLE_MESHES, "--out", m, *SETTINGS], expect_exit=1)
    assert "merged dataset" in res.output


def test_merge_refuses_missing_unfinished_foreign_and_duplicate_parts(tmp_path):
    meshes = tmp_path / "meshes" / "chair"
    meshes.mkdir(parents=True)
    for f in sorted((SAMPLE_MESHES / "chair").glob("*.glb"))[:3] + sorted((SAMPLE_MESHES / "airplane").glob("*.glb"))[:2]:
        shutil.copy(f, meshes / f.name)
    common = ["--meshes", tmp_path / "meshes", "--views", "2", "--no-progress", "--workers", "1", "--split", "random:1,0,0"]
    p = [tmp_path / f"p{i}" for i in range(3)]
    for i in range(3):
        run_cli(main, ["render", "--out", p[i], "--part", f"{i}/3", *common])

    def refused(*parts) -> str:
        res = run_cli(main, ["merge", tmp_path / "m", *parts], expect_exit=1)
        assert "Traceback" not in res.output and len(res.output.strip().splitlines()) == 1
        return res.output

    assert "missing part(s) 2/3" in refused(p[0], p[1])
    assert "given twice" in refused(p[0], p[1], p[1], p[2])
    other = tmp_path / "other"
    run_cli(main, ["render", "--out", other, "--part", "2/3", "--image-size", "32", *common])
    assert "made with other settings than" in (msg := refused(p[0], p[1], other)) and "(image_size differ)" in msg
    two = tmp_path / "two"
    run_cli(main, ["render", "--out", two, "--part", "1/2", *common])
    assert "another plan" in refused(p[0], p[1], two)
    # an unfinished part (killed mid-run): its index is not complete
    idx = json.loads((p[2] / "index.json").read_text())
    broken = tmp_path / "unfinished"
    shutil.copytree(p[2], broken)
    (broken / "index.json").write_text(json.dumps(dict(idx, complete=False)))
    assert "not finished" in refused(p[0], p[1], broken)
    # an object listed by two parts
    i0 = json.loads((p[0] / "index.json").read_text())
    dup = tmp_path / "dup"
    shutil.copytree(p[1], dup)
    i1 = json.loads((dup / "index.json").read_text())
    # at a row of its own: the index's own lists agree (else it is refused as malformed first)
    i1["objects"].append(dict(i0["objects"][0], shard=i1["shards"][0]["file"], row=i1["shards"][0]["objects"]))
    i1["part"]["assigned"] += 1
    i1["shards"][0]["objects"] += 1
    (dup / "index.json").write_text(json.dumps(i1))
    assert "duplicate" in refused(p[0], dup, p[2])
    # a part into the folder of another part is refused at render time
    res = run_cli(main, ["render", "--out", p[0], "--part", "1/3", *common], expect_exit=1)
    assert "holds part 0/3" in res.output
    assert not (tmp_path / "m" / "index.json").exists()
    run_cli(main, ["merge", tmp_path / "m", *p])


def test_slurm_env_sets_the_part(tmp_path):
    from click.testing import CliRunner

    env = {"SLURM_ARRAY_TASK_ID": "3", "SLURM_ARRAY_TASK_MIN": "1", "SLURM_ARRAY_TASK_COUNT": "3"}
    res = CliRunner(env=env).invoke(main, ["render", "--meshes", SAMPLE_MESHES / "car", "--out", tmp_path / "o",
                                           "--category", "car", "--views", "2", "--no-progress", "--workers", "1"])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "o" / "index.json").read_text())["part"]["index"] == 2
    assert res.output.startswith("part 2/3, ")


# ----------------------------------------------------------------------------- SLURM
def test_slurm_array_through_submitit_local_equals_local_run_and_reruns(local_run, tmp_path):
    args = ["render", "--meshes", SAMPLE_MESHES, "--out", tmp_path / "out", "--executor", "slurm",
            "--slurm-cluster", "local", "--slurm-parts", "3", "--slurm-cpus-per-task", "1", *SETTINGS]
    res = run_cli(main, args)
    assert "3/3 parts finished" in res.output and "done 11" in res.output
    assert_same_dataset(tmp_path / "out", local_run)
    assert sorted(os.listdir(tmp_path / "out" / "parts"))[:3] == ["part-000-of-003", "part-001-of-003",
                                                                  "part-002-of-003"]
    res = run_cli(main, args)                          # a rerun: every part resumes, nothing redone
    assert "done 0, resumed 11" in res.output


@pytest.mark.skipif(shutil.which("srun") is not None, reason="a real SLURM cluster is here")
def test_slurm_without_a_cluster_is_refused_not_run_locally(tmp_path):
    res = run_cli(main, ["render", "--meshes", SAMPLE_MESHES / "car", "--out", tmp_path / "o", "--executor", "slurm",
                         "--no-progress"], expect_exit=1)
    assert "srun" in res.output and "--slurm-cluster local" in res.output and len(res.output.splitlines()) == 1
    assert not (tmp_path / "o" / "index.json").exists()


# ----------------------------------------------------------------------------- Ray
@pytest.fixture(scope="module")
def ray_cluster():
    """A local Ray cluster of 2 CPUs; its workers get the test-only crash hook for the model id
    ``crash_me`` (no other test mesh has that id)."""
    from sc3d_data.pipeline.executors.ray_executor import init_local
    from sc3d_data.pipeline.executors.job import CRASH_ENV

    os.environ[CRASH_ENV] = "crash_me"
    try:
        ray = init_local(2)
        yield ray
        ray.shutdown()
    finally:
        del os.environ[CRASH_ENV]


def test_ray_equals_local_run(ray_cluster, local_run, tmp_path):
    res = run_cli(main, ["render", "--meshes", SAMPLE_MESHES, "--out", tmp_path / "ray", "--executor", "ray", *SETTINGS])
    assert "done 11" in res.output and "failed 0" in res.output
    assert_same_dataset(tmp_path / "ray", local_run)
    # same plan, same chunks: even the shard layout is the local run's
    names = lambda d: sorted(p.name for p in d.glob("shard-*.h5"))  # noqa: E731
    assert names(tmp_path / "ray") == names(local_run)


def _kill_first_render_task(killed: list, stop: threading.Event) -> None:
    """SIGKILL the first Ray worker seen running render_task (as the OOM killer would)."""
    import psutil

    while not stop.is_set() and not killed:
        for proc in psutil.process_iter(["pid", "cmdline"]):
            cmd = " ".join(proc.info["cmdline"] or [])
            if cmd.startswith("ray::job_task_split"):
                try:
                    os.kill(proc.info["pid"], signal.SIGKILL)
                    killed.append(proc.info["pid"])
                except ProcessLookupError:
                    continue
                return
        time.sleep(0.01)


def test_ray_killed_worker_is_retried_and_a_hung_mesh_is_timed_out(ray_cluster, local_run, tmp_path):
    """13 objects: the 11 samples, a glTF whose buffer is a FIFO nobody writes to (the loader
    blocks forever) and a cube whose worker dies every time (test-only hook, as a mesh that
    crashes the GL driver): 15 % of the run hangs or crashes. On top, one worker is SIGKILLed
    from outside while rendering (as the OOM killer would): Ray runs that object again."""
    meshes = tmp_path / "meshes"
    shutil.copytree(SAMPLE_MESHES, meshes)
    cube = [[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)]
    faces = [[1, 2, 4], [1, 4, 3], [5, 7, 8], [5, 8, 6], [1, 5, 6], [1, 6, 2], [3, 4, 8], [3, 8, 7], [1, 3, 7],
             [1, 7, 5], [2, 6, 8], [2, 8, 4]]
    (meshes / "chair" / "crash_me.obj").write_text("".join(f"v {x} {y} {z}\n" for x, y, z in cube)
                                                    + "".join(f"f {a} {b} {c}\n" for a, b, c in faces))
    write_hanging_gltf(meshes / "chair")
    killed, stop = [], threading.Event()
    killer = threading.Thread(target=_kill_first_render_task, args=(killed, stop), daemon=True)
    killer.start()
    t0 = time.monotonic()
    try:
        res = run_cli(main, ["render", "--meshes", meshes, "--out", tmp_path / "ray", "--executor", "ray",
                             "--timeout", "15", "--retries", "1", *SETTINGS])  # 15 s: a loaded CI machine
    finally:
        stop.set()
        killer.join()
    assert time.monotonic() - t0 < 90
    assert killed, "no Ray worker was seen rendering"
    index = json.loads((tmp_path / "ray" / "index.json").read_text())
    reasons = {f["model_id"]: f["reason"] for f in index["failures"]}
    assert sorted(reasons) == ["crash_me", "hang"], reasons
    assert "hang.gltf: timed out after 15 s (--timeout)" in reasons["hang"]
    assert "crash_me.obj: render worker died on all 2 attempts" in reasons["crash_me"]
    assert "done 11" in res.output and "failed 2" in res.output
    # nothing lost: the 11 objects are those of the local run (ids, arrays, cameras)
    got, ref = objects_by_id(tmp_path / "ray"), objects_by_id(local_run)
    assert sorted(got) == sorted(ref)
    for key in ref:
        for name in ("images", "masks", "K", "R", "t", "voxels", "to_canonical"):
            np.testing.assert_array_equal(got[key][name], ref[key][name], err_msg=f"{key} {name}")


@pytest.mark.parametrize("engine,args,message", [
    ("submitit", ["--executor", "slurm", "--slurm-cluster", "local"],
     "the SLURM executor needs submitit: pip install 'sc3d[slurm]'"),
    ("ray", ["--executor", "ray"], "the Ray executor needs Ray: pip install 'sc3d[ray]'")])
def test_missing_engine_gives_one_line(tmp_path, monkeypatch, engine, args, message):
    import builtins

    real_import = builtins.__import__

    def without_engine(name, *a, **k):
        if name == engine:
            raise ImportError(f"No module named {engine!r}")
        return real_import(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", without_engine)
    res = run_cli(main, ["render", "--meshes", SAMPLE_MESHES / "car", "--out", tmp_path / "o", *args, "--no-progress"],
                  expect_exit=1)
    assert res.output.strip() == f"Error: {message}"


def test_voxelize_meshes_in_parts_share_one_folder(tmp_path):
    """`voxelize --meshes --part I/2` twice into one folder == one run: same .binvox files."""
    meshes = SAMPLE_MESHES / "chair"
    run_cli(main, ["voxelize", "--meshes", meshes, "--out", tmp_path / "whole", "--resolution", "16", "--no-progress"])
    for i in range(2):
        res = run_cli(main, ["voxelize", "--meshes", meshes, "--out", tmp_path / "parts", "--part", f"{i}/2",
                             "--resolution", "16", "--no-progress"])
        assert "0 failed" in res.output
    whole = sorted(p.relative_to(tmp_path / "whole") for p in (tmp_path / "whole").rglob("*.binvox"))
    parts = sorted(p.relative_to(tmp_path / "parts") for p in (tmp_path / "parts").rglob("*.binvox"))
    assert whole == parts and len(whole) == 4
    for rel in whole:
        assert (tmp_path / "whole" / rel).read_bytes() == (tmp_path / "parts" / rel).read_bytes()
    assert sorted(p.name for p in (tmp_path / "parts").glob("failures*.json")) == [
        "failures.part-000-of-002.json", "failures.part-001-of-002.json"]


# ----------------------------------------------------------------------------- voxelize --meshes, import-r2n2
def _files(folder: Path) -> dict:
    """The files under ``folder`` with their bytes, but the write locks (``.sc3d.lock*``)."""
    return {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*")
            if p.is_file() and not p.name.startswith(".sc3d.lock")}


def test_voxelize_meshes_on_ray_equals_local_file_by_file(ray_cluster, tmp_path):
    """6 sample meshes, an OBJ without triangles and a glTF whose loader blocks forever: Ray
    writes the same .binvox bytes and the same failures.json (the hang timed out) as the local
    pool; a rerun on Ray resumes (keeps the files there, redoes a deleted one and the failures)."""
    meshes = tmp_path / "meshes"
    for cat in ("chair", "car"):
        shutil.copytree(SAMPLE_MESHES / cat, meshes / cat)
    (meshes / "chair" / "broken.obj").write_text("v 0 0 0\nv 1 0 0\n")
    write_hanging_gltf(meshes / "chair")
    common = ["voxelize", "--meshes", meshes, "--resolution", "16", "--timeout", "2", "--workers", "2",
              "--no-progress"]
    for engine in ("local", "ray"):
        res = run_cli(main, [*common, "--out", tmp_path / engine, "--executor", engine])
        assert "wrote 6 .binvox files" in res.output and "(0 already there), 2 failed" in res.output
    assert _files(tmp_path / "ray") == _files(tmp_path / "local") and len(_files(tmp_path / "local")) == 9  # + failures.json, voxelize.json, sources.json
    reasons = {Path(f["source"]).name: f["reason"] for f in json.loads((tmp_path / "ray" / "failures.json").read_text())}
    assert reasons == {"broken.obj": f"MeshError: {meshes / 'chair' / 'broken.obj'}: empty mesh (no triangles)",
                       "hang.gltf": f"{meshes / 'chair' / 'hang.gltf'}: timed out after 2 s (--timeout)"}
    (meshes / "chair" / "hang.gltf").unlink()
    (tmp_path / "ray" / "car" / "jeep_psionic.binvox").unlink()
    res = run_cli(main, [*common, "--out", tmp_path / "ray", "--executor", "ray"])
    assert "wrote 1 .binvox files" in res.output and "(5 already there), 1 failed" in res.output
    assert _files(tmp_path / "ray").keys() == _files(tmp_path / "local").keys()
    for rel, data in _files(tmp_path / "local").items():
        assert rel.name == "failures.json" or _files(tmp_path / "ray")[rel] == data, rel


@pytest.fixture(scope="module")
def r2n2_local(tmp_path_factory):
    """Fake 3D-R2N2 release (tests/r2n2_synth.py: 1 airplane, 2 chairs) plus a chair with a
    rendering missing, and its local import (2 objects per shard): ``(args, local out)``."""
    from test_import_r2n2 import CHAIR, synthesize

    root = tmp_path_factory.mktemp("r2n2")
    renderings, voxels, _ = synthesize(root, seed=3)
    shutil.copytree(renderings / CHAIR / "chair2_blendswap", renderings / CHAIR / "nopng")
    (renderings / CHAIR / "nopng" / "rendering" / "07.png").unlink()
    shutil.copytree(voxels / CHAIR / "chair2_blendswap", voxels / CHAIR / "nopng")
    args = ["import-r2n2", "--renderings", renderings, "--voxels", voxels, "--objects-per-shard", "2",
            "--no-progress"]
    res = run_cli(main, [*args, "--out", root / "local", "--workers", "2"])
    assert "imported 3 of 4 models" in res.output and "1 failed" in res.output
    return args, root / "local"


def _failure_reasons(out: Path) -> dict:
    return {f["model_id"]: f["reason"] for f in json.loads((out / "index.json").read_text())["failures"]}


def test_import_r2n2_on_ray_and_slurm_equals_local_import(ray_cluster, r2n2_local, tmp_path):
    args, local = r2n2_local
    res = run_cli(main, [*args, "--out", tmp_path / "ray", "--executor", "ray"])
    assert "imported 3 of 4 models" in res.output and "1 failed" in res.output
    assert_same_dataset(tmp_path / "ray", local)
    names = lambda d: sorted(p.name for p in d.glob("shard-*.h5"))  # noqa: E731
    assert names(tmp_path / "ray") == names(local)                   # same chunks, plan order
    res = run_cli(main, [*args, "--out", tmp_path / "slurm", "--executor", "slurm", "--slurm-cluster", "local",
                         "--slurm-parts", "2", "--slurm-cpus-per-task", "1"])
    assert "2/2 parts finished" in res.output and "imported 3 of 4 models" in res.output
    assert_same_dataset(tmp_path / "slurm", local)
    reasons = _failure_reasons(local)
    assert list(reasons) == ["nopng"] and "07.png: missing rendering" in reasons["nopng"]
    assert _failure_reasons(tmp_path / "ray") == reasons == _failure_reasons(tmp_path / "slurm")
