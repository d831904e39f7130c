"""What only a GPU machine can show: training with fit's CUDA defaults, resume and evaluation on
CUDA, rendering through a GPU's EGL, DDP over two GPUs.

Every test here carries the ``gpu`` marker and is skipped, with the reason, where torch sees no
CUDA device (CI and the 2-core development machines); ``pytest -m gpu`` runs just these. The
tolerances are those CUDA allows and are stated per test: cuDNN picks its convolution kernels per
machine and some backward kernels add with atomics, so two CUDA runs agree to rounding, not bit
for bit, and bf16 autocast (fit's default on CUDA) keeps 8 bits of mantissa.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from sc3d_cli.train import main as train_main
from tests.conftest import SAMPLE_MESHES, assert_same_raster, require_backend, run_cli
from tests.test_train import TINY, interrupt_at, read_csv
from conftest import error_lines

pytestmark = [pytest.mark.gpu,
              pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA: torch sees no CUDA device")]


def test_fit_on_cuda_with_the_defaults_learns(sample_shards, tmp_path):
    """``fit --device cuda`` with every CUDA default (bf16 autocast, channels_last, the compiled
    step with CUDA graphs, which must not fall back to eager) runs and its loss falls: the mean
    of the last 10 of 60 steps is below 0.85 x the first 5 (on the CPU the same run falls to
    about 0.6-0.7 x)."""
    out = tmp_path / "run"
    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", out, "--steps", 60, "--batch-size", 8,
                         *TINY, "--lr", 1e-3, "--lr-schedule", "constant", "--device", "cuda"])
    rows = read_csv(out / "metrics.csv")
    total = np.array([float(r["total"]) for r in rows])
    assert len(total) == 60 and np.isfinite(total).all()
    assert total[-10:].mean() < 0.85 * total[:5].mean(), (total[:5].mean(), total[-10:].mean())
    cfg = (out / "config.yaml").read_text()
    assert "device: cuda" in cfg
    assert "samples/s on cuda" in res.output, res.output
    assert "training eagerly" not in res.output, res.output  # the compiled step ran, no fallback


def test_the_suites_cpu_tests_train_on_the_cpu_here(sample_shards, tmp_path):
    """The CPU tests run ``fit`` with ``--device auto``; in the suite (``SC3D_AUTO_DEVICE=cpu``,
    conftest.py) that is the CPU on this GPU machine too, so their CPU bounds and bit-for-bit
    comparisons hold here; a user's ``auto`` (the variable unset) is CUDA."""
    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", tmp_path / "run", "--steps", 1, *TINY,
                               "--val-every", 0])
    assert "samples/s on cpu;" in res.output, res.output
    env = {k: v for k, v in os.environ.items() if k != "SC3D_AUTO_DEVICE"}
    r = subprocess.run([sys.executable, "-c", "from sc3d_train.loop.runtime import auto_device; print(auto_device())"],
                       env=env, capture_output=True, text=True, check=True)
    assert r.stdout.strip() == "cuda", r.stdout + r.stderr


def test_a_cuda_batch_that_does_not_fit_is_one_line(sample_shards, tmp_path):
    """A batch whose step does not fit the GPU's memory ends ``fit`` with one line saying the
    GPU's memory ran out and to lower ``--batch-size``, not a traceback. The process may use
    1 GiB of the GPU here (``torch.cuda.set_per_process_memory_fraction``: the caching allocator
    itself raises ``torch.OutOfMemoryError`` beyond it, as it does at a card's end), and a step
    of batch 2,048 of the tests' tiny network (4 base channels) needs more (it ran out on an
    H100, 2026-11-27): a real out-of-memory, reached in seconds. (A batch too large for the whole card, 100,000,
    first spends minutes building its 5 GB host batch: the lease of 2026-11-27 cut the gpu
    tests there.) Eager (``--compile off``): compiling a step that cannot run would only cost time."""
    limit = min(1.0, 2**30 / torch.cuda.get_device_properties(0).total_memory)
    torch.cuda.set_per_process_memory_fraction(limit)
    try:
        res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", tmp_path / "run", "--steps", 1,
                                   "--batch-size", 2048, *TINY, "--device", "cuda", "--compile", "off"],
                      expect_exit=1)
    finally:
        torch.cuda.set_per_process_memory_fraction(1.0)
        torch.cuda.empty_cache()
    errors = error_lines(res.output)
    assert len(errors) == 1 and errors[0].startswith("Error: out of GPU memory while training ("), res.output
    assert errors[0].endswith("use a smaller one"), errors[0]
    assert "Traceback" not in res.output


def test_eval_on_cuda_equals_eval_on_cpu(trained_run, sample_shards, tmp_path):
    """One checkpoint evaluated on CUDA and on the CPU (fp32 both: eval uses no autocast): per
    object and view the voxel IoU within 0.01 and the predicted pose within 1 degree; the
    overall figures within 0.01 and 1 degree. A voxel at the 0.4 threshold may flip, a pose bin
    may not."""
    def evaluate(device):
        out = tmp_path / device
        run_cli(train_main, ["eval", "--checkpoint", trained_run / "checkpoints" / "last.pt", "--shards",
                             sample_shards, "--split", "train", "--device", device, "--out", out])
        return json.loads((out / "metrics.json").read_text())

    cpu, cuda = evaluate("cpu"), evaluate("cuda")
    for key in ("voxel_iou_0.4", "voxel_iou_0.5", "mask_iou"):
        assert cuda["overall"][key] == pytest.approx(cpu["overall"][key], abs=0.01), key
    assert cuda["overall"]["pose_rotation_median"] == pytest.approx(cpu["overall"]["pose_rotation_median"], abs=1.0)


