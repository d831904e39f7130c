"""Deterministic partition of a plan of objects into ``N`` parts (``--part I/N``).

Rule: object ``(category, model_id)`` belongs to part
``int(sha256("category/model_id")[:16 hex], 16) mod N``. It depends on the object's id only,
not on directory order, the other objects or the machine, so ``N`` independent jobs (a SLURM
job array, N shells) cover every planned object exactly once, any part can be rerun alone,
and adding objects to the collection never moves the others to another part.

Parts are numbered from 0: ``--part 0/4`` ... ``--part 3/4``. Inside a SLURM job array the
part defaults to ``SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN`` of ``SLURM_ARRAY_TASK_COUNT``.

Every part records in its index (key ``"part"``) its number, the part count, how many objects
it was assigned and a digest of the WHOLE plan (ids and splits of all parts), so
``sc3d-data merge`` can tell a missing part, an unfinished part or parts planned from
different collections.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from typing import Iterable, Mapping

RULE = "sha256('category/model_id') first 64 bits mod count"


@dataclass(frozen=True)
class Part:
    """Part ``index`` of ``count`` (0 <= index < count)."""

    index: int = 0
    count: int = 1

    def __post_init__(self) -> None:
        if not (self.count >= 1 and 0 <= self.index < self.count):
            raise ValueError(f"--part {self.index}/{self.count}: need 0 <= I < N (parts are numbered from 0)")

    def __str__(self) -> str:
        return f"{self.index}/{self.count}"

    @property
    def whole(self) -> bool:
        return self.count == 1

    def dirname(self) -> str:
        """Folder name of this part's output, e.g. ``part-003-of-008``."""
        width = max(3, len(str(self.count)))
        return f"part-{self.index:0{width}d}-of-{self.count:0{width}d}"


def parse_part(text: str) -> Part:
    """``"I/N"`` -> ``Part(I, N)``; ``ValueError`` naming ``--part`` otherwise."""
    i, sep, n = str(text).partition("/")
    try:
        if not sep:
            raise ValueError
        return Part(int(i), int(n))
    except ValueError as e:
        if "need 0 <= I < N" in str(e):
            raise
        raise ValueError(f"--part {text!r}: expected I/N, e.g. 0/4 (parts are numbered from 0)") from None


def part_from_env(env: Mapping[str, str] = os.environ) -> Part | None:
    """The part of a SLURM array task, or None outside a job array: task ``SLURM_ARRAY_TASK_ID``
    of the evenly spaced ids ``_MIN``, ``_MIN + _STEP``, ... ``_MAX`` (``--array=MIN-MAX[:STEP]``)
    is part ``(ID - MIN) / STEP`` of ``_COUNT``. ``ValueError`` (naming the array, not
    ``--part``) for an array that is not such a range, e.g. ``--array=1,5,7``."""
    if "SLURM_ARRAY_TASK_ID" not in env or "SLURM_ARRAY_TASK_COUNT" not in env:
        return None
    try:
        task, count = int(env["SLURM_ARRAY_TASK_ID"]), int(env["SLURM_ARRAY_TASK_COUNT"])
        first, step = int(env.get("SLURM_ARRAY_TASK_MIN", 0)), int(env.get("SLURM_ARRAY_TASK_STEP") or 1)
        last = int(env.get("SLURM_ARRAY_TASK_MAX", first + (count - 1) * step))
    except ValueError:
        raise ValueError("the SLURM_ARRAY_TASK_* variables are not integers; give --part I/N") from None
    if (count < 1 or step < 1 or last != first + (count - 1) * step or (task - first) % step
            or not first <= task <= last):
        raise ValueError(f"SLURM array task {task} of {count} (ids {first} to {last}, step {step}): the part can "
                         "only be taken from an evenly spaced array (--array=MIN-MAX or MIN-MAX:STEP); give "
                         "--part I/N")
    return Part((task - first) // step, count)


def part_of(category: str, model_id: str, count: int) -> int:
    """The part (0..count-1) that object ``(category, model_id)`` belongs to (module doc)."""
    digest = hashlib.sha256(f"{category}/{model_id}".encode()).hexdigest()
    return int(digest[:16], 16) % count


def plan_digest(keys: Iterable[tuple[str, str, str]]) -> str:
    """SHA-256 of the whole plan: sorted ``(category, model_id, split)`` triples."""
    h = hashlib.sha256()
    for c, m, s in sorted(keys):
        h.update(f"{c}/{m}/{s}\n".encode())
    return h.hexdigest()


def part_record(part: Part, assigned: int, planned: int, digest: str) -> dict:
    """The index's ``"part"`` entry of a run."""
    return {"index": part.index, "count": part.count, "rule": RULE, "assigned": assigned,
            "planned_total": planned, "plan_sha256": digest}
