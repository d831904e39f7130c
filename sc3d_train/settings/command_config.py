"""Settings of ``sc3d-train eval``, ``predict`` and ``claims``: their defaults and help, written
once here; the command-line options are generated from these fields (``cli/config_options.py``)
and the library functions take their keyword defaults from them (e.g.
``evaluate(..., batch_size=EvalConfig.batch_size)``). No heavy imports."""
from __future__ import annotations

from dataclasses import dataclass

from sc3d_train.settings.config import DEVICE_HELP
from sc3d_train.settings.config_io import setting

#: where the pose of a prediction comes from: ``search`` the azimuth whose projection of the
#: predicted voxels best matches the predicted mask, at the pose head's elevation (test-time
#: self-consistency, :func:`sc3d_train.paper.pose_search.self_consistent_pose`; no label read), ``head``
#: the pose head's soft-argmax alone
POSE_SOURCES = ("search", "head")
#: the one default of every entry point (``eval``, ``predict``, ``evaluate()``, ``predict()``,
#: ``evaluate.predict_dataset`` and so ``fit``'s validation): the paper's test-time
#: self-consistency, what the command line has always given. A caller that wants the cheaper
#: head pose passes ``pose_from="head"`` where it calls.
DEFAULT_POSE_SOURCE = "search"
CLAIMS_PRESETS = ("cpu", "paper")
#: which checkpoint of a run folder is read (``sc3d_train.loop.checkpoint.run_checkpoint``)
CHECKPOINT_PICKS = ("best", "last")
PICK_HELP = ("Checkpoint of a run folder: best (checkpoints/best.pt, the best validation of fit; last.pt "
             "where the run kept none) or last.")


def check_pose_source(pose_from: str) -> str:
    """``pose_from`` when it is one of :data:`POSE_SOURCES`, else ``ValueError`` naming them."""
    if pose_from not in POSE_SOURCES:
        raise ValueError(f"pose_from must be one of {POSE_SOURCES}, got {pose_from!r}")
    return pose_from


@dataclass
class InferenceConfig:
    """Settings shared by ``eval`` and ``predict``."""

    pose_from: str = setting(DEFAULT_POSE_SOURCE, "search: the pose head's elevation and the azimuth whose "
                             "projection of the predicted voxels best matches the predicted mask "
                             "(test-time self-consistency); head: the pose head alone.",
                             choices=POSE_SOURCES, option="--pose")
    device: str = setting("auto", DEVICE_HELP)


@dataclass
class EvalConfig(InferenceConfig):
    """``sc3d-train eval``."""

    split: str = setting("test", "Split of the shards to evaluate.")
    pick: str = setting("best", PICK_HELP, choices=CHECKPOINT_PICKS)
    batch_size: int = setting(64, "Images per forward pass.")
    examples: int = setting(2, "Objects per category shown in predictions.png (views 3 and 15 of each; 0: no picture).")


@dataclass
class PredictConfig(InferenceConfig):
    """``sc3d-train predict``."""

    threshold: float = setting(0.5, "Occupancy threshold of the saved voxels and mesh.")
    pick: str = setting("best", PICK_HELP, choices=CHECKPOINT_PICKS)


@dataclass
class ClaimsConfig:
    """``sc3d-train claims``."""

    eval_split: str = setting("test", "Split of --eval-shards to evaluate.")
    preset: str = setting("cpu", "cpu: tiny network, 700 steps of 32, semi pretraining 200 (~40 min a seed "
                          "on 2 cores for ~200 objects); paper: full width, 20000 steps of 48, for a GPU.",
                          choices=CLAIMS_PRESETS)
    device: str = setting("auto", DEVICE_HELP)
    workers: int | None = setting(None, "DataLoader workers per run and stream [auto, as fit's --workers].")
    pick: str = setting("best", PICK_HELP, choices=CHECKPOINT_PICKS)
    seeds: int = setting(1, "Seeds per run (the preset's seed 0, then 1, 2, ...; 1 to 100): each cell of "
                         "claims.md becomes mean +- standard deviation over them.")
