"""Speed of training: one optimiser step, the shard loader, the self-consistency module.

    python benchmarks/train_step.py [--shards DIR] [--compare-shards DIR] [--batch-size 48] [--device auto] [--tiny]
                                    [--loader-only] [--workers 0,2,4] [--skip-loader] [--skip-supervised] [--skip-semi] [--skip-sc]
                                    [--profile [--profile-steps 3]]

Without ``--shards`` the bundled sample meshes are rendered + voxelized into a temporary
directory first (a few seconds). Three tables, each with a straightforward baseline measured in
the same run, so improvements show as ratios:

1. training step (forward + losses + backward + Adam: ``fit``'s own ``TrainStep``) at the given
   batch, variants interleaved step by step (the median of ``--steps`` per variant, after two
   warm-up steps that compile), all from the same weights, batch and noise: the baseline (plain
   fp32 eager, NCHW, default Adam) against ``fit``'s default for the device (CUDA: compiled with
   CUDA graphs, bf16/fp16 autocast, channels_last, fused Adam; CPU: fp32 eager) and, for
   reference, ``--compile off`` on CUDA, the compiled step on the CPU and bf16 variants; the last
   column is the largest relative difference of the first step's loss terms from the baseline's;
   1b. the same for the mixed step of ``--semi`` (half the batch labelled, half unlabelled, with
   the pose search on the predictions); ``--profile``: torch.profiler's top kernels and the
   kernel launches per step of ``fit``'s default (``step_variants.py``);
2. loader samples/s with 0, 2 and 4 worker processes (``--workers``): the per-item DataLoader
   (the first ``make_loader``) and the previous one (whole batches per worker, each packed into
   a new tensor sent through the DataLoader's queue) against ``make_loader`` (whole batches per
   worker written into a shared-memory ring made once, compact batches) and ``make_loader`` followed by the float expansion on the CPU (what a CPU
   training step adds; on a GPU it runs on the device), with every object of the split cached
   once decoded, without a cache (each batch reads its views from the files: large
   datasets) and from a decoded cache folder (``--decoded-cache``, built in a temporary
   folder first), against the training step's samples/s (the loader should outrun the step);
3. the self-consistency module (``benchmark_self_consistency`` below): ms per batch and memory,
   against the gather + loop baseline.
"""
from __future__ import annotations

import argparse
import os
import platform
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))  # drc_reference: the plain baseline the tests also use
sys.path.insert(0, str(REPO / "benchmarks"))  # step_variants

import torch  # noqa: E402

warnings.filterwarnings("ignore", message="This DataLoader will create")


def render_samples(out: Path) -> Path:
    from click.testing import CliRunner

    from sc3d_cli.data import main

    res = CliRunner().invoke(main, ["render", "--meshes", str(REPO / "assets" / "sample_meshes"),
                                    "--out", str(out), "--voxelize", "--workers", "2"])
    if res.exit_code:
        raise SystemExit(f"rendering the sample meshes failed:\n{res.output}")
    return out


def per_item_loader(ds, batch_size: int, workers: int, seed: int = 0):
    """The first make_loader, kept as the baseline: per-sample ``__getitem__`` in the
    workers, ``default_collate`` into ~14 float tensors sent through shared memory."""
    from sc3d_train.data.loader import ViewSampler, _limit_worker_threads

    return torch.utils.data.DataLoader(
        ds, batch_size=batch_size, sampler=ViewSampler(ds.num_objects, ds.num_views, seed),
        num_workers=workers, drop_last=True, worker_init_fn=_limit_worker_threads if workers else None,
        prefetch_factor=4 if workers else None)


class _QueuedBatches(torch.utils.data.Dataset):
    """Whole compact batches, each packed into a new tensor in the worker (the previous
    make_loader): the DataLoader queue gives every batch its own shared-memory segment and fd."""

    def __init__(self, ds):
        self.ds = ds

    def __len__(self):
        return len(self.ds)

    def __getitem__(self, key):
        from sc3d_train.data.batch_format import BINARY_KEYS
        from sc3d_train.data.batch_transfer import pack

        arrays, strings = self.ds.compact_batch(key[1][0])
        return pack(arrays, strings, bits=BINARY_KEYS) if torch.utils.data.get_worker_info() else (arrays, strings)


