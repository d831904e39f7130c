"""The configuration of training: typed dataclasses that are the one source of every default.

* :class:`ModelConfig`: the network's architecture (``model`` of a run);
* :class:`LossWeights`: the loss weights and pose-search resolutions (``loss_weights``);
* :class:`RunConfig`: a whole run (optimisation, semi-supervised phases, data/loader, logging,
  device), with the two above nested.

Each setting is declared once (:func:`~sc3d_train.settings.config_io.setting`: type, default, help); the
``sc3d-train fit`` options are generated from these declarations (``cli/config_options.py``).
A run's resolved config is written beside it as ``RUN_DIR/config.yaml`` and, as plain data,
inside every checkpoint; ``fit --config RUN_DIR/config.yaml`` starts the same run again
(docs/config.md). The settings of ``eval``, ``predict`` and ``claims`` are declared the same way
in :mod:`sc3d_train.settings.command_config`. This module imports nothing heavy (no torch), so
``fit --help`` stays fast. Length: it is the one place of every training setting, each declared
once with its check; split up, a setting's default and its check would live apart.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from sc3d_data.formats.splits import SPLIT_NAMES
from sc3d_train.settings.config_io import ConfigError, check_choices, dump_yaml, from_plain, load_yaml, setting

#: the help of every ``--device`` option
DEVICE_HELP = "auto (CUDA if present), cpu, cuda or cuda:N."
#: the largest --batch-size of ``fit`` and ``eval``: 2^24 images of 64x64 RGB are 200 GB even as
#: bytes, so no batch that could run is refused, while a mistyped one (1e20) is, in one line
#: (unbounded, it failed deep inside the data loader, or built index lists until memory ran out)
MAX_BATCH_SIZE = 2 ** 24
#: the side (pixels) of the masks of the self-consistency module: 48 as in the paper
MASK_SIZE = 48
#: samples per ray of the self-consistency losses
RAY_SAMPLES = 64
#: the run's config file in its folder; ``config.json`` is what runs of earlier versions wrote
CONFIG_NAME = "config.yaml"
LEGACY_CONFIG_NAME = "config.json"

VOXEL_DECODERS = ("3tube", "1tube")
#: training modes: the paper's three, and ``true-pose-masks``, the self-consistency ablation
#: (voxels from masks at the true pose; the only mode that reads pose labels; used by ``claims``)
MODES = ("supervised", "semi", "labeled-only", "true-pose-masks")
#: fields that ``--resume`` may change (they do not alter the optimisation trajectory up to the
#: checkpoint); every other field must match the checkpoint's config. ``shards`` may name another
#: folder only when it holds the data the run started on (``loop.resolve.check_same_shards``).
RESUMABLE_FIELDS = ("steps", "checkpoint_every", "workers", "decoded_cache", "log_every", "device", "progress",
                    "out", "compile", "compile_backend", "val_every", "shards")
#: the orders of a dataset's objects (``data.dataset.ShardDataset(order=)``, ``object_order``): by
#: category and model_id (the same for every shard layout of the same objects: one render, a merge
#: of ``--part`` renders, a copy), or as the shard files and rows hold them (runs started before
#: 2026-11-29, whose config has no ``object_order``)
OBJECT_ORDERS = ("category/model_id", "shards")
#: what picks ``checkpoints/best.pt`` among the validations of a run (:mod:`sc3d_train.loop.validation`)
SELECT_BY = ("iou+pose", "iou", "pose")
#: the one "tiny" preset (``fit --tiny``, ``ModelConfig.tiny()``): a small network for CPU demos
#: and tests
TINY_MODEL = {"base_channels": 8, "shape_dim": 32, "pose_dim": 8}


def check_pose_grid(azimuth_bins: int, elevation_bins: int, elevation_min: float, elevation_max: float) -> None:
    """``ValueError`` unless the candidate poses make a grid (>= 3 azimuths, >= 1 elevation,
    ``-90 < min <= max < 90`` degrees). Checked here, not only by
    :class:`sc3d_train.paper.pose.PoseGrid` (which calls this), so that a config is refused when it
    is read: settings sit below the paper's modules and import none of them."""
    grid = (f"PoseGrid(azimuth_bins={azimuth_bins!r}, elevation_bins={elevation_bins!r}, "
            f"elevation_min={elevation_min!r}, elevation_max={elevation_max!r})")
    if azimuth_bins < 3 or elevation_bins < 1:
        raise ValueError(f"pose grid needs >= 3 azimuth bins and >= 1 elevation bin, got {grid}")
    if not -90.0 < elevation_min <= elevation_max < 90.0:
        raise ValueError(f"pose grid elevations must satisfy -90 < min <= max < 90, got {grid}")


