"""Two training runs' loss curves against the run-to-run noise, and their in-loop speed (issue 21).

    python benchmarks/compare_curves.py RUN_A RUN_B --noise RUN_C [--out curves.png] [--windows 4]

RUN_A, RUN_B, RUN_C are ``fit --out`` folders (their ``metrics.csv``). The question is whether A
and B (e.g. ``--compile off`` and the compiled default, same seed) train the same: the total
loss is averaged over ``--windows`` equal stretches of steps (those with a logged step in each
run), and the mean absolute difference
of A and B over the stretches is set against that of B and C, where C is B's setting with
another seed (the run-to-run noise). "same curve" when A-B is at most twice B-C.

Prints per stretch the three mean losses, the two differences, the verdict, and per run the
median samples/s of the loop (the logged ``samples_per_s``, leaving out the first tenth of the
log, where compilation and warm-up fall); with ``--project-steps N --wall-b S``, the wall time
of B's setting for N steps (S, B's own wall time, plus the steps it lacks at its median rate:
issue 21's paper supervised run, 20,000 steps of 48, in under 10 minutes). ``--out``: a picture of the three curves (the total
loss per logged step, and its running mean).
"""
from __future__ import annotations

import argparse
import csv
import statistics
from pathlib import Path


def read_log(run: Path) -> tuple[list[int], list[float], list[float]]:
    """``(steps, total loss, samples/s)`` from ``RUN/metrics.csv``."""
    steps, total, rate = [], [], []
    with open(run / "metrics.csv", newline="") as f:
        for row in csv.DictReader(f):
            steps.append(int(row["step"]))
            total.append(float(row["total"]))
            rate.append(float(row["samples_per_s"]))
    if not steps:
        raise SystemExit(f"compare_curves: {run / 'metrics.csv'} has no logged step")
    return steps, total, rate


def window_means(steps: list[int], values: list[float], edges: list[float]) -> list[float]:
    """Mean of ``values`` whose step lies in each ``[edges[i], edges[i+1])`` (the last one closed)."""
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        inside = [v for s, v in zip(steps, values) if lo <= s < hi or (hi == edges[-1] and s == hi)]
        out.append(statistics.fmean(inside) if inside else float("nan"))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run_a", type=Path)
    ap.add_argument("run_b", type=Path)
    ap.add_argument("--noise", type=Path, required=True, help="RUN_B's setting with another seed")
    ap.add_argument("--windows", type=int, default=4)
    ap.add_argument("--out", type=Path, default=None, help="picture of the curves (PNG)")
    ap.add_argument("--project-steps", type=int, default=0,
                    help="with --wall-b: project RUN_B's setting to this many steps (the paper preset: 20000)")
    ap.add_argument("--wall-b", type=float, default=0.0, help="RUN_B's wall seconds, start-up and compiling included")
    ap.add_argument("--batch-size", type=int, default=48, help="RUN_B's batch (for --project-steps)")
    a = ap.parse_args()
    runs = {"A": a.run_a, "B": a.run_b, "C": a.noise}
    logs = {k: read_log(p) for k, p in runs.items()}
    last = min(log[0][-1] for log in logs.values())
    edges = [last * i / a.windows for i in range(a.windows + 1)]
    means = {k: window_means(log[0], log[1], edges) for k, log in logs.items()}
    kept = [i for i in range(a.windows) if all(means[k][i] == means[k][i] for k in runs)]  # stretches logged in all
    if not kept:
        raise SystemExit("compare_curves: no stretch of steps is logged in all three runs (fewer --windows?)")
    ab = [abs(means["A"][i] - means["B"][i]) for i in kept]
    bc = [abs(means["B"][i] - means["C"][i]) for i in kept]
    for k, p in runs.items():
        print(f"{k}: {p}")
    print("\n| steps | A total loss | B | C (B, other seed) | abs(A-B) | abs(B-C) |")
    print("|---|---|---|---|---|---|")
    for j, i in enumerate(kept):
        print(f"| {edges[i]:.0f}-{edges[i + 1]:.0f} | {means['A'][i]:.4f} | {means['B'][i]:.4f} | {means['C'][i]:.4f} | "
              f"{ab[j]:.4f} | {bc[j]:.4f} |")
    mab, mbc = statistics.fmean(ab), statistics.fmean(bc)
    verdict = "same curve (within twice the run-to-run noise)" if mab <= 2 * mbc else "DIFFERENT curves"
    print(f"\nmean abs(A-B) {mab:.4f} against run-to-run abs(B-C) {mbc:.4f}: {verdict}")
    print("\n| run | median samples/s in the loop (first tenth of the log left out) | logged steps |")
    print("|---|---|---|")
    for k, (steps, _, rate) in logs.items():
        warm = rate[len(rate) // 10:] or rate
        print(f"| {k} | {statistics.median(warm):.0f} | {steps[-1]} |")
    if a.project_steps and a.wall_b:
        steps_b, _, rate_b = logs["B"]
        rate = statistics.median(rate_b[len(rate_b) // 10:] or rate_b)
        projected = a.wall_b + max(a.project_steps - steps_b[-1] - 1, 0) * a.batch_size / rate
        print(f"\nB's setting for {a.project_steps} steps of {a.batch_size}: {projected:.0f} s ({projected / 60:.1f} min): "
              f"its {a.wall_b:.0f} s for {steps_b[-1] + 1} steps, start-up and compiling included, plus the rest "
              f"at {rate:.0f} samples/s")
    if a.out:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(8, 4.5))
        for k, (steps, total, _) in logs.items():
            ax.plot(steps, total, lw=0.6, alpha=0.35)
            run_mean = [statistics.fmean(total[max(0, i - 9):i + 1]) for i in range(len(total))]
            ax.plot(steps, run_mean, lw=1.6, color=ax.lines[-1].get_color(), label=f"{k}: {runs[k].name}")
        ax.set_xlabel("step")
        ax.set_ylabel("total loss (running mean of 10 logs; thin: as logged)")
        ax.set_yscale("log")
        ax.set_title(f"A against B: {verdict}")
        ax.legend()
        fig.tight_layout()
        fig.savefig(a.out, dpi=110)
        print(f"\npicture: {a.out}")


if __name__ == "__main__":
    main()
