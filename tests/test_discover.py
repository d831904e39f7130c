"""Mesh discovery: ShapeNet v1/v2 layouts, CATEGORY/NAME, flat and nested folders, symlinks,
duplicates, missing meshes, category filters (file names only: discovery never loads meshes)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from sc3d_data.formats.discover import discover_meshes
from sc3d_data.formats.shapenet import R2N2_SYNSETS, category_name, resolve_categories

REPO = Path(__file__).resolve().parents[1]
AIRPLANE, CAR, CHAIR = "02691156", "02958343", "03001627"


def touch(path: Path, text: str = "x") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def keys(entries):
    return [(e.category, e.model_id) for e in entries]


def reasons(problems):
    return " | ".join(p["reason"] for p in problems)


def test_synset_table_and_resolution():
    assert len(R2N2_SYNSETS) == 13
    assert category_name(AIRPLANE) == "airplane" and category_name("spaceship") == "spaceship"
    assert resolve_categories("airplane,car, 03001627") == {AIRPLANE, CAR, CHAIR}
    assert resolve_categories(["Chair", "speaker", "spaceship"]) == {CHAIR, "03691459", "spaceship"}


def test_bundled_samples_category_name_layout():
    entries, problems = discover_meshes(REPO / "assets" / "sample_meshes")
    assert problems == []
    assert len(entries) == 11                      # licenses/, manifest.json, LICENSES.md skipped
    assert keys(entries) == sorted(keys(entries))
    assert {e.category for e in entries} == {AIRPLANE, CAR, CHAIR, "04379243"}
    assert (AIRPLANE, "c182_fgai") in keys(entries)


def test_shapenet_v1_layout_with_missing_mesh(tmp_path):
    root = tmp_path / "ShapeNetCore.v1"
    for syn, mid in [(AIRPLANE, "a1"), (AIRPLANE, "a0"), (CAR, "c0")]:
        touch(root / syn / mid / "model.obj")
        touch(root / syn / mid / "model.mtl")
        touch(root / syn / mid / "images" / "texture0.jpg")
    (root / CAR / "broken").mkdir(parents=True)
    touch(root / CAR / "broken" / "model.mtl")
    entries, problems = discover_meshes(root)
    assert keys(entries) == [(AIRPLANE, "a0"), (AIRPLANE, "a1"), (CAR, "c0")]
    assert all(e.path.name == "model.obj" for e in entries)
    assert len(problems) == 1 and problems[0]["source"].endswith("broken")
    assert "without its mesh" in problems[0]["reason"]
    # one synset folder as root, and filters by name / id
    sub, _ = discover_meshes(root / AIRPLANE)
    assert keys(sub) == [(AIRPLANE, "a0"), (AIRPLANE, "a1")]
    assert keys(discover_meshes(root, categories="car")[0]) == [(CAR, "c0")]
    assert keys(discover_meshes(root, categories=[AIRPLANE])[0]) == [(AIRPLANE, "a0"), (AIRPLANE, "a1")]
    _, probs = discover_meshes(root, categories="airplane,chair")
    assert "'03001627' matches no mesh" in reasons(probs)


def test_shapenet_v2_layout(tmp_path):
    root = tmp_path / "ShapeNetCore.v2"
    for mid in ("m1", "m2"):
        touch(root / CHAIR / mid / "models" / "model_normalized.obj")
        touch(root / CHAIR / mid / "models" / "model_normalized.json")
        touch(root / CHAIR / mid / "models" / "model_normalized.solid.binvox")
        touch(root / CHAIR / mid / "images" / "texture.png")
    entries, problems = discover_meshes(root)
    assert problems == []
    assert keys(entries) == [(CHAIR, "m1"), (CHAIR, "m2")]
    assert entries[0].path == root / CHAIR / "m1" / "models" / "model_normalized.obj"


def test_flat_nested_unknown_and_override(tmp_path):
    flat = tmp_path / "chair"
    touch(flat / "b.ply")
    touch(flat / "a.STL")
    touch(flat / "readme.txt")
    assert keys(discover_meshes(flat)[0]) == [(CHAIR, "a"), (CHAIR, "b")]
    root = tmp_path / "mixed"
    touch(root / "spaceship" / "x.glb")
    touch(root / "chair" / "set1" / "deep" / "y.off")
    touch(root / "chair" / ".hidden" / "z.obj")
    entries, problems = discover_meshes(root)
    assert problems == []
    assert keys(entries) == [(CHAIR, "set1/deep/y"), ("spaceship", "x")]
    over, _ = discover_meshes(root, category_override="lamp")
    assert {e.category for e in over} == {"03636649"}


def test_duplicates_and_symlinks(tmp_path):
    root = tmp_path / "meshes"
    touch(root / "car" / "jeep.obj")
    touch(root / "car" / "jeep.glb")
    touch(tmp_path / "elsewhere" / "sofa" / "s1.obj")
    os.symlink(tmp_path / "elsewhere" / "sofa", root / "sofa")        # followed
    os.symlink(root, root / "car" / "loop")                           # a loop
    entries, problems = discover_meshes(root)
    assert keys(entries) == [(CAR, "jeep"), ("04256520", "s1")]
    assert entries[0].path.name == "jeep.glb"                         # first in path order
    text = reasons(problems)
    assert "duplicate id 02958343/jeep" in text
    assert "symlink loop" in text
    assert len(problems) == 2


@pytest.mark.skipif(os.geteuid() == 0, reason="root can read any folder")
def test_unreadable_folder_is_reported(tmp_path):
    root = tmp_path / "m"
    touch(root / "car" / "a.obj")
    locked = root / "chair"
    touch(locked / "b.obj")
    locked.chmod(0)
    try:
        entries, problems = discover_meshes(root)
    finally:
        locked.chmod(0o755)
    assert keys(entries) == [(CAR, "a")]
    assert "cannot be read" in reasons(problems)


def test_bad_roots(tmp_path):
    with pytest.raises(FileNotFoundError):
        discover_meshes(tmp_path / "nope")
    single = touch(tmp_path / "car" / "one.glb")
    assert keys(discover_meshes(single)[0]) == [(CAR, "one")]
