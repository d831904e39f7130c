"""Recorded settings compared by meaning, not spelling: a rerun (resume), a part being merged or
a shard found in ``--out`` is the same run when its settings *mean* the same, however the
options were typed (``settings_differ`` in ``resume.py``).

- ``up`` / ``front``: ``+z`` is ``+Z`` (``axis_name``);
- ``categories``: a set of synset ids, names or ids in any order (``chair,car`` is
  ``02958343,03001627``; ``shapenet.resolve_categories``);
- ``split``: ``random:0.7,0.3`` is ``random:0.70,0,0.30`` (the fractions that are not 0, as
  numbers: an empty val split assigns no object), ``R2N2`` is ``r2n2``;
- ``split_file``: the files' absolute paths, in their order (``./sp.txt`` is ``sp.txt``; the first
  file's split wins where two list an id; their contents are held to the run by the split
  description's SHA-256).

The index's ``split`` record (the rule and its counts) compares by meaning too
(:func:`split_record_meaning`): a split file by the SHA-256 of its content, not the path typed.

A value that does not parse is compared as recorded (the run refuses it with its own message).
"""
from __future__ import annotations

import json
from dataclasses import MISSING, fields
from pathlib import Path

#: settings that name an axis (``--up``, ``--front``), any spelling that ``axis_vector`` reads
AXIS_SETTINGS = ("up", "front")


def setting_meaning(key: str, value):
    """``value`` of setting ``key`` in a form equal for every spelling of the same meaning."""
    from sc3d_data.formats.shapenet import resolve_categories
    from sc3d_data.formats.splits import parse_random_spec
    from sc3d_data.geometry.normalize import axis_name

    try:
        if key in AXIS_SETTINGS and isinstance(value, str):
            return axis_name(value)
        if key == "categories" and value:
            return sorted(resolve_categories(value))
        if key == "split" and isinstance(value, str):
            spec = value.strip().lower()
            if spec.startswith("random"):
                return ["random", sorted((name, f) for name, f in parse_random_spec(spec).items() if f)]
            return spec
        if key == "split_file" and value:
            # in their order: the first file's split wins where two list an id
            return [str(Path(f).resolve()) for f in ([value] if isinstance(value, str) else value)]
    except (ValueError, TypeError, OSError):
        pass
    return value


def split_record_meaning(record) -> object:
    """The index's ``split`` record (``splits.assign_splits``' description) in a form equal for
    every spelling of the same split: its method, the random fractions that are not 0 and the
    seed, the split files' SHA-256 in their order (not the paths they were given by), and the
    counts; rule texts and the spec as typed are left out. Another value is returned as is."""
    if not isinstance(record, dict):
        return record
    meaning = {"method": record.get("method"), "counts": record.get("counts")}
    if record.get("method") == "random":
        fractions = record.get("fractions") or {}
        meaning.update(fractions=sorted((k, v) for k, v in fractions.items() if v), seed=record.get("seed"))
    elif record.get("method") == "file":
        digests = record.get("sha256") or {}
        meaning["sha256"] = [digests.get(f) for f in record.get("files", [])]
    elif record.get("method") != "r2n2":
        return record
    return meaning


def config_defaults(config_class) -> dict:
    """``{field: default}`` of a command's config dataclass as an index records values (JSON: a
    tuple is a list), fields without a default left out: what a setting an older sc3d did not
    record stands for (a setting added later defaults to what the older code did)."""
    return {f.name: json.loads(json.dumps(f.default, default=str)) for f in fields(config_class)
            if f.default is not MISSING}
