"""The training step of ``fit`` (sc3d_train/loop/train_step.py): the compiled step against the eager
one, exact resume of a compiled run, the finiteness window, and (``gpu`` marker) the CUDA fast
path: no host sync in the steady-state step, CUDA graphs replayed (a short CUDA fit with the
defaults, now compiled, that learns: tests/test_gpu.py).

On the CPU the compiled step uses the ``aot_eager`` backend: Dynamo's capture and AOTAutograd's
forward and backward graphs, the same as inductor receives, without generating C++ (inductor's
CPU build of the step takes ~2 minutes on 2 cores; ``benchmarks/train_step.py`` times and
compares it)."""
from __future__ import annotations

import pytest
import torch

from sc3d_cli.train import main
from tests.conftest import run_cli
from tests.test_train import TINY, interrupt_at, read_csv

needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA: torch sees no CUDA device")


def make_step(sample_shards, mode: str, compile_: str, backend: str = "aot_eager", device: str = "cpu",
              batch: int = 4, amp: str = "off"):
    """A :class:`TrainStep` on a fresh seeded tiny model (C = 4) and its batches iterator."""
    from sc3d_train.loop.resolve import resolve_config
    from sc3d_train.loop.streams import phase_loaders
    from sc3d_train.loop.metrics_log import DataWaitClock
    from sc3d_train.loop.train_step import TrainStep, compile_plan
    from sc3d_train.loop.trainer import device_batches, prepare

    cfg = resolve_config({"shards": str(sample_shards), "out": "unused", "batch_size": batch, "mode": mode,
                          "labeled_fraction": 0.5, "pretrain_steps": 0, "compile": compile_,
                          "compile_backend": backend, "device": device, "amp": amp,
                          "model": {"base_channels": 4}}, {"tiny": True})
    t = prepare(cfg)
    torch.manual_seed(1)
    step_fn = TrainStep(t.model, t.train_model, t.optimizer, t.scaler, t.amp_dtype, cfg,
                        compile_plan(cfg, t.device, 1))
    return t, step_fn, device_batches(t, phase_loaders(t, 0), DataWaitClock())


def test_compiled_mixed_step_equals_eager_step(sample_shards):
    """Two optimiser steps of the mixed phase of ``semi`` from the same weights, batches and
    random numbers, compiled and eager: losses within 1e-5 relative and weights within 1e-5
    (float32; the compiled graphs decompose ops and reorder sums). That step has every part of
    the others: the labelled pass (supervised loss), the unlabelled pass with BatchNorm's running
    statistics frozen, the pose search on the predictions. It is captured whole: no graph break
    (which CUDA graphs need)."""
    from torch._dynamo.utils import counters

    counters.clear()
    runs = {}
    for how in ("off", "on"):
        t, step_fn, batches = make_step(sample_shards, "semi", how)
        assert step_fn.plan.enabled == (how == "on") and set(batches) == {"supervised", "unsupervised"}
        losses = [{k: float(v.detach()) for k, v in step_fn({p: next(it) for p, it in batches.items()}).items()}
                  for _ in range(2)]
        runs[how] = losses, t.model.state_dict()
    assert step_fn.proven and not counters["graph_break"], dict(counters["graph_break"])
    assert runs["on"][0][0].keys() == runs["off"][0][0].keys()
    for eager, compiled in zip(runs["off"][0], runs["on"][0]):
        for k in eager:
            assert compiled[k] == pytest.approx(eager[k], rel=1e-5, abs=1e-6), k
    for k, v in runs["off"][1].items():
        torch.testing.assert_close(runs["on"][1][k], v, rtol=1e-5, atol=1e-5, msg=k)


def test_compiled_run_resumes_exactly_and_follows_the_eager_run(sample_shards, tmp_path):
    """A compiled supervised run (``compile: on``) interrupted after its checkpoint at step 2
    and resumed logs the uninterrupted compiled run's losses bit for bit, as the eager path does
    (tests/test_train.py::test_resume_equals_uninterrupted); and the same run eager
    (``--compile off``) logs the same losses within 1e-5 relative."""
    config = tmp_path / "compiled.yaml"
    config.write_text(f"shards: {sample_shards}\nout: {tmp_path}\ncompile: 'on'\ncompile_backend: aot_eager\n")
    args = ["--shards", sample_shards, "--steps", "4", "--batch-size", "4", *TINY, "--checkpoint-every", "2",
            "--seed", "5"]
    whole, parts, eager = tmp_path / "whole", tmp_path / "parts", tmp_path / "eager"
    run_cli(main, ["fit", "--config", config, "--out", whole, *args])
    interrupt_at(whole, parts, 2)
    run_cli(main, ["fit", "--out", parts, "--steps", "4", "--resume", "--no-progress"])
    run_cli(main, ["fit", "--config", config, "--out", eager, *args, "--compile", "off"])
    a, b, e = (read_csv(run / "metrics.csv") for run in (whole, parts, eager))
    assert len(a) == len(b) == len(e) == 4
    for ra, rb, re in zip(a, b, e):
        for key in ("total", "l3d", "l2d", "lsc", "kl", "pose"):
            assert ra[key] == rb[key], (ra["step"], key, ra[key], rb[key])
            assert float(ra[key]) == pytest.approx(float(re[key]), rel=1e-5, abs=1e-6), (ra["step"], key)


