"""Throughput of the executors of ``sc3d-data render`` on one machine (issue 13).

    python benchmarks/scale.py [--meshes ../shared/meshes] [--workers 2] [--parts 2] [--views 24]

Renders ``--meshes`` (``--voxelize``, 64x64, shards to a temporary folder) four ways with the
same number of CPU slots (``--workers``):

- ``local``: the default process pool (``--workers`` spawned workers);
- ``ray``: ``--executor ray`` on a local Ray cluster of ``--workers`` CPUs; its start-up
  (``ray.init``) is timed apart and the rate is given without and with it;
- ``parts``: ``--parts`` processes ``sc3d-data render --part I/N`` side by side (``--workers``
  slots shared between them), then ``sc3d-data merge`` (timed, included);
- ``slurm-local``: ``--executor slurm --slurm-cluster local`` (submitit's LocalExecutor,
  ``--parts`` array tasks), merge included.

Prints objects/s and views/s (views of the objects that succeeded), the ratio to ``local``
and the overhead per object of each engine, ``(T_engine - T_local) / objects``. Every run is
checked to produce the same objects as ``local``. ``--repeat R`` runs R rounds of all four
(the machine's load changes over time) and shows the fastest of each.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def ids(out: Path) -> list:
    from sc3d_data.io.shards import load_index

    return sorted((o["category"], o["model_id"]) for o in load_index(out)["objects"])


def run_local(cfg) -> float:
    from sc3d_data.pipeline.jobs.render_run import render_dataset

    t0 = time.monotonic()
    render_dataset(cfg)
    return time.monotonic() - t0


def run_ray(cfg, workers: int) -> tuple[float, float]:
    import dataclasses

    from sc3d_data.pipeline.executors.ray_executor import init_local
    from sc3d_data.pipeline.jobs.render_run import render_dataset

    t0 = time.monotonic()
    ray = init_local(workers)
    t_init = time.monotonic() - t0
    try:
        t0 = time.monotonic()
        render_dataset(dataclasses.replace(cfg, executor="ray"))
        return t_init, time.monotonic() - t0
    finally:
        ray.shutdown()


def cli_args(cfg) -> list[str]:
    return ["--meshes", str(cfg.meshes), "--views", str(cfg.num_views), "--voxelize", "--no-progress",
            "--bad-texture", cfg.bad_texture, "--objects-per-shard", str(cfg.objects_per_shard)]


def run_parts(cfg, out: Path, parts: int, workers: int) -> float:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    t0 = time.monotonic()
    procs = []
    for i in range(parts):
        w = max(1, workers // parts + (1 if i < workers % parts else 0))
        cmd = [sys.executable, "-c", "from sc3d_cli.data import main; main()", "render", "--out", str(out / f"p{i}"), "--part", f"{i}/{parts}",
               "--workers", str(w), *cli_args(cfg)]
        procs.append(subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL))
    if any(p.wait() for p in procs):
        raise SystemExit("a part failed")
    subprocess.run([sys.executable, "-c", "from sc3d_cli.data import main; main()", "merge", str(out / "merged")]
                   + [str(out / f"p{i}") for i in range(parts)], cwd=REPO, env=env, check=True,
                   stdout=subprocess.DEVNULL)
    return time.monotonic() - t0


def run_slurm_local(cfg, parts: int, workers: int) -> float:
    from sc3d_data.pipeline.executors.slurm_executor import SlurmOptions
    from sc3d_data.pipeline.jobs.render_run import render_on_slurm

    t0 = time.monotonic()
    render_on_slurm(cfg, SlurmOptions(parts=parts, cpus_per_task=max(1, workers // parts), cluster="local"))
    return time.monotonic() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", type=Path, default=REPO.parent / "shared" / "meshes")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--parts", type=int, default=2)
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--repeat", type=int, default=1, help="rounds of all engines; the fastest of each is shown")
    args = ap.parse_args()
    sys.argv = sys.argv[:1]
    from sc3d_data.pipeline.jobs.render_job import RenderConfig

    with tempfile.TemporaryDirectory(prefix="sc3d-scale-") as tmp:
        tmp = Path(tmp)

        def cfg(name):
            return RenderConfig(out=tmp / name, meshes=args.meshes, num_views=args.views, voxelize=True,
                                workers=args.workers, bad_texture="fallback", progress=False, objects_per_shard=64)

        rows: dict = {}

        def keep(name, t, t0=0.0):
            if name not in rows or t < rows[name][0]:
                rows[name] = (t, t0)

        for r in range(args.repeat):  # rounds, so that a change of load hits every engine alike
            sub = tmp / f"round{r}"
            keep("local", run_local(cfg(f"round{r}/local")))
            n = len(ids(sub / "local"))
            t_init, t_ray = run_ray(cfg(f"round{r}/ray"), args.workers)
            keep("ray", t_ray, t_init)
            keep(f"{args.parts} parts + merge", run_parts(cfg("parts"), sub / "parts", args.parts, args.workers))
            keep(f"slurm-local {args.parts} parts + merge",
                 run_slurm_local(cfg(f"round{r}/slurm"), args.parts, args.workers))
            for out in ("ray", "parts/merged", "slurm"):
                assert ids(sub / out) == ids(sub / "local"), f"{out}: other objects than the local run"
    views = n * args.views
    t_local = rows["local"][0]
    print(f"{n} objects x {args.views} views (+ 32^3 voxels), {args.workers} CPU slots, meshes {args.meshes}")
    print("| engine | wall s | objects/s | views/s | vs local | overhead ms/object |")
    print("|---|---|---|---|---|---|")
    for name, (t, t0) in rows.items():
        for label, total in ((name, t),) + (((f"{name} incl. start-up {t0:.1f} s", t + t0),) if t0 else ()):
            print(f"| {label} | {total:.1f} | {n / total:.2f} | {views / total:.0f} | {t_local / total:.2f}x | "
                  f"{1000 * (total - t_local) / n:+.0f} |")


if __name__ == "__main__":
    main()
