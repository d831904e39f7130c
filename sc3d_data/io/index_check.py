"""Validation of a parsed ``index.json`` (SPEC "Shards") before any reader uses it: the schema
version, and the types of the keys readers index into, so that a hand-edited or foreign index is
refused in one line naming the file and the key instead of failing deep in a reader (an
``AttributeError`` on a ``failures`` entry, a float conversion of a background).

Checked: ``schema_version`` an integer no newer than the one this sc3d reads (shard files'
``schema_version`` attribute too: :func:`version_problem`); ``settings`` an
object whose ``background`` (a number, or a list of 3 numbers: RGB 0..255, or 0..1 floats),
``elevations`` (a list of numbers, degrees), ``image_size`` / ``num_views`` / ``voxel_resolution``
(integers) and ``distance`` / ``fov_deg`` (numbers) have those types where present and not null;
``objects``, ``failures``, ``skipped`` and ``warnings`` lists of objects; ``part`` (where present) an
object with its integers and strings, ``counts`` (where present) an object of integers per split and
category (``info`` and ``merge`` read both: a hand-edited one crashed them with a traceback). Other
keys are left to their readers."""
from __future__ import annotations


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _numbers(v) -> bool:
    return isinstance(v, list) and all(_number(x) for x in v)


def _integer(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


#: settings key -> (test, what it must be)
SETTING_TYPES = {
    "background": (lambda v: _number(v) or (_numbers(v) and len(v) == 3), "a number or a list of 3 numbers (RGB)"),
    "elevations": (_numbers, "a list of numbers (degrees)"),
    "image_size": (_integer, "an integer (pixels)"),
    "num_views": (_integer, "an integer"),
    "voxel_resolution": (_integer, "an integer"),
    "distance": (_number, "a number (world units)"),
    "fov_deg": (_number, "a number (degrees)"),
}
#: keys of a ``part`` record (``partition.part_record``) that ``merge`` and ``info`` read -> its type
PART_KEYS = {"index": _integer, "count": _integer, "assigned": _integer, "planned_total": _integer,
             "plan_sha256": lambda v: isinstance(v, str), "rule": lambda v: isinstance(v, str)}
#: top-level lists whose entries readers use as objects (``entry.get(...)``)
OBJECT_LISTS = ("objects", "failures", "skipped", "warnings")


def version_problem(version, present: bool, newest: int) -> str | None:
    """What is wrong with a file's ``schema_version`` (from ``index.json`` or a shard's HDF5
    attributes; ``present``: whether the key was there), or None: it must be an integer no newer
    than ``newest``, the one this sc3d reads."""
    if present and hasattr(version, "item") and getattr(version, "ndim", 1) == 0:
        version = version.item()  # a numpy scalar of the HDF5 attribute
    if not _integer(version):
        return (f"malformed: schema_version is {version!r}, not an integer" if present
                else "malformed: no schema_version (not written by sc3d?)")
    if version > newest:
        return (f"schema_version {version} is newer than the {newest} this sc3d reads (written by a newer "
                "sc3d): upgrade sc3d to read it")
    return None


def _part_problem(part) -> str | None:
    """What is wrong with an index's ``part`` record (``merge`` compares parts by it), or None."""
    if not isinstance(part, dict):
        return f"malformed: part is {part!r}, not an object"
    for key, test in PART_KEYS.items():
        if not test(part.get(key)):
            what = "a string" if key in ("plan_sha256", "rule") else "an integer"
            value = repr(part[key]) if key in part else "missing"
            return f"malformed: part.{key} is {value}, not {what}"
    return None


def _counts_problem(counts) -> str | None:
    """What is wrong with an index's ``counts`` (``index_counts``: ``info`` prints them), or None."""
    def per(v):
        return isinstance(v, dict) and all(_integer(n) for n in v.values())

    if not isinstance(counts, dict):
        return f"malformed: counts is {counts!r}, not an object"
    if not _integer(counts.get("total", 0)):
        return f"malformed: counts.total is {counts['total']!r}, not an integer"
    if not per(counts.get("by_split", {})):
        return f"malformed: counts.by_split is {counts['by_split']!r}, not an object of integers"
    by_cat = counts.get("by_category", {})
    if not isinstance(by_cat, dict):
        return f"malformed: counts.by_category is {by_cat!r}, not an object"
    bad = next((c for c, v in by_cat.items() if not per(v)), None)
    return None if bad is None else f"malformed: counts.by_category.{bad} is {by_cat[bad]!r}, not an object of integers"


def index_problem(index, schema_version: int) -> str | None:
    """What is wrong with parsed index ``index`` (one phrase naming the key), or None.
    ``schema_version``: the newest one this sc3d reads."""
    if not isinstance(index, dict):
        return f"not an sc3d index (a JSON {type(index).__name__}, not an object)"
    problem = version_problem(index.get("schema_version"), "schema_version" in index, schema_version)
    if problem:
        return problem
    settings = index.get("settings", {})
    if not isinstance(settings, dict):
        return f"malformed: settings is {type(settings).__name__}, not an object"
    for key, (test, what) in SETTING_TYPES.items():
        value = settings.get(key)
        if value is not None and not test(value):
            return f"malformed: settings.{key} is {value!r}, not {what}"
    for key in OBJECT_LISTS:
        entries = index.get(key, [])
        if not isinstance(entries, list):
            return f"malformed: {key} is {type(entries).__name__}, not a list"
        bad = next((i for i, e in enumerate(entries) if not isinstance(e, dict)), None)
        if bad is not None:
            return f"malformed: {key}[{bad}] is {entries[bad]!r}, not an object"
    if "part" in index and (problem := _part_problem(index["part"])):
        return problem
    return _counts_problem(index["counts"]) if "counts" in index else None


def listing_problems(index: dict) -> dict[str, str]:
    """``{shard file name: problem}`` where the index's ``shards`` and ``objects`` disagree: a
    file listed twice, an object (category/model_id) listed twice, an object naming a file
    ``shards`` lacks, a file whose ``objects`` count differs from the objects naming it, an object
    whose ``row`` is not one of its file's (:func:`row_problems`). Readers
    trust these lists (training reads every listed file, eval counts its rows), so a hand-edited
    index that lists a shard twice trained and evaluated its objects twice with exit 0; checks of
    the files themselves (``info --verify``) cannot see it. A duplicated object names every file
    it is listed in. ``index``: the parsed index, its ``shards`` list already checked."""
    from sc3d_data.io.names import printable

    shards, objects = index.get("shards", []), index.get("objects", [])
    out: dict[str, str] = {}
    seen: set[str] = set()
    for e in shards:
        if e["file"] in seen:
            out.setdefault(e["file"], f"{printable(e['file'])} is listed twice in shards")
        seen.add(e["file"])
    named: dict[str, int] = {}
    first: dict[tuple, str] = {}
    for o in objects:
        key, file = (str(o.get("category")), str(o.get("model_id"))), o.get("shard")  # hashable, whatever it holds
        if not isinstance(file, str):  # not a reader's concern here (older or partial entries)
            continue
        named[file] = named.get(file, 0) + 1
        if key in first:
            what = f"{printable(key[0])}/{printable(key[1])} is listed twice in objects"
            for f in (first[key], file):
                out.setdefault(f, what)
        first.setdefault(key, file)
    for file in named.keys() - seen:
        out.setdefault(file, f"objects name {printable(file)}, which shards does not list")
    for e in shards:
        if isinstance(e.get("objects"), int) and e["objects"] != named.get(e["file"], 0):
            out.setdefault(e["file"], f"shards says {printable(e['file'])} holds {e['objects']} objects, "
                                      f"objects name it {named.get(e['file'], 0)} times")
    for file, problem in row_problems(index).items():
        out.setdefault(file, problem)
    return out


def row_problems(index: dict) -> dict[str, str]:
    """``{shard file name: problem}`` where an object's ``row`` is not a row of its shard: not an
    integer, outside ``0 .. count-1`` where ``shards`` gives the file's object ``count``, or the row
    of another object too. ``preview`` reads the object at that row: row 99 of a shard of 3 ended
    in an h5py ``IndexError`` traceback, row -1 drew the shard's last object under another one's
    name with exit 0. Where ``shards`` gives no count, the reader checks the row when it opens the
    shard (``sc3d_data.qa.preview``)."""
    from sc3d_data.io.names import printable

    counts = {e["file"]: e["objects"] for e in index.get("shards", []) if _integer(e.get("objects"))}
    out: dict[str, str] = {}
    taken: dict[tuple, str] = {}
    for o in index.get("objects", []):
        file, row = o.get("shard"), o.get("row")
        if not isinstance(file, str):  # as listing_problems: not a reader's concern here
            continue
        name = f"{printable(str(o.get('category')))}/{printable(str(o.get('model_id')))}"
        if not _integer(row):
            out.setdefault(file, f"{name} has row {row!r} in {printable(file)}, not an integer")
        elif file in counts and not 0 <= row < counts[file]:
            out.setdefault(file, f"{name} has row {row} in {printable(file)}, which holds {counts[file]} objects "
                                 f"(rows 0 to {counts[file] - 1})")
        elif (file, row) in taken:
            out.setdefault(file, f"{taken[file, row]} and {name} both have row {row} in {printable(file)}")
        else:
            taken[file, row] = name
    return out
