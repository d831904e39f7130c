"""Where ``fit``'s training loop spends the host's time (issue 21): the whole loop, not one step.

    python benchmarks/fit_profile.py --shards SHARDS [--steps 400] [--batch-size 48] [--tiny]
                                     [--skip-share 0.5] [--top 25] [-- FIT OPTIONS...]

Runs ``sc3d-train fit`` in this process (``--device auto``, its defaults otherwise, options after
``--`` added) under ``torch.profiler`` (CPU, and CUDA where present) and keeps the events that
start in the last ``1 - --skip-share`` of the profiled wall time, after compiling and the first
batches. Prints the host operations of that stretch by self CPU time (ms per training step and
calls per step), then the CUDA runtime calls that make the host wait for the GPU or page-lock
memory (``cudaStreamSynchronize``, ``cudaDeviceSynchronize``, ``cudaEventSynchronize``,
``cudaMemcpy``, ``cudaHostAlloc``, ``cudaFreeHost``, ``cudaGraphLaunch``) with their calls and
ms per step. The question it answers: does the loop build the next batch while the GPU runs the
current step, or does something make the two take turns (on an H100 with 16 cores, 2026-11-27,
the loop took about the loader's time plus the step's)?
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile

#: CUDA runtime calls that block the host on the GPU or page-lock host memory
WAITING_CALLS = ("cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaEventSynchronize", "cudaMemcpy",
                 "cudaMemcpyAsync", "cudaHostAlloc", "cudaFreeHost", "cudaGraphLaunch")


def late_host_events(events, skip_share: float) -> tuple[list, float]:
    """The CPU-side events of ``events`` (``prof.events()``) starting after ``skip_share`` of the
    span from the first event's start to the last event's end, and that stretch's length (ms)."""
    host = [e for e in events if e.device_type == torch.autograd.DeviceType.CPU]
    if not host:
        return [], 0.0
    t0 = min(e.time_range.start for e in host)
    t1 = max(e.time_range.end for e in host)
    cut = t0 + skip_share * (t1 - t0)
    return [e for e in host if e.time_range.start >= cut], (t1 - cut) / 1000.0


def per_name(events) -> dict[str, tuple[int, float]]:
    """``{name: (calls, self CPU ms)}`` of ``events``."""
    out: dict[str, list] = defaultdict(lambda: [0, 0.0])
    for e in events:
        out[e.name][0] += 1
        out[e.name][1] += e.self_cpu_time_total / 1000.0
    return {k: (c, ms) for k, (c, ms) in out.items()}


def main() -> None:
    argv = sys.argv[1:]
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--shards", type=Path, required=True)
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--batch-size", type=int, default=48)
    ap.add_argument("--tiny", action="store_true")
    ap.add_argument("--skip-share", type=float, default=0.5)
    ap.add_argument("--top", type=int, default=25)
    args = ap.parse_args(argv)
    if not 0 <= args.skip_share < 1:
        raise SystemExit("fit_profile: --skip-share must be in [0, 1)")
    from sc3d_cli.train import main as train_main

    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if torch.cuda.is_available() else [])
    with tempfile.TemporaryDirectory() as tmp:
        fit_args = ["fit", "--shards", str(args.shards), "--out", str(Path(tmp) / "run"), "--steps", str(args.steps),
                    "--batch-size", str(args.batch_size), "--val-every", "0", "--no-progress",
                    *(["--tiny"] if args.tiny else []), *extra]
        with profile(activities=activities) as prof:
            try:
                train_main(fit_args, standalone_mode=False)
            except SystemExit as e:
                if e.code:
                    raise
        events, ms = late_host_events(prof.events(), args.skip_share)
    names = per_name(events)
    # the optimiser's step (torch.optim's record_function) happens once a training step
    steps = sum(c for n, (c, _) in names.items() if n.startswith("Optimizer.step#"))
    if not steps:
        raise SystemExit("fit_profile: no optimiser step in the profiled stretch (lower --skip-share)")
    print(f"\nfit's loop, last {100 * (1 - args.skip_share):.0f}% of the profiled time: {ms:.0f} ms, "
          f"{steps} steps, {ms / steps:.2f} ms a step; torch's host operations "
          f"{sum(c for _, c in names.values()) / steps:.2f} ms of self CPU a step (all threads), the rest "
          "is Python: the loader's reads and the loop")
    print(f"| host operation (top {args.top} by self CPU) | calls a step | self CPU ms a step |")
    print("|---|---|---|")
    for name, (calls, cpu) in sorted(names.items(), key=lambda kv: -kv[1][1])[:args.top]:
        print(f"| {name[:80]} | {calls / steps:.1f} | {cpu / steps:.3f} |")
    print("\n| CUDA runtime call | calls a step | self CPU ms a step |")
    print("|---|---|---|")
    for name in WAITING_CALLS:
        calls, cpu = names.get(name, (0, 0.0))
        print(f"| {name} | {calls / steps:.2f} | {cpu / steps:.3f} |")


if __name__ == "__main__":
    main()
