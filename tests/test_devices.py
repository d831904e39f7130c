"""``--gpus``: which EGL device each render worker draws on (``sc3d_data/pipeline/executors/devices.py``).

No GPU here: the assignment, the option and its plumbing into the executors are checked, and
with the real renderer that each worker makes its context on the device of its slot (device 0
= Mesa's only device: the same dataset as without the option; a device this machine lacks
stops the run with a line naming it)."""
from __future__ import annotations


import pytest

from conftest import SAMPLE_MESHES, assert_same_dataset, run_cli, error_lines
from sc3d_cli.data import main
from sc3d_data.pipeline.executors.devices import DEVICE_ENV, device_of_slot, parse_gpus, worker_environ


def test_gpus_spread_worker_slots_round_robin():
    assert parse_gpus(None) == parse_gpus("") == ()
    assert parse_gpus("0,1,3") == (0, 1, 3)
    # 5 workers over 2 GPUs: slots 0..4 -> 0, 1, 0, 1, 0; over devices (3, 1): 3, 1, 3, 1, 3
    assert [device_of_slot(i, (0, 1)) for i in range(5)] == [0, 1, 0, 1, 0]
    assert [device_of_slot(i, (3, 1)) for i in range(5)] == [3, 1, 3, 1, 3]
    assert device_of_slot(4, ()) is None
    base = {"PATH": "/bin", DEVICE_ENV: "2"}
    assert worker_environ(base, 1, ()) == base  # no --gpus: the environment as it is
    assert worker_environ(base, 1, (0, 5)) == {"PATH": "/bin", DEVICE_ENV: "5"}
    assert base[DEVICE_ENV] == "2"  # a copy
    for bad in ("a", "0,0", "-1", "1,,2"):
        with pytest.raises(ValueError, match="--gpus"):
            parse_gpus(bad)


def test_gpus_on_a_cluster_one_share_per_ray_task_own_gpus_per_slurm_task(tmp_path):
    from sc3d_data.pipeline.jobs.r2n2_job import IMPORT
    from sc3d_data.pipeline.executors.ray_executor import _gpu_share
    from sc3d_data.pipeline.jobs.render_job import RENDER, RenderConfig
    from sc3d_data.pipeline.executors.slurm_executor import part_configs

    cfg = RenderConfig(out=tmp_path, gpus=(2, 5))
    assert _gpu_share(RENDER, cfg, 8) == 0.25 and _gpu_share(RENDER, cfg, 1) == 1.0
    assert _gpu_share(RENDER, RenderConfig(out=tmp_path), 8) == 0.0 and _gpu_share(IMPORT, cfg, 8) == 0.0
    parts = part_configs(cfg, 3, 4)
    assert [p.gpus for p in parts] == [(0, 1)] * 3  # each array task: the 2 GPUs of its own allocation
    assert all(p.gpus == () for p in part_configs(RenderConfig(out=tmp_path), 2, 4))
    assert cfg.settings("egl") == RenderConfig(out=tmp_path).settings("egl")  # not an output setting


def test_each_worker_draws_on_its_slots_device(sample_shards, tmp_path):
    """``--gpus 0`` with 2 workers: the same dataset as the session's run without the option;
    ``--gpus 0,7``: the second worker's context is asked for device 7, which this machine
    lacks, and the run stops naming it, also with ``--backend auto`` (no silent fall back to
    OSMesa, which would draw on the CPU whatever --gpus says)."""
    out = tmp_path / "gpu0"
    run_cli(main, ["render", "--meshes", SAMPLE_MESHES, "--out", out, "--voxelize", "--workers", "2",
                   "--gpus", "0", "--no-progress"])
    assert_same_dataset(sample_shards, out)
    res = run_cli(main, ["render", "--meshes", SAMPLE_MESHES / "chair", "--out", tmp_path / "gpu7", "--workers",
                         "2", "--gpus", "0,7", "--backend", "egl", "--views", "4", "--no-progress"], expect_exit=1)
    assert "EGL device 7 does not exist" in res.output
    res = run_cli(main, ["render", "--meshes", SAMPLE_MESHES / "chair", "--out", tmp_path / "auto7", "--workers",
                         "1", "--gpus", "7", "--views", "4", "--no-progress"], expect_exit=1)
    assert "EGL device 7 does not exist" in res.output and "osmesa:" not in res.output
    # one line (round ten): it came wrapped twice, with the packages to install given twice
    assert error_lines(res.output) == [res.output.strip()] and "install" not in res.output, res.output
