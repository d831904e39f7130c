"""Resume of ``sc3d-data render``: what an existing ``index.json`` in ``--out`` lets a run keep.

The index is rewritten atomically after every shard (past 10,000 objects less often:
``jobs/shard_output.py``). A rerun with the same settings (and the
same ``--part``) skips chunks that are complete (their shard is listed, exists and matches the
size and SHA-256 in the index: a truncated or corrupted shard is rendered again) and, with
``retry_failed``, renders the recorded failures of complete chunks again and rewrites their
shard in plan order. A kept chunk holding a mesh that changed since it was rendered (its
``source_file`` fingerprint, :func:`changed_sources`) is rendered again. Stale ``*.tmp`` files
are deleted (sc3d's own names only: :data:`OWN_TMP`). A rerun whose split rule puts a kept
object in another split than its shard holds (an edited ``--split-file``, or ``--split r2n2``
over a folder that gained meshes) is refused before any work (:func:`check_kept_splits`): the
index would describe splits the shards do not hold.
"""
from __future__ import annotations

import os

import re
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Iterator

from sc3d_data.pipeline.run.plan import Task


#: the temporary files that sc3d's writers make in a dataset folder (``io.shards``: a shard's or
#: the index's name + ``.tmp``, or + ``.PID.tmp`` when several processes may write it); any
#: other ``*.tmp`` in the folder is someone else's and is left alone
OWN_TMP = re.compile(r"^(?:[A-Za-z0-9][A-Za-z0-9_.-]*\.h5|index\.json)(?:\.[0-9]+)?\.tmp$")


def clean_tmp(out: Path) -> None:
    """Delete the temporary files (:data:`OWN_TMP`) a killed run left in ``out``."""
    for p in out.glob("*.tmp"):
        if OWN_TMP.match(p.name) and not p.is_dir():
            with suppress(OSError):
                p.unlink()


@contextmanager
def tmp_cleaned(out: Path) -> Iterator[None]:
    """A command's ``with`` block (under ``out``'s lock), with ``clean_tmp`` before and after."""
    clean_tmp(out)
    try:
        yield
    finally:
        clean_tmp(out)


def check_unlisted_shard(path: Path, settings: dict, index_file: Path, what: str, hint: str) -> None:
    """``ValueError`` when ``path``, a file named like a shard that ``what`` (a command) is about
    to write but that its folder's index ``index_file`` does not list, exists and is not a shard
    made with ``settings`` (such a shard was left by a run killed before its index listed it and
    may be replaced); anything else is someone's file. ``hint``: what the user can do."""
    import json

    from sc3d_data.io.shards import ShardError
    from sc3d_data.io.shard_reader import open_shard

    if not (path.exists() or path.is_symlink()):
        return
    try:
        with open_shard(path) as f:
            theirs = json.loads(f.attrs["settings"])
        ours = isinstance(theirs, dict) and not settings_differ(theirs, settings)
    except (ShardError, KeyError, ValueError, OSError):
        ours = False
    if not ours:
        raise ValueError(f"{path}: named like a shard {what} writes, but {index_file} does not list it and it "
                         f"was not made with this run's settings; {hint}")


def listed_shard_names(out: Path) -> set[str]:
    """The shard file names that ``out``'s index lists (none when it cannot be read)."""
    from sc3d_data.io.shards import ShardError, load_index

    try:
        return {e["file"] for e in load_index(out).get("shards", []) if isinstance(e, dict) and "file" in e}
    except ShardError:
        return set()


def remove_listed_outputs(out: Path) -> None:
    """``--overwrite``: delete the shards that ``out``'s index lists, then the index. A file the
    index does not list (a shard-like name the run did not write) is left alone, and so is a
    listed name that is not a plain file name of ``out`` or leads outside it. An unreadable
    index is deleted alone."""
    from sc3d_data.io.shards import INDEX_NAME, ShardError, shard_path

    index_file = out / INDEX_NAME
    if not index_file.is_file():
        return
    for name in listed_shard_names(out):
        try:
            shard_path(out, name).unlink(missing_ok=True)
        except ShardError:
            continue
    index_file.unlink()


