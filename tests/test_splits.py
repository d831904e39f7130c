"""Split assignment: seeded stable random splits, 3D-R2N2's rule, PTN split files, plain lists."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from sc3d_data.formats.discover import MeshEntry
from sc3d_data.formats.splits import assign_splits

AIRPLANE, CAR, CHAIR = "02691156", "02958343", "03001627"


def entries_of(pairs):
    return [MeshEntry(Path(f"/m/{c}/{m}/model.obj"), m, c) for c, m in pairs]


def many(n=2000):
    return entries_of([(c, f"{c[-3:]}{i:05d}") for c in (AIRPLANE, CAR) for i in range(n // 2)])


def test_random_fractions_stable_and_seeded():
    es = many()
    splits, desc, problems = assign_splits(es, "random:0.7,0.1,0.2", seed=3)
    assert problems == [] and len(splits) == len(es)
    json.dumps(desc)
    assert desc["method"] == "random" and desc["seed"] == 3
    frac = {s: n / len(es) for s, n in desc["counts"].items()}
    assert abs(frac["train"] - 0.7) < 0.04 and abs(frac["val"] - 0.1) < 0.03 and abs(frac["test"] - 0.2) < 0.03
    # an object's split does not depend on the other objects
    sub, _, _ = assign_splits(es[::7] + entries_of([(CHAIR, "new")]), "random:0.7,0.1,0.2", seed=3)
    assert all(sub[k] == splits[k] for k in sub if k in splits)
    other, _, _ = assign_splits(es, "random:0.7,0.1,0.2", seed=4)
    assert sum(other[k] != splits[k] for k in splits) > len(es) // 5
    two, desc2, _ = assign_splits(es, "random:0.5,0.5")
    assert set(two.values()) == {"train", "test"} and desc2["fractions"] == {"train": 0.5, "test": 0.5}


@pytest.mark.parametrize("spec", ["random:0.5,0.6,0.2", "random:a,b,c", "random:1", "kfold"])
def test_bad_specs(spec):
    with pytest.raises(ValueError):
        assign_splits(many(10), spec)


def test_r2n2_rule():
    es = entries_of([(AIRPLANE, f"p{i}") for i in (4, 0, 3, 1, 2, 9, 8, 7, 6, 5)] +
                    [(CAR, "b"), (CAR, "a"), (CAR, "c")])
    splits, desc, _ = assign_splits(es, "r2n2")
    assert [splits[(AIRPLANE, f"p{i}")] for i in range(10)] == ["train"] * 8 + ["test"] * 2
    assert [splits[(CAR, m)] for m in "abc"] == ["train", "train", "test"]   # int(0.8 * 3) = 2
    assert desc["method"] == "r2n2" and desc["counts"] == {"test": 3, "train": 10}


def test_ptn_split_directory(tmp_path):
    d = tmp_path / "splits"
    d.mkdir()
    (d / f"{CHAIR}_trainids.txt").write_text(f"{CHAIR}/c0\n{CHAIR}/c1\n\n{CHAIR}/ghost\n")
    (d / f"{CHAIR}_valids.txt").write_text(f"{CHAIR}/c2\n")
    (d / f"{CHAIR}_testids.txt").write_text(f"{CHAIR}/c3\n")
    (d / f"{AIRPLANE}_trainids.txt").write_text("".join(f"{AIRPLANE}/p{i}\n" for i in range(5)))
    es = entries_of([(CHAIR, f"c{i}") for i in range(5)])
    splits, desc, problems = assign_splits(es, split_file=d)
    assert splits == {(CHAIR, "c0"): "train", (CHAIR, "c1"): "train", (CHAIR, "c2"): "val",
                      (CHAIR, "c3"): "test"}          # c4 is in no file: absent (skipped by callers)
    assert desc["method"] == "file" and len(desc["files"]) == 4 and desc["counts"]["train"] == 2
    text = [p["reason"] for p in problems]
    assert any("'03001627/ghost'" in t and "matches no mesh" in t for t in text)
    assert any("5 models of category '02691156'" in t for t in text)
    assert len(problems) == 2
    ghost = next(p for p in problems if "ghost" in p["reason"])
    assert ghost["source"].endswith("03001627_trainids.txt:4")


def test_plain_list_and_several_files(tmp_path):
    f = tmp_path / "my_split.txt"
    f.write_text(f"# comment\ntrain\t{CHAIR}/c0\nval chair/c1\ntest c2\nc3\ntest {CHAIR}/c0\n")
    extra = tmp_path / "test.txt"
    extra.write_text(f"{CHAIR}/c4\n")
    es = entries_of([(CHAIR, f"c{i}") for i in range(5)])
    splits, desc, problems = assign_splits(es, split_file=[f, extra])
    assert splits == {(CHAIR, "c0"): "train", (CHAIR, "c1"): "val", (CHAIR, "c2"): "test",
                      (CHAIR, "c3"): "train", (CHAIR, "c4"): "test"}
    assert len(problems) == 1 and "listed as test here but as train" in problems[0]["reason"]
    bad = tmp_path / "bad.txt"
    bad.write_text("a b c\n")
    with pytest.raises(ValueError, match="bad.txt:1"):
        assign_splits(es, split_file=bad)
    with pytest.raises(FileNotFoundError):
        assign_splits(es, split_file=tmp_path / "missing.txt")


def test_a_byte_order_mark_is_not_part_of_the_first_id_or_split(tmp_path):
    """A split file saved with a UTF-8 byte-order mark (Notepad's "UTF-8") used to give its first
    line an id (or split name) starting with U+FEFF: that object matched nothing (named files) or
    went to a split called '\\ufefftrain' (two-field files). Expected values: the ids written."""
    from sc3d_data.formats.splits import read_split_lines

    named = tmp_path / "chair_testids.txt"
    named.write_bytes("\ufeffabc\ndef\n".encode("utf-8"))
    assert read_split_lines(named) == [(1, "test", "abc"), (2, "test", "def")]
    pairs = tmp_path / "splits.txt"
    pairs.write_bytes("\ufefftrain abc\nval def\n".encode("utf-8"))
    assert read_split_lines(pairs) == [(1, "train", "abc"), (2, "val", "def")]
