"""The data streams of a training run: the phase datasets (all, labelled, unlabelled objects),
the list of labelled objects, and the seeded, resumable loaders of each phase."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

from sc3d_train.settings.config import RunConfig
from sc3d_train.data.dataset import ShardDataset
from sc3d_train.data.loader import make_loader, ring_slots, slot_bytes
from sc3d_train.loop.schedule import batch_split, data_position

#: most loader worker processes per stream that ``--workers`` auto gives a CUDA run: a worker
#: builds a batch of 48 from the shards in ~4 CPU-ms (docs/benchmarks.md), so 4 outrun a step of
#: ~8 ms several times over; more would only take cores from other ranks
AUTO_WORKERS_MAX = 4
#: loader seed offsets of the streams (labelled pre-training / all, unlabelled, labelled in the mix)
STREAM_SEEDS = {"supervised": 0, "unlabeled": 7919, "labeled_mix": 104729}


def phase_dataset(cfg: RunConfig, subset: str) -> ShardDataset:
    """``subset``: ``"all"``, ``"labeled"`` (with voxels) or ``"unlabeled"`` (no voxels needed)."""
    fraction = cfg.labeled_fraction if cfg.mode in ("semi", "labeled-only") else 1.0
    return ShardDataset(cfg.shards, cfg.split, subset=subset, labeled_fraction=fraction,
                        seed=cfg.seed, mask_size=cfg.model.mask_size,
                        require_voxels=subset != "unlabeled", image_size=cfg.image_size,
                        decoded_cache=cfg.decoded_cache)


def run_datasets(cfg: RunConfig) -> dict:
    """The datasets of a run: ``{"all": ...}`` (``supervised``, ``true-pose-masks``) or
    ``{"labeled": ...}`` (``labeled-only``), plus ``"unlabeled"`` when ``semi`` has a second
    phase. Every data error surfaces here, before any work."""
    labeled_subset = "labeled" if cfg.mode in ("semi", "labeled-only") else "all"
    datasets = {labeled_subset: phase_dataset(cfg, labeled_subset)}
    if cfg.mode == "semi" and cfg.pretrain_steps < cfg.steps:
        datasets["unlabeled"] = phase_dataset(cfg, "unlabeled")
    return datasets


def labeled_dataset(datasets: dict) -> ShardDataset:
    """The dataset of the labelled (supervised) stream of :func:`run_datasets`."""
    return datasets["labeled" if "labeled" in datasets else "all"]


def write_labeled_objects(path: Path, dataset: ShardDataset) -> None:
    """``CATEGORY/MODEL_ID`` of every labelled object, one per line."""
    lines = sorted(f"{r.category}/{r.model_id}" for r in dataset.objects)
    Path(path).write_text("\n".join(lines) + "\n")


def loader_workers(requested: int | None, device_type: str, decoded_cache: str | None, streams: int,
                   cpus: int | None = None, ranks_here: int = 1) -> int:
    """Worker processes of each of a phase's ``streams`` loaders. ``requested`` (``--workers``)
    when given; auto (None): 0 on the CPU (the step itself uses every core, and the main process
    outruns workers on a cached split) and with ``decoded_cache`` (a batch then costs the main
    process ~0.25 ms); on CUDA, where the main process only launches the step and building a
    batch of 48 from gzip-compressed shards in it (~4-7 ms) is most of a compiled step's 8 ms,
    ``min(AUTO_WORKERS_MAX, (cores of this rank - 1) // streams)``: the cores this process may
    use (``cpus``: its affinity) shared by the ranks of this machine (``ranks_here``:
    ``DistInfo.local_world_size``), one kept for the rank itself."""
    if requested is not None:
        return requested
    if device_type != "cuda" or decoded_cache:
        return 0
    if cpus is None:
        cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    spare = cpus // max(ranks_here, 1) - 1
    return max(0, min(AUTO_WORKERS_MAX, spare // max(streams, 1)))


def phase_loaders(t, step: int) -> dict:
    """Iterators over the batches of the phase that starts (or resumes) at ``step``, positioned
    where that phase's streams stopped: ``{"supervised": ...}`` and/or ``{"unsupervised": ...}``.
    ``t``: the :class:`~sc3d_train.loop.trainer.Training` of this process."""
    cfg, pos = t.cfg, data_position(t.cfg, step, t.local_batch)
    if pos["phase"] == "supervised":  # {name: (dataset, batch, stream seed, start)}
        specs = {"supervised": (t.labeled, t.local_batch, "supervised", pos["samples_per_rank"])}
    else:
        n_lab, n_unl = batch_split(cfg, t.local_batch)
        specs = {"unsupervised": (t.datasets["unlabeled"], n_unl, "unlabeled", pos["samples_per_rank"])}
        if n_lab:
            specs["supervised"] = (t.labeled, n_lab, "labeled_mix", pos["labeled_samples_per_rank"])
    here = t.dist.local_world_size
    workers = loader_workers(cfg.workers, t.device.type, cfg.decoded_cache, len(specs), ranks_here=here)
    note = ""
    if cfg.workers is None and workers:
        workers, note = fit_shared_memory(workers, [(d, b) for d, b, _, _ in specs.values()], ranks_here=here)
    if cfg.workers is None and t.dist.is_main and (workers or note):  # the CPU's 0 goes unsaid
        print(f"loader: {workers} worker process{'es' if workers != 1 else ''} per stream "
              f"(--workers auto on {t.device.type}{note}; --workers N sets it)")
    return {name: iter(make_loader(dataset, batch, cfg.seed + STREAM_SEEDS[stream], start=start,
                                   rank=t.dist.rank, world_size=t.dist.world_size,
                                   workers=workers, pin_memory=t.device.type == "cuda"))
            for name, (dataset, batch, stream, start) in specs.items()}


def fit_shared_memory(workers: int, streams: list[tuple[ShardDataset, int]],
                      free: int | None = None, ranks_here: int = 1) -> tuple[int, str]:
    """The most workers, at most ``workers``, whose loaders' rings (``ring_bytes`` of each
    ``(dataset, batch)`` stream) take at most this rank's share of half of the free shared
    memory (``free`` bytes; None: what ``/dev/shm`` has free, unlimited where there is no such
    folder; shared by the ``ranks_here`` ranks of this machine, ``DistInfo.local_world_size``), and a
    note saying so when that is fewer: a container's default /dev/shm (64 MB) holds the rings
    of few workers."""
    if free is None:
        if not os.path.isdir("/dev/shm"):
            return workers, ""
        free = shutil.disk_usage("/dev/shm").free
    slot_of_each = sum(slot_bytes(d, b) for d, b in streams)  # bytes: one slot of every stream's ring
    for w in range(workers, 0, -1):
        if ring_slots(w) * slot_of_each <= free // (2 * max(ranks_here, 1)):
            return w, "" if w == workers else f", fewer for the {free / 2 ** 20:.0f} MiB free in /dev/shm"
    return 0, f", none: {free / 2 ** 20:.0f} MiB free in /dev/shm"
