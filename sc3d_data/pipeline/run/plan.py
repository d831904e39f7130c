"""The plan of ``sc3d-data render``: which objects a run renders, in which order.

The plan is every discovered mesh that has a split, ordered by ``(category, model_id)``; splits
are assigned on the WHOLE collection before partitioning, so a part gives each object the same
split as a run over everything. With ``--part I/N`` the plan keeps the objects of part ``I``
(``partition.part_of``) and numbers them ``0..`` in the same order; chunk ``c`` of a run is its
plan positions ``c*K .. c*K+K-1`` (``K = objects_per_shard``). Discovery problems and skipped
files are reported by part 0 only, so merged parts list each once; so are the lines of a split file
that name no mesh or name an object twice (``split_notes``: ``render`` prints them, since such a
line, a typo or a comment after an id, leaves an object out of the run with exit 0). A mesh whose path holds a name
that is not valid UTF-8 is a discovery problem (``io.names.split_not_utf8``): shards store names
as UTF-8 text.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from sc3d_data.pipeline.run.partition import part_of, part_record, plan_digest


@dataclass(frozen=True)
class Task:
    """One object of a run's plan: its position ``pos`` (0.. in plan order), mesh ``path`` (the
    file named in failure reasons), ``category``, ``model_id`` and ``split``. Every job's task is
    one of these (``r2n2_job.R2N2Task`` adds fields)."""

    pos: int
    path: str
    category: str
    model_id: str
    split: str


@dataclass
class Plan:
    """``tasks`` of this run (positions 0..), discovery ``problems`` (failures without an
    object), ``skipped`` files, the split description, the index's ``part`` record and
    ``split_notes``, the lines for the user of what the split files name wrongly (:func:`split_notes`)."""

    tasks: list[Task]
    problems: list[dict]
    skipped: list[dict]
    split_desc: dict
    part: dict = field(default_factory=dict)
    found_any: bool = True
    split_notes: list[str] = field(default_factory=list)


#: how many of the split files' problems ``render`` prints one line each (the rest are counted)
SHOWN_SPLIT_PROBLEMS = 5


def split_notes(split_problems: list[dict]) -> list[str]:
    """One line per problem of a split file's line (``splits.line_problems``: ``FILE:LINE: split file
    names 'ID' (train), which matches no mesh``), the first :data:`SHOWN_SPLIT_PROBLEMS` of them,
    then one line counting the rest; all are listed under ``skipped`` in ``index.json``."""
    lines = [f"{p['source']}: {p['reason']}" for p in split_problems[:SHOWN_SPLIT_PROBLEMS]]
    if len(split_problems) > SHOWN_SPLIT_PROBLEMS:
        lines.append(f"and {len(split_problems) - SHOWN_SPLIT_PROBLEMS} more problems of the split files, "
                     "listed under skipped in index.json")
    return lines


def make_plan(config) -> Plan:
    """Discover, split and partition ``config.meshes`` (module doc); ``config`` is a
    ``jobs.render_job.RenderConfig`` (not imported: ``run/`` sits below ``jobs/``)."""
    from sc3d_data.formats.discover import discover_meshes
    from sc3d_data.formats.splits import assign_splits, line_problems

    from sc3d_data.io.names import split_not_utf8

    entries, problems = discover_meshes(Path(config.meshes), categories=config.categories,
                                        category_override=config.category)
    entries, name_problems = split_not_utf8(entries, lambda e: e.path, config.meshes)
    problems += name_problems
    splits, split_desc, split_problems = assign_splits(entries, spec=config.split, seed=config.seed,
                                                       split_file=config.split_file)
    skipped = list(split_problems) + [p for p in problems if p.get("skipped")]
    problems = [p for p in problems if not p.get("skipped")]
    found_any = bool(entries or problems or skipped)
    planned = []
    for e in entries:
        key = (e.category, e.model_id)
        if key in splits:
            planned.append((str(e.path), e.category, e.model_id, splits[key]))
        else:
            skipped.append({"source": str(e.path), "reason": "not in any split (--split-file)"})
    part = config.part
    mine = [p for p in planned if part.whole or part_of(p[1], p[2], part.count) == part.index]
    tasks = [Task(i, *p) for i, p in enumerate(mine)]
    if part.index != 0:
        problems, skipped, split_problems = [], [], []
    record = part_record(part, len(tasks), len(planned), plan_digest((c, m, s) for _, c, m, s in planned))
    return Plan(tasks, problems, skipped, split_desc, record, found_any, split_notes(line_problems(split_problems)))
