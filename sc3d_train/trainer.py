"""``sc3d-train fit``: supervised, semi-supervised and labelled-only training of the
self-consistency network (paper Sec. 3.3) on sc3d shards.

Phases (see :class:`~sc3d_train.config.RunConfig`):

* ``supervised`` (all training objects) and ``labeled-only`` (the seeded labelled subset only):
  ``supervised_loss`` (L_3D + L_2D + L_sc on ground-truth voxels/masks with the *predicted*
  pose + KL) at ``lr``.
* ``semi``: ``pretrain_steps`` steps as ``labeled-only`` (a checkpoint is written at the phase
  boundary), then mixed batches at ``semi_lr`` (default ``lr``): ``semi_labeled_share`` of each
  batch labelled images with ``supervised_loss``, the rest unlabelled training objects with
  ``unsupervised_loss`` (L_sc on predicted voxels and masks + KL + pose search on the
  predictions), two forward passes (BatchNorm statistics of the labelled images only); the Adam moments carry over. Logged: the labelled
  terms under their names, the unlabelled ones prefixed ``u_``.

Pose: the pose head is a classifier over a candidate grid (:mod:`sc3d_train.pose`); its target
for a labelled image is the candidate with the lowest L_sc between the image's ground-truth voxels
and mask, searched once per object before training (:func:`~sc3d_train.pose_search.dataset_pose_targets`),
and for an unlabelled image the same search between the predicted voxels and mask.
The labelled objects of ``semi`` / ``labeled-only`` are listed in ``RUN_DIR/labeled_objects.txt``.

The ground-truth pose (``azimuth``, ``elevation``, ``R``, ``t``) is removed from every training
batch before the model and the losses see it; in the unsupervised phase the voxels and masks
are removed too. The camera's intrinsics and distance (fixed by the dataset) stay.

Run on one device or with ``torchrun`` (DDP, env ``RANK``/``WORLD_SIZE``/``LOCAL_RANK``; NCCL
on CUDA, gloo on CPU); the global batch is split evenly over ranks. Everything that decides the
trajectory (weights, optimiser, AMP scaler, every RNG, step, data position) is checkpointed, so
``--resume`` continues exactly: the loss at step N equals the uninterrupted run's.
"""
from __future__ import annotations

import csv
import math
import os
import random
import time
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from sc3d_train.checkpoint import (CheckpointError, build_model, last_path, resume_checkpoint,
                                   rng_state, save_checkpoint, set_rng_state, state_dict_mismatch)
from sc3d_train.config import RunConfig
from sc3d_train.data import ShardDataset, make_loader

#: batch keys that carry the ground-truth pose: never given to the model or a loss
POSE_KEYS = ("azimuth", "elevation", "R", "t")
#: batch keys that carry 3D/2D labels: removed in the unsupervised phase
LABEL_KEYS = ("voxels", "masks", "masks_sc")
CSV_NAME = "metrics.csv"


class TrainingDiverged(RuntimeError):
    """The loss became NaN/inf; the message names the step and the last good checkpoint."""


# ----------------------------------------------------------------------------- environment
@dataclass
class DistInfo:
    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def setup_distributed(device_name: str) -> DistInfo:
    """Join the torchrun process group when ``WORLD_SIZE > 1`` (NCCL on CUDA, else gloo)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistInfo()
    import torch.distributed as dist

    info = DistInfo(int(os.environ["RANK"]), world, int(os.environ.get("LOCAL_RANK", "0")))
    if not dist.is_initialized():
        use_cuda = torch.cuda.is_available() and device_name != "cpu"
        dist.init_process_group("nccl" if use_cuda else "gloo")
    return info


def resolve_device(name: str, dist: DistInfo) -> torch.device:
    """``auto``: CUDA (this rank's local GPU) when available, else CPU."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda":
        name = f"cuda:{dist.local_rank}"
    device = torch.device(name)
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise RuntimeError(f"device {name} requested but CUDA is not available")
        torch.cuda.set_device(device)
    return device


def resolve_amp(cfg: RunConfig, device: torch.device) -> torch.dtype | None:
    """The autocast dtype: ``auto`` is bf16 on CUDA GPUs that support it, else fp16 on CUDA,
    and off (fp32) on the CPU."""
    if cfg.amp == "off" or (cfg.amp == "auto" and device.type != "cuda"):
        return None
    if cfg.amp == "bf16" or (cfg.amp == "auto" and torch.cuda.is_bf16_supported()):
        return torch.bfloat16
    return torch.float16


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % 2 ** 32)
    torch.manual_seed(seed)