def test_a_compiled_step_that_fails_on_its_second_call_falls_back_to_eager(sample_shards, capsys):
    """CUDA graphs are recorded on a compiled step's second call, and the mixed phase of ``semi``
    compiles its own graph when it starts: a failure there was raised (the run stopped), since
    only the very first compiled call was guarded. Injected here (the compiled function raises
    on its second call, as a graph that cannot be recorded does), the step must say so once and
    go on eagerly from the same state: after three steps its weights equal those of the eager
    step within 1e-5 (aot_eager reorders sums) and it no longer compiles."""
    states = {}
    for how in ("off", "on"):
        t, step_fn, batches = make_step(sample_shards, "supervised", how)
        if how == "on":
            compiled, calls = step_fn.compiled, []

            def fails_second(batch):
                calls.append(1)
                if len(calls) == 2:
                    raise RuntimeError("graph could not be recorded (injected)")
                return compiled(batch)

            step_fn.compiled = fails_second
        for _ in range(3):
            step_fn({p: next(it) for p, it in batches.items()})
        states[how] = t.model.state_dict()
    assert step_fn.compiled is None and len(calls) == 2
    said = capsys.readouterr().out
    assert said.count("training eagerly") == 1 and "graph could not be recorded (injected)" in said, said
    for k, v in states["off"].items():
        torch.testing.assert_close(states["on"][k], v, rtol=1e-5, atol=1e-5, msg=k)


def test_loss_window_names_the_first_bad_step():
    """Steps 7..11 recorded without a read-back; the check finds step 9, the first non-finite
    one, and empties the window."""
    from sc3d_train.loop.loss_window import LossWindow
    from sc3d_train.loop.runtime import DistInfo

    window = LossWindow(5, torch.device("cpu"))
    for step, value in zip(range(7, 12), [1.0, 2.0, float("nan"), float("inf"), 3.0]):
        window.record(step, torch.tensor(value))
    assert window.check(DistInfo())[0] == 9
    assert window.check(DistInfo()) is None
    window.record(12, torch.tensor(0.5))
    assert window.check(DistInfo()) is None


@pytest.mark.gpu
@needs_cuda
def test_cuda_step_has_no_host_sync_and_replays_cuda_graphs(sample_shards):
    """fit's default step on CUDA (bf16/fp16 autocast, channels_last, inductor with CUDA graphs,
    fused Adam): after three warm-up steps (compile, record, first replay) each step launches
    recorded CUDA graphs (``cudaGraphLaunch`` in torch.profiler: forward and backward), and
    steps under ``set_sync_debug_mode("error")`` (any host sync raises) run through."""
    from torch.profiler import ProfilerActivity, profile

    t, step_fn, batches = make_step(sample_shards, "supervised", "auto", backend="inductor", device="cuda",
                                    batch=8, amp="auto")
    assert step_fn.plan.cuda_graphs and step_fn.compiled is not None
    for _ in range(3):
        step_fn({p: next(it) for p, it in batches.items()})
    torch.cuda.synchronize()
    with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
        for _ in range(2):
            step_fn({p: next(it) for p, it in batches.items()})
        torch.cuda.synchronize()
    graph_launches = sum(e.count for e in prof.key_averages() if e.key == "cudaGraphLaunch")
    assert graph_launches >= 2 * 2, graph_launches
    torch.cuda.set_sync_debug_mode("error")
    try:
        for _ in range(3):
            losses = step_fn({p: next(it) for p, it in batches.items()})
            total = losses["total"].detach().clone()
    finally:
        torch.cuda.set_sync_debug_mode(0)
    assert step_fn.proven and step_fn.compiled is not None and torch.isfinite(total).item()
