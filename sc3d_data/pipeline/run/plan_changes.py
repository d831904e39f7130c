"""Why an existing dataset's shards are not this run's plan's chunks, in one line: the meshes
its index lists that the plan lacks, and the planned meshes it does not list (new ones, or ones
it had skipped, such as meshes in no split of a split file edited since). ``render`` and
``import-r2n2`` refuse to resume such a folder (``jobs.shard_output``)."""
from __future__ import annotations

from pathlib import Path

from sc3d_data.pipeline.run.plan import Task

__all__ = ["plan_change_text", "plan_changes"]


def plan_changes(old: dict, tasks: list[Task], K: int) -> tuple[list[str], list[str]]:
    """``(removed, added)`` mesh paths between an existing index ``old`` and this run's plan
    ``tasks`` (chunks of ``K``): the objects and failures it lists that the plan lacks, and the
    planned objects it does not list that fall in a chunk it covers (any, when it is complete;
    an unfinished run lists only the chunks it did). Both in plan/index order."""
    listed = {}
    for e in old.get("objects", []) + old.get("failures", []):
        if e.get("stage") != "voxelize" and "model_id" in e:
            listed.setdefault((e.get("category"), e["model_id"]), e.get("source", e["model_id"]))
    planned = {(t.category, t.model_id) for t in tasks}
    covered = ({e.get("chunk") for e in old.get("objects", []) + old.get("failures", [])}
               | set(old.get("empty_chunks", [])))
    removed = [src for key, src in listed.items() if key not in planned]
    added = [t.path for t in tasks if (t.category, t.model_id) not in listed
             and (old.get("complete") or t.pos // K in covered)]
    return removed, added


def plan_change_text(out: Path, removed: list[str], added: list[str], skipped: list | tuple = (), show: int = 3) -> str:
    """One line refusing to resume ``out`` whose shards hold another plan's chunks, naming up to
    ``show`` of the ``removed`` and ``added`` meshes (:func:`plan_changes`) with their counts; an
    added mesh the index lists under ``skipped`` (``[{"source", "reason"}]``, e.g. not in any split
    of a split file since edited) is named as such, not as new."""
    from sc3d_data.io.names import printable

    def some(paths: list[str]) -> str:
        more = f", ... ({len(paths) - show} more)" if len(paths) > show else ""
        return ", ".join(printable(p) for p in paths[:show]) + more

    what, fix = [], []
    if removed:
        what.append(f"{len(removed)} mesh(es) it lists are gone ({some(removed)})")
        fix.append("restore them")
    was_skipped = {e.get("source"): e.get("reason") for e in skipped if isinstance(e, dict)}
    unskipped = [a for a in added if a in was_skipped]
    added = [a for a in added if a not in was_skipped]
    if unskipped:
        what.append(f"{len(unskipped)} mesh(es) it skipped are now to be done ({some(unskipped)}: skipped as "
                    f"{printable(str(was_skipped[unskipped[0]]))})")
        fix.append("give the settings that skipped them again")
    if added:
        what.append(f"{len(added)} mesh(es) are new ({some(added)})")
        fix.append("move the new ones away")
    why = "; ".join(what) if what else "the collection changed, or an older sc3d made them"
    return (f"{out}: its shards do not hold this plan's chunks: {why}; "
            f"{' and '.join(fix) + ', or ' if fix else ''}use another --out or --overwrite")