def resolve_config(options: dict, model_options: dict, given: set[str], resume: bool) -> RunConfig:
    """The full :class:`RunConfig` of a ``fit`` command line.

    New run: ``options`` (RunConfig fields) plus the model config: ModelConfig defaults, the
    image size and voxel resolution of the shards, ``--tiny`` (:data:`TINY_MODEL`),
    ``base_channels`` and ``voxel_decoder`` from ``model_options``; loss weights are the
    LossWeights defaults. ``--resume``: the run's saved ``config.json``, where options given on
    the command line (``given``) may change only :data:`RESUMABLE_FIELDS`."""
    from dataclasses import asdict

    from sc3d_train.config import RESUMABLE_FIELDS, TINY_MODEL
    from sc3d_train.data import DataError, background_of, scan_objects
    from sc3d_train.losses import LossWeights
    from sc3d_train.model import ModelConfig

    out = Path(options["out"])
    if resume:
        saved_path = out / "config.json"
        if not saved_path.is_file():
            raise CheckpointError(f"{out}: nothing to resume (no config.json)")
        cfg = RunConfig.load(saved_path)
        changed = []
        for k in sorted(given & set(options)):
            same = (Path(options[k]).resolve() == Path(getattr(cfg, k)).resolve()) if k == "shards" \
                else options[k] == getattr(cfg, k)
            if k in RESUMABLE_FIELDS:
                setattr(cfg, k, options[k])
            elif not same:
                changed.append(f"--{k.replace('_', '-')} {options[k]!r} (run has {getattr(cfg, k)!r})")
        for k in sorted(given & set(model_options)):
            v = model_options[k]
            if k in cfg.model and v is not None and v != cfg.model[k]:
                changed.append(f"--{k.replace('_', '-')} {v!r} (run has {cfg.model[k]!r})")
        if changed:
            raise CheckpointError(f"{out}: cannot change on --resume: " + ", ".join(changed))
        return cfg
    if options.get("split") == "test":
        raise DataError("refusing to train on the test split: its evaluation would then measure "
                        "objects the model was trained on; train on 'train' (or 'val')")
    if (out / "checkpoints" / "last.pt").is_file():
        raise CheckpointError(f"{out}: already holds a run (checkpoints/last.pt); use --resume "
                              f"to continue it or choose another --out")
    _, info = scan_objects(Path(options["shards"]))
    if info["voxel_resolution"] is None:
        raise DataError(f"{options['shards']}: shards have no voxels; run `sc3d-data voxelize` first")
    model = {"image_size": info["image_size"], "voxel_resolution": info["voxel_resolution"],
             "voxel_decoder": model_options.get("voxel_decoder") or "3tube"}
    if model_options.get("tiny"):
        model.update(TINY_MODEL)
    if model_options.get("base_channels"):
        model["base_channels"] = model_options["base_channels"]
    model = ModelConfig.from_dict(model).to_dict()
    return RunConfig(**options, model=model, loss_weights=asdict(LossWeights()),
                     image_size=info["image_size"], num_views=info["num_views"],
                     background=background_of(info), intrinsics=info["K"],
                     camera_distance=info["distance"])


