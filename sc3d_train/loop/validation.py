"""Validation during ``fit`` and the choice of ``checkpoints/best.pt``.

Every ``val_every`` steps and after the last step, rank 0 evaluates the network (eval mode, no
gradient) on ``val_views`` evenly spaced views of every object of the ``val_split`` of the
training shards: objects fit never trains on (:class:`~sc3d_train.settings.config.RunConfig` refuses the
training split, and the test split, whose objects stay unseen by ``fit``). The figures are
``eval``'s, means over categories (its "mean" row), pose from ``eval``'s default source
(:data:`~sc3d_train.settings.command_config.DEFAULT_POSE_SOURCE`, the test-time search), passed by name
at the call: ``best.pt`` is chosen by the pose ``eval`` then reports, not by the cheaper head
pose (validation reads few views, so the search's extra cost stays small):

* ``val_iou``: voxel IoU@0.4;
* ``val_rot_median``: median rotation error (degrees);
* ``val_rot_acc30``: share of views within 30 degrees;
* ``val_score``: what picks ``best.pt`` (``select_by``): ``iou+pose`` (default) =
  ``val_iou + val_rot_acc30``, ``iou`` or ``pose`` (``val_rot_acc30``). Higher is better; a tie
  keeps the earlier checkpoint.

Why ``iou+pose``: the network has two outputs. IoU alone would keep a checkpoint whose pose the
unlabelled phase had wrecked (issue 24: semi raised IoU while sofa's median rotation error went
from 60 to 83 degrees); the share within 30 degrees rather than the median because it lies in
[0, 1] like the IoU and moves smoothly on a few views, where the median jumps by whole 15-degree
azimuth bins. The true pose and voxels of the validation objects are read only to *score* a
checkpoint: no gradient flows from them, they only choose which weights are kept (ordinary
model selection on a validation split).

Files in the run folder: ``validation.csv`` (one row per validation: ``step`` = steps done, the
figures, ``seconds`` it took, ``best`` 1 where it became the best), TensorBoard scalars ``val/*``
and ``checkpoints/best.pt`` (model, config, step and the validation record: what ``eval`` and
``claims`` read by default). On ``--resume`` the rows after the resumed step are dropped (with
validation off too: :func:`resumed_rows`) and
``best.pt``'s record is the best to beat; a ``best.pt`` of a step after the resumed one (kept by
the interrupted run from steps now trained again, on another schedule where ``--steps`` changed:
weights of no step of the resumed run) is removed, and the best is chosen again from there
(exact resume retraces the same weights and keeps the same step). A resumed step that was due a
validation and has none (the run stopped while validating it, after saving its checkpoint) is
validated before training goes on, also at a finished run's last step. The torch RNG
state is restored after each validation, so the trajectory does not depend on ``val_every``.

**Only the last phase's weights.** A ``semi`` run validates during its labelled pretraining too
(the curves show it), but ``best.pt`` is chosen among the checkpoints of its mixed phase
(:func:`in_last_phase`): a pretraining checkpoint has seen no unlabelled image, and keeping one
would report a labelled-only network under the semi run's name. This happened: in the 3-seed
claims study (docs/training.md) one semi seed's ``best.pt`` was step 100 of 350 pretraining steps,
its airplane median rotation error 60 degrees against 15 at its last step. The same holds on
``--resume``: a ``best.pt`` of a phase that the resumed run's ``--steps`` made no longer its last
(a semi run trained only to the end of its pretraining, then extended) is removed, and so is
the ``best.pt`` of a run resumed with validation off (its later steps are not validated: eval
reads ``last.pt``) and one a new run finds of a run that stopped before its first checkpoint
(:func:`best_of_an_early_stop`: that run is started again, not resumed).

**Too few validation objects.** With fewer than ``val_min_objects`` (5) objects in the split the
figures are still computed and logged (``best`` stays 0), but no ``best.pt`` is kept: ``eval`` and
``claims`` then read ``last.pt``. Why: a score on a handful of objects follows noise, not the
network. On the bundled sample meshes (2 val objects, 8 images) a 300-step run's ``best.pt`` was
step 100, chosen because 2 of its 8 images were within 30 degrees and none of step 300's.
"""
from __future__ import annotations

