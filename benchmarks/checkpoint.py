"""What a checkpoint of ``fit`` costs the training loop, against the way it was written before.

    python benchmarks/checkpoint.py [--tiny] [--device auto] [--repeat 3] [--dir DIR]

At the paper's width (or ``--tiny``) with Adam's moments (one step taken, so they exist), on
``--device``: the model's and the optimiser's state written as ``fit`` writes them
(``save_checkpoint``: ``torch.save`` through a file whose failed write is named, then copied to
``last.pt``) against the previous way (``torch.save`` to the path, then the copy); and ``curves.png`` drawn from a ``metrics.csv`` of 2,000 and
of 20,000 steps (one row per 10). Each is the median of ``--repeat`` runs, in ``--dir`` (default:
a temporary folder; give one on the disk your runs write to). Last, the paper's supervised run
(20,000 steps, a checkpoint every 500) at a given loop speed: seconds its 40 checkpoints cost the
loop before (the curves redrawn at each) and now (the curves at most once a minute,
``metrics_log.CURVES_EVERY_S``, and at the end).
"""
from __future__ import annotations

import argparse
import csv
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def previous_save(run_dir: Path, payload: dict) -> None:
    """The previous ``save_checkpoint``: ``torch.save`` to the step file's path, then a copy to ``last.pt``."""
    folder = run_dir / "checkpoints"
    folder.mkdir(parents=True, exist_ok=True)
    step = folder / f"step_{payload['step']:06d}.pt"
    torch.save(payload, step)
    shutil.copyfile(step, folder / "last.pt")


def write_metrics(path: Path, steps: int) -> None:
    """A ``metrics.csv`` as ``fit`` writes it: one row per 10 steps, the supervised terms."""
    fields = ["step", "phase", "total", "l3d", "l2d", "kl", "pose", "lsc", "ray", "proj", "lr", "samples_per_s",
              "data_wait"]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(fields)
        for s in range(9, steps, 10):
            w.writerow([s, "supervised"] + [f"{1.0 / (s + 1) + 0.1 * k:.5f}" for k in range(8)] + [1e-3, 3000.0, 0.05])


def timed(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tiny", action="store_true")
    ap.add_argument("--device", default="auto")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--dir", type=Path, default=None)
    ap.add_argument("--loop-samples-per-s", type=float, default=3000.0,
                    help="the loop's speed for the paper-run projection (H100, 2026-11-27: ~3,000)")
    args = ap.parse_args()

    from sc3d_train.loop.checkpoint import save_checkpoint
    from sc3d_train.loop.metrics_log import CURVES_EVERY_S, plot_curves
    from sc3d_train.loop.runtime import DistInfo, resolve_device
    from sc3d_train.paper.model import SelfConsistencyNet
    from sc3d_train.settings.config import ModelConfig

    device = resolve_device(args.device, DistInfo())
    model = SelfConsistencyNet(ModelConfig.tiny() if args.tiny else ModelConfig()).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    sum(p.float().sum() for p in model.parameters()).backward()
    opt.step()
    payload = lambda: {"model": model.state_dict(), "optimizer": opt.state_dict(), "step": 500}  # noqa: E731
    size = sum(t.numel() * t.element_size() for t in model.state_dict().values()) + \
        sum(v.numel() * v.element_size() for s in opt.state_dict()["state"].values() for v in s.values()
            if torch.is_tensor(v))

    root = Path(tempfile.mkdtemp(dir=args.dir, prefix="sc3d-ckpt-"))
    try:
        before = timed(lambda: previous_save(root / "before", payload()), args.repeat)
        now = timed(lambda: save_checkpoint(root / "now", payload()), args.repeat)
        plots = {}
        for steps in (2000, 20000):
            write_metrics(root / f"metrics{steps}.csv", steps)
            plot_curves(root / f"metrics{steps}.csv", root / "warm.png")  # matplotlib's import, once
            plots[steps] = timed(lambda s=steps: plot_curves(root / f"metrics{s}.csv", root / "curves.png"),
                                 args.repeat)
    finally:
        shutil.rmtree(root, ignore_errors=True)

    print(f"model at {'--tiny' if args.tiny else 'the paper width'}: {size / 2**20:.0f} MiB of weights and Adam "
          f"moments on {device}; {args.repeat} runs each, median; folder on {args.dir or tempfile.gettempdir()}")
    print("| what | seconds | baseline, same run (ratio) |")
    print("|---|---|---|")
    print(f"| checkpoint as `fit` writes it (step file + copy to last.pt) | {now:.3f} | "
          f"torch.save to the path + copy: {before:.3f} ({before / now:.2f}x) |")
    for steps, sec in plots.items():
        print(f"| `curves.png` from {steps:,} steps of `metrics.csv` | {sec:.3f} | |")
    checkpoints = 20000 // 500
    interval = 500 * 48 / args.loop_samples_per_s  # seconds between checkpoints in the loop
    draws = min(checkpoints, int(checkpoints * interval // CURVES_EVERY_S) + 1)
    plot = statistics.mean(plots.values())
    was = checkpoints * (now + plot)
    is_ = checkpoints * now + draws * plot
    print(f"| the paper's run (20,000 steps, batch 48, a checkpoint every 500, loop at "
          f"{args.loop_samples_per_s:,.0f} samples/s: one every {interval:.0f} s): its {checkpoints} checkpoints "
          f"| {is_:.1f} ({draws} drawings) | drawn at each: {was:.1f} ({was / is_:.2f}x) |")


if __name__ == "__main__":
    main()
