"""``sc3d-data merge OUT PART_DIR...``: part folders (``--part I/N`` runs of ``render`` or
``import-r2n2``) -> one normal dataset folder.

Checks, before anything is written (each refusal is one line naming the folder; ``merge_checks.py``):

- every part is a finished dataset (``index.json`` says complete, every listed shard intact);
- all parts have the same settings and split, by meaning (the GL backend may differ; a setting
  an older sc3d did not record counts as its default), the same part count ``N`` and the same
  plan digest (planned from the same collection);
- parts ``0..N-1`` are each given exactly once (a missing part is named);
- each part accounts for the objects it was assigned (shards + failures), and no object id
  appears twice across parts;
- a file in ``OUT`` named like a shard the merge writes that ``OUT``'s index does not list is
  someone's unless it is a shard of the parts' settings (``resume.check_unlisted_shard``, as
  ``render`` decides); ``overwrite=True`` replaces it.

Output: the shards of part 0, then part 1, ... become ``OUT/shard-00000.h5``, ... (hard links
when ``OUT`` is on the same file system, else copies; ``copy=True`` always copies), so the
merged folder holds its own files and the parts can be deleted afterwards. ``index.json``
lists them with their objects (rows unchanged), all failures, skipped files and warnings, the
counts, the settings of the parts and ``"merged"`` (which parts, when). The shard files are
not rewritten: each object's arrays, cameras and attributes are the bytes the part wrote,
which are those of a run over the whole collection (``tests/test_scale.py``).

The parts are held (a shared lock) while they are checked and linked: a rerun of a part started
meanwhile is refused, naming the merge, and a part being written is refused, naming its writer.

Resumable: a shard already in ``OUT`` with the right size and SHA-256 is kept; the index is
written last, so an interrupted merge is finished by running it again. A merge run again after
``sc3d-data voxelize OUT`` keeps the voxelized dataset when ``OUT`` still holds the same merge,
and is refused when the parts changed since (``--overwrite`` merges afresh, without the voxels);
``merged.voxels`` records the grids the parts gave, so parts voxelized after the merge merge
again. A merge into an ``OUT`` that holds a merge made with other settings, or in which an
object of the parts has another split, is refused (``--overwrite`` replaces it), as ``render``
refuses a rerun with other settings or splits.
"""
from __future__ import annotations

import os
import shutil
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from sc3d_data.io.shards import INDEX_NAME, SHARD_PATTERN, file_sha256, io_reason, load_index, shard_path, write_index
from sc3d_data.pipeline.run.merge_checks import MergeError, check_parts, check_same_settings
from sc3d_data.pipeline.run.resume import check_unlisted_shard


def merged_voxels_record(parts: list[dict]) -> dict | None:
    """The merge's ``voxels`` record: ``sc3d-data voxelize``'s of the parts that have one (their
    grids are the same, ``check_parts``), with the failures of all of them; None when no part
    was voxelized afterwards (the render's settings then say what the grids are)."""
    records = [p["voxels"] for p in parts if p.get("voxels")]
    if not records:
        return None
    return dict(records[0], failed=sum(r.get("failed", 0) for r in records))


@dataclass
class MergeSummary:
    parts: int
    shards: int
    objects: int
    failed: int
    linked: int
    copied: int
    kept: int
    seconds: float
    out: str


def _renamed_failures(failures: list[dict], names: dict[str, str]) -> list[dict]:
    """``failures`` of one part with the ``shard`` of each ``voxelize`` failure renamed by
    ``names`` (the part's shard file -> its merged name); the others unchanged."""
    return [dict(f, shard=names.get(f.get("shard"), f.get("shard"))) if f.get("stage") == "voxelize" else f
            for f in failures]


