"""Train/val/test assignment of discovered objects.

Three ways (``spec`` / ``split_file`` of :func:`assign_splits`):

``random:a,b,c`` (default ``random:0.7,0.1,0.2``; ``random:a,b`` means train/test)
    Per object, ``u = int(sha256(f"{seed}/{category}/{model_id}")[:16 hex], 16) / 2**64`` is a
    uniform number in [0, 1) that depends on nothing else, so an object's split never changes
    when other objects are added or removed; ``u < a`` -> train, ``u < a + b`` -> val, else
    test. The fractions are therefore met in expectation, not exactly.
``r2n2``
    3D-R2N2's rule: per category, model ids sorted, the first ``int(0.8 * n)`` train, the rest
    test (``n`` = the number of objects of that category that were found).
split files (``split_file``: one file, several files, or a directory)
    * PTN style ``SYNSET_trainids.txt`` / ``_valids.txt`` / ``_testids.txt`` (also ``train.txt``
      ``val.txt`` ``test.txt``, exactly; ``holdout_test.txt`` is a plain list): the split comes
      from the file name; one id per line (the whole line, its ends stripped: an id may hold
      spaces).
    * any other file is a plain list: each line ``SPLIT ID`` (SPLIT is train, val or test in any
      case, anything else is refused naming the line; then a tab or spaces, and the rest of the
      line, ends stripped, is the id, spaces and all), or just ``ID`` meaning train (one word: an
      id with spaces needs its SPLIT first, so a mistyped split name is never read as an id).
    An id is ``synset/model_id`` (the category may also be a name such as ``chair``) or a bare
    ``model_id`` (matches that model id in any category). Empty lines and lines starting with
    ``#`` are ignored. A directory contributes every ``*.txt`` in it.
    Objects that no file lists get no split (absent from the returned mapping: the caller skips
    and records them, as ``sc3d-data render`` does); ids that match no object are reported one by one (for categories among the
    objects) or summed up per category (for categories not among them).
"""
from __future__ import annotations

import hashlib
import re
from pathlib import Path
from typing import Iterable, Sequence

from sc3d_data.formats.shapenet import resolve_category
from sc3d_data.io.names import normal_form_note, normal_forms, printable

DEFAULT_SPLIT = "random:0.7,0.1,0.2"
#: the ``--split`` / ``--split-file`` rules as the CLIs' ``--help`` shows them (module doc)
SPLIT_HELP = ("random:TRAIN,VAL,TEST (fractions summing to 1, e.g. random:0.7,0.1,0.2; "
              "random:1,0,0 puts everything in train; random:TRAIN,TEST has no val): each object "
              "is placed by a hash of (--seed, category, model id), so adding objects never moves "
              "others and the fractions hold in expectation. r2n2: per category, model ids sorted, "
              "first 80% train, rest test (3D-R2N2). --split-file overrides --split.")
SPLIT_FILE_HELP = ("PTN SYNSET_{train,val,test}ids.txt files, a directory of them, or a plain list "
                   "(lines 'SPLIT ID' or 'ID' = train; ID = synset/model_id or model_id, the rest of "
                   "the line). Objects no file lists are skipped and reported.")
R2N2_TRAIN_FRACTION = 0.8
#: the splits a split file may name (any case); ``sc3d-train`` reads train, val and test
SPLIT_NAMES = ("train", "val", "test")
#: a file whose name gives its split: PTN's ``SYNSET_trainids.txt`` (any prefix ending in ``_``, or
#: none), or exactly ``train.txt`` / ``val.txt`` / ``test.txt``; ``holdout_test.txt`` is a plain list
_NAMED_FILE = re.compile(r"(?:(?:^|_)(train|val|test)ids|^(train|val|test))\.txt$", re.IGNORECASE)


#: how the problem of a category the split files list and the meshes lack starts (one line per
#: category; a subset of the official split files' categories, ``--categories chair``, is no error)
OTHER_CATEGORY_PROBLEM = "split files list"


def line_problems(problems: list[dict]) -> list[dict]:
    """The problems of ``assign_splits`` that are of one line of a split file (an id that matches
    no mesh, an object listed under two splits): those a user would want to see, unlike the
    categories the files list beyond the meshes (:data:`OTHER_CATEGORY_PROBLEM`)."""
    return [p for p in problems if not p["reason"].startswith(OTHER_CATEGORY_PROBLEM)]


def _problem(source, reason: str) -> dict:
    return {"source": str(source), "reason": reason}


