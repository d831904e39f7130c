"""What ``sc3d-train claims`` refuses of its shards before any run trains: evaluation objects
that a run trains on or that choose its ``best.pt``, and evaluation shards that ``eval`` would
refuse for a checkpoint trained on the training shards (another image size or voxel resolution).
Each is one ``DataError`` naming the folders."""
from __future__ import annotations

from pathlib import Path

from sc3d_train.data.dataset import DataError


def split_objects(shards: Path, split: str) -> set:
    """``{(category, model_id)}`` of the objects of ``split`` of ``shards``."""
    from sc3d_train.data.dataset import scan_objects

    return {(r.category, r.model_id) for r in scan_objects(Path(shards))[0] if r.split == split}


def check_held_out(train_shards: Path, eval_shards: Path, eval_split: str, train_split: str) -> None:
    """``DataError`` when an object of ``eval_split`` of ``eval_shards`` (by category and model id)
    is one of the ``train_split`` objects of ``train_shards`` that the runs train on: their
    figures would not be of held-out objects (``--eval-split train``, or shards split otherwise)."""
    seen = sorted(split_objects(eval_shards, eval_split) & split_objects(train_shards, train_split))
    if seen:
        raise DataError(f"{eval_shards}: {len(seen)} object(s) of split {eval_split!r} are {train_split!r} objects of "
                        f"{train_shards} that the runs train on (e.g. {'/'.join(seen[0])}); claims evaluates on "
                        f"objects never trained on: choose another --eval-split or --eval-shards")


def check_not_selection(train_shards: Path, eval_shards: Path, eval_split: str, settings: dict,
                        pick: str) -> None:
    """``DataError`` when an object of ``eval_split`` of ``eval_shards`` is one of the validation
    objects of ``train_shards`` that pick each run's ``best.pt`` (``pick="best"``, validation on
    and at least ``val_min_objects`` of them, as ``fit`` keeps a best.pt): the figures of a
    checkpoint chosen as the best on these very objects are optimistic. ``settings``: the runs'
    ``fit`` settings (``val_every``, ``val_split``, ``val_min_objects``)."""
    if pick != "best" or settings["val_every"] <= 0:
        return
    chose = split_objects(train_shards, settings["val_split"])
    seen = sorted(split_objects(eval_shards, eval_split) & chose)
    if seen and len(chose) >= settings["val_min_objects"]:
        raise DataError(f"{eval_shards}: {len(seen)} object(s) of split {eval_split!r} are the {settings['val_split']!r} "
                        f"objects of {train_shards} that choose each run's best.pt (e.g. {'/'.join(seen[0])}): its "
                        f"figures on them would be optimistic; choose another --eval-split (test) or --pick last")


def check_evaluable(train_shards: Path, eval_shards: Path) -> None:
    """``DataError`` naming both folders when ``eval`` would refuse ``eval_shards`` for a checkpoint
    trained on ``train_shards``: the runs' network takes the image size of ``train_shards`` and
    predicts grids of their voxel resolution (``fit`` reads both from them), and ``eval`` refuses
    shards of another image size or voxel resolution
    (:func:`~sc3d_train.evaluation.evaluate.evaluate`). Shards without voxels are left to
    ``ShardDataset``'s message (``require_voxels``), training shards without them to ``fit``'s."""
    from sc3d_train.data.dataset import scan_objects

    trained, evaluated = scan_objects(Path(train_shards))[1], scan_objects(Path(eval_shards))[1]
    found = []
    if evaluated["image_size"] != trained["image_size"]:
        found.append(f"images are {evaluated['image_size']}x{evaluated['image_size']} but the runs train on "
                     f"{trained['image_size']}x{trained['image_size']}")
    grid, trained_grid = evaluated["voxel_resolution"], trained["voxel_resolution"]
    if trained_grid is not None and not evaluated["files_without_voxels"] and grid != trained_grid:
        found.append(f"voxels are {'of several resolutions' if grid is None else f'{grid}^3'} but the runs "
                     f"predict {trained_grid}^3")
    if found:
        raise DataError(f"{eval_shards}: {'; '.join(found)} (--train-shards {train_shards}); a checkpoint is "
                        f"evaluated at the image size and voxel resolution it was trained at: give --eval-shards "
                        f"rendered with --image-size {trained['image_size']}"
                        + (f" --voxel-resolution {trained_grid}" if trained_grid is not None else ""))