def queued_loader(ds, batch_size: int, workers: int, seed: int = 0):
    """The previous make_loader, kept as a baseline: whole batches per worker, packed into one
    tensor per batch that travels through the DataLoader's queue (not the shared ring)."""
    from sc3d_train.data.batch_format import compact_tensors
    from sc3d_train.data.batch_transfer import PackedBatch, unpack
    from sc3d_train.data.loader import BatchSampler, ViewSampler, _keep, _limit_worker_threads

    loader = torch.utils.data.DataLoader(
        _QueuedBatches(ds), batch_size=None, num_workers=workers, collate_fn=_keep,
        sampler=BatchSampler(ViewSampler(ds.num_objects, ds.num_views, seed), batch_size),
        worker_init_fn=_limit_worker_threads if workers else None, prefetch_factor=4 if workers else None)
    return (compact_tensors(*((unpack(b), b.other) if isinstance(b, PackedBatch) else b)) for b in loader)


def children_cpu_seconds() -> float:
    """User + system CPU seconds of this process's live child processes (the loader's workers),
    from /proc (Linux; 0 elsewhere)."""
    total, tick = 0.0, os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    for task in Path(f"/proc/{os.getpid()}/task").glob("*"):
        try:
            pids = (task / "children").read_text().split()
        except OSError:
            continue
        for pid in pids:
            try:
                fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:  # exited meanwhile
                continue
            total += (int(fields[11]) + int(fields[12])) / tick
    return total