def check_out(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    try:
        Path(os.path.abspath(out)).mkdir(parents=True, exist_ok=True)  # `new/../data` makes no `new`
    except OSError as e:
        raise ValueError(f"--out {out}: cannot create the folder ({e.strerror or e})") from e


def settings_differ(old: dict, new: dict, defaults: dict | None = None) -> list[str]:
    """Settings that differ between an existing index and this run, or between two parts
    (keys an older index lacks count as their value in ``defaults``; the GL backend is not
    compared: EGL and OSMesa give the same images; values compare by meaning: ``+z`` is ``+Z``,
    ``chair,car`` is ``car,chair``, ``setting_meaning.py``)."""
    from sc3d_data.pipeline.run.setting_meaning import setting_meaning

    defaults = defaults or {}

    def value(settings, k):
        return setting_meaning(k, settings.get(k, defaults.get(k)))

    skip = ("backend", "requested_backend")
    keys = (set(old) | set(new)) - set(skip)
    return sorted(k for k in keys if value(old, k) != value(new, k))


def resume_state(out: Path, old: dict, retry_failed: bool, K: int, tasks: list[Task], meshes: str | None = None
                 ) -> dict:
    """What an existing index lets this run keep: chunks whose shard is intact (or that were
    empty), their index entries, and the failures to render again (``retry_failed``).
    ``meshes``: this run's ``--meshes`` (the folder companion files must lie in).
    ``ValueError`` when this run's split rule moves a kept object (:func:`check_kept_splits`)."""
    from sc3d_data.io.index_check import listing_problems
    from sc3d_data.io.shard_reader import verify_shard
    from sc3d_data.io.shards import INDEX_NAME

    by_key = {(t.category, t.model_id): t for t in tasks}
    done_chunks, broken = set(old.get("empty_chunks", [])), []
    listing = listing_problems(old)  # an index whose lists disagree: its files' chunks are made again
    for s in old.get("shards", []):
        problem = verify_shard(out, s) or (f"{out / INDEX_NAME}: {listing[s['file']]}" if s["file"] in listing
                                           else None)
        if problem is None:
            done_chunks.add(s["chunk"])
        elif problem + "; rendering its objects again" not in broken:  # a shard listed twice: said once
            broken.append(problem + "; rendering its objects again")
    for chunk, problem in changed_sources(old.get("objects", []), by_key, done_chunks, meshes).items():
        done_chunks.discard(chunk)
        broken.append(problem)
    shards = [s for s in old.get("shards", []) if s["chunk"] in done_chunks]
    objects = [o for o in old.get("objects", []) if o.get("chunk") in done_chunks]
    check_kept_splits(out, objects, tasks)
    kept_files = {s["file"] for s in shards}
    failures = [f for f in old.get("failures", []) if f.get("chunk") in done_chunks
                or (f.get("stage") == "voxelize" and f.get("shard") in kept_files)]
    warnings = [w for w in old.get("warnings", []) if w.get("chunk") in done_chunks]
    retry, attempts = set(), {}
    if retry_failed:
        for f in failures:
            t = by_key.get((f.get("category"), f.get("model_id")))
            if t is not None and t.pos // K == f.get("chunk"):
                retry.add(t.pos)
                attempts[t.pos] = int(f.get("attempts", 1))
        failures = [f for f in failures if f.get("pos") not in retry]
        warnings = [w for w in warnings if w.get("source") not in {tasks[p].path for p in retry}]
    unlisted = unlisted_positions(tasks, K, done_chunks, objects + failures) - retry
    return {"done_chunks": done_chunks, "shards": shards, "objects": objects, "failures": failures,
            "warnings": warnings, "retry": retry | unlisted, "unlisted": unlisted, "attempts": attempts,
            "broken": broken,
            "empty_chunks": [c for c in old.get("empty_chunks", []) if c in done_chunks],
            "extra": {k: old[k] for k in ("voxels",) if k in old}}  # the record of `voxelize SHARDS`


def changed_sources(objects: list[dict], by_key: dict, chunks: set, meshes: str | None = None) -> dict[int, str]:
    """``{chunk: reason}`` for the ``chunks`` holding an object (index entry) whose mesh file,
    or a companion file it names (a material file, a texture: ``"materials"``, present or
    missing then), differs from the fingerprint recorded when it was rendered (``source_file``;
    ``io.source_fingerprint``): such a chunk is rendered again. ``by_key``: the plan's tasks by
    (category, model id); entries without a fingerprint (earlier versions) are not compared;
    ``meshes``: this run's ``--meshes``, the folder (a file's folder for a file) companion files
    must lie in to be read."""
    from sc3d_data.io.materials import dataset_folder
    from sc3d_data.io.source_fingerprint import materials_change, source_change

    root = None if meshes is None else dataset_folder(meshes)

    out: dict[int, str] = {}
    for o in objects:
        task = by_key.get((o.get("category"), o.get("model_id")))
        if o.get("chunk") not in chunks or o["chunk"] in out or task is None or "source_file" not in o:
            continue
        if ((why := source_change(task.path, o["source_file"])) is not None
                or (why := materials_change(task.path, o["source_file"].get("materials", {}), root)) is not None):
            out[o["chunk"]] = f"{task.path}: changed since it was rendered ({why}); rendering its chunk again"
    return out


def split_changes(objects: list[dict], tasks: list[Task]) -> list[tuple[str, str, str, str]]:
    """``[(category, model_id, old split, new split)]`` of the kept ``objects`` (index entries)
    that this run's plan ``tasks`` puts in another split than the one their shard holds, in
    index order. Objects the plan lacks are left out (the plan check refuses them)."""
    new = {(t.category, t.model_id): t.split for t in tasks}
    return [(o.get("category"), o.get("model_id"), o.get("split"), new[key]) for o in objects
            if (key := (o.get("category"), o.get("model_id"))) in new and o.get("split") != new[key]]


def check_kept_splits(out: Path, objects: list[dict], tasks: list[Task]) -> None:
    """``ValueError`` (one line) when a kept object would change split under this run's split
    rule: its shard keeps the old split while the index would list the new rule (module doc)."""
    from sc3d_data.io.names import printable

    changes = split_changes(objects, tasks)
    if changes:
        cat, mid, was, now = changes[0]
        raise ValueError(f"{out}: {len(changes)} kept object(s) would change split under this run's split rule "
                         f"(e.g. {printable(cat)}/{printable(mid)}: {was} -> {now}), but their shards keep the "
                         "split they were made with; render into another --out (or --overwrite), or keep the "
                         "split rule and split file as they were")


def unlisted_positions(tasks: list[Task], K: int, done_chunks: set, listed: list[dict]) -> set[int]:
    """Plan positions of kept chunks whose object the kept entries (``listed``: objects and
    failures) do not name: a run stopped while retrying a failure has already dropped its
    record, so keeping the chunk as done would lose the object silently; and meshes added to the
    collection that fall in a kept chunk. They are done again (``render`` counts them as added,
    not as retried failures)."""
    names = {(e.get("category"), e.get("model_id")) for e in listed}
    return {t.pos for t in tasks if t.pos // K in done_chunks and (t.category, t.model_id) not in names}


def empty_state() -> dict:
    """The resume state of a fresh run (nothing kept)."""
    return {"done_chunks": set(), "shards": [], "objects": [], "failures": [], "warnings": [],
            "retry": set(), "unlisted": set(), "attempts": {}, "broken": [], "empty_chunks": [], "extra": {}}


def remaining(tasks: list[Task], state: dict, K: int) -> tuple[list[Task], int]:
    """``(todo, resumed)`` of a run with resume ``state`` over ``tasks`` in chunks of ``K``: the
    tasks of chunks not kept plus the failures it retries, and how many objects the kept chunks
    hold (their recorded failures left out)."""
    done, retry = state["done_chunks"], state["retry"]
    todo = [t for t in tasks if t.pos // K not in done or t.pos in retry]
    kept_failed = {(f.get("category"), f.get("model_id")) for f in state["failures"] if f.get("stage") != "voxelize"}
    resumed = sum(1 for t in tasks if t.pos // K in done and t.pos not in retry
                  and (t.category, t.model_id) not in kept_failed)
    return todo, resumed


def shards_layout(out: Path, old: dict) -> str | None:
    """The chunk layout (``io.shards.CHUNK_LAYOUTS``) of the first shard listed in ``out``'s index
    ``old`` that opens, read from its ``images``; None when none opens (their chunks are done
    again). For an index that does not record ``chunks``: render wrote one object per chunk
    before it had ``--chunks`` (whose default is one view), import-r2n2 one view per chunk for a
    while before it recorded it, so only the shards tell; a rerun that took the default kept
    them and recorded ``view`` (``info`` named the wrong layout) and wrote new chunks per view."""
    from sc3d_data.io.shards import ShardError, shard_path
    from sc3d_data.io.shard_reader import open_shard

    for entry in old.get("shards", []):
        try:
            with open_shard(shard_path(out, entry["file"])) as f:
                chunks = f["images"].chunks
        except (ShardError, KeyError, TypeError, OSError):
            continue
        if chunks and len(chunks) > 1:
            return "view" if chunks[1] == 1 else "object"
    return None


def held_settings(folder: Path, index: dict) -> dict:
    """``index``'s settings (of the dataset in ``folder``), with ``chunks`` the layout its shards hold
    where it does not record one (:func:`shards_layout`): what a rerun over it (:func:`check_resume`)
    and ``merge`` (its parts) compare, so an older dataset is neither recorded as the other layout
    nor merged with a part of it into a dataset of two."""
    settings = index.get("settings", {})
    layout = None if "chunks" in settings else shards_layout(folder, index)
    return {**settings, "chunks": layout} if layout else settings


def check_resume(out: Path, old: dict, settings: dict, defaults: dict, part: dict) -> None:
    """``ValueError`` when ``out``'s index cannot be resumed by this run: other settings, another
    ``--part`` or a merged dataset."""
    if "merged" in old:
        made_by = "import-r2n2" if settings.get("source") == "3D-R2N2" else "render"
        raise ValueError(f"{out}: is a merged dataset (sc3d-data merge); {made_by} parts into their own "
                         "folders and merge again, or use another --out")
    recorded = held_settings(out, old)  # an older index did not record chunks: not the default older code wrote
    diff = settings_differ(recorded, settings, defaults)
    if diff:
        held = f"; its shards hold one {recorded['chunks']} per chunk" if {"chunks"} & set(diff) & set(recorded) else ""
        raise ValueError(f"{out}: existing shards were made with other settings ({', '.join(diff)} differ){held}; "
                         "use another --out or --overwrite")
    old_part = old.get("part", {"index": 0, "count": 1})
    if (old_part.get("index"), old_part.get("count")) != (part["index"], part["count"]):
        this = "of all objects (no --part)" if part["count"] == 1 else f"part {part['index']}/{part['count']}"
        raise ValueError(f"{out}: holds part {old_part.get('index')}/{old_part.get('count')}, this run is {this}; "
                         "give each part its own --out")
