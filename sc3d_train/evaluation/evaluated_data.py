"""What an evaluation measured. As one digest: ``eval`` records it in ``metrics.json``
(``data_sha256``) and ``claims`` reuses an evaluation only while its shards still give the same
digest (shards re-rendered in place with other settings, objects or a new split are evaluated
again). And how the evaluated objects relate to the checkpoint's run: how many it trained on
(``trained_on``), and whether they chose the checkpoint (``selected_on_this_split``: ``best.pt``
evaluated on its own validation objects, optimistic figures)."""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path


def evaluated_data_digest(shards: Path, split: str, objects) -> str:
    """SHA-256 (hex) of what evaluating ``split`` of ``shards`` reads: the sorted
    ``category/model_id`` of ``objects`` (the ``ObjectRef``s evaluated), the render ``settings``
    of ``shards/index.json`` and the ``sha256`` of each of its shard files in index order (None
    where the index records none). Reads ``index.json`` only; ``DataError`` when it cannot be
    read."""
    from sc3d_data.io.shards import ShardError, load_index
    from sc3d_train.data.dataset import DataError

    try:
        index = load_index(Path(shards))
    except (ShardError, OSError) as e:
        raise DataError(str(e)) from e
    content = {"split": split, "objects": sorted(f"{r.category}/{r.model_id}" for r in objects),
               "settings": index.get("settings", {}),
               "shard_sha256": [entry.get("sha256") for entry in index.get("shards", [])]}
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


def split_digest(shards: Path, split: str) -> str:
    """:func:`evaluated_data_digest` of every object of ``split`` of ``shards`` (what ``eval``
    evaluates: ``ShardDataset(shards, split)``'s objects)."""
    from sc3d_train.data.dataset import scan_objects

    refs, _ = scan_objects(Path(shards))
    return evaluated_data_digest(shards, split, [r for r in refs if r.split == split])


def run_objects(cfg, shards: Path) -> list | None:
    """The ``ObjectRef``s of the objects as the run of ``cfg`` saw them, read once per evaluation:
    from the run's shards while they still hold the objects it trained on (``cfg.objects_sha256``,
    compared where recorded), else from ``shards`` (the evaluated ones) when their training split
    holds exactly the run's objects. None when neither tells: the run's shards moved (a copy on
    another machine) or were re-rendered in place with another split, and ``shards`` does not
    hold the run's objects either."""
    from sc3d_train.data.dataset import DataError, scan_objects
    from sc3d_train.loop.resolve import objects_digest

    for folder, need_digest in ((Path(cfg.shards), False), (Path(shards), True)):
        try:
            refs, _ = scan_objects(folder)
        except (DataError, OSError):
            continue
        recorded = cfg.objects_sha256
        if (recorded is None and need_digest) or (recorded is not None and objects_digest(refs, cfg.split) != recorded):
            continue
        return refs
    return None


def split_of(refs: list | None, split: str) -> set | None:
    """``{(category, model_id)}`` of the objects of ``split`` among ``refs`` (:func:`run_objects`),
    None where those are unknown."""
    return None if refs is None else {(r.category, r.model_id) for r in refs if r.split == split}


def training_objects_among(cfg, objects, run_refs: list | None) -> int | None:
    """How many of ``objects`` (``ObjectRef``s being evaluated) are objects the run of ``cfg``
    trained on, by category and model id (its ``split`` among ``run_refs``, :func:`run_objects`;
    of a ``labeled-only`` run only its labelled subset, the one fit drew: it reads no other);
    None when that cannot be told. ``eval --split train`` is a legitimate check of the training
    fit, but its figures are not of held-out objects, and ``eval`` says so."""
    from sc3d_train.data.dataset import choose_labeled

    trained = split_of(run_refs, cfg.split)
    if trained is not None and cfg.mode == "labeled-only" and cfg.labeled_fraction < 1:
        in_split = [r for r in run_refs if r.split == cfg.split]
        keys = choose_labeled(in_split, cfg.labeled_fraction, cfg.seed)
        trained = {(r.category, r.model_id) for r in in_split if f"{r.shard}:{r.row}" in keys}
    return None if trained is None else sum(1 for r in objects if (r.category, r.model_id) in trained)


