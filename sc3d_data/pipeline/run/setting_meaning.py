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

A value that does not parse is compared as recorded (the run refuses it with its own message).
"""
from __future__ import annotations

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