class _Plain:
    """``to_dict`` / ``from_dict`` of a config dataclass (nested ones become nested dicts)."""

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict):
        return from_plain(cls, d)


def batch_size_too_large(batch_size: int, name: str = "batch_size") -> str:
    """The one-line refusal of a ``--batch-size`` (or the setting ``name``) above :data:`MAX_BATCH_SIZE`."""
    return (f"{name} (--{name.replace('_', '-')}) must be at most {MAX_BATCH_SIZE} (2^24 images of 64x64 RGB "
            f"are 200 GB even as bytes), got {batch_size}")


@dataclass
class ModelConfig(_Plain):
    """Architecture settings (saved with every checkpoint); see :mod:`sc3d_train.paper.model`.

    ``image_size`` and ``voxel_resolution`` are read from the shards by ``fit``."""

    image_size: int = setting(64, "Input RGB size S (square, a multiple of 32).", cli=False)
    voxel_resolution: int = setting(32, "Output grid G (a multiple of 4, >= 8).", cli=False)
    mask_size: int = setting(MASK_SIZE, "Mask size of the self-consistency module (pixels).")
    shape_dim: int = setting(200, "Size of the shape code z_s.")
    pose_dim: int = setting(16, "Size of the pose code z_p.")
    voxel_decoder: str = setting("3tube", "Voxel decoder: 3 tubes (paper) or 1 (ablation).",
                                 choices=VOXEL_DECODERS)
    base_channels: int = setting(32, "Network width C.")
    azimuth_bins: int = setting(24, "Candidate azimuths of the pose head.", cli=False)
    elevation_bins: int = setting(5, "Candidate elevations of the pose head.", cli=False)
    elevation_min: float = setting(10.0, "Lowest candidate elevation (degrees).", cli=False)
    elevation_max: float = setting(50.0, "Highest candidate elevation (degrees).", cli=False)

    def __post_init__(self) -> None:
        if self.image_size % 32 or self.image_size < 32:
            raise ValueError(f"image_size must be a multiple of 32 (5 stride-2 blocks), got {self.image_size}")
        if self.voxel_resolution % 4 or self.voxel_resolution < 8:
            raise ValueError(f"voxel_resolution must be a multiple of 4 and >= 8, got {self.voxel_resolution}")
        check_choices(self)
        for name in ("mask_size", "shape_dim", "pose_dim", "base_channels"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if int(self.mask_size) > max(self.image_size, MASK_SIZE):  # finer than the stored masks: no information
            raise ValueError(f"mask_size (--mask-size) must be at most the image size {self.image_size} (or the "
                             f"default {MASK_SIZE}), got {self.mask_size}")
        check_pose_grid(self.azimuth_bins, self.elevation_bins, self.elevation_min, self.elevation_max)

    @classmethod
    def tiny(cls, **overrides) -> "ModelConfig":
        """The tiny preset (:data:`TINY_MODEL`: C = 8, z_s 32, z_p 8) with ``overrides``."""
        return cls(**{**TINY_MODEL, **overrides})


@dataclass
class LossWeights(_Plain):
    """Loss weights (paper): ``w3d`` alpha_3, ``w2d`` alpha_4, ``wsc`` alpha_5, ``wkl`` alpha_6,
    ``ray`` alpha_1, ``proj`` alpha_2, ``pos_weight`` alpha_p; ``num_samples`` per ray;
    ``wpose`` / ``wpose_unlabeled`` the pose classification loss on labelled / unlabelled images
    (not in the paper: how its L_sc is minimised over the pose grid); ``search_mask_size`` and
    ``search_samples`` the resolution of that search for labelled images (once per object before
    training), ``unlabeled_search_*`` for unlabelled images (every step, over the azimuths at the
    predicted elevation: cheaper). Set in the config file (no command-line options)."""

    w3d: float = setting(0.5, "Weight of L_3D (alpha_3).", cli=False)
    w2d: float = setting(0.5, "Weight of L_2D (alpha_4).", cli=False)
    wsc: float = setting(1.0, "Weight of L_sc on labelled images (alpha_5).", cli=False)
    wkl: float = setting(0.02, "Weight of L_KL on labelled images (alpha_6).", cli=False)
    ray: float = setting(5.0, "Weight of L_ray inside L_sc (alpha_1).", cli=False)
    proj: float = setting(0.125, "Weight of L_proj inside L_sc (alpha_2).", cli=False)
    pos_weight: float = setting(3.0, "Weight of occupied voxels in the cross-entropy (alpha_p).", cli=False)
    num_samples: int = setting(RAY_SAMPLES, "Samples per ray of L_sc.", cli=False)
    wpose: float = setting(1.0, "Weight of the pose loss on labelled images.", cli=False)
    wpose_unlabeled: float = setting(0.0, "Weight of the pose loss on unlabelled images (0: the searched "
                                     "azimuth is no pseudo-label; measured: at 1 it cost the pose that the "
                                     "labels taught, docs/training.md).", cli=False)
    wsc_unlabeled: float = setting(1.0, "Weight of L_sc on unlabelled images.", cli=False)
    wkl_unlabeled: float = setting(0.02, "Weight of L_KL on unlabelled images.", cli=False)
    unlabeled_sc_at_search: bool = setting(True, "Unlabelled images: L_sc at the searched pose "
                                           "(else at the pose head's).", cli=False)
    unlabeled_pose_gate: int = setting(-1, "Unlabelled images: the searched azimuth is a pseudo-label "
                                       "(L_pose, L_sc at it) only where it lies within this many azimuth bins "
                                       "of the head's top azimuth; elsewhere no L_pose and L_sc at the head's "
                                       "pose (-1: always; issue 24).", cli=False)
    search_mask_size: int = setting(24, "Mask size of the pose search for labelled images.", cli=False)
    search_samples: int = setting(32, "Samples per ray of that search.", cli=False)
    unlabeled_search_mask_size: int = setting(16, "Mask size of the pose search for unlabelled images.",
                                              cli=False)
    unlabeled_search_samples: int = setting(16, "Samples per ray of that search.", cli=False)

    def __post_init__(self) -> None:
        for name in ("num_samples", "search_mask_size", "search_samples", "unlabeled_search_mask_size",
                     "unlabeled_search_samples"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for f in (f for f in fields(self) if f.type == "float"):  # < 0 ascends its loss, NaN: all NaN
            value, positive = getattr(self, f.name), f.name == "pos_weight"  # 0: no occupied voxel in L_3D
            if not (math.isfinite(value) and (value > 0 if positive else value >= 0)):
                raise ValueError(f"{f.name} must be a finite weight {'> 0' if positive else '>= 0'}, got {value}")


@dataclass
class RunConfig(_Plain):
    """Resolved settings of one training run.

    ``steps`` counts optimiser steps over all phases. In semi-supervised mode the first
    ``pretrain_steps`` steps train on the labelled subset (supervised loss, ``lr``); the rest
    train on mixed batches at ``semi_lr`` (``None``: ``lr``): a share ``semi_labeled_share`` of
    each batch (``semi_batch_size`` images, ``batch_size`` when None) are labelled images
    (supervised loss: keeps the canonical frame and what the labelled phase learnt), the others
    unlabelled images (self-consistency + KL + pose search on
    the predictions). ``semi_labeled_share = 0`` is the paper's pure unlabelled fine-tuning.
    ``batch_size`` is the global batch (split evenly over DDP ranks).
    """

    # data and run folder (options written by hand in cli/train_fit.py: paths, mode flags)
    shards: str = setting(help="Shard directory (absolute path).", cli=False)
    out: str = setting(help="Run directory.", cli=False)
    split: str = setting("train", "Split to train on (train or val; test is refused).")
    # optimisation
    steps: int = setting(2000, "Optimiser steps (all phases).")
    batch_size: int = setting(48, "Global batch size.")
    lr: float = setting(1e-3, "Adam lr at the start of each phase (the paper: 2e-4 constant).")
    lr_schedule: str = setting("cosine", "cosine: annealed over each phase down to lr_min_ratio x lr; "
                               "constant: the paper's.", choices=("cosine", "constant"))
    lr_min_ratio: float = setting(0.1, "End of the cosine schedule, as a share of the phase's lr.")
    seed: int = setting(0, "Seed of the weights, the labelled subset and the data order.")
    augment: bool = setting(False, "Augment the training images (labelled and unlabelled), never the labels: "
                            "colour jitter and shading of the object, a random background "
                            "(sc3d_train.data.augment; seeded by seed and step).")
    # modes and the semi-supervised phases
    mode: str = setting("supervised", "supervised, semi (--semi), labeled-only (--labeled-only) "
                       "or true-pose-masks (the claims ablation).", cli=False, choices=MODES)
    labeled_fraction: float = setting(0.15, "Fraction of training objects with labels (semi / "
                                      "labeled-only); chosen by object, seeded.")
    pretrain_steps: int | None = setting(None, "semi: supervised steps first [steps // 2].")
    semi_lr: float | None = setting(None, "Adam lr of the mixed/unlabelled phase [lr].")
    semi_labeled_share: float = setting(0.5, "semi: share of each batch of the second phase that are "
                                        "labelled images (0 = the paper's fine-tuning on unlabelled "
                                        "images alone).")
    semi_batch_size: int | None = setting(None, "semi: global batch of the second phase, labelled and unlabelled "
                                          "images together [batch size] (twice the batch size adds the "
                                          "unlabelled images to a whole labelled batch instead of taking "
                                          "half of it).")
    # loader, device, logging
    workers: int | None = setting(None, "DataLoader worker processes per stream and rank [auto: 0, the "
                                  "batches built in the training process: fastest on the CPU and on "
                                  "an H100 with 16 cores].")
    decoded_cache: str | None = setting(None, "Folder for a decoded, uncompressed, memory-mapped copy of "
                                        "the training arrays (opt-in: ~22x the shards' disk space; "
                                        "built once, keyed by each shard's SHA-256).")
    device: str = setting("auto", DEVICE_HELP)
    amp: str = setting("auto", "Mixed precision; auto = bf16/fp16 on CUDA, off on CPU.",
                       choices=("auto", "off", "bf16", "fp16"))
    channels_last: str = setting("auto", "Channels-last memory format (auto: on for CUDA).",
                                 choices=("auto", "on", "off"))
    compile: str = setting("auto", "torch.compile the training step (auto: on for one CUDA device, "
                           "with CUDA graphs; off on the CPU and under torchrun).", choices=("auto", "on", "off"))
    compile_backend: str = setting("inductor", "torch.compile backend: inductor (generates kernels); "
                                   "aot_eager traces and differentiates the step the same way but runs "
                                   "it with eager kernels (tests, debugging).", choices=("inductor", "aot_eager"))
    checkpoint_every: int = setting(500, "Write a checkpoint every N steps (and at the end).")
    # validation and the choice of checkpoints/best.pt (sc3d_train.loop.validation)
    val_every: int = setting(100, "Evaluate on the --val-split objects every N steps and at the end, and "
                             "keep the best as checkpoints/best.pt (0: off).")
    val_split: str = setting("val", "Split of --shards to validate on: objects never trained on (not the "
                             "training split; test is refused).", choices=SPLIT_NAMES)
    val_views: int = setting(4, "Views per validation object (evenly spaced), to keep validation cheap.")
    val_min_objects: int = setting(5, "Keep best.pt only when the val split has at least N objects; with "
                                   "fewer the figures are still logged, no best.pt is kept and eval reads "
                                   "last.pt (a pick on 1-4 objects follows noise).")
    select_by: str = setting("iou+pose", "What picks best.pt: iou+pose (mean IoU@0.4 + share of views "
                             "within 30 deg), iou, or pose (that share).", choices=SELECT_BY)
    log_every: int = setting(10, "Log the losses every N steps.")
    progress: bool = setting(True, "Show a progress bar.")
    # nested configs
    model: ModelConfig = setting(help="Architecture.", cli=False, default_factory=ModelConfig)
    loss_weights: LossWeights = setting(help="Loss weights.", cli=False, default_factory=LossWeights)
    # dataset facts copied from the shards (--resume refuses shards that changed; eval checks the
    # image size and voxel resolution)
    image_size: int = setting(64, "Image size of the shards.", cli=False)
    num_views: int = setting(24, "Views per object in the shards.", cli=False)
    background: list = setting(help="Background RGB of the shards.", cli=False,
                               default_factory=lambda: [255, 255, 255])
    intrinsics: list | None = setting(None, "K [3][3] in pixels at image_size.", cli=False)
    camera_distance: float = setting(2.0, "Camera distance of the shards (world units; the median of their views': "
                                     "predict draws at it).", cli=False)
    camera_distance_range: list | None = setting(None, "[min, max] of the shard views' camera distances (world "
                                                 "units; 3D-R2N2's imports vary by view).", cli=False)
    objects_sha256: str | None = setting(None, "SHA-256 of the sorted category/model_id of the training split's "
                                         "objects (--resume refuses shards whose objects changed).", cli=False)
    val_objects_sha256: str | None = setting(None, "SHA-256 of the sorted category/model_id of the validation "
                                             "split's objects (--resume of a run that validates refuses shards whose "
                                             "validation objects changed: best.pt compares scores on them).",
                                             cli=False)
    view_setup: str | None = setting(None, "How the shards' views were rendered: elevations, up and front axes, "
                                     "normalisation, shading (--resume refuses shards rendered otherwise).", cli=False)
    steps_before: list | None = setting(None, "[[step, steps], ...]: where --resume changed --steps, oldest first: "
                                        "the steps before `step` followed the cosine schedule of a run of `steps` "
                                        "(fit --config repeats them).", cli=False)
    object_order: str | None = setting(None, "The order of the objects that the seeded shuffles follow: "
                                       "category/model_id (runs started since 2026-11-29: the same for every shard "
                                       "layout of the same objects) or shards, the shard files' order (runs started "
                                       "before, whose config has none: their --resume and fit --config repeats keep "
                                       "it).", cli=False)

    def __post_init__(self):
        check_choices(self)
        for name in ("steps", "batch_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} (--{name.replace('_', '-')}) must be >= 1, got {getattr(self, name)}")
        for name in ("batch_size", "semi_batch_size"):
            if (getattr(self, name) or 0) > MAX_BATCH_SIZE:
                raise ValueError(batch_size_too_large(getattr(self, name), name))
        if self.semi_batch_size is not None and self.semi_batch_size < 2:
            raise ValueError("semi_batch_size (--semi-batch-size) must be at least 2 (a labelled and an unlabelled "
                             f"image), got {self.semi_batch_size}")
        if not 0.0 < self.labeled_fraction <= 1.0:
            raise ValueError(f"labeled_fraction (--labeled-fraction) must be in (0, 1], got {self.labeled_fraction}")
        if not 0.0 <= self.semi_labeled_share < 1.0:
            raise ValueError(f"semi_labeled_share (--semi-labeled-share) must be in [0, 1), got {self.semi_labeled_share}")
        if self.val_every and self.val_split in (self.split, "test"):
            raise ValueError(f"val split {self.val_split!r} must hold objects never trained on and not "
                             f"the test objects (training split {self.split!r}; --val-every 0 turns validation off)")
        for name, least in (("val_every", 0), ("val_views", 1), ("val_min_objects", 1), ("log_every", 1),
                            ("checkpoint_every", 1)):
            if getattr(self, name) < least:
                raise ValueError(f"{name} (--{name.replace('_', '-')}) must be >= {least}, got {getattr(self, name)}")
        if self.workers is not None and self.workers < 0:
            raise ValueError(f"workers (--workers) must be >= 0, got {self.workers}")
        if not 0 <= self.seed < 2 ** 63:
            raise ValueError(f"seed (--seed) must be in [0, 2^63), got {self.seed}")
        for name in ("lr", "semi_lr"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} (--{name.replace('_', '-')}) must be a positive finite number, got {value}")
        if self.object_order is not None and self.object_order not in OBJECT_ORDERS:
            raise ValueError(f"object_order must be one of {', '.join(OBJECT_ORDERS)} (or null), got {self.object_order!r}")
        pairs = self.steps_before or []
        if not all(isinstance(p, list) and len(p) == 2 and all(type(x) is int and x >= 0 for x in p) for p in pairs):
            raise ValueError(f"steps_before must be a list of [step, steps] pairs of whole numbers (what --resume "
                             f"records), got {self.steps_before!r}")
        if not 0.0 <= self.lr_min_ratio <= 1.0:
            raise ValueError(f"lr_min_ratio (--lr-min-ratio) must be in [0, 1] (a share of the lr), got {self.lr_min_ratio}")
        K = self.intrinsics
        if K is not None and not (isinstance(K, list) and len(K) == 3 and all(
                isinstance(row, list) and len(row) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                                and math.isfinite(x) for x in row) for row in K)):
            raise ValueError(f"intrinsics must be a 3x3 list of finite numbers (K in pixels), got {K!r}"[:200])
        if self.mode == "semi":
            if self.pretrain_steps is None:
                self.pretrain_steps = self.steps // 2
            if not 0 <= self.pretrain_steps <= self.steps:
                raise ValueError(f"pretrain_steps (--pretrain-steps) {self.pretrain_steps} not in [0, steps={self.steps}]")

    def save(self, path: Path) -> None:
        """Write the config as YAML (atomically)."""
        from sc3d_data.io.shards import atomic_write_bytes

        header = "sc3d-train fit config; rerun with: sc3d-train fit --config THIS_FILE --out NEW_DIR"
        atomic_write_bytes(Path(path), dump_yaml(self.to_dict(), header).encode())

    @classmethod
    def load(cls, path: Path, paths: dict | None = None, without: tuple = ()) -> "RunConfig":
        """The config in YAML (or, from earlier versions, JSON) file ``path``; ``ConfigError``
        naming the file and the key when it is not a valid one. ``paths``: settings given elsewhere
        (``fit --shards/--out``, ``loop.config_file``), which replace the file's or stand in for
        them; ``without``: settings of the file left at their defaults."""
        try:
            return cls.from_dict({**{k: v for k, v in load_yaml(path).items() if k not in without}, **(paths or {})})
        except ConfigError as e:
            if str(e).startswith(f"{path}:"):
                raise
            raise ConfigError(f"{path}: {e}") from e

    @property
    def dataset_order(self) -> str:
        """The order the run's datasets hold their objects in (``ShardDataset(order=)``):
        ``object_order``, or the shards' order for a run of an earlier version, which has none."""
        return self.object_order or "shards"

    @staticmethod
    def path_in(run_dir: Path) -> Path:
        """The config file of run folder ``run_dir`` (``config.json`` for runs of earlier
        versions that have no ``config.yaml``: a JSON object naming ``shards`` and ``model``,
        not another file of that name, e.g. ``predict``'s record of an image ``config.png``)."""
        run_dir = Path(run_dir)
        legacy = run_dir / LEGACY_CONFIG_NAME
        if (run_dir / CONFIG_NAME).is_file() or not legacy.is_file():
            return run_dir / CONFIG_NAME
        try:
            with open(legacy, "rb") as f:
                plain = json.loads(f.read(1 << 20))  # a run's config is a few KiB
        except (ValueError, OSError):  # not JSON (or cut short), or not UTF-8: no run's config
            return run_dir / CONFIG_NAME
        return legacy if isinstance(plain, dict) and {"shards", "model"} <= plain.keys() else run_dir / CONFIG_NAME

    def differences(self, other: "RunConfig", ignore=RESUMABLE_FIELDS) -> list[str]:
        """Names and values of the fields that differ, other than ``ignore``."""
        a, b = self.to_dict(), other.to_dict()
        return [f"{k}: {a[k]!r} != {b[k]!r}" for k in a if k not in ignore and a[k] != b[k]]