# ----------------------------------------------------------------------------- logging
class MetricsLog:
    """Scalars to ``metrics.csv`` (one row per logged step) and TensorBoard (``tb/``).
    On resume, rows at or after the resume step (written after the checkpoint by the
    interrupted run) are dropped first, so the CSV has each step once."""

    def __init__(self, run_dir: Path, start_step: int, enabled: bool = True):
        self.path = Path(run_dir) / CSV_NAME
        self.enabled = enabled
        self.rows: list[dict] = []
        if not enabled:
            return
        if start_step > 0 and self.path.is_file():
            with open(self.path, newline="") as f:
                self.rows = [r for r in csv.DictReader(f) if int(r["step"]) < start_step]
        self.fields = list(self.rows[0].keys()) if self.rows else None
        if self.fields is not None:
            for r in self.rows[1:]:
                self.fields += [k for k in r if k not in self.fields]
        self._rewrite()
        from torch.utils.tensorboard import SummaryWriter

        self.tb = SummaryWriter(str(Path(run_dir) / "tb"), purge_step=start_step or None)

    def _rewrite(self):
        if self.fields is None:
            self.path.write_text("")
            return
        with open(self.path, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=self.fields)
            w.writeheader()
            w.writerows(self.rows)

    def log(self, step: int, values: dict) -> None:
        if not self.enabled:
            return
        row = {"step": step, **values}
        self.rows.append(row)
        new = [k for k in row if k not in (self.fields or [])]
        if new:  # first row, or a phase that logs more terms: widen the header, rewrite the file
            self.fields = (self.fields or []) + new
            self._rewrite()
        else:
            with open(self.path, "a", newline="") as f:
                csv.DictWriter(f, fieldnames=self.fields, extrasaction="ignore").writerow(row)
        for k, v in values.items():
            if isinstance(v, (int, float)):
                self.tb.add_scalar(k if "/" in k else f"train/{k}", v, step)

    def close(self):
        if self.enabled:
            self.tb.close()


def plot_curves(csv_path: Path, png_path: Path) -> None:
    """Loss terms (log scale) and samples/s against the step, from ``metrics.csv``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(csv_path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return
    steps = [int(r["step"]) for r in rows]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    for key in ("total", "l3d", "l2d", "lsc", "kl", "pose", "u_lsc", "u_pose"):
        if any(r.get(key) not in ("", None) for r in rows):
            vals = [float(r[key]) if r.get(key) not in ("", None) else math.nan for r in rows]
            if any(v > 0 for v in vals if not math.isnan(v)):
                ax.plot(steps, vals, label=key)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_title("training losses")
    ax.legend(fontsize=8)
    ax2.plot(steps, [float(r["samples_per_s"]) for r in rows])
    ax2.set_xlabel("step")
    ax2.set_title("samples/s")
    fig.tight_layout()
    fig.savefig(png_path, dpi=80)
    plt.close(fig)


# ----------------------------------------------------------------------------- the loop
def training_batch(batch: dict, phase: str, device: torch.device, channels_last: bool,
                   pose_targets: torch.Tensor | None = None) -> dict:
    """Move a loader batch to ``device``, dropping the ground-truth pose (and, unsupervised,
    the labels). ``pose_targets [num_objects * V]`` (searched from voxels and masks) adds
    ``pose_target [B]`` for labelled batches."""
    drop = POSE_KEYS + (LABEL_KEYS if phase == "unsupervised" else ())
    if phase == "true-pose-masks":  # the ablation: masks and the true pose, no 3D labels
        drop = ("R", "t", "voxels")
    out = {}
    for k, v in batch.items():
        if k in drop:
            continue
        out[k] = v.to(device, non_blocking=True) if torch.is_tensor(v) else v
    if pose_targets is not None and phase == "supervised" and "index" in batch:
        out["pose_target"] = pose_targets[batch["index"]].to(device)
    if channels_last:
        out["images"] = out["images"].contiguous(memory_format=torch.channels_last)
    return out


def _phase_dataset(cfg: RunConfig, subset: str, image_size: int | None) -> ShardDataset:
    """``subset``: ``"all"``, ``"labeled"`` (with voxels) or ``"unlabeled"`` (no voxels needed)."""
    fraction = cfg.labeled_fraction if cfg.mode in ("semi", "labeled-only") else 1.0
    return ShardDataset(cfg.shards, cfg.split, subset=subset, labeled_fraction=fraction,
                        seed=cfg.seed, mask_size=cfg.model.get("mask_size", 48),
                        require_voxels=subset != "unlabeled", image_size=image_size)


def _data_position(cfg: RunConfig, step: int, local_batch: int) -> dict:
    """Samples of this phase's streams consumed by each rank before ``step``."""
    phase = cfg.phase_at(step)
    start = cfg.phase_start(step)
    if phase == "unsupervised":
        labeled, unlabeled = cfg.batch_split(local_batch)
        return {"phase": phase, "phase_start": start, "samples_per_rank": (step - start) * unlabeled,
                "labeled_samples_per_rank": (step - start) * labeled}
    return {"phase": phase, "phase_start": start, "samples_per_rank": (step - start) * local_batch}


