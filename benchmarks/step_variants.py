"""(A module of ``train_step.py``, not run directly.) Table 1 of ``train_step.py``: ``fit``'s
training step (:class:`sc3d_train.loop.train_step.TrainStep`, the code ``fit`` runs) in several
variants on one fixed batch, interleaved step by step, each from the same weights, batch and
random numbers so that their losses can be compared; and ``--profile``: where a step goes
(torch.profiler's top kernels and kernel launches per step).

A variant is ``(name, amp dtype or None, channels_last, compile)`` with ``compile`` one of
``off``, ``on`` (inductor; on one CUDA device with CUDA graphs, as ``fit``'s ``auto``), and the
baseline is plain fp32 eager NCHW with PyTorch's default Adam (``fit``'s steps use fused Adam on
CUDA)."""
from __future__ import annotations

import time
from dataclasses import replace

import torch

#: kernel launches seen by the profiler on the host (CUDA runtime/driver calls)
LAUNCH_EVENTS = ("cudaLaunchKernel", "cuLaunchKernel", "cudaLaunchKernelExC", "cuLaunchKernelEx",
                 "cudaGraphLaunch")


def phase_batches(cfg, batch: dict, device, channels_last: bool, phase: str) -> dict:
    """The device batches of one step: ``supervised`` (the whole batch, with its pose targets
    searched from its voxels and masks once, as ``fit`` does before training) or ``semi`` (the
    mixed phase: the first half labelled, the second half without labels)."""
    from sc3d_train.paper.losses import search_target
    from sc3d_train.paper.pose import PoseGrid
    from sc3d_train.loop.phase_step import training_batch

    def part(lo, hi, kind):
        sub = {k: v[lo:hi] for k, v in batch.items()}
        out = training_batch(sub, kind, device, channels_last)
        if kind == "supervised":
            out["pose_target"] = search_target(out["voxels"], out["masks_sc"], out, PoseGrid.of(cfg.model),
                                               cfg.loss_weights)
        return out

    n = len(batch["images"])
    if phase == "supervised":
        return {"supervised": part(0, n, "supervised")}
    return {"supervised": part(0, n // 2, "supervised"), "unsupervised": part(n // 2, n, "unsupervised")}


class StepRunner:
    """One variant: its own model (seed 0), Adam and :class:`TrainStep` on fixed device batches."""

    def __init__(self, cfg, batch: dict, device, amp_dtype, channels_last: bool, compile_: str, phase: str):
        from sc3d_train.loop.checkpoint_model import build_model
        from sc3d_train.loop.train_step import TrainStep, compile_plan

        cfg = replace(cfg, compile=compile_, mode="semi" if phase == "semi" else "supervised")
        torch.manual_seed(0)
        self.device = device
        self.model = build_model(cfg).to(device)
        if channels_last:
            self.model = self.model.to(memory_format=torch.channels_last)
        fit_like = compile_ != "off" or amp_dtype is not None or channels_last
        self.opt = torch.optim.Adam(self.model.parameters(), lr=cfg.lr, fused=fit_like and device.type == "cuda")
        scaler = torch.amp.GradScaler("cuda") if amp_dtype == torch.float16 else None
        self.step_fn = TrainStep(self.model, self.model, self.opt, scaler, amp_dtype, cfg,
                                 compile_plan(cfg, device, 1))
        self.batches = phase_batches(cfg, batch, device, channels_last, phase)
        self.losses: list[dict] = []

    def step(self, seed: int) -> float:
        """Seconds of one optimiser step (forward, losses, backward, Adam); the noise is drawn
        from ``seed``; the step's losses are kept in :attr:`losses`."""
        torch.manual_seed(seed)
        if self.device.type == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        losses = self.step_fn(self.batches)
        if self.device.type == "cuda":
            torch.cuda.synchronize()
        sec = time.perf_counter() - t0
        self.losses.append({k: float(v.detach()) for k, v in losses.items()})
        return sec


def time_variants(cfg, batch, device, variants, steps: int, phase: str = "supervised"):
    """``(median seconds per step or None, runner or None)`` of each variant. Variants run
    interleaved (one step each per round) after two warm-up rounds (compiling, recording CUDA
    graphs); step ``i`` of every variant draws its noise from the same seed. A variant that
    fails gives None."""
    runners = []
    for name, amp_dtype, cl, comp in variants:
        try:
            t0 = time.perf_counter()
            r = StepRunner(cfg, batch, device, amp_dtype, cl, comp, phase)
            r.step(0)
            r.step(1)
            print(f"  {name}: built and warmed up in {time.perf_counter() - t0:.1f} s")
            runners.append(r)
        except Exception as e:  # noqa: BLE001 - reported in the table, not fatal
            print(f"variant {name} failed: {type(e).__name__}: {e}")
            runners.append(None)
    times = [[] for _ in runners]
    for i in range(steps):
        for k, r in enumerate(runners):
            if r is not None:
                times[k].append(r.step(2 + i))
    return [(sorted(t)[len(t) // 2] if t else None, r) for t, r in zip(times, runners)]


def loss_difference(runner, baseline) -> float | None:
    """The largest relative difference of the first step's loss terms from the baseline's (same
    weights, batch and noise)."""
    if runner is None or baseline is None:
        return None
    a, b = runner.losses[0], baseline.losses[0]
    return max(abs(a[k] - b[k]) / max(abs(b[k]), 1e-12) for k in b)


def profile_steps(runner, steps: int, rows: int = 15) -> str:
    """torch.profiler over ``steps`` steps of ``runner`` (already warmed up): the top ops and
    kernels by self time on the device (CUDA) or the CPU, and per step the kernel launches
    (CUDA: runtime/driver launch calls, a CUDA graph launch counted once; CPU: aten ops)."""
    from torch.profiler import ProfilerActivity, profile

    cuda = runner.device.type == "cuda"
    acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
    with profile(activities=acts) as prof:
        for i in range(steps):
            runner.step(100 + i)
    events = prof.key_averages()
    sort = "self_cuda_time_total" if cuda else "self_cpu_time_total"
    table = events.table(sort_by=sort, row_limit=rows)
    if cuda:
        launches = sum(e.count for e in events if e.key in LAUNCH_EVENTS)
        graphs = sum(e.count for e in events if e.key == "cudaGraphLaunch")
        kernels = sum(e.count for e in prof.events() if e.device_type.name == "CUDA")
        line = (f"per step: {launches / steps:.0f} kernel launch calls ({graphs / steps:.0f} of them CUDA graph "
                f"launches), {kernels / steps:.0f} kernels run on the GPU")
    else:
        ops = sum(e.count for e in events if e.key.startswith("aten::"))
        line = f"per step: {ops / steps:.0f} aten op calls on the CPU, nested ones included (no kernel launches off CUDA)"
    return f"{table}\n{line}"