def stable_uniform(seed: int, category: str, model_id: str) -> float:
    """A number in [0, 1) fixed by ``(seed, category, model_id)`` alone (SHA-256 based)."""
    h = hashlib.sha256(f"{seed}/{category}/{model_id}".encode()).hexdigest()
    return int(h[:16], 16) / 2.0 ** 64


def parse_random_spec(spec: str) -> dict[str, float]:
    """``"random:0.7,0.1,0.2"`` -> ``{"train": .7, "val": .1, "test": .2}`` (two values: train,
    test). The fractions must be >= 0 and sum to 1."""
    body = spec.split(":", 1)[1] if ":" in spec else "0.7,0.1,0.2"
    try:
        values = [float(v) for v in body.split(",")]
    except ValueError:
        raise ValueError(f"split {spec!r}: fractions must be numbers, e.g. random:0.7,0.1,0.2") from None
    names = {2: ("train", "test"), 3: ("train", "val", "test")}.get(len(values))
    if names is None or not all(0 <= v <= 1 for v in values) or abs(sum(values) - 1.0) > 1e-6:
        raise ValueError(f"split {spec!r}: give 2 or 3 fractions in [0, 1] that sum to 1 "
                         "(train,test or train,val,test), e.g. random:0.7,0.1,0.2")
    return dict(zip(names, values))


def _random_splits(keys, fractions: dict[str, float], seed: int) -> dict:
    out = {}
    for cat, mid in keys:
        u, acc = stable_uniform(seed, cat, mid), 0.0
        split = list(fractions)[-1]
        for name, frac in fractions.items():
            acc += frac
            if u < acc:
                split = name
                break
        out[(cat, mid)] = split
    return out


def _r2n2_splits(keys) -> dict:
    by_cat: dict[str, list[str]] = {}
    for cat, mid in keys:
        by_cat.setdefault(cat, []).append(mid)
    out = {}
    for cat, mids in by_cat.items():
        mids = sorted(mids)
        n_train = int(len(mids) * R2N2_TRAIN_FRACTION)
        for i, mid in enumerate(mids):
            out[(cat, mid)] = "train" if i < n_train else "test"
    return out


def absolute_split_file(split_file):
    """``--split-file`` as an index records it: each path made absolute (``./sp.txt`` typed in
    ``/data`` is ``/data/sp.txt``), so that a rerun or a part started in another folder is
    compared by the file it names (``setting_meaning``); None and ``""`` as given."""
    if not split_file:
        return split_file
    if isinstance(split_file, (str, Path)):
        return str(Path(split_file).absolute())
    return [str(Path(f).absolute()) for f in split_file]


def split_files_of(split_file) -> list[Path]:
    """The files a ``--split-file`` argument names: a file, a directory (its ``*.txt``), or a
    list of those. Missing paths raise ``FileNotFoundError``."""
    items = [split_file] if isinstance(split_file, (str, Path)) else list(split_file)
    files: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.suffix == ".txt" and q.is_file())
            if not found:
                raise FileNotFoundError(f"{p}: split directory holds no *.txt split files")
            files.extend(found)
        elif p.is_file():
            files.append(p)
        else:
            raise FileNotFoundError(f"{p}: split file not found")
    return files