#: loader seed offsets of the streams (labelled pre-training / all, unlabelled, labelled in the mix)
STREAM_SEEDS = {"supervised": 0, "unlabeled": 7919, "labeled_mix": 104729}


@contextmanager
def frozen_batchnorm_statistics(model: torch.nn.Module):
    """Inside: BatchNorm layers still normalise with the batch's statistics (train mode) but do
    not update their running statistics (momentum 0)."""
    layers = [m for m in model.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
    saved = [(m.momentum, m.num_batches_tracked.clone()) for m in layers]
    for m in layers:
        m.momentum = 0.0
    try:
        yield
    finally:
        for m, (momentum, tracked) in zip(layers, saved):
            m.momentum = momentum
            m.num_batches_tracked.copy_(tracked)


def write_labeled_objects(path: Path, dataset: ShardDataset) -> None:
    """``CATEGORY/MODEL_ID`` of every labelled object, one per line."""
    lines = sorted(f"{r.category}/{r.model_id}" for r in dataset.objects)
    Path(path).write_text("\n".join(lines) + "\n")


def fit(cfg: RunConfig, resume: bool = False) -> dict:
    """Train according to ``cfg`` (see module doc). Returns a summary dict: ``step``,
    ``last_losses``, ``samples_per_s``, ``checkpoint`` (path of last.pt).

    Raises :class:`TrainingDiverged` on a non-finite loss, ``DataError`` / ``CheckpointError``
    on bad inputs, before any training step."""
    from sc3d_train.losses import LossWeights, supervised_loss, true_pose_mask_loss, unsupervised_loss
    from sc3d_train.model import ModelConfig
    from sc3d_train.pose_search import dataset_pose_targets

    dist_info = setup_distributed(cfg.device)
    device = resolve_device(cfg.device, dist_info)
    run_dir = Path(cfg.out)
    if cfg.batch_size % dist_info.world_size:
        raise ValueError(f"batch size {cfg.batch_size} is not divisible by {dist_info.world_size} ranks")
    local_batch = cfg.batch_size // dist_info.world_size
    weights = LossWeights(**cfg.loss_weights)
    grid = ModelConfig.from_dict(cfg.model).pose_grid()
    mixed = cfg.mode == "semi" and cfg.semi_labeled_share > 0
    if mixed and min(cfg.batch_split(local_batch)) < 1:
        raise ValueError(f"batch {local_batch} per rank is too small to mix labelled and unlabelled images")

    # ---- datasets first: every data error surfaces before any work
    labeled_subset = "labeled" if cfg.mode in ("semi", "labeled-only") else "all"
    datasets = {labeled_subset: _phase_dataset(cfg, labeled_subset, cfg.image_size)}
    if cfg.mode == "semi" and cfg.pretrain_steps < cfg.steps:
        datasets["unlabeled"] = _phase_dataset(cfg, "unlabeled", cfg.image_size)
    labeled_ds = datasets[labeled_subset]
    pose_targets = None
    if weights.wpose and cfg.mode != "true-pose-masks" and (cfg.mode != "semi" or cfg.pretrain_steps > 0 or mixed):
        pose_targets = dataset_pose_targets(labeled_ds, grid, weights.ray, weights.proj,
                                            weights.search_mask_size, weights.search_samples,
                                            device).reshape(-1)

    # ---- model, optimiser, AMP
    seed_everything(cfg.seed)
    model = build_model(cfg).to(device)
    amp_dtype = resolve_amp(cfg, device)
    channels_last = cfg.channels_last == "on" or (cfg.channels_last == "auto" and device.type == "cuda")
    if channels_last:
        model = model.to(memory_format=torch.channels_last)
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.lr_at(0))
    scaler = torch.amp.GradScaler("cuda") if amp_dtype == torch.float16 else None

    start_step = 0
    if resume:
        ckpt_file, ckpt = resume_checkpoint(run_dir)  # newest complete checkpoint
        saved = RunConfig.from_dict(ckpt["config"])
        diffs = saved.differences(cfg)
        if diffs:
            raise CheckpointError(f"{ckpt_file}: the run config differs from the checkpoint's: "
                                  + "; ".join(diffs))
        problems = state_dict_mismatch(model.state_dict(), ckpt["model"])
        if problems:
            raise CheckpointError(f"{ckpt_file}: weights do not match the run's model ({problems})")
        model.load_state_dict(ckpt["model"])
        optimizer.load_state_dict(ckpt["optimizer"])
        if scaler is not None and ckpt.get("scaler"):
            scaler.load_state_dict(ckpt["scaler"])
        start_step = int(ckpt["step"])
        expected = _data_position(cfg, start_step, local_batch)
        if ckpt["data_position"] != expected:
            raise CheckpointError(f"{ckpt_file}: data position {ckpt['data_position']} != {expected}")
        states = ckpt["rng"]
        if len(states) != dist_info.world_size:
            raise CheckpointError(f"{ckpt_file}: saved with {len(states)} ranks, now {dist_info.world_size}")
        set_rng_state(states[dist_info.rank])
        if start_step >= cfg.steps:
            return {"step": start_step, "last_losses": {}, "samples_per_s": 0.0,
                    "checkpoint": str(ckpt_file)}
    else:
        torch.manual_seed(cfg.seed + 1000003 * dist_info.rank)  # per-rank noise (reparameterisation)

    train_model = model
    if dist_info.world_size > 1:
        from torch.nn.parallel import DistributedDataParallel as DDP

        # the unsupervised phase gives the mask decoder no gradient (its mask is detached)
        train_model = DDP(model, device_ids=[device.index] if device.type == "cuda" else None,
                          find_unused_parameters=cfg.mode == "semi")

    if dist_info.is_main:
        run_dir.mkdir(parents=True, exist_ok=True)
        cfg.save(run_dir / "config.json")
        if cfg.mode in ("semi", "labeled-only"):
            write_labeled_objects(run_dir / "labeled_objects.txt", labeled_ds)
    log = MetricsLog(run_dir, start_step, enabled=dist_info.is_main)
    progress = None
    if dist_info.is_main and cfg.progress:
        from sc3d_data.progress import progress_bar

        progress = progress_bar(total=cfg.steps, initial=start_step, unit="step", desc="train")

    def checkpoint(step_done: int) -> Path | None:
        states = [rng_state()]
        if dist_info.world_size > 1:
            import torch.distributed as dist

            states = [None] * dist_info.world_size
            dist.all_gather_object(states, rng_state())
        if not dist_info.is_main:
            return None
        path = save_checkpoint(run_dir, {
            "model": model.state_dict(), "optimizer": optimizer.state_dict(),
            "scaler": scaler.state_dict() if scaler is not None else None, "rng": states,
            "step": step_done, "config": cfg.to_dict(),
            "data_position": _data_position(cfg, step_done, local_batch)})
        plot_curves(log.path, run_dir / "curves.png")
        return path

    def loader(dataset, batch, stream, start):
        return iter(make_loader(dataset, batch, cfg.seed + STREAM_SEEDS[stream], start=start,
                                rank=dist_info.rank, world_size=dist_info.world_size,
                                workers=cfg.workers, pin_memory=device.type == "cuda"))

    last_good = str(last_path(run_dir)) if resume else None
    phase, loaders, last_losses = None, {}, {}
    t_log, n_log, rate = time.perf_counter(), 0, 0.0
    try:
        for step in range(start_step, cfg.steps):
            if cfg.phase_at(step) != phase:
                phase = cfg.phase_at(step)
                pos = _data_position(cfg, step, local_batch)
                if phase == "supervised":
                    loaders = {"supervised": loader(labeled_ds, local_batch, "supervised", pos["samples_per_rank"])}
                else:
                    n_lab, n_unl = cfg.batch_split(local_batch)
                    loaders = {"unsupervised": loader(datasets["unlabeled"], n_unl, "unlabeled", pos["samples_per_rank"])}
                    if n_lab:
                        loaders["supervised"] = loader(labeled_ds, n_lab, "labeled_mix",
                                                       pos["labeled_samples_per_rank"])
            for group in optimizer.param_groups:
                group["lr"] = cfg.lr_at(step)
            batches = {p: training_batch(next(it), cfg.mode if cfg.mode == "true-pose-masks" else p,
                                         device, channels_last, pose_targets)
                       for p, it in loaders.items()}
            train_model.train()
            optimizer.zero_grad(set_to_none=True)
            autocast = torch.autocast(device.type, dtype=amp_dtype) if amp_dtype else nullcontext()
            with autocast:
                if len(batches) == 2:
                    # two passes, so that BatchNorm never normalises labelled images with
                    # statistics of unlabelled ones; the unlabelled pass leaves the running
                    # statistics alone (eval normalises as the labelled training did). Measured:
                    # one pass over the concatenated batch let held-out mask IoU fall from 0.85
                    # to 0.20 even with every unlabelled loss weight at 0 (docs/training.md).
                    sup, uns = batches["supervised"], batches["unsupervised"]
                    ls = supervised_loss(train_model(sup["images"]), sup, weights, grid)
                    with frozen_batchnorm_statistics(model):
                        lu = unsupervised_loss(model(uns["images"]), uns, weights, grid)
                    losses = {**ls, **{f"u_{k}": v for k, v in lu.items()}}
                    losses["total"] = ls["total"] + lu["total"]
                elif "unsupervised" in batches:
                    out = train_model(batches["unsupervised"]["images"])
                    losses = {f"u_{k}": v for k, v in
                              unsupervised_loss(out, batches["unsupervised"], weights, grid).items()}
                    losses["total"] = losses.pop("u_total")
                else:
                    out = train_model(batches["supervised"]["images"])
                    loss_fn = true_pose_mask_loss if cfg.mode == "true-pose-masks" else supervised_loss
                    losses = loss_fn(out, batches["supervised"], weights, grid)
            loss = losses["total"]
            finite = torch.isfinite(loss.detach()).float()
            if dist_info.world_size > 1:
                import torch.distributed as dist

                dist.all_reduce(finite, op=dist.ReduceOp.MIN)
            if finite.item() < 1:
                raise TrainingDiverged(
                    f"loss is {loss.item()} at step {step} (phase {phase}); "
                    f"last good checkpoint: {last_good or 'none (no checkpoint written yet)'}")
            if scaler is not None:
                scaler.scale(loss).backward()
                scaler.step(optimizer)
                scaler.update()
            else:
                loss.backward()
                optimizer.step()
            n_log += cfg.batch_size
            done = step + 1
            if done % cfg.log_every == 0 or done == cfg.steps:
                if device.type == "cuda":
                    torch.cuda.synchronize()
                now = time.perf_counter()
                rate = n_log / max(now - t_log, 1e-9)
                t_log, n_log = now, 0
                scalars = {k: v.detach().float() for k, v in losses.items() if torch.is_tensor(v) and v.ndim == 0}
                values = torch.stack(list(scalars.values()))
                if dist_info.world_size > 1:  # log the mean over ranks
                    import torch.distributed as dist

                    dist.all_reduce(values)
                    values = values / dist_info.world_size
                last_losses = dict(zip(scalars, values.tolist()))
                log.log(step, {"phase": phase, **last_losses, "lr": cfg.lr_at(step),
                               "samples_per_s": round(rate, 2)})
                if progress is not None:
                    progress.set_postfix(loss=f"{last_losses['total']:.4f}", phase=phase,
                                         samples_s=f"{rate:.1f}")
            if progress is not None:
                progress.update(1)
            boundary = cfg.mode == "semi" and done == cfg.pretrain_steps
            if done % cfg.checkpoint_every == 0 or done == cfg.steps or boundary:
                path = checkpoint(done)
                last_good = str(path) if path else last_good
    except KeyboardInterrupt:
        if dist_info.is_main:
            print(f"\ninterrupted; last good checkpoint: {last_good or 'none'} "
                  f"(resume with --resume)")
        raise
    finally:
        if progress is not None:
            progress.close()
        log.close()
    return {"step": cfg.steps, "last_losses": last_losses, "samples_per_s": rate,
            "checkpoint": str(last_path(run_dir))}