import csv
import time
from pathlib import Path

import numpy as np
import torch

from sc3d_train.loop.checkpoint import best_path, load_checkpoint, save_best
from sc3d_train.loop.metrics_log import cell_number, complete_rows, write_csv_atomic
from sc3d_train.loop.schedule import phase_at
from sc3d_train.settings.command_config import DEFAULT_POSE_SOURCE
from sc3d_train.settings.config import RunConfig
from sc3d_train.data.dataset import DataError, ShardDataset

VAL_CSV = "validation.csv"
FIELDS = ("step", "val_iou", "val_rot_median", "val_rot_acc30", "val_score", "seconds", "best")


def view_indices(num_objects: int, num_views: int, views: int) -> list[int]:
    """Dataset items ``object * V + view`` of ``views`` evenly spaced views (``floor(k V / views)``,
    k < views) of every object; all views when ``views >= V``. E.g. 2 objects, V = 24, 4 views:
    ``[0, 6, 12, 18, 24, 30, 36, 42]``."""
    chosen = sorted({int(k * num_views // views) for k in range(min(views, num_views))})
    return [o * num_views + v for o in range(num_objects) for v in chosen]


def in_last_phase(cfg: RunConfig, done: int) -> bool:
    """Whether the weights after ``done`` steps come from the run's last phase (module doc):
    always for one-phase runs; for ``semi``, once a mixed step has been taken."""
    return phase_at(cfg, done - 1) == phase_at(cfg, cfg.steps - 1)


def score(figures: dict, select_by: str) -> float:
    """The figure that picks ``best.pt`` from ``figures`` (``val_iou``, ``val_rot_acc30``)."""
    if select_by == "iou":
        return figures["val_iou"]
    if select_by == "pose":
        return figures["val_rot_acc30"]
    return figures["val_iou"] + figures["val_rot_acc30"]


def validation_dataset(cfg: RunConfig) -> ShardDataset | None:
    """The ``val_split`` objects of ``cfg.shards`` with voxels; None when validation is off or
    the split is empty (the run then keeps no ``best.pt``)."""
    if not cfg.val_every:
        return None
    try:
        return ShardDataset(cfg.shards, cfg.val_split, subset="all", mask_size=cfg.model.mask_size,
                            require_voxels=True, image_size=cfg.image_size, order=cfg.dataset_order)
    except DataError as e:
        if "is empty" in str(e):
            return None
        raise


def resumed_best(run_dir: Path, start_step: int, cfg: RunConfig) -> dict | None:
    """The validation record of ``run_dir``'s ``best.pt`` to beat when resuming run ``cfg`` at
    ``start_step`` (module doc); a ``best.pt`` of a later step, from steps the resume trains
    again, or of a phase that is no longer the run's last (a ``semi`` run pretrained alone, then
    extended with ``--resume --steps``: its ``best.pt`` came from the labelled pretraining) is
    removed and None returned."""
    best = load_checkpoint(best_path(run_dir)).get("validation")
    if best is not None and (int(best.get("step", 0)) > start_step or not in_last_phase(cfg, int(best.get("step", 0)))):
        best_path(run_dir).unlink()
        return None
    return best


def final_validation_owed(cfg: RunConfig, start_step: int) -> bool:
    """Whether run ``cfg``, resumed at its last step ``start_step`` (nothing left to train), lacks
    that step's validation (:meth:`Validator.owed`): ``fit --resume`` then validates it rather
    than saying there is nothing to do."""
    path = Path(cfg.out) / VAL_CSV
    if not cfg.val_every or start_step != cfg.steps or not path.is_file():
        return False
    return start_step not in {int(r["step"]) for r in complete_rows(path)} and validation_dataset(cfg) is not None


def best_of_an_early_stop(run_dir: Path) -> bool:
    """Whether ``run_dir``'s checkpoints are a ``best.pt`` alone of a step before its run's first
    checkpoint, whose ``metrics.csv`` logged no step after it and whose ``validation.csv`` holds no
    step from it on (a run stopped, e.g. by Ctrl-C or a full disk, before or while writing it:
    nothing to resume, so ``fit`` starts it again and drops that ``best.pt``; one kept from a
    finished run whose other checkpoints were deleted stays refused). The checkpoint's own step
    may be logged: a step logs before it checkpoints, and validates after."""
    if sorted(p.name for p in (run_dir / "checkpoints").glob("*.pt")) != ["best.pt"]:
        return False
    try:
        best = load_checkpoint(best_path(run_dir))
        c = best["config"]  # the first checkpoint: every N steps, the end, a semi run's pretraining's end
        first = min(int(c["checkpoint_every"]), int(c["steps"]),
                    *([int(c.get("pretrain_steps") or int(c["steps"]) // 2)] if c.get("mode") == "semi" else []))
        log = run_dir / "metrics.csv"
        logged = [int(r["step"]) + 1 for r in complete_rows(log)] if log.is_file() else []  # 0-based
        val = run_dir / VAL_CSV
        validated = [int(r["step"]) for r in complete_rows(val)] if val.is_file() else []
        return int(best["step"]) < first and max(logged, default=0) <= first and max(validated, default=0) < first
    except Exception:  # unreadable or not fit's: refused as before
        return False


def resumed_rows(path: Path, start_step: int) -> list[dict]:
    """The complete rows of ``validation.csv`` ``path`` of steps up to ``start_step`` (a run resumed
    there; the rows after it are of steps it trains again), ``path`` rewritten to hold only them
    (only the header for a new run, ``start_step`` 0)."""
    rows = [r for r in complete_rows(path) if int(r["step"]) <= start_step] if start_step > 0 and path.is_file() else []
    write_csv_atomic(path, FIELDS, rows)
    return rows


def validation_due(cfg: RunConfig, done: int) -> bool:
    """Whether run ``cfg`` validates after ``done`` steps (where it has a validation split), the same
    on every rank: the ranks that do not validate must still join the loss check made before it
    (``trainer``), or their next collective meets another one and the run hangs."""
    return bool(cfg.val_every) and (done % cfg.val_every == 0 or done == cfg.steps)


class Validator:
    """Validation of one run on rank 0 (module doc). ``due(done)`` says when, ``run`` does it."""

    def __init__(self, cfg: RunConfig, dataset: ShardDataset, device: torch.device, start_step: int, tb=None):
        self.cfg, self.dataset, self.device, self.tb = cfg, dataset, device, tb
        self.indices = view_indices(dataset.num_objects, dataset.num_views, cfg.val_views)
        self.run_dir = Path(cfg.out)
        self.path = self.run_dir / VAL_CSV
        rows = resumed_rows(self.path, start_step)
        self.validated = {int(r["step"]) for r in rows}  # the steps validated before this run
        for r in rows:  # TensorBoard's resume purge (from start_step on) took the resumed step's own row
            if int(r["step"]) >= start_step > 0:
                self._to_tb({k: cell_number(r, k) for k in FIELDS[1:5]}, int(r["step"]))
        self.best = None
        #: whether this split is large enough to pick best.pt (module doc: too few objects)
        self.selects = dataset.num_objects >= cfg.val_min_objects
        if start_step > 0 and best_path(self.run_dir).is_file():
            self.best = resumed_best(self.run_dir, start_step, cfg)

    @classmethod
    def for_run(cls, cfg: RunConfig, device: torch.device, start_step: int, is_main: bool,
                tb=None, say=print) -> "Validator | None":
        """The run's validator on the main rank; None elsewhere, with validation off, or when the
        shards have no ``val_split`` objects (said once through ``say``). On resume, a ``best.pt`` of
        steps trained again is removed here (:func:`resumed_best`), with validation off too."""
        if not is_main:
            return None
        out = Path(cfg.out)
        if best_path(out).is_file() and (start_step == 0 or not cfg.val_every):
            step = load_checkpoint(best_path(out)).get("step")
            best_path(out).unlink()
            say(f"removed best.pt of step {step}: " + ("validation is off from here (eval reads last.pt)" if start_step
                else "its run stopped before its first checkpoint, and this run starts it again"))
        elif start_step > 0 and best_path(out).is_file():
            resumed_best(out, start_step, cfg)
        dataset = validation_dataset(cfg) if cfg.val_every else None
        if dataset is None:  # no validator, which would drop them: no row of a step trained again either
            if start_step > 0 and (out / VAL_CSV).is_file():
                resumed_rows(out / VAL_CSV, start_step)
            if cfg.val_every:
                say(f"no {cfg.val_split!r} objects in {cfg.shards}: no validation, no best.pt "
                    f"(eval reads last.pt)")
            return None
        if dataset.num_objects < cfg.val_min_objects:
            say(f"only {dataset.num_objects} {cfg.val_split!r} object(s) in {cfg.shards} (< --val-min-objects "
                f"{cfg.val_min_objects}): validation figures are logged, no best.pt (eval reads last.pt)")
        return cls(cfg, dataset, device, start_step, tb)

    def due(self, done: int) -> bool:
        """Whether to validate after ``done`` steps."""
        return validation_due(self.cfg, done)

    def owed(self, start_step: int) -> bool:
        """Whether the step a run resumes from was due a validation that it lacks: the run was
        stopped (Ctrl-C, a kill) while validating it, after its checkpoint was saved (first)."""
        return start_step > 0 and self.due(start_step) and start_step not in self.validated

    def run(self, model: torch.nn.Module, done: int) -> dict:
        """Validate ``model`` after ``done`` steps: figures to ``validation.csv`` and TensorBoard,
        ``best.pt`` rewritten when the score beats the best so far. Returns the row."""
        from sc3d_train.paper.metrics import predict_dataset, summarize

        t0 = time.perf_counter()
        was_training = model.training
        devices = [self.device] if self.device.type == "cuda" else []
        with torch.random.fork_rng(devices=devices):
            model.eval()
            try:
                rows, _ = predict_dataset(model, self.dataset, self.device, keep=0,
                                          pose_from=DEFAULT_POSE_SOURCE,  # eval's pose (module doc)
                                          loss_weights=self.cfg.loss_weights, indices=self.indices)
            finally:
                model.train(was_training)
        mean = summarize(rows)["mean"]
        figures = {"val_iou": mean["voxel_iou_0.4"], "val_rot_median": mean["pose_rotation_median"],
                   "val_rot_acc30": mean["pose_rotation_acc30"]}
        figures["val_score"] = score(figures, self.cfg.select_by)
        kept = self.best is not None and self.best["step"] == done  # its best.pt written, its row cut off (a kill)
        better = self.selects and in_last_phase(self.cfg, done) and (
            self.best is None or figures["val_score"] > self.best["val_score"] or not np.isfinite(self.best["val_score"]))
        if better:
            self.best = {"step": done, "select_by": self.cfg.select_by, "split": self.cfg.val_split,
                         "images": len(rows), **figures}
            save_best(self.run_dir, {"model": model.state_dict(), "step": done, "config": self.cfg.to_dict(),
                                     "validation": self.best})
        row = {"step": done, **{k: round(v, 6) for k, v in figures.items()},
               "seconds": round(time.perf_counter() - t0, 3), "best": int(better or kept)}
        with open(self.path, "a", newline="") as f:
            csv.DictWriter(f, fieldnames=FIELDS).writerow(row)
        self._to_tb(figures, done)
        return row

    def _to_tb(self, figures: dict, done: int) -> None:
        """The ``val_*`` figures of the validation after ``done`` steps as TensorBoard ``val/*``."""
        if self.tb is not None:
            for k, v in figures.items():
                self.tb.add_scalar(f"val/{k[4:]}", v, done)
