"""The data streams of a training run: the phase datasets (all, labelled, unlabelled objects),
the list of labelled objects, and the seeded, resumable loaders of each phase."""
from __future__ import annotations

from pathlib import Path

from sc3d_train.settings.config import RunConfig
from sc3d_train.data.dataset import ShardDataset
from sc3d_train.data.loader import make_loader
from sc3d_train.loop.schedule import batch_split, data_position, mixed_batch

#: loader seed offsets of the streams (labelled pre-training / all, unlabelled, labelled in the mix)
STREAM_SEEDS = {"supervised": 0, "unlabeled": 7919, "labeled_mix": 104729}


def phase_dataset(cfg: RunConfig, subset: str) -> ShardDataset:
    """``subset``: ``"all"``, ``"labeled"`` (with voxels) or ``"unlabeled"`` (no voxels needed)."""
    fraction = cfg.labeled_fraction if cfg.mode in ("semi", "labeled-only") else 1.0
    return ShardDataset(cfg.shards, cfg.split, subset=subset, labeled_fraction=fraction,
                        seed=cfg.seed, mask_size=cfg.model.mask_size,
                        require_voxels=subset != "unlabeled", image_size=cfg.image_size,
                        decoded_cache=cfg.decoded_cache, order=cfg.dataset_order)


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


def phase_loaders(t, step: int) -> dict:
    """Iterators over the batches of the phase that starts (or resumes) at ``step``, positioned
    where that phase's streams stopped: ``{"supervised": ...}`` and/or ``{"unsupervised": ...}``.
    ``t``: the :class:`~sc3d_train.loop.trainer.Training` of this process."""
    cfg, pos = t.cfg, data_position(t.cfg, step, t.local_batch)
    if pos["phase"] == "supervised":  # {name: (dataset, batch, stream seed, start)}
        specs = {"supervised": (t.labeled, t.local_batch, "supervised", pos["samples_per_rank"])}
    else:
        n_lab, n_unl = batch_split(cfg, mixed_batch(cfg, t.local_batch))
        specs = {"unsupervised": (t.datasets["unlabeled"], n_unl, "unlabeled", pos["samples_per_rank"])}
        if n_lab:
            specs["supervised"] = (t.labeled, n_lab, "labeled_mix", pos["labeled_samples_per_rank"])
    # --workers auto (None) is 0, the batches built in this process: on the CPU the step uses every
    # core, and on an H100 with 16 cores 0 beat 4 and 8 worker processes (docs/benchmarks.md)
    workers = cfg.workers or 0
    return {name: iter(make_loader(dataset, batch, cfg.seed + STREAM_SEEDS[stream], start=start,
                                   rank=t.dist.rank, world_size=t.dist.world_size,
                                   workers=workers, pin_memory=t.device.type == "cuda"))
            for name, (dataset, batch, stream, start) in specs.items()}