def time_loaders(datasets: dict[str, Path], batch_size: int, workers: tuple[int, ...], batches: int,
                 rounds: int, cache_objects: int, decoded_cache: Path | None = None) -> dict:
    """Samples/s, main-process CPU ms per batch (``time.process_time``, all its threads) and
    worker-process CPU ms per batch (:func:`children_cpu_seconds`) of
    the per-item baseline, the previous packed-tensor loader and ``make_loader`` (as it yields,
    and followed by the float expansion on the CPU) at each worker count, for each of ``datasets`` (label ->
    shard folder, e.g. the same meshes rendered with ``--chunks view`` and ``--chunks
    object``): the median over ``rounds`` rounds, each round running every variant once,
    interleaved (a fresh loader with its own seed each time, so that no run finds another's
    samples in HDF5's chunk cache: at scale a view comes back once per epoch). Not timed: the first batches
    (worker start-up, prefetch queue: ``2 + 8 * workers``) and, with a cache, enough batches for each worker to have
    decoded every object (6 epochs per worker). ``cache_objects=0``: no cache, each batch reads
    its views from the files; ``decoded_cache``: a folder for the decoded copy
    (``sc3d_train.data.decoded_cache``, built before timing), gathered from instead."""
    from sc3d_train.data.batch_format import expand_batch
    from sc3d_train.data.dataset import ShardDataset
    from sc3d_train.data.loader import make_loader

    makers, warm = {}, {}
    for label, shards in datasets.items():
        ds = ShardDataset(shards, "train", cache_objects=cache_objects,
                          decoded_cache=decoded_cache / label.strip(": ") if decoded_cache else None)
        epoch = -(-6 * ds.num_objects // batch_size) if cache_objects else 0
        for w in workers:
            makers[(label, "per-item", w)] = lambda s, ds=ds, w=w: per_item_loader(ds, batch_size, w, s)
            makers[(label, "packed tensor per batch (previous)", w)] = \
                lambda s, ds=ds, w=w: queued_loader(ds, batch_size, w, s)
            makers[(label, "make_loader", w)] = lambda s, ds=ds, w=w: make_loader(ds, batch_size, s, workers=w)
            makers[(label, "make_loader + float on CPU", w)] = \
                lambda s, ds=ds, w=w: map(expand_batch, make_loader(ds, batch_size, s, workers=w))
            for name in ("per-item", "packed tensor per batch (previous)", "make_loader",
                         "make_loader + float on CPU"):
                warm[(label, name, w)] = 2 + 8 * w + max(w, 1) * epoch
    rates: dict = {k: [] for k in makers}
    cpu: dict = {k: [] for k in makers}
    worker_cpu: dict = {k: [] for k in makers}
    for r in range(rounds):
        for i, (key, make) in enumerate(makers.items()):
            it = iter(make(1000 * r + i))  # a new seed each time: no run replays another's reads
            for _ in range(warm[key]):
                next(it)
            t0, c0, w0 = time.perf_counter(), time.process_time(), children_cpu_seconds()
            for _ in range(batches):
                next(it)
            rates[key].append(batches * batch_size / (time.perf_counter() - t0))
            cpu[key].append(1000 * (time.process_time() - c0) / batches)
            worker_cpu[key].append(1000 * (children_cpu_seconds() - w0) / batches)
            del it
    med = lambda v: sorted(v)[len(v) // 2]  # noqa: E731
    return {k: (med(v), med(cpu[k]), med(worker_cpu[k])) for k, v in rates.items()}


def table(title: str, header: tuple[str, ...], rows: list[tuple]) -> str:
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    fmt = "  ".join(f"{{:<{w}}}" if i == 0 else f"{{:>{w}}}" for i, w in enumerate(widths))
    lines = [title, fmt.format(*header), fmt.format(*("-" * w for w in widths))]
    lines += [fmt.format(*r) for r in rows]
    return "\n".join(lines)


def benchmark_self_consistency(batch_size: int = 48, device: str | torch.device = "cpu", repeats: int = 3,
                               voxel_resolution: int = 32, mask_size: int | None = None,
                               num_samples: int | None = None) -> list[dict]:
    """Time forward + backward of the self-consistency loss at ``batch_size`` on ``device``:
    the baseline (``tests/drc_reference.py``, hand-written gather + loop) and the module
    (grid_sample + log-space escape). Returns one row per variant: ``name``, ``ms_per_batch`` (median of
    ``repeats`` after one warm-up), ``saved_mb`` (tensors kept for backward, measured with
    saved-tensor hooks; device independent) and ``peak_mb`` (CUDA peak allocation, else None)."""

    from drc_reference import project_occupancy_reference

    from sc3d_data.geometry.camera import intrinsics, scale_intrinsics
    from sc3d_train.paper.self_consistency import DEFAULT_NUM_SAMPLES, iou_loss, self_consistency_losses

    from sc3d_train.settings.config import MASK_SIZE

    num_samples = num_samples or DEFAULT_NUM_SAMPLES
    mask_size = mask_size or MASK_SIZE
    dev = torch.device(device)
    gen = torch.Generator().manual_seed(0)
    occ0 = (torch.rand(batch_size, voxel_resolution, voxel_resolution, voxel_resolution, generator=gen) * 0.3)
    masks = (torch.rand(batch_size, mask_size, mask_size, generator=gen) > 0.5).float().to(dev)
    K = torch.as_tensor(scale_intrinsics(intrinsics(64), mask_size, 64), dtype=torch.float32)
    K = K.expand(batch_size, 3, 3).contiguous().to(dev)
    az0 = torch.rand(batch_size, generator=gen) * 360
    el = torch.full((batch_size,), 30.0, device=dev)
    dist = torch.full((batch_size,), 2.0, device=dev)

    def run_module(occ, az):
        out = self_consistency_losses(occ, masks, az, el, dist, K, num_samples)
        return 5.0 * out["ray"] + 0.125 * out["proj"]

    def run_reference(occ, az):
        p = project_occupancy_reference(occ, az, el, dist, K, mask_size, num_samples)
        return iou_loss(p, masks)

    rows = []
    for name, fn in (("baseline: gather + loop (fp32)", run_reference), ("grid_sample + log-space escape (fp32)", run_module)):
        times, saved = [], 0
        for rep in range(repeats + 1):
            occ = occ0.to(dev).requires_grad_(True)
            az = az0.to(dev).requires_grad_(True)
            nbytes = [0]

            def pack(t, nbytes=nbytes):
                nbytes[0] += t.numel() * t.element_size()
                return t

            if dev.type == "cuda":
                torch.cuda.synchronize(dev)
                torch.cuda.reset_peak_memory_stats(dev)
            t0 = time.perf_counter()
            with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
                loss = fn(occ, az)
            loss.backward()
            if dev.type == "cuda":
                torch.cuda.synchronize(dev)
            if rep > 0:
                times.append(time.perf_counter() - t0)
            saved = nbytes[0]
        peak = torch.cuda.max_memory_allocated(dev) / 2**20 if dev.type == "cuda" else None
        times.sort()
        rows.append({"name": name, "ms_per_batch": 1000 * times[len(times) // 2], "saved_mb": saved / 2**20,
                     "peak_mb": peak, "batch_size": batch_size, "device": str(dev)})
    return rows


def step_variants_of(device) -> list[tuple]:
    """Table 1's variants ``(name, amp dtype, channels_last, compile)``: the plain fp32 eager
    baseline first, ``fit``'s default for the device second."""
    base = [("baseline: plain fp32 eager, NCHW", None, False, "off")]
    if device.type == "cuda":
        amp = torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16
        name = str(amp)[6:]
        return base + [(f"fit default: compiled (CUDA graphs), {name} autocast + channels_last", amp, True, "on"),
                       (f"--compile off: {name} autocast + channels_last, eager", amp, True, "off"),
                       (f"{name} autocast only, eager", amp, False, "off")]
    return base + [("fit default on CPU: fp32 eager, NCHW (same code as the baseline)", None, False, "off"),
                   ("--compile on: inductor (C++), fp32, NCHW", None, False, "on"),
                   ("bf16 autocast + channels_last, eager", torch.bfloat16, True, "off")]


def step_tables(cfg, batch, device, args) -> float | None:
    """Tables 1 (supervised step) and 1b (the mixed step of ``--semi``), ``--profile`` of fit's
    default; returns fit's default samples/s (for table 2)."""
    from step_variants import loss_difference, profile_steps, time_variants

    variants = step_variants_of(device)
    rate = None
    for phase, title in (("supervised", "1. training step (supervised)"),
                         ("semi", "1b. mixed step of --semi (half labelled, half unlabelled: pose search on the "
                                  "predictions)")):
        if (phase == "semi" and args.skip_semi) or (phase == "supervised" and args.skip_supervised):
            continue
        print(f"\n{title}: building and warming up")
        timed = time_variants(cfg, batch, device, variants, args.steps, phase)
        base_sec, base_runner = timed[0]
        rows = []
        for (name, *_), (sec, runner) in zip(variants, timed):
            diff = loss_difference(runner, base_runner)
            rows.append((name, "failed", "-", "-", "-") if sec is None else
                        (name, f"{1000 * sec:.0f}", f"{args.batch_size / sec:.1f}",
                         f"{base_sec / sec:.2f}x" if base_sec else "-", f"{diff:.1e}" if diff is not None else "-"))
        print()
        print(table(f"{title}, batch {args.batch_size}, {device.type}",
                    ("variant", "ms/step", "samples/s", "vs baseline", "loss vs baseline"), rows))
        if phase == "supervised" and timed[1][0]:
            rate = args.batch_size / timed[1][0]
        if args.profile and timed[1][1] is not None:
            print(f"\nprofile of '{variants[1][0]}', {phase}, {args.profile_steps} steps:")
            print(profile_steps(timed[1][1], args.profile_steps))
    return rate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shards", type=Path, default=None)
    ap.add_argument("--compare-shards", type=Path, default=None,
                    help="a second shard folder for table 2 (e.g. the same meshes rendered with --chunks object)")
    ap.add_argument("--batch-size", type=int, default=48)
    ap.add_argument("--steps", type=int, default=5, help="timed steps per variant (median)")
    ap.add_argument("--loader-batches", type=int, default=30)
    ap.add_argument("--loader-rounds", type=int, default=3)
    ap.add_argument("--workers", default="0,2,4", help="loader worker counts of table 2 (comma-separated, 0 first)")
    ap.add_argument("--device", default="auto")
    ap.add_argument("--tiny", action="store_true", help="the --tiny model instead of the paper's width")
    ap.add_argument("--skip-loader", action="store_true")
    ap.add_argument("--skip-semi", action="store_true", help="no table 1b (the mixed step of --semi)")
    ap.add_argument("--skip-supervised", action="store_true", help="no table 1 (the supervised step)")
    ap.add_argument("--skip-sc", action="store_true", help="no table 3 (the self-consistency module)")
    ap.add_argument("--profile", action="store_true",
                    help="torch.profiler of fit's default step: top kernels, kernel launches per step")
    ap.add_argument("--profile-steps", type=int, default=3)
    ap.add_argument("--loader-only", action="store_true", help="only table 2 (no training step: its last column is then -)")
    args = ap.parse_args()

    from sc3d_train.data.dataset import ShardDataset
    from sc3d_train.data.loader import make_loader
    from sc3d_train.loop.resolve import resolve_config
    from sc3d_train.loop.runtime import DistInfo, resolve_device

    device = resolve_device(args.device, DistInfo())
    tmp = None
    shards = args.shards
    if shards is None:
        tmp = tempfile.TemporaryDirectory()
        shards = render_samples(Path(tmp.name) / "shards")
    cfg = resolve_config({"shards": str(shards), "out": "unused", "batch_size": args.batch_size},
                         {"tiny": args.tiny})
    gpu = torch.cuda.get_device_name(device) if device.type == "cuda" else None
    print(f"device: {device} ({gpu or platform.processor() or 'cpu'}; {torch.get_num_threads()} torch threads); "
          f"GPU available: {torch.cuda.is_available()}; torch {torch.__version__}")
    print(f"model: {cfg.model}")
    batch = next(iter(make_loader(ShardDataset(shards, "train"), args.batch_size, seed=0)))

    # 1. training step (and 1b. the mixed step of --semi)
    step_rate = None
    if not args.loader_only:
        step_rate = step_tables(cfg, batch, device, args)

    # 2. loader
    workers = tuple(int(w) for w in args.workers.split(","))
    if not args.skip_loader:
        decoded = Path(tempfile.mkdtemp(prefix="sc3d-decoded-"))
        for cache, regime, folder in ((10 ** 6, "every object cached once decoded", None),
                                      (0, "no cache: every sample read from the file", None),
                                      (0, "decoded cache folder (opt-in --decoded-cache)", decoded)):
            batches = args.loader_batches
            datasets = {"": shards} if args.compare_shards is None else \
                {f"{shards.name}: ": shards, f"{args.compare_shards.name}: ": args.compare_shards}
            timed = time_loaders(datasets, args.batch_size, workers, batches, args.loader_rounds, cache, folder)
            rates = {k: r for k, (r, _, _) in timed.items()}
            base = {label: rates[(label, "per-item", 0)] for label in datasets}
            rows = [(f"{label}{name}, {w} workers", f"{r:.0f}", f"{r / base[label]:.2f}x",
                     f"{r / rates[(label, name, 0)]:.2f}x" if (label, name, 0) in rates else "-",
                     f"{timed[(label, name, w)][1]:.2f}", f"{timed[(label, name, w)][2]:.2f}",
                     f"{r / step_rate:.1f}x" if step_rate else "-")
                    for (label, name, w), r in rates.items()]
            print()
            print(table(f"2. loader, batch {args.batch_size}, {regime} (samples/s, median of "
                        f"{args.loader_rounds} interleaved rounds of {batches} batches)",
                        ("loader", "samples/s", "vs per-item 0 workers", "vs same, 0 workers",
                         "main CPU ms/batch", "workers CPU ms/batch", "vs fit step"), rows))
        shutil.rmtree(decoded, ignore_errors=True)

    if args.loader_only or args.skip_sc:
        return
    # 3. self-consistency module
    sc = benchmark_self_consistency(batch_size=args.batch_size, device=device)
    base = sc[0]["ms_per_batch"]
    rows = [(r["name"], f"{r['ms_per_batch']:.0f}", f"{base / r['ms_per_batch']:.2f}x", f"{r['saved_mb']:.0f}",
             "-" if r["peak_mb"] is None else f"{r['peak_mb']:.0f}") for r in sc]
    print()
    print(table(f"3. self-consistency loss forward+backward, batch {args.batch_size}, 48x48 rays x 64 samples",
                ("variant", "ms/batch", "vs baseline", "saved MB", "CUDA peak MB"), rows))
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