def read_split_lines(path: Path) -> list[tuple[int, str, str]]:
    """``[(line number, split, id)]`` of one split file (format in the module docstring)."""
    m = _NAMED_FILE.search(path.name)
    named = (m.group(1) or m.group(2)).lower() if m else None
    out = []
    # utf-8-sig: a byte-order mark (Notepad writes one) is not part of the first id or split name
    for lineno, line in enumerate(path.read_text(encoding="utf-8-sig", errors="replace").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if named is not None:  # the whole line is the id: ids may hold spaces
            out.append((lineno, named, line))
            continue
        fields = line.split(None, 1)  # SPLIT, then the rest of the line is the id
        if len(fields) == 1:
            out.append((lineno, "train", fields[0]))
        elif fields[0].lower() not in SPLIT_NAMES:
            raise ValueError(f"{path}:{lineno}: split '{printable(fields[0])}' is none of "
                             f"{', '.join(SPLIT_NAMES)} (lines are 'SPLIT ID' or 'ID')")
        else:
            out.append((lineno, fields[0].lower(), fields[1]))
    return out


def _file_splits(keys: Sequence[tuple[str, str]], files: list[Path], problems: list[dict]) -> dict:
    keyset = set(keys)
    by_model: dict[str, list[tuple[str, str]]] = {}
    for cat, mid in keys:
        by_model.setdefault(mid, []).append((cat, mid))
    present_cats = {cat for cat, _ in keys}
    # for the note on an id typed in another Unicode normalisation than the mesh's name (NFC/NFD)
    id_forms, mid_forms = normal_forms(f"{c}/{m}" for c, m in keys), normal_forms(by_model)
    cat_forms = normal_forms(present_cats)
    out: dict[tuple[str, str], str] = {}
    origin: dict[tuple[str, str], str] = {}
    absent_cats: dict[str, int] = {}
    for path in files:
        for lineno, split, ident in read_split_lines(path):
            where = f"{path}:{lineno}"
            if "/" in ident:
                cat, mid = ident.split("/", 1)
                cat = resolve_category(cat)
                targets = [(cat, mid)] if (cat, mid) in keyset else []
                if not targets and cat not in present_cats and not normal_form_note(cat, cat_forms):
                    absent_cats[cat] = absent_cats.get(cat, 0) + 1
                    continue
            else:
                targets = by_model.get(ident, [])
            if not targets:
                note = (normal_form_note(f"{cat}/{mid}", id_forms) if "/" in ident
                        else normal_form_note(ident, mid_forms))
                problems.append(_problem(where, f"split file names {ident!r} ({split}), which matches no mesh{note}"))
                continue
            for key in targets:
                if key in out and out[key] != split:
                    problems.append(_problem(where, f"{key[0]}/{key[1]} listed as {split} here but "
                                                    f"as {out[key]} at {origin[key]}; kept {out[key]}"))
                    continue
                out.setdefault(key, split)
                origin.setdefault(key, where)
    for cat, n in sorted(absent_cats.items()):
        problems.append(_problem(", ".join(map(str, files)),
                                 f"{OTHER_CATEGORY_PROBLEM} {n} models of category {cat!r}, which is not "
                                 "among the meshes (not present, or filtered out); ignored"))
    return out


def assign_splits(entries, spec: str = DEFAULT_SPLIT, seed: int = 0, split_file=None
                  ) -> tuple[dict[tuple[str, str], str], dict, list[dict]]:
    """Assign a split to every entry (anything with ``category`` and ``model_id``, e.g.
    :class:`sc3d_data.formats.discover.MeshEntry`).

    Returns ``(splits, description, problems)``: ``splits`` maps ``(category, model_id)`` to a
    split name (entries missing from it must be skipped: only possible with ``split_file``);
    ``description`` is a JSON-able record of the rule used (for the index's ``"split"``), with
    the resulting ``counts``; ``problems`` is ``[{"source", "reason"}]``.
    ``split_file`` (a path, a directory or a list of them) takes precedence over ``spec``.
    """
    entries = list(entries)
    keys = [(e.category, e.model_id) for e in entries]
    problems: list[dict] = []
    if split_file:
        files = split_files_of(split_file)
        splits = _file_splits(keys, files, problems)
        description = {"method": "file", "files": [str(f) for f in files],
                       "sha256": {str(f): hashlib.sha256(f.read_bytes()).hexdigest() for f in files},
                       "format": "PTN SYNSET_{train,val,test}ids.txt (split from the file name) "
                                 "or plain 'SPLIT ID' / 'ID' (= train) lines; ID = synset/model_id"}
    elif spec.strip().lower() == "r2n2":
        splits = _r2n2_splits(keys)
        description = {"method": "r2n2", "train_fraction": R2N2_TRAIN_FRACTION,
                       "rule": "per category, model ids sorted, first int(0.8*n) train, rest test"}
    elif spec.strip().lower().startswith("random"):
        fractions = parse_random_spec(spec.strip())
        splits = _random_splits(keys, fractions, int(seed))
        description = {"method": "random", "fractions": fractions, "seed": int(seed),
                       "rule": "u = int(sha256(f'{seed}/{category}/{model_id}')[:16], 16) / 2**64; "
                               "splits in order of fractions by cumulative sum"}
    else:
        raise ValueError(f"unknown split {spec!r}: use random:TRAIN,VAL,TEST, r2n2, or --split-file")
    counts: dict[str, int] = {}
    for s in splits.values():
        counts[s] = counts.get(s, 0) + 1
    description["spec"] = "file" if split_file else spec
    description["counts"] = dict(sorted(counts.items()))
    return splits, description, problems


def split_names(splits: Iterable[str]) -> list[str]:
    """Distinct split names in the conventional order (train, val, test, then the others)."""
    order = {"train": 0, "val": 1, "test": 2}
    return sorted(set(splits), key=lambda s: (order.get(s, 3), s))
