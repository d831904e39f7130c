"""``sc3d-train eval``: metrics of a checkpoint on a split of the shards (SPEC "Metrics").

Every view of every object of the split is one test image (24 per object by default).

* Voxel IoU at thresholds 0.4 (3D-R2N2) and 0.5 (PTN): ``|P & G| / |P | G|`` of the predicted
  occupancy probability ``>= thr`` against the ground-truth grid, per image.
* Mask IoU: predicted mask probability ``>= 0.5`` against the rendered mask at the size the
  model predicts (the image size), per image.
* Pose error: the rotation error, the geodesic angle between the predicted camera rotation and
  the shard's true ``R`` (MVC's metric): median, mean, fraction within 15 and 30 degrees; the
  absolute wrapped azimuth and elevation errors in degrees (``sc3d_train.paper.pose``): mean, median
  and the fraction within 30 degrees; ``az~flip`` (``pose_azimuth_flip_acc30``), a diagnostic,
  also counts azimuths within 30 degrees of the true azimuth + 180 (front/back confusion).
  The evaluated pose is, by default, the test-time self-consistent one (``pose_from="search"``:
  the azimuth whose projection of the predicted voxels best matches the predicted mask, at the
  elevation of the pose head; no label) or the pose head's alone (``"head"``). The default is
  :data:`~sc3d_train.settings.command_config.DEFAULT_POSE_SOURCE`, the same for :func:`evaluate`,
  :func:`~sc3d_train.paper.metrics.predict_dataset`, ``predict`` and the command line.

Per category: the mean over that category's images. ``mean``: the unweighted mean of the
per-category values (the paper's "Mean" column). ``overall``: pooled over all images.
Thresholds are fixed in advance (never tuned on the test set).
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import torch

from sc3d_data.formats.shapenet import category_label
from sc3d_data.io.drawn_names import mpl_name
from sc3d_data.io.names import printable
from sc3d_data.io.outlock import exclusive_lock
from sc3d_data.io.pictures import write_figure
from sc3d_data.io.shards import atomic_write_bytes
from sc3d_train.loop.checkpoint import run_checkpoint
from sc3d_train.loop.checkpoint_model import load_model
from sc3d_train.settings.command_config import EvalConfig
from sc3d_train.settings.config import MAX_BATCH_SIZE, batch_size_too_large
from sc3d_train.data.dataset import ShardDataset
from sc3d_train.evaluation.evaluated_data import (evaluated_data_digest, run_objects,
                                                  selection_objects_among, training_objects_among, untrained_categories)
from sc3d_train.evaluation.evaluation_files import (EVALUATION_PICTURE, check_default_folder_free,
                                                    check_outputs_replaceable, check_split_name)
from sc3d_train.paper.metrics import MASK_THRESHOLD, VOXEL_THRESHOLDS, predict_dataset, summarize
from sc3d_train.paper.pose import PoseGrid

TABLE_COLUMNS = (("images", "n", "{:d}"), ("voxel_iou_0.4", "IoU@.4", "{:.3f}"),
                 ("voxel_iou_0.5", "IoU@.5", "{:.3f}"), ("mask_iou", "maskIoU", "{:.3f}"),
                 ("pose_rotation_median", "rot med", "{:.1f}"), ("pose_rotation_mean", "rot err", "{:.1f}"),
                 ("pose_rotation_acc15", "rot<15", "{:.2f}"), ("pose_rotation_acc30", "rot<30", "{:.2f}"),
                 ("pose_azimuth_mean", "az err", "{:.1f}"), ("pose_azimuth_median", "az med", "{:.1f}"),
                 ("pose_azimuth_acc30", "az<30", "{:.2f}"), ("pose_azimuth_flip_acc30", "az~flip", "{:.2f}"),
                 ("pose_elevation_mean", "el err", "{:.1f}"),
                 ("pose_elevation_acc30", "el<30", "{:.2f}"))


def format_table(summary: dict) -> str:
    """A fixed-width text table: one row per category (``io.names.printable``), then ``mean`` and ``overall``."""
    lines = [f"{'category':<22}" + "".join(f"{h:>9}" for _, h, _ in TABLE_COLUMNS)]
    rows = list(summary["per_category"].items()) + [("mean", summary["mean"]), ("overall", summary["overall"])]
    for name, vals in rows:
        if name in summary["per_category"]:
            name = printable(category_label(name))
        cells = []
        for key, _, fmt in TABLE_COLUMNS:
            v = vals.get(key)
            cells.append(f"{'':>9}" if v is None else f"{fmt.format(v):>9}")
        lines.append(f"{name[:22]:<22}" + "".join(cells))
    return "\n".join(lines)


def voxel_silhouette(voxels: np.ndarray, azimuth: float, elevation: float, distance: float,
                     K: np.ndarray, image_size: int) -> np.ndarray:
    """Silhouette ``[S, S]`` bool of a boolean grid seen from a pose (``sc3d_data.geometry.projection``
    with the camera of ``sc3d_data.geometry.camera``)."""
    from sc3d_data.geometry.camera import extrinsics
    from sc3d_data.geometry.projection import project_voxels

    R, t = extrinsics(np.float64(azimuth), np.float64(elevation), np.float64(distance))
    return project_voxels(voxels, K, R, t, image_size)


def example_label(example: dict, height_pt: float | None = None) -> str:
    """The object and view of an example of :func:`plot_examples`, a line each: category, model
    id, ``view N``; whole (a ShapeNet id is 32 characters; a cut one loses the view and can match
    another object's), or as drawn in ``height_pt`` points at fontsize 5 (``io.drawn_names.mpl_name``:
    what the font cannot draw as ``\\uXXXX``; a name longer than a ShapeNet id, which ran off the
    figure, cut with ``...``)."""
    lines = (example["category"], example["model_id"], f"view {example['view']}")
    return "\n".join(line if height_pt is None else mpl_name(line, height_pt, 5) for line in lines)


def example_figures(example: dict) -> str:
    """What is written under an example's predicted voxels: its voxel IoU at the 0.5 threshold,
    rotation error (deg) and predicted / true (azimuth, elevation) in degrees."""
    return (f"IoU@0.5 {example['iou']:.2f} rot {example['rotation_error']:.0f}\n"
            f"pred ({example['azimuth_pred']:.0f},{example['elevation_pred']:.0f}) true "
            f"({example['azimuth_true']:.0f},{example['elevation_true']:.0f})")


def plot_examples(examples: list[dict], path: Path, per_row: int = 2) -> None:
    """``per_row`` examples per figure row, each as 5 panels: input, true mask, predicted mask,
    true voxels at the true pose, predicted voxels (>= 0.5) at the predicted pose; each example
    is labelled with its object, view, IoU and true/predicted (azimuth, elevation) and rotation
    error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_rows = max(1, math.ceil(len(examples) / per_row))
    fig, axes = plt.subplots(n_rows, 5 * per_row, figsize=(1.3 * 5 * per_row, 1.55 * n_rows), squeeze=False)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
        ax.axis("off")
    titles = ("input", "mask true", "mask pred", "vox @ true pose", "vox @ pred pose")
    for k, ex in enumerate(examples):
        r, c0 = divmod(k, per_row)
        c0 *= 5
        S = ex["image"].shape[0]
        panels = (ex["image"], ex["mask_true"], ex["mask_pred"],
                  voxel_silhouette(ex["voxels_true"], ex["azimuth_true"], ex["elevation_true"], ex["distance"], ex["K"], S),
                  voxel_silhouette(ex["voxels_pred"] >= 0.5, ex["azimuth_pred"], ex["elevation_pred"], ex["distance"], ex["K"], S))
        for c, img in enumerate(panels):
            ax = axes[r, c0 + c]
            ax.axis("on")
            ax.imshow(img, cmap=None if img.ndim == 3 else "gray", vmin=0, vmax=1)
            if r == 0:
                ax.set_title(titles[c], fontsize=7)
        # within its row (1.55 inches): a 32-character ShapeNet id stays whole, 200 m's ran off the figure
        axes[r, c0].set_ylabel(example_label(ex, 0.93 * 1.55 * 72), fontsize=5, parse_math=False)
        axes[r, c0 + 4].set_xlabel(example_figures(ex), fontsize=5)
    fig.tight_layout()
    write_figure(fig, path, dpi=90, metadata={"Description": EVALUATION_PICTURE})
    plt.close(fig)