def test_render_through_the_gpus_egl_equals_llvmpipe(tmp_path):
    """The bundled meshes rendered through EGL on the GPU and through OSMesa (llvmpipe, Mesa's
    CPU rasteriser) agree within GL's rules (``assert_same_raster``: masks except at edge
    pixels, colours within 1 per 8-bit channel inside). Skipped where EGL is not a GPU's or
    OSMesa is missing."""
    from sc3d_cli.data import main as data_main

    egl, osmesa = require_backend("egl"), require_backend("osmesa")
    if "llvmpipe" in egl.lower():
        pytest.skip(f"EGL renders through {egl} here, not a GPU")
    outs = {}
    for backend in ("egl", "osmesa"):
        outs[backend] = tmp_path / backend
        run_cli(data_main, ["render", "--meshes", SAMPLE_MESHES, "--out", outs[backend], "--backend", backend,
                            "--workers", "2", "--no-progress"])
    from tests.conftest import objects_by_id

    a, b = objects_by_id(outs["egl"]), objects_by_id(outs["osmesa"])
    assert sorted(a) == sorted(b)
    for key in a:
        assert_same_raster(a[key]["images"], a[key]["masks"], b[key]["images"], b[key]["masks"],
                           f"{key}: {egl} vs {osmesa}")


@pytest.mark.skipif(torch.cuda.device_count() < 2, reason="needs 2 GPUs")
def test_ddp_two_gpu_ranks(sample_shards, tmp_path):
    """torchrun with 2 ranks on 2 GPUs (NCCL): the run completes, rank 0 alone reports and writes,
    and the checkpoint holds both ranks' RNG states."""
    script = Path(sys.executable).parent / "sc3d-train"
    if not script.is_file():
        pytest.skip(f"{script} not installed")
    out = tmp_path / "ddp"
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2", str(script),
           "fit", "--device", "cuda", "--shards", str(sample_shards), "--out", str(out), "--steps", "4",
           "--batch-size", "4", *TINY, "--checkpoint-every", "2"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env={**os.environ, "OMP_NUM_THREADS": "1"},
                       cwd=Path(__file__).resolve().parents[1])
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    assert r.stdout.count("done: step 4") == 1
    assert [int(x["step"]) for x in read_csv(out / "metrics.csv")] == [0, 1, 2, 3]
    ckpt = torch.load(out / "checkpoints" / "last.pt", weights_only=False)
    assert len(ckpt["rng"]) == 2


def test_resume_on_cuda_equals_the_uninterrupted_run(sample_shards, tmp_path):
    """Killed after the checkpoint of step 3 and resumed: the resumed steps 3-5 log the losses of
    the uninterrupted run within 2% (relative) and end at weights within 2e-2 (absolute) of its
    weights. Not bit for bit as on the CPU: cuDNN's backward kernels may add in another order
    on each run. Same lr schedule, same samples (the resume restores the loader and RNG
    states exactly, as the CPU test shows)."""
    args = ["--shards", sample_shards, "--batch-size", "4", *TINY, "--checkpoint-every", "3", "--seed", "5",
            "--device", "cuda"]
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    run_cli(train_main, ["fit", "--out", whole, "--steps", "6", *args])
    interrupt_at(whole, parts, 3)
    run_cli(train_main, ["fit", "--out", parts, "--steps", "6", "--resume", "--no-progress"])
    a, b = read_csv(whole / "metrics.csv"), read_csv(parts / "metrics.csv")
    assert [r["step"] for r in b] == [str(i) for i in range(6)]
    for ra, rb in zip(a[3:], b[3:]):
        assert ra["lr"] == rb["lr"]
        for key in ("total", "l3d", "l2d", "lsc", "pose"):
            assert float(rb[key]) == pytest.approx(float(ra[key]), rel=2e-2, abs=1e-4), (ra["step"], key)
    wa = torch.load(whole / "checkpoints" / "last.pt", weights_only=False)["model"]
    wb = torch.load(parts / "checkpoints" / "last.pt", weights_only=False)["model"]
    worst = max(float((wa[k].float() - wb[k].float()).abs().max()) for k in wa if wa[k].is_floating_point())
    assert worst < 2e-2, worst


def test_a_loader_error_reaches_the_loop_after_the_batches_before_it_on_cuda_too():
    """The CUDA prefetcher reads the loader one batch ahead; a loader error while it did (a
    truncated shard) was raised in place of the batch before it, one step early (that step not
    trained, a checkpoint due after it not written; the CPU path hands that batch out first).
    On CUDA as on the CPU, the batches before the error come out, then the error."""
    from sc3d_train.data.device_prefetch import DevicePrefetcher

    def batches():
        for i in range(2):
            yield {"x": torch.full((4,), float(i)).pin_memory()}
        raise OSError("shard-00000.h5: truncated (injected)")

    for device in (torch.device("cpu"), torch.device("cuda")):
        got = []
        with pytest.raises(OSError, match="truncated"):
            for batch in DevicePrefetcher(batches(), lambda b: {k: v.to(device, non_blocking=True)
                                                                for k, v in b.items()}, device):
                got.append(float(batch["x"][0]))
        assert got == [0.0, 1.0], (device, got)
