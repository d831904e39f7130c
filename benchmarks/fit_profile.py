"""Where ``fit``'s training loop spends the host's time (issue 21): the whole loop, not one step.

    python benchmarks/fit_profile.py --shards SHARDS [--steps 400] [--active 50] [--batch-size 48] [--tiny]
                                     [--top 25] [-- FIT OPTIONS...]

Runs ``sc3d-train fit`` in this process (``--device auto``, its defaults otherwise, options after
``--`` added) and profiles (``torch.profiler``: CPU, and CUDA where present) only its last
``--active`` training steps: before them the profiler is off (compiling, warm-up, the decoded
cache filling), so a run at the paper's width on a GPU ends in about the time of ``fit`` itself
(profiling every step, compiling included, passed 180 s for 500 steps on the H100). Prints, per
training step of that stretch: its wall time; the spans of the loop's parts (labelled with
``record_function``: the next batch (loader, copy to the device, expansion), the step itself
(forward, losses, backward, Adam, each also on its own), the loss window, the logging); the GPU's
kernel time; the host operations by
self CPU time; the CUDA runtime calls that make the host wait for the GPU or page-lock memory
(``cudaStreamSynchronize``, ``cudaDeviceSynchronize``, ``cudaEventSynchronize``, ``cudaMemcpy``,
``cudaHostAlloc``, ``cudaFreeHost``, ``cudaGraphLaunch``). The question it answers: what does the
loop do beyond the training step that ``train_step.py`` times (on an H100 with 16 cores,
2026-11-27: ~15 ms a step in the loop against ~8 ms for the step alone)?
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile, schedule

#: CUDA runtime calls that block the host on the GPU or page-lock host memory
WAITING_CALLS = ("cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaEventSynchronize", "cudaMemcpy",
                 "cudaMemcpyAsync", "cudaHostAlloc", "cudaFreeHost", "cudaGraphLaunch")


def annotate(label: str, fn):
    """``fn`` inside ``record_function(label)``."""
    def wrapped(*a, **k):
        with torch.profiler.record_function(label):
            return fn(*a, **k)
    return wrapped


def annotate_batches(label: str, fn):
    """``fn`` (``trainer.device_batches``) whose iterators' ``next`` runs inside
    ``record_function(label)``."""
    def spanned(batches):
        while True:
            with torch.profiler.record_function(label):
                try:
                    batch = next(batches)
                except StopIteration:
                    return
            yield batch

    def wrapped(*a, **k):
        return {p: spanned(it) for p, it in fn(*a, **k).items()}
    return wrapped


#: the logging's span: the four functions that log every --log-every steps
LOGGING = "loop: logging (finiteness check, losses read back, metrics.csv + TensorBoard, GPU utilisation)"
#: the loop's parts, as record_function spans: (label, module, attribute, wrapper); a label that
#: starts with a space is a part of the part above it (its span lies inside that one's) and does
#: not count again in the sum the rest is found from; one label may wrap several functions
PARTS = (("loop: next batch (loader, to the device, expansion)", "sc3d_train.loop.trainer", "device_batches",
          annotate_batches),
         ("  of it: to the device + expansion (training_batch)", "sc3d_train.loop.trainer", "training_batch", annotate),
         ("loop: training step (forward, losses, backward, Adam)", "sc3d_train.loop.train_step", "TrainStep.__call__",
          annotate),
         ("  of it: noise", "sc3d_train.loop.train_step", "draw_noise", annotate),
         ("  of it: forward + losses (the compiled call)", "sc3d_train.loop.train_step", "TrainStep._forward", annotate),
         ("  of it: backward", "sc3d_train.loop.train_step", "backward", annotate),
         ("  of it: Adam", "sc3d_train.loop.train_step", "optimizer_step", annotate),
         ("loop: loss window", "sc3d_train.loop.loss_window", "LossWindow.record", annotate),
         (LOGGING, "sc3d_train.loop.trainer", "check_finite", annotate),
         (LOGGING, "sc3d_train.loop.trainer", "mean_scalars", annotate),
         (LOGGING, "sc3d_train.loop.metrics_log", "MetricsLog.log", annotate),
         (LOGGING, "sc3d_train.loop.metrics_log", "GpuUtilisation.__call__", annotate))


def patch_loop(prof) -> None:
    """Wrap the loop's parts (:data:`PARTS`) in spans, and ``trainer.train_step`` so that each
    training step advances the profiler's schedule (``prof.step()``)."""
    import importlib

    from sc3d_train.loop import trainer

    for label, module, attr, wrapper in PARTS:
        owner = importlib.import_module(module)
        if "." in attr:
            owner, attr = getattr(owner, attr.split(".")[0]), attr.split(".")[1]
        setattr(owner, attr, wrapper(label, getattr(owner, attr)))
    step = trainer.train_step

    def stepped(*a, **k):
        out = step(*a, **k)
        prof.step()
        return out
    trainer.train_step = stepped