def default_output_dir(checkpoint: Path, name: str) -> Path:
    """Beside the checkpoint's run: ``RUN_DIR/NAME`` for ``RUN_DIR/checkpoints/X.pt``, else
    ``CHECKPOINT_DIR/NAME``."""
    checkpoint = Path(checkpoint)
    parent = checkpoint.parent
    return (parent.parent if parent.name == "checkpoints" else parent) / name


def evaluate(checkpoint: Path, shards: Path, split: str, out: Path | None, device: str = EvalConfig.device,
             batch_size: int = EvalConfig.batch_size, examples: int = EvalConfig.examples,
             pose_from: str = EvalConfig.pose_from, pick: str = EvalConfig.pick) -> dict:
    """Evaluate ``checkpoint`` (a file, or a run folder: its ``pick`` checkpoint,
    :func:`~sc3d_train.loop.checkpoint.run_checkpoint`) on ``split`` of ``shards``; writes ``out/metrics.json`` and
    ``out/predictions.png`` (``out`` None: ``RUN_DIR/eval_SPLIT``, :func:`default_output_dir`), the
    picture first and ``metrics.json`` last, atomically, so that ``metrics.json`` exists only for a
    finished evaluation (``claims`` reads it back instead of evaluating again while the shards
    give the same ``data_sha256``, :func:`~sc3d_train.evaluation.evaluated_data.evaluated_data_digest`);
    ``examples`` objects per category are drawn. Returns the metrics dict (with ``table``, the text table, and ``out``)."""
    from sc3d_train.loop.runtime import resolve_device

    if batch_size < 1 or examples < 0:
        name, value, least = ("batch_size", batch_size, 1) if batch_size < 1 else ("examples", examples, 0)
        raise ValueError(f"{name} (--{name.replace('_', '-')}) must be >= {least}, got {value}")
    if batch_size > MAX_BATCH_SIZE:
        raise ValueError(batch_size_too_large(batch_size))
    check_split_name(split)
    dev = resolve_device(device)
    checkpoint = run_checkpoint(checkpoint, pick)
    model, cfg, ckpt = load_model(checkpoint, dev)
    require_finite_weights(checkpoint, model)
    if out is None:
        out = default_output_dir(checkpoint, f"eval_{split}")
        check_default_folder_free(out, checkpoint, shards, pose_from)
    out = Path(out)
    check_outputs_replaceable(out)
    with exclusive_lock(out, "sc3d-train eval", create=True):  # one evaluation writes here at a time
        dataset = ShardDataset(shards, split, subset="all", mask_size=cfg.model.mask_size,
                               require_voxels=True, image_size=cfg.model.image_size)
        if dataset.info["voxel_resolution"] != cfg.model.voxel_resolution:
            raise ValueError(f"{shards}: voxels are {dataset.info['voxel_resolution']}^3 but the checkpoint "
                             f"predicts {cfg.model.voxel_resolution}^3")
        differences = differences_from_training(cfg, dataset.info, shards)
        run_refs = run_objects(cfg, shards)  # the run's objects, scanned once for both questions
        trained_on = training_objects_among(cfg, dataset.objects, run_refs)
        unseen = untrained_categories(cfg, dataset.objects, run_refs)
        selected_on = selection_objects_among(cfg, ckpt.get("validation"), dataset.objects, shards, run_refs)
        data_sha256 = evaluated_data_digest(shards, split, dataset.objects)
        rows, kept = predict_dataset(model, dataset, dev, batch_size, keep=examples, pose_from=pose_from,
                                     loss_weights=cfg.loss_weights)
        require_finite_predictions(checkpoint, rows)
        summary = summarize(rows)
        grid = PoseGrid.of(cfg.model)  # the pose error's floor of views off its azimuths: eval's note
        result = {"checkpoint": os.path.abspath(checkpoint), "step": int(ckpt.get("step", -1)), "shards": os.path.abspath(shards),
                  "split": split, "pose_from": pose_from, "voxel_thresholds": list(VOXEL_THRESHOLDS), "mask_threshold": MASK_THRESHOLD,
                  "differs_from_training": differences, "outside_pose_grid": outside_pose_grid(cfg, dataset.info),
                  "pose_grid_elevations": [cfg.model.elevation_min, cfg.model.elevation_max],
                  "pose_grid_azimuth_step": grid.azimuth_step,
                  "azimuth_grid_floor": round(grid.azimuth_floor([r["azimuth_true"] for r in rows]), 2),
                  "trained_on": trained_on, "categories_not_trained_on": unseen,
                  "selected_on_this_split": selected_on, "data_sha256": data_sha256,
                  "shards_complete": dataset.info["complete"], **summary}
        (out / "metrics.json").unlink(missing_ok=True)  # written last: it marks a finished evaluation
        (out / "predictions.png").unlink(missing_ok=True)  # --examples 0: none (an earlier one is not of these)
        if kept:
            plot_examples(kept, out / "predictions.png")
        atomic_write_bytes(out / "metrics.json", json.dumps(_finite(result), indent=1).encode())
        result["table"] = format_table(summary)
        result["out"] = str(out)
        return result


