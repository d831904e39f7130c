"""What ``sc3d-data merge`` refuses, before anything is written (``merge.py``'s module doc lists
it): the parts' own checks (:func:`check_parts`) and, into an ``OUT`` that holds a merge, one of
other settings or splits (:func:`check_same_settings`). Each refusal is a :class:`MergeError`
of one line naming the folder."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from sc3d_data.io.shards import held_voxel_resolution, load_index
from sc3d_data.io.shard_reader import verify_shard
from sc3d_data.pipeline.run.resume import held_settings, settings_differ
from sc3d_data.pipeline.run.setting_meaning import split_record_meaning


#: render settings that say how the grids were made: parts are compared by the grids they hold
#: instead (``render --voxelize`` and ``voxelize PART`` afterwards give the same grids)
VOXEL_SETTINGS = ("voxelize", "voxel_resolution")


def _grids(resolution: int | None) -> str:
    return "no voxels" if resolution is None else f"{resolution}^3 voxels"


class MergeError(ValueError):
    """Parts that cannot be merged (message names the folder and the problem)."""


def object_key(entry: dict) -> tuple[str, str] | None:
    return (entry["category"], entry["model_id"]) if entry.get("model_id") else None


def lost_objects(index: dict) -> list[dict]:
    """The failures of ``index`` that stand for an object missing from its shards: those of the
    render/import stage with an object id. A ``voxelize`` failure names an object that keeps
    its row (with an empty grid), so it is no object of its own."""
    return [f for f in index.get("failures", []) if object_key(f) and f.get("stage") != "voxelize"]


def check_parts(dirs: list[Path], defaults_of: Callable[[dict], dict] = lambda settings: {}) -> list[dict]:
    """The parts' indexes, in part order, after every check of the module doc. ``defaults_of``:
    what a setting an index lacks stands for, given its settings (``recorded_defaults``: a part
    made by an older sc3d merges with one made by a newer)."""
    if not dirs:
        raise MergeError("no part folders given")
    indexes = []
    for d in dirs:
        try:
            index = load_index(d)
        except (FileNotFoundError, ValueError) as e:
            raise MergeError(str(e)) from None
        if "part" not in index:
            raise MergeError(f"{d}: index has no part record (made by an older sc3d?); rerun it with --part")
        if not index.get("complete"):
            raise MergeError(f"{d}: part {index['part']['index']}/{index['part']['count']} is not finished "
                             "(index incomplete); rerun it (it resumes), then merge")
        for entry in index.get("shards", []):
            problem = verify_shard(d, entry, full=False, grids=held_voxel_resolution(index))
            if problem:
                raise MergeError(f"{problem}; rerun that part (it re-renders the shard), then merge")
        indexes.append(index)
    first, d0 = indexes[0], dirs[0]
    n = first["part"]["count"]
    seen: dict[int, Path] = {}
    settings0 = held_settings(d0, first)
    for d, index in zip(dirs, indexes):
        p = index["part"]
        diff = [k for k in settings_differ(settings0, held_settings(d, index),
                                           defaults_of(index.get("settings", {})))
                if k not in VOXEL_SETTINGS + ("split_file",)]  # the grids they hold and the split, below
        if diff:
            raise MergeError(f"{d}: made with other settings than {d0} ({', '.join(diff)} differ); refused")
        totals = (p.get("planned_total"), first["part"].get("planned_total"))
        if p["count"] == n and totals[0] != totals[1]:  # the split's record counts the plan's objects: named first
            raise MergeError(f"{d}: part {p['index']}/{n} planned from {totals[0]} objects, {d0} from {totals[1]}: "
                             "the meshes changed between their runs? rerun the earlier parts (they resume and "
                             "plan again), then merge; refused")
        if split_record_meaning(index.get("split")) != split_record_meaning(first.get("split")):
            raise MergeError(f"{d}: split differs from {d0}; refused")
        grids, grids0 = held_voxel_resolution(index), held_voxel_resolution(first)
        if grids != grids0:
            raise MergeError(f"{d}: {_grids(grids)}, {d0}: {_grids(grids0)}; refused: give every part the same "
                             f"grids (`sc3d-data voxelize PART --resolution R`), then merge")
        if p["count"] != n or p.get("plan_sha256") != first["part"].get("plan_sha256"):
            raise MergeError(f"{d}: part {p['index']}/{p['count']} of another plan than {d0} "
                             f"(part {first['part']['index']}/{n}); refused")
        if p["index"] in seen:
            raise MergeError(f"{d}: part {p['index']}/{n} is given twice (also {seen[p['index']]})")
        seen[p["index"]] = d
        done = len(index.get("objects", [])) + len(lost_objects(index))
        if done != p["assigned"]:
            raise MergeError(f"{d}: part {p['index']}/{n} accounts for {done} of its {p['assigned']} objects")
    missing = sorted(set(range(n)) - set(seen))
    if missing:
        raise MergeError(f"missing part(s) {', '.join(f'{i}/{n}' for i in missing)} (given: "
                         f"{', '.join(str(i) for i in sorted(seen))}); run them, then merge")
    owner: dict[tuple[str, str], Path] = {}
    for d, index in zip(dirs, indexes):
        for e in index.get("objects", []) + lost_objects(index):
            key = object_key(e)
            if key is None:
                continue
            if key in owner:
                raise MergeError(f"{d}: object {key[0]}/{key[1]} is also in {owner[key]} (duplicate); refused")
            owner[key] = d
    if sum(ix["part"]["assigned"] for ix in indexes) != first["part"]["planned_total"]:
        raise MergeError(f"the parts were assigned {sum(ix['part']['assigned'] for ix in indexes)} objects, "
                         f"the plan has {first['part']['planned_total']}")
    order = sorted(range(len(dirs)), key=lambda k: indexes[k]["part"]["index"])
    return [dict(indexes[k], _dir=str(dirs[k])) for k in order]


def check_same_settings(out: Path, old: dict, first: dict, objects: list[dict], defaults: dict) -> None:
    """``MergeError`` when ``out`` holds a merge made with other settings than the parts (other
    meshes, views, source...; compared as ``render`` compares a rerun's, by meaning, grids
    apart; ``defaults``: what a setting an older index lacks stands for), or in which an object
    of the parts (``objects``) has another split (an edited split file): merging would replace
    that dataset, which needs ``--overwrite``, as ``render`` refuses both. The same settings merge
    again (a part rerun after a fix, more meshes in the same collection)."""
    from sc3d_data.io.names import printable

    diff = [k for k in settings_differ(old.get("settings", {}), first.get("settings", {}), defaults)
            if k not in VOXEL_SETTINGS + ("split_file",)]  # a split file by the splits it gives, below
    if diff:
        raise MergeError(f"{out}: holds a merge made with other settings than {first['_dir']} ({', '.join(diff)} "
                         "differ); merging would replace it: use another OUT or --overwrite")
    was = {object_key(o): o.get("split") for o in old.get("objects", [])}
    moved = [(key, was[key], o.get("split")) for o in objects if (key := object_key(o)) in was
             and was[key] != o.get("split")]
    if moved:
        (cat, mid), before, now = moved[0]
        raise MergeError(f"{out}: holds a merge in which {len(moved)} object(s) of these parts have another split "
                         f"(e.g. {printable(cat)}/{printable(mid)}: {before} -> {now}); merging would replace it: "
                         "use another OUT or --overwrite")