def per_name(events) -> dict[str, tuple[int, float, float]]:
    """``{name: (calls, self CPU ms, total CPU ms)}`` of the host events of ``events``."""
    out: dict[str, list] = defaultdict(lambda: [0, 0.0, 0.0])
    for e in events:
        if e.device_type == torch.autograd.DeviceType.CPU:
            out[e.name][0] += 1
            out[e.name][1] += e.self_cpu_time_total / 1000.0
            out[e.name][2] += e.cpu_time_total / 1000.0
    return {k: tuple(v) for k, v in out.items()}


def main() -> None:
    argv = sys.argv[1:]
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--shards", type=Path, required=True)
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--active", type=int, default=50, help="training steps profiled, the last of the run")
    ap.add_argument("--batch-size", type=int, default=48)
    ap.add_argument("--tiny", action="store_true")
    ap.add_argument("--top", type=int, default=25)
    args = ap.parse_args(argv)
    if not 0 < args.active < args.steps:
        raise SystemExit("fit_profile: --active must be between 1 and --steps - 1")
    from sc3d_cli.train import main as train_main

    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if torch.cuda.is_available() else [])
    # the schedule counts prof.step() calls: one per training step; the last (active + 1) steps are warm-up + active
    wait = args.steps - args.active - 1
    with tempfile.TemporaryDirectory() as tmp:
        fit_args = ["fit", "--shards", str(args.shards), "--out", str(Path(tmp) / "run"), "--steps", str(args.steps),
                    "--batch-size", str(args.batch_size), "--val-every", "0", "--no-progress",
                    *(["--tiny"] if args.tiny else []), *extra]
        done = {}
        with profile(activities=activities, schedule=schedule(wait=wait, warmup=1, active=args.active, repeat=1),
                     on_trace_ready=lambda p: done.setdefault("events", p.events())) as prof:
            patch_loop(prof)
            try:
                train_main(fit_args, standalone_mode=False)
            except SystemExit as e:
                if e.code:
                    raise
    events = done.get("events")
    if not events:
        raise SystemExit("fit_profile: the profiled steps did not complete")
    host = [e for e in events if e.device_type == torch.autograd.DeviceType.CPU]
    steps = args.active
    wall = (max(e.time_range.end for e in host) - min(e.time_range.start for e in host)) / 1000.0
    gpu = sum(e.device_time_total for e in events if e.device_type == torch.autograd.DeviceType.CUDA) / 1000.0
    names = per_name(events)
    print(f"\nfit's last {steps} steps: {wall / steps:.2f} ms of wall time a step "
          f"({args.batch_size * steps / wall * 1000:.0f} samples/s); GPU kernels {gpu / steps:.2f} ms a step")
    print("| part of the loop | calls a step | wall ms a step (span) |")
    print("|---|---|---|")
    spans = 0.0
    for label in dict.fromkeys(p[0] for p in PARTS):  # each label once, in order
        calls, _, total = names.get(label, (0, 0.0, 0.0))
        spans += 0.0 if label.startswith(" ") else total
        print(f"| {label} | {calls / steps:.2f} | {total / steps:.3f} |")
    print(f"| rest: the loop's own Python, lr, the host sync before each log, checkpoints | - | "
          f"{(wall - spans) / steps:.3f} |")
    print(f"\n| host operation (top {args.top} by self CPU) | calls a step | self CPU ms a step |")
    print("|---|---|---|")
    ops = {n: v for n, v in names.items() if n not in {p[0] for p in PARTS}}
    for name, (calls, cpu, _) in sorted(ops.items(), key=lambda kv: -kv[1][1])[:args.top]:
        print(f"| {name[:80]} | {calls / steps:.1f} | {cpu / steps:.3f} |")
    print("\n| CUDA runtime call | calls a step | self CPU ms a step |")
    print("|---|---|---|")
    for name in WAITING_CALLS:
        calls, cpu, _ = names.get(name, (0, 0.0, 0.0))
        print(f"| {name} | {calls / steps:.2f} | {cpu / steps:.3f} |")


if __name__ == "__main__":
    main()