def require_finite_weights(checkpoint: Path, model: torch.nn.Module) -> None:
    """``CheckpointError`` naming ``checkpoint`` when a weight or buffer of its loaded ``model`` is
    NaN or infinite: every prediction would be NaN (``eval``'s figures nan and 0.000, ``predict``'s
    marching cubes failing), so ``eval`` and ``predict`` refuse it once, at load, before anything is
    computed or written."""
    from sc3d_train.loop.checkpoint import CheckpointError

    bad = [name for name, t in model.state_dict().items()
           if t.is_floating_point() and not bool(torch.isfinite(t).all())]
    if bad:
        raise CheckpointError(f"{checkpoint}: its weights are not finite (NaN or inf in {len(bad)} tensor(s), e.g. "
                              f"{bad[0]}): its run diverged or the file was altered; use an earlier checkpoint of "
                              "the run, or train again")


def require_finite_predictions(checkpoint: Path, rows: list[dict]) -> None:
    """``CheckpointError`` naming ``checkpoint`` when its prediction of an image (``rows`` of
    ``predict_dataset``) is not finite although its weights are (the network overflows on these
    inputs): the figures would count those images as IoU 0 and their pose errors as nan, so
    ``eval`` refuses before writing anything, as ``predict`` does."""
    from sc3d_train.loop.checkpoint import CheckpointError

    bad = [r for r in rows if not r["finite"]]
    if bad:
        first = bad[0]
        raise CheckpointError(f"{checkpoint}: its predictions are not finite (NaN or inf voxels, mask or pose) for "
                              f"{len(bad)} of {len(rows)} images (first: {printable(first['category'] + '/' + first['model_id'])} "
                              f"view {first['view']}) although its weights are: the network overflows on these "
                              "inputs; nothing written")