def _place(src: Path, dst: Path, copy: bool) -> str:
    """Put ``src`` at ``dst`` atomically (temporary name, then rename): a hard link, or a copy
    across file systems / with ``copy``. Returns ``"linked"`` or ``"copied"``. On failure (disk
    full) the temporary file is removed and the ``OSError`` names ``dst``."""
    tmp = dst.with_name(dst.name + ".tmp")
    if tmp.exists():
        tmp.unlink()
    how = "copied"
    if not copy:
        try:
            os.link(src, tmp)
            how = "linked"
        except OSError:
            pass
    try:
        if how == "copied":
            shutil.copyfile(src, tmp)  # its ENOSPC names the source file: renamed below
        os.replace(tmp, dst)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise OSError(e.errno, io_reason(e), str(dst)) from e
    return how


def _voxelized_since(out: Path, old: dict, parts: list[dict], objects: list[dict], sources: list[str],
                     t0: float) -> MergeSummary:
    """A merge run again into ``out`` after ``sc3d-data voxelize out`` gave its shards voxels
    (its index's ``voxels`` record is not the parts'): the parts' shards would replace them.
    When ``out`` still holds this merge (the same parts, plan and objects, the parts' shards the
    ones merged: ``sources``, their SHA-256 as the merge recorded them; every shard of ``out``
    intact as its index lists it, lists that agree) nothing is written and the voxelized dataset is kept; otherwise
    ``MergeError``: merging again needs ``--overwrite`` (and then ``voxelize`` again)."""
    from sc3d_data.io.index_check import listing_problems
    from sc3d_data.io.shard_reader import verify_shard

    same_merge = (old["merged"].get("plan_sha256") == parts[0]["part"]["plan_sha256"]
                  and old["merged"].get("sources_sha256") == sources
                  and sorted(map(os.path.realpath, old["merged"].get("parts", [])))
                  == sorted(os.path.realpath(p["_dir"]) for p in parts))

    def rows(entries):
        return {(o["category"], o["model_id"], o["shard"], o.get("row")) for o in entries}

    shards = old.get("shards", [])
    intact = not listing_problems(old) and all(verify_shard(out, s) is None for s in shards)
    if same_merge and intact and rows(old.get("objects", [])) == rows(objects):
        return MergeSummary(parts=len(parts), shards=len(shards), objects=len(objects),
                            failed=len(old.get("failures", [])), linked=0, copied=0, kept=len(shards),
                            seconds=time.monotonic() - t0, out=str(out))
    raise MergeError(f"{out}: its shards were given voxels by `sc3d-data voxelize` after the merge, and the "
                     "parts differ from what was merged; merging again would replace them: use another OUT, "
                     "or --overwrite (then run `sc3d-data voxelize` on it again)")


def merge_parts(out: Path, part_dirs: list[Path], copy: bool = False, overwrite: bool = False,
                defaults_of: Callable[[dict], dict] = lambda settings: {}) -> MergeSummary:
    """Merge ``part_dirs`` into ``out`` (module doc); ``defaults_of``: as for :func:`check_parts`."""
    from sc3d_data.io.outlock import reading_lock

    t0 = time.monotonic()
    out = Path(out)
    dirs = [Path(d) for d in part_dirs]
    if any(d.resolve() == out.resolve() for d in dirs):
        raise MergeError(f"{out}: the output folder cannot be one of the parts")
    with ExitStack() as reading:  # no part is rewritten while it is checked and linked, nor merged while written
        for d in dict.fromkeys(dirs):  # a folder without an index is refused below: no lock file left in it
            if (d / INDEX_NAME).is_file():
                reading.enter_context(reading_lock(d, "sc3d-data merge", "merge when it has finished"))
        return _merge_checked(out, check_parts(dirs, defaults_of), copy, overwrite, defaults_of, t0)


def _refuse_damaged(src: Path, entry: dict) -> None:
    """``MergeError`` when part shard ``src`` is not the file its part's index records (SHA-256):
    the checks before the merge compare sizes only, so a shard with flipped bytes was linked,
    exit 0, and every rerun linked it again. Only the shards to be placed are hashed (kept ones
    were just hashed in ``OUT``)."""
    from sc3d_data.io.shard_reader import verify_shard

    if (problem := verify_shard(src.parent, entry)) is not None:
        raise MergeError(f"{problem}; rerun that part (it re-renders the shard), then merge")


