"""Where ``sc3d-train eval`` writes (``OUT/metrics.json``, ``OUT/predictions.png``): the checks,
made before anything is computed or written, that the output folder is one an evaluation may use
and that its files replace no file of someone else and, in the default folder, no evaluation of
another checkpoint, shards or ``--pose`` (as ``prediction_files`` checks for ``predict``)."""
from __future__ import annotations

import os
from pathlib import Path

from sc3d_train.evaluation.evaluated_data import read_record, replaced_provenance
from sc3d_train.evaluation.prediction_files import listed_files

#: keys every ``metrics.json`` that ``eval`` wrote holds
EVALUATION_KEYS = ("checkpoint", "shards", "split")
#: the ``Description`` text chunk of the ``predictions.png`` that ``eval`` draws (drawn first,
#: ``metrics.json`` last: an evaluation cut short between them leaves the picture alone)
EVALUATION_PICTURE = "sc3d-train eval: examples of an evaluation's predictions"


def check_split_name(split: str) -> None:
    """``ValueError`` when ``split`` (``--split``) is no name but a path (``../x``, ``a/b``, ``..``):
    it names the default output folder ``RUN_DIR/eval_SPLIT``, which would then lie elsewhere
    (and was made before the split was found missing)."""
    if not split or split in (".", "..") or "/" in split or "\\" in split:
        raise ValueError(f"--split {split!r}: a split is a name in the shards (train, val, test), not a path")


def check_default_folder_free(out: Path, checkpoint: Path, shards: Path, pose_from: str) -> None:
    """``ValueError`` when the default output folder ``out`` (``RUN_DIR/eval_SPLIT``) holds the
    evaluation of another checkpoint file, other shards or another ``--pose``, which this one would
    replace without a word (``eval --checkpoint RUN`` then ``eval --checkpoint RUN/checkpoints/
    step_000500.pt``). Evaluating the same checkpoint file again (after training went on) replaces
    its own evaluation."""
    given = {"checkpoint": checkpoint, "shards": shards, "pose_from": pose_from}
    if changed := replaced_provenance(Path(out) / "metrics.json", given):
        raise ValueError(f"{out}: holds the evaluation of {changed[0]}, which this one ({changed[1]}) would replace; "
                         "give --out for this one (or remove that folder)")


def _is_evaluation(path: Path) -> bool:
    """Whether ``path`` is a ``metrics.json`` that ``eval`` wrote (:data:`EVALUATION_KEYS`)."""
    record = read_record(path)
    return record is not None and all(k in record for k in EVALUATION_KEYS)


def _drawn_by_eval(path: Path) -> bool:
    """Whether ``path`` is a picture that ``eval`` drew (:data:`EVALUATION_PICTURE`)."""
    from PIL import Image

    try:
        with Image.open(path) as image:
            return image.info.get("Description") == EVALUATION_PICTURE
    except (OSError, ValueError, Image.DecompressionBombError):
        return False


def check_outputs_replaceable(out: Path) -> None:
    """``ValueError`` naming ``--out`` and the file when ``out/metrics.json`` or
    ``out/predictions.png`` exists and is not of an earlier evaluation. The folder holds one where
    its ``metrics.json`` is an evaluation's or its ``predictions.png`` was drawn by eval
    (:func:`_drawn_by_eval`: an evaluation cut short before its ``metrics.json``, or whose
    ``metrics.json`` was damaged, is redone, as ``claims`` does); else either file is someone
    else's (another tool's results, a picture), and so is a ``predictions.png`` that a prediction
    lists as its picture."""
    metrics, picture = Path(out) / "metrics.json", Path(out) / "predictions.png"
    has_picture = os.path.islink(picture) or picture.is_file()  # a folder there is not replaced: the write fails
    ours = _is_evaluation(metrics) or (has_picture and _drawn_by_eval(picture))
    if (os.path.islink(metrics) or metrics.is_file()) and not ours:
        raise ValueError(f"--out {out}: metrics.json exists and is not an evaluation's (sc3d-train eval writes "
                         f"{', '.join(EVALUATION_KEYS)} in it), which this evaluation would replace; choose another --out")
    predicted = has_picture and picture.name in listed_files(Path(out) / "predictions.json")  # an image's picture
    if has_picture and (predicted or not ours):
        whose = "a prediction's picture" if predicted else "not of an earlier evaluation (not drawn by eval)"
        raise ValueError(f"--out {out}: predictions.png exists and is {whose}, which this evaluation would replace; "
                         "choose another --out")