def untrained_categories(cfg, objects, run_refs: list | None) -> list[str] | None:
    """The categories of ``objects`` (``ObjectRef``s being evaluated) of which the run of ``cfg``
    had no training object (its ``split`` among ``run_refs``, :func:`run_objects`), sorted; None
    when that cannot be told. Evaluating on unseen categories is a legitimate experiment, but
    their figures, and a mean over categories that holds them, are not of the trained task."""
    trained = split_of(run_refs, cfg.split)
    return None if trained is None else sorted({r.category for r in objects} - {c for c, _ in trained})


def selection_objects_among(cfg, validation: dict | None, objects, shards: Path, run_refs: list | None) -> bool:
    """Whether ``objects`` (``ObjectRef``s of ``shards`` being evaluated) include objects of the
    validation split that chose the checkpoint (``validation``: its record, ``best.pt``'s
    ``validation``; None for ``last.pt`` and other checkpoints that nothing chose, then False):
    its figures on them are optimistic, the checkpoint being the best of several on exactly these
    objects. Judged by category and model id against the run's ``validation["split"]`` among
    ``run_refs`` (:func:`run_objects`); where that cannot be told, True when the evaluated objects
    hold the same split name as the validation's in the same shard folder as the run's."""
    if not validation:
        return False
    val_split = validation.get("split", cfg.val_split)
    chose = split_of(run_refs, val_split)
    if chose is None:
        return Path(shards).resolve() == Path(cfg.shards).resolve() and any(r.split == val_split for r in objects)
    return any((r.category, r.model_id) in chose for r in objects)


#: how :func:`replaced_provenance` names what an output was made from
PROVENANCE_LABELS = {"checkpoint": "checkpoint", "shards": "shards", "pose_from": "--pose", "image_realpath": "image",
                     "image": "image"}


def read_record(record: Path) -> dict | None:
    """The JSON object in file ``record`` (an evaluation's ``metrics.json``, a prediction's
    ``NAME.json``); None where it is missing, unreadable or no object."""
    try:
        was = json.loads(Path(record).read_text())
    except (OSError, ValueError):
        return None
    return was if isinstance(was, dict) else None


def replaced_provenance(record: Path, given: dict) -> tuple[str, str] | None:
    """Whether the JSON file ``record`` (an evaluation's ``metrics.json``, a prediction's
    ``NAME.json``) holds the output of another ``checkpoint``, ``shards`` or ``image_realpath`` (paths,
    compared by real path) or ``pose_from`` than ``given`` records: ``(what it holds, what is given)``, each as
    ``"LABEL VALUE, ..."`` (:data:`PROVENANCE_LABELS`), which a default output folder must not
    replace without a word; None where it holds the same, or is no readable record."""
    was = read_record(record)
    return None if was is None else provenance_changes(was, given)


def provenance_changes(was: dict, given: dict) -> tuple[str, str] | None:
    """:func:`replaced_provenance` of a record already read (``was``)."""

    def same(key, recorded, now) -> bool:
        if key == "pose_from":
            return recorded == now
        return _same_path(str(recorded), now, tail=key == "checkpoint")

    changed = [k for k, v in given.items() if k in was and not same(k, was[k], v)]
    if not changed:
        return None
    return (", ".join(f"{PROVENANCE_LABELS[k]} {was[k]}" for k in changed),
            ", ".join(f"{PROVENANCE_LABELS[k]} {given[k]}" for k in changed))


def _same_path(recorded: str, now: str, tail: bool) -> bool:
    """Whether a recorded path names the file ``now``: by real path, or, with ``tail``, for a relative
    path (an earlier version recorded the path as given, relative to a folder no record names), where
    ``now``'s real path ends with it; resolved against today's folder it named another file. Only a
    checkpoint's is judged by its tail: the default folder holding the record lies in the run folder of
    the checkpoint given, so a path in it that ends so is that file; shards of the same folder name
    elsewhere (``data/shards``) are other shards, whose evaluation must not replace it."""
    if os.path.realpath(recorded) == os.path.realpath(now):
        return True
    if not tail:
        return False
    tail = Path(os.path.normpath(recorded)).parts
    return not os.path.isabs(recorded) and ".." not in tail and Path(os.path.realpath(now)).parts[-len(tail):] == tail