def _span(low: float, high: float) -> str:
    """``"2"`` or ``"1.63 to 2.25"``: a range of camera distances as a note names it."""
    return f"{low:g}" if math.isclose(low, high, rel_tol=1e-4) else f"{low:.3g} to {high:.3g}"


def differences_from_training(cfg, info: dict, shards: Path | None = None) -> list[str]:
    """How the evaluated shards' images differ from those the checkpoint was trained on
    (``cfg``: its run config; ``info``: ``ShardDataset.info`` of ``shards``), one phrase each; empty when
    they are alike (camera distances: where the evaluated shards hold views outside the range of those
    trained on; focal lengths within 0.1%). Background, intrinsics, camera distance and the view setup (axes,
    normalisation, shading: ``loop.resolve.view_setup``) change what the network sees
    (elevations outside the pose grid are :func:`outside_pose_grid`). Not refused: evaluating across such a change (other renders, 3D-R2N2's imports) is a
    legitimate experiment, but its figures must say so (``eval`` prints a note, and
    ``metrics.json`` keeps the list under ``differs_from_training``)."""
    from sc3d_train.data.dataset import background_of
    from sc3d_train.loop.front_axis import front_as_auto
    from sc3d_train.loop.resolve import view_setup, view_setup_but_elevations

    found = []
    background = background_of(info)
    if list(cfg.background) != background:
        found.append(f"background {background} (trained on {list(cfg.background)})")
    if cfg.intrinsics is not None and not np.allclose(info["K"], cfg.intrinsics, rtol=1e-3):
        fx, trained_fx = np.asarray(info["K"])[0, 0], np.asarray(cfg.intrinsics)[0, 0]
        found.append(f"intrinsics K (focal length {fx:.2f} px, trained on {trained_fx:.2f} px)")
    near, far = info["distance_range"]
    trained = cfg.camera_distance_range or [cfg.camera_distance] * 2  # a run of an earlier version: one distance
    if near < trained[0] * (1 - 1e-4) or far > trained[1] * (1 + 1e-4):  # views at distances never trained on
        found.append(f"camera distance {_span(near, far)} (trained at {_span(*trained)})")
    if cfg.view_setup is not None:  # elevations: outside_pose_grid
        now, was = (view_setup_but_elevations(v) for v in (view_setup(front_as_auto(info.get("settings", {}), shards)), cfg.view_setup))
        if now != was:
            found.append(f"views of {now} (trained on {was})")
    return found


def outside_pose_grid(cfg, info: dict) -> list[float]:
    """The shards' view elevations (degrees) outside the checkpoint's pose grid (``cfg``: its
    run config; ``info``: ``ShardDataset.info``): their pose error has a floor, whether or not
    the checkpoint was trained on these very shards (``fit`` warns of them), so it is a note of
    its own, not a difference from the training data (``metrics.json``: ``outside_pose_grid``)."""
    from sc3d_train.paper.pose import PoseGrid

    return PoseGrid.of(cfg.model).outside(info.get("settings", {}).get("elevations"))


def _finite(obj):
    """JSON-safe copy: NaN/inf become None."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
