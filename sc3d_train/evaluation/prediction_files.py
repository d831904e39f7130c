"""Where ``sc3d-train predict`` writes: the output files of each image and the checks, made before
anything is written, that they replace no input image, no file of someone else and, in the default
folder, no prediction of another checkpoint or ``--pose``."""
from __future__ import annotations

import os
from pathlib import Path


class ImageError(ValueError):
    """An input image that cannot be fed to the model (size, mode, unreadable)."""


def output_files(images: list[Path], out: Path) -> list[dict]:
    """Per image, ``{kind: out/NAME.kind}`` of the files :func:`~sc3d_train.evaluation.predict.predict` writes (binvox, npz, obj,
    json, png): NAME is the image's stem, with ``_`` appended while an earlier image took it."""
    used, outputs = set(), []
    for path in images:
        name = Path(path).stem
        while name in used:
            name += "_"
        used.add(name)
        outputs.append({k: Path(out) / f"{name}.{k}" for k in ("binvox", "npz", "obj", "json", "png")})
    return outputs


def recorded_files(files: dict) -> dict[str, str]:
    """``files`` (one image's of :func:`output_files`) as ``NAME.json`` records them: absolute
    paths, as its ``checkpoint`` and ``image_realpath`` are, so that a reader who opens the record
    from another folder finds them (an ``--out`` given relative was recorded as given, relative to
    the folder predict ran in, which no record names). A record of an earlier version may hold such
    relative paths: its files are the ones of those names beside it (:func:`listed_files`)."""
    return {kind: os.path.abspath(path) for kind, path in files.items()}


def check_inputs_kept(images: list[Path], outputs: list[dict], out: Path) -> None:
    """``ImageError`` naming ``--out`` when a file of ``outputs`` (:func:`output_files`) is one of
    the input ``images`` (``--out`` the images' folder: ``NAME.png`` would replace ``NAME.png``)."""
    inputs = {os.path.realpath(p): p for p in images}
    for files in outputs:
        for kind, path in files.items():
            if os.path.realpath(path) in inputs:
                raise ImageError(f"--out {out}: its {path.name} (the prediction's .{kind}) would overwrite "
                                 f"the input image {inputs[os.path.realpath(path)]}; choose another --out")


def listed_files(record: Path) -> set[str]:
    """The names of the files that the prediction record ``record`` (a ``NAME.json`` that
    ``predict`` wrote, in its output folder) lists as its own; empty where it is none."""
    from sc3d_train.evaluation.evaluated_data import read_record

    info = read_record(record)
    if not (info is not None and "checkpoint" in info and isinstance(info.get("files"), dict)):
        return set()
    return {Path(v).name for v in info["files"].values() if isinstance(v, str)}  # all in its folder


def check_outputs_replaceable(outputs: list[dict], out: Path) -> None:
    """``ImageError`` naming ``--out`` and the file when a file of ``outputs`` (:func:`output_files`)
    exists and is not of an earlier prediction: one that the prediction's ``NAME.json`` beside it
    lists (an image named ``index.png`` into a shard folder would otherwise replace its
    ``index.json``; ``curves.png`` into a run folder its curves). Predicting again into the same
    folder replaces its own files."""
    for files in outputs:
        existing = [p for p in files.values() if os.path.lexists(p)]
        if not existing:
            continue
        listed = listed_files(files["json"])
        for path in existing:
            if path.name not in listed:
                raise ImageError(f"--out {out}: {path.name} exists and is not a file of an earlier prediction "
                                 f"(no {Path(files['json']).name} of predict lists it), which this prediction would "
                                 "replace; choose another --out")


def check_default_folder_free(outputs: list[dict], checkpoint: Path, pose_from: str, out: Path) -> None:
    """``ImageError`` when the default output folder ``out`` (``RUN_DIR/predictions``) holds, under
    the name of an image of ``outputs`` (:func:`output_files`), the prediction of another
    checkpoint file or another ``--pose``, which this one would replace without a word
    (``predict --checkpoint RUN`` then ``--pick last``), as ``eval``'s default folder does. The same
    checkpoint file again replaces its own predictions; an explicit ``--out`` is not judged."""
    from sc3d_train.evaluation.evaluated_data import replaced_provenance

    for files in outputs:
        if changed := replaced_provenance(files["json"], {"checkpoint": checkpoint, "pose_from": pose_from}):
            raise ImageError(f"{out}: {files['json'].name} holds the prediction of {changed[0]}, which this one "
                             f"({changed[1]}) would replace; give --out for this one (or remove those files)")


def check_same_images(images: list[Path], outputs: list[dict], out: Path) -> None:
    """``ImageError`` naming ``--out`` when an image's ``NAME.json`` (:func:`output_files`) holds the
    prediction of another image file of the same name: camera names restart per folder
    (``day1/IMG_0001.jpg``, then ``day2/IMG_0001.jpg`` into the same ``--out``), and the second
    call replaced the first one's files without a word. The same file again, by any path,
    replaces its own prediction; a record of an earlier version is judged by its ``image``
    (:func:`_image_key`)."""
    from sc3d_data.io.names import printable
    from sc3d_train.evaluation.evaluated_data import provenance_changes, read_record

    for path, files in zip(images, outputs):
        was = read_record(files["json"])
        key = _image_key(was) if was is not None else None
        if key and (changed := provenance_changes(was, {key: str(path)})):
            raise ImageError(f"--out {out}: {files['json'].name} holds the prediction of another {printable(changed[0])} "
                             f"of that name, which this one ({printable(path)}) would replace; choose another --out "
                             "(or remove those files)")


def _image_key(was: dict) -> str | None:
    """The key of record ``was`` (a ``NAME.json``'s object) naming the image it was predicted from:
    ``image_realpath``; in a record of an earlier version, which has only the path as given,
    ``image`` where that is absolute (a relative one is relative to a folder no record names:
    not judged); None where neither."""
    if "image_realpath" in was:
        return "image_realpath"
    return "image" if isinstance(was.get("image"), str) and os.path.isabs(was["image"]) else None
