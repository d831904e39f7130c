"""``sc3d-train fit``: supervised, semi-supervised and labelled-only training of the
self-consistency network (paper Sec. 3.3) on sc3d shards.

Phases (see :class:`~sc3d_train.settings.config.RunConfig`):

* ``supervised`` (all training objects) and ``labeled-only`` (the seeded labelled subset only):
  ``supervised_loss`` (L_3D + L_2D + L_sc on ground-truth voxels/masks with the *predicted*
  pose + KL) at ``lr``.
* ``semi``: ``pretrain_steps`` steps as ``labeled-only`` (a checkpoint is written at the phase
  boundary), then mixed batches at ``semi_lr`` (default ``lr``): ``semi_labeled_share`` of each
  batch labelled images with ``supervised_loss``, the rest unlabelled training objects with
  ``unsupervised_loss`` (L_sc on predicted voxels and masks + KL + pose search on the
  predictions), two forward passes (BatchNorm statistics of the labelled images only); the Adam
  moments carry over. Logged: the labelled terms under their names, the unlabelled ones prefixed
  ``u_``.

Pose: the pose head is a classifier over a candidate grid (:mod:`sc3d_train.paper.pose`); its target
for a labelled image is the candidate with the lowest L_sc between the image's ground-truth voxels
and mask, searched once per object before training (:func:`~sc3d_train.paper.pose_search.dataset_pose_targets`),
and for an unlabelled image the same search between the predicted voxels and mask.
The labelled objects of ``semi`` / ``labeled-only`` are listed in ``RUN_DIR/labeled_objects.txt``.
The ground-truth pose (``azimuth``, ``elevation``, ``R``, ``t``) is removed from every training
batch before the model and the losses see it; in the unsupervised phase the voxels and masks
are removed too. The camera's intrinsics and distance (fixed by the dataset) stay.

Run on one device or with ``torchrun`` (DDP, env ``RANK``/``WORLD_SIZE``/``LOCAL_RANK``; NCCL
on CUDA, gloo on CPU); the global batch is split evenly over ranks. Everything that decides the
trajectory (weights, optimiser, AMP scaler, every RNG, step, data position) is checkpointed, so
``--resume`` continues exactly: the loss at step N equals the uninterrupted run's.

Modules: :mod:`~sc3d_train.loop.schedule` (phase, lr, data position of a step), :mod:`~sc3d_train.loop.phase_step`
(batches and losses of a step), :mod:`~sc3d_train.loop.train_step` (the step, eager or compiled; CUDA graphs on one
GPU), :mod:`~sc3d_train.data.device_prefetch` (the next batch copied to the GPU on a side stream),
:mod:`~sc3d_train.loop.loss_window` (finiteness check, no host sync a step), :mod:`~sc3d_train.loop.runtime` (ranks,
device, AMP), :mod:`~sc3d_train.loop.memory_check` (does a CPU batch fit), :mod:`~sc3d_train.loop.metrics_log`
(metrics.csv, TensorBoard, curves), :mod:`~sc3d_train.loop.streams` (datasets and loaders of each phase),
:mod:`~sc3d_train.loop.checkpoint`, :mod:`~sc3d_train.loop.validation` (val split, ``best.pt``): this one the loop.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import torch

from sc3d_train.loop.checkpoint import (CheckpointError, checkpoint_config, last_path, rng_state, save_checkpoint,
                                        set_rng_state)
from sc3d_train.loop.checkpoint_resume import (check_saved_ranks, finished_run, interrupted_line, restore_last,
                                               resume_checkpoint)
from sc3d_train.loop.checkpoint_model import build_model, state_dict_mismatch
from sc3d_train.settings.config import CONFIG_NAME, RESUMABLE_FIELDS, RunConfig
from sc3d_train.data.dataset import ShardDataset
from sc3d_train.data.device_prefetch import DevicePrefetcher
from sc3d_train.data.loader import worker_death
from sc3d_train.loop.loss_window import LossWindow, check_finite
from sc3d_train.loop.memory_check import check_cpu_batch_fits
from sc3d_train.loop.metrics_log import DataWaitClock, GpuUtilisation, MetricsLog, in_loop_rate
from sc3d_train.loop.phase_step import augment_step, training_batch
from sc3d_train.loop.runtime import (DistInfo, all_gather, channels_last_on, mean_scalars, resolve_amp,
                                     check_same_weights, peer_stopped, resolve_device, seed_everything, setup_distributed)
from sc3d_train.loop.batch_floor import check_batch_parts
from sc3d_train.loop.schedule import data_position, lr_at, phase_at, step_samples
from sc3d_train.loop.streams import labeled_dataset, phase_loaders, run_datasets, write_labeled_objects
from sc3d_train.loop.train_step import TrainStep, compile_plan
from sc3d_train.loop.validation import Validator, validation_due
from sc3d_train.paper.pose import PoseGrid
from sc3d_train.paper.pose_search import dataset_pose_targets


@dataclass
class Training:
    """What one process trains with: the network (and its DDP wrapper ``train_model``), Adam,
    the AMP scaler and dtype, the labelled (and unlabelled) datasets and the pose targets."""

    cfg: RunConfig
    dist: DistInfo
    device: torch.device
    local_batch: int
    model: torch.nn.Module
    train_model: torch.nn.Module
    optimizer: torch.optim.Optimizer
    scaler: object
    amp_dtype: torch.dtype | None
    channels_last: bool
    datasets: dict
    pose_targets: torch.Tensor | None

    @property
    def run_dir(self) -> Path:
        return Path(self.cfg.out)

    @property
    def labeled(self) -> ShardDataset:
        return labeled_dataset(self.datasets)


def prepare(cfg: RunConfig, resume: bool = False) -> Training:
    """Datasets (every data error surfaces here, before any work), pose targets, the seeded
    model, Adam and AMP of this process; a CPU batch too large for memory is refused (``memory_check``).
    ``resume``: a run resumed on ranks that do not split its batch is told the ranks it was saved with."""
    dist_info = setup_distributed(cfg.device)
    device = resolve_device(cfg.device, dist_info)
    if cfg.batch_size % dist_info.world_size:
        if resume:  # 2 ranks resumed on 3: the cause is the rank count, not the batch
            check_saved_ranks(*resume_checkpoint(Path(cfg.out)), dist_info.world_size)
        raise ValueError(f"batch size {cfg.batch_size} is not divisible by {dist_info.world_size} ranks")
    local_batch = cfg.batch_size // dist_info.world_size
    weights, grid = cfg.loss_weights, PoseGrid.of(cfg.model)
    mixed = cfg.mode == "semi" and cfg.semi_labeled_share > 0
    check_batch_parts(cfg, local_batch)  # BatchNorm: 2 values per channel or more (batch_floor)

    datasets = run_datasets(cfg)
    pose_targets = None
    if weights.wpose and cfg.mode != "true-pose-masks" and (cfg.mode != "semi" or cfg.pretrain_steps > 0 or mixed):
        pose_targets = dataset_pose_targets(labeled_dataset(datasets), grid, weights.ray, weights.proj,
                                            weights.search_mask_size, weights.search_samples,
                                            device).reshape(-1).to(device)

    seed_everything(cfg.seed)
    model = build_model(cfg).to(device)
    amp_dtype = resolve_amp(cfg, device)
    channels_last = channels_last_on(cfg, device)
    if channels_last:
        model = model.to(memory_format=torch.channels_last)
    optimizer = torch.optim.Adam(model.parameters(), lr=lr_at(cfg, 0), fused=device.type == "cuda")
    scaler = torch.amp.GradScaler("cuda") if amp_dtype == torch.float16 else None
    return check_cpu_batch_fits(Training(cfg, dist_info, device, local_batch, model, model, optimizer, scaler,
                                         amp_dtype, channels_last, datasets, pose_targets))


def restore(t: Training) -> tuple[int, Path]:
    """Load the run's newest complete checkpoint into ``t`` after checking that it belongs to
    this config, data position and number of ranks. Returns ``(step, checkpoint file)``."""
    cfg = t.cfg
    ckpt_file, ckpt = resume_checkpoint(t.run_dir, say=print if t.dist.is_main else None)
    saved = checkpoint_config(ckpt_file, ckpt)
    diffs = saved.differences(cfg, ignore=RESUMABLE_FIELDS + ("steps_before",))
    if diffs:
        raise CheckpointError(f"{ckpt_file}: the run config differs from the checkpoint's: " + "; ".join(diffs))
    problems = state_dict_mismatch(t.model.state_dict(), ckpt["model"])
    if problems:
        raise CheckpointError(f"{ckpt_file}: weights do not match the run's model ({problems})")
    t.model.load_state_dict(ckpt["model"])
    t.optimizer.load_state_dict(ckpt["optimizer"])
    if t.scaler is not None and ckpt.get("scaler"):
        t.scaler.load_state_dict(ckpt["scaler"])
    step, states = int(ckpt["step"]), ckpt["rng"]
    check_saved_ranks(ckpt_file, ckpt, t.dist.world_size)  # before the data position, which the rank count changes
    expected = data_position(cfg, step, t.local_batch)
    if ckpt["data_position"] != expected:
        raise CheckpointError(f"{ckpt_file}: data position {ckpt['data_position']} != {expected}")
    set_rng_state(states[t.dist.rank], t.device)
    # the schedule the checkpoint's steps followed, kept in config.yaml (lr_at; fit --config repeats it)
    cfg.steps_before = (saved.steps_before or []) + ([[step, saved.steps]] if saved.steps != cfg.steps else []) or None
    return step, ckpt_file


def wrap_ddp(t: Training) -> None:
    """Under torchrun, ``t.train_model`` becomes the DDP wrapper of ``t.model`` (the unlabelled
    pass of the mixed phase runs on ``t.model``: ``phase_step.step_losses`` says why that is right)."""
    if t.dist.world_size > 1:  # the unsupervised phase gives the mask decoder no gradient (its mask is detached)
        t.train_model = torch.nn.parallel.DistributedDataParallel(
            t.model, device_ids=[t.device.index] if t.device.type == "cuda" else None,
            find_unused_parameters=t.cfg.mode == "semi")


def save(t: Training, step_done: int) -> Path | None:
    """Checkpoint after ``step_done`` steps (every rank's RNG; rank 0 writes it) once the ranks agree."""
    check_same_weights(t.model, t.dist, step_done)
    states = all_gather(rng_state(t.device), t.dist)
    if not t.dist.is_main:
        return None
    path = save_checkpoint(t.run_dir, {
        "model": t.model.state_dict(), "optimizer": t.optimizer.state_dict(),
        "scaler": t.scaler.state_dict() if t.scaler is not None else None, "rng": states,
        "step": step_done, "config": t.cfg.to_dict(),
        "data_position": data_position(t.cfg, step_done, t.local_batch)})
    return path


def device_batches(t: Training, loaders: dict, wait: DataWaitClock) -> dict:
    """The phase's loaders (``phase_loaders``) as iterators over device training batches, each
    next batch prefetched on a side CUDA stream (:class:`DevicePrefetcher`), waits timed by
    ``wait``."""
    def to_device(batch, phase):
        phase = t.cfg.mode if t.cfg.mode == "true-pose-masks" else phase
        return training_batch(batch, phase, t.device, t.channels_last, t.pose_targets)

    return {p: DevicePrefetcher(wait.wrap(it), lambda b, p=p: to_device(b, p), t.device) for p, it in loaders.items()}


def train_step(t: Training, step_fn: TrainStep, batches: dict, step: int, window: LossWindow) -> dict:
    """One optimiser step at ``step``'s learning rate on the next batch of each of ``batches``
    (:func:`device_batches`; images augmented with ``--augment``); its total loss goes to ``window``
    (no host sync). Returns the losses (tensors on the device)."""
    for group in t.optimizer.param_groups:
        group["lr"] = lr_at(t.cfg, step)
    losses = step_fn(augment_step({p: next(it) for p, it in batches.items()}, t.cfg, step, t.dist.rank))
    window.record(step, losses["total"])
    return losses


def fit(cfg: RunConfig, resume: bool = False, resume_hint: str = "resume with --resume", announce=lambda: None) -> dict:
    """Train according to ``cfg`` (see module doc); ``resume_hint``: printed on Ctrl-C; ``announce``: called once
    steps will run (a new run: first; a resumed one: not where :func:`finished_run` finds nothing left to do).
    Returns a summary dict: ``step``, ``last_losses``,
    ``samples_per_s`` (:func:`in_loop_rate`), ``device`` (e.g. ``cuda:0``), ``checkpoint`` (last.pt), ``best``.

    Raises :class:`~sc3d_train.loop.loss_window.TrainingDiverged` on a non-finite loss, ``DataError`` / ``CheckpointError``
    on bad inputs, before any training step."""
    if not resume:
        announce()
    t = prepare(cfg, resume)
    start_step, last_good = 0, None
    if resume:
        start_step, ckpt_file = restore(t)
        last_good = str(last_path(t.run_dir))
        if t.dist.is_main and ckpt_file != last_path(t.run_dir):  # last.pt older: its copy was cut off
            restore_last(t.run_dir, ckpt_file)
        if (done := finished_run(cfg, start_step, ckpt_file)) is not None:
            return done
        announce()
    else:
        torch.manual_seed(cfg.seed + 1000003 * t.dist.rank)  # per-rank noise (reparameterisation)
    wrap_ddp(t)
    step_fn = TrainStep(t.model, t.train_model, t.optimizer, t.scaler, t.amp_dtype, cfg,
                        compile_plan(cfg, t.device, t.dist.world_size), say=print if t.dist.is_main else lambda _: None)
    window = LossWindow(max(1, min(cfg.log_every, cfg.checkpoint_every, cfg.steps - start_step)), t.device)
    if t.dist.is_main:
        t.run_dir.mkdir(parents=True, exist_ok=True)
        cfg.save(t.run_dir / CONFIG_NAME)
        if cfg.mode in ("semi", "labeled-only"):
            write_labeled_objects(t.run_dir / "labeled_objects.txt", t.labeled)
    log = MetricsLog(t.run_dir, start_step, enabled=t.dist.is_main)
    validator = Validator.for_run(cfg, t.device, start_step, t.dist.is_main, getattr(log, "tb", None))
    if validator is not None and validator.owed(start_step):  # stopped while validating it: done now
        validator.run(t.model, start_step)
        log.draw_curves(t.run_dir / "curves.png", final=start_step >= cfg.steps)
    progress = None
    if t.dist.is_main and cfg.progress:
        from sc3d_data.pipeline.run.progress import progress_bar

        progress = progress_bar(total=cfg.steps, initial=start_step, unit="step", desc="train")

    phase, loaders, last_losses = None, {}, {}
    t_log, n_log, rates, wait, gpu_util = time.perf_counter(), 0, [], DataWaitClock(), GpuUtilisation(t.device)
    try:
        for step in range(start_step, cfg.steps):
            if phase_at(cfg, step) != phase:
                phase = phase_at(cfg, step)
                loaders = device_batches(t, phase_loaders(t, step), wait)
            losses = train_step(t, step_fn, loaders, step, window)
            n_log += step_samples(cfg, step)
            done = step + 1
            log_now = done % cfg.log_every == 0 or done == cfg.steps
            boundary = cfg.mode == "semi" and done == cfg.pretrain_steps
            save_now = done % cfg.checkpoint_every == 0 or done == cfg.steps or boundary
            validation_now = validation_due(cfg, done)  # on every rank (rank 0 alone validates)
            validate_now = validator is not None and validation_now
            if log_now or save_now or validation_now:  # the loop's only host syncs (every rank: a collective);
                # best.pt never of NaN weights
                check_finite(window, t.dist, cfg, last_good)
            if log_now:
                if t.device.type == "cuda":
                    torch.cuda.synchronize()
                now = time.perf_counter()
                wait_share = wait.seconds / max(now - t_log, 1e-9)
                rates.append(rate := n_log / max(now - t_log, 1e-9))
                t_log, n_log, wait.seconds = now, 0, 0.0
                last_losses = mean_scalars(losses, t.dist)
                gpu = gpu_util()
                log.log(step, {"phase": phase, **last_losses, "lr": lr_at(cfg, step),
                               "samples_per_s": round(rate, 2), "data_wait": round(wait_share, 4),
                               **({"gpu_util": gpu} if gpu is not None else {})})
                if progress is not None:
                    progress.set_postfix(loss=f"{last_losses['total']:.4f}", phase=phase,
                                         samples_s=f"{rate:.1f}", data_wait=f"{100 * wait_share:.0f}%")
            if progress is not None:
                progress.update(1)
            if save_now:  # before validating: a best.pt of this step then has a checkpoint beside it
                path = save(t, done)
                last_good = str(path) if path else last_good
            if validate_now:
                validator.run(t.model, done)
            if save_now and t.dist.is_main:  # curves.png after the step's validation (its best.pt)
                log.draw_curves(t.run_dir / "curves.png", final=done >= cfg.steps)
    except KeyboardInterrupt:
        if t.dist.is_main:
            print("\n" + interrupted_line(t.run_dir, resume_hint))
        raise
    except RuntimeError as e:  # a loader worker killed (OOM killer, kill -9), another rank stopped: one line
        raise worker_death(e, then := interrupted_line(t.run_dir, resume_hint)) or peer_stopped(e, then) or e
    finally:
        if progress is not None:
            progress.close()
        log.close()
    return {"step": cfg.steps, "last_losses": last_losses, "samples_per_s": in_loop_rate(rates),
            "device": str(t.device), "checkpoint": str(last_path(t.run_dir)), "best": validator.best if validator else None}