def _merge_checked(out: Path, parts: list[dict], copy: bool, overwrite: bool, defaults_of: Callable[[dict], dict],
                   t0: float) -> MergeSummary:
    """:func:`merge_parts` once the ``parts`` (their checked indexes, in part order) are held."""
    from sc3d_data.io.outlock import exclusive_lock
    from sc3d_data.pipeline.run.resume import tmp_cleaned

    out.mkdir(parents=True, exist_ok=True)
    with exclusive_lock(out, "sc3d-data merge"), tmp_cleaned(out):  # a killed merge's *.tmp go
        # OUT's lists may disagree (hand-edited): readers say to merge again, which writes them anew
        old = load_index(out, listing=False) if (out / INDEX_NAME).is_file() else {}
        if old and not overwrite and "merged" not in old:
            raise MergeError(f"{out}: already holds a dataset that is not a merge; use another OUT or --overwrite")
        listed = {e["file"] for e in old.get("shards", [])}
        shards, objects, failures, skipped, warnings, places = [], [], [], [], [], []
        counts = {"linked": 0, "copied": 0, "kept": 0}
        for index in parts:
            src_dir, names = Path(index["_dir"]), {}
            for entry in index.get("shards", []):
                name = SHARD_PATTERN.format(len(shards))
                places.append((src_dir / entry["file"], out / name, entry))
                objects += [dict(o, shard=name, chunk=len(shards)) for o in index["objects"]
                            if o["shard"] == entry["file"]]
                names[entry["file"]] = name
                shards.append(dict(entry, file=name, chunk=len(shards)))
            failures += _renamed_failures(index.get("failures", []), names)
            skipped += index.get("skipped", [])
            warnings += index.get("warnings", [])
        voxels = merged_voxels_record(parts)
        if old.get("merged") and not overwrite:
            check_same_settings(out, old, parts[0], objects, defaults_of(old.get("settings", {})))
            given = old["merged"].get("voxels", voxels if old.get("voxels") else None)  # older merges: no record
            if old.get("voxels") != given:
                return _voxelized_since(out, old, parts, objects, [e["sha256"] for _, _, e in places], t0)
        kept = [dst.is_file() and dst.stat().st_size == entry["bytes"] and file_sha256(dst) == entry["sha256"]
                for _, dst, entry in places]
        if not overwrite:  # a shard-named file no merge wrote is someone's: refused before any write
            for (_, dst, _), same in zip(places, kept):
                if not same and dst.name not in listed:
                    check_unlisted_shard(dst, parts[0]["settings"], out / INDEX_NAME, "this merge",
                                         "move it away, use another OUT or --overwrite")
        for (src, _, entry), same in zip(places, kept):
            if not same:
                _refuse_damaged(src, entry)
        for (src, dst, _), same in zip(places, kept):
            counts["kept" if same else _place(src, dst, copy)] += 1
        for stale in listed - {s["file"] for s in shards}:
            shard_path(out, stale).unlink(missing_ok=True)  # listed by an earlier merge of other parts
        first = parts[0]
        extra = {"merged": {"parts": [p["_dir"] for p in parts], "count": first["part"]["count"],
                            "rule": first["part"]["rule"], "plan_sha256": first["part"]["plan_sha256"],
                            "planned_total": first["part"]["planned_total"],
                            "sources_sha256": [e["sha256"] for _, _, e in places],
                            "backends": sorted({str(b) for p in parts if (b := p["settings"].get("backend"))})}}
        extra["merged"]["voxels"] = voxels  # what the parts gave: a later `voxelize OUT` changes "voxels" alone
        if voxels is not None:
            extra["voxels"] = voxels
        write_index(out, complete=True, settings=first["settings"], split=first.get("split", {}), shards=shards,
                    objects=objects, failures=failures, skipped=skipped, warnings=warnings, extra=extra)
    return MergeSummary(parts=len(parts), shards=len(shards), objects=len(objects),
                        failed=sum(1 for f in failures), seconds=time.monotonic() - t0, out=str(out), **counts)
