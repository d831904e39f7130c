"""ShapeNetCore v1 / v2 folder layouts built from the bundled sample meshes (GLB -> OBJ with
its .mtl and textures, as ShapeNet ships them), discovered and rendered with `sc3d-data render`
(--categories by name, --split r2n2, PTN --split-file)."""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from sc3d_data.formats.discover import discover_meshes
from sc3d_data.io.shards import load_index
from sc3d_data.io.shard_reader import iter_objects

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "assets" / "sample_meshes"
AIRPLANE, CAR, CHAIR = "02691156", "02958343", "03001627"
PICK = {AIRPLANE: ["airplane/f16_lowpoly_fgai.glb", "airplane/c182_fgai.glb"],
        CAR: ["car/jeep_psionic.glb"], CHAIR: ["chair/chair2_blendswap.glb"]}


# the sample meshes face +Z; ShapeNetCore v1 files face +X, v2 files -Z (+Y up in all; see
# docs/data.md for the evidence): rotations about +Y taking +Z to that front
TO_SHAPENET = {1: np.array([[0, 0, 1, 0], [0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1]], float),
               2: np.diag([-1.0, 1.0, -1.0, 1.0])}


def model_id(rel: str) -> str:
    """A ShapeNet-looking model id (32 hex digits) for a sample mesh."""
    return hashlib.md5(rel.encode()).hexdigest()


def build_tree(root: Path, version: int) -> Path:
    import trimesh

    for syn, rels in PICK.items():
        for rel in rels:
            folder = root / syn / model_id(rel)
            target = folder / "model.obj" if version == 1 else folder / "models" / "model_normalized.obj"
            target.parent.mkdir(parents=True, exist_ok=True)
            scene = trimesh.load(SAMPLES / rel)
            scene.apply_transform(TO_SHAPENET[version])           # sample front +Z -> ShapeNet's front
            scene.export(target)                                  # writes material.mtl + textures
            if version == 2:
                (target.parent / "model_normalized.json").write_text("{}")
    (root / CAR / ("0" * 32)).mkdir()                             # a model folder without its mesh
    (root / CAR / ("0" * 32) / "model.mtl").write_text("")
    return root


@pytest.fixture(scope="module")
def trees(tmp_path_factory):
    base = tmp_path_factory.mktemp("shapenet")
    return {1: build_tree(base / "ShapeNetCore.v1", 1), 2: build_tree(base / "ShapeNetCore.v2", 2)}


def render(args):
    from sc3d_cli.data import main


    res = CliRunner().invoke(main, ["render", "--workers", "1", "--no-progress"] + [str(a) for a in args],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    return res


@pytest.mark.parametrize("version", [1, 2])
def test_discovery_of_shapenet_trees(trees, version):
    entries, problems = discover_meshes(trees[version], categories="airplane,car")
    want = sorted([(syn, model_id(r)) for syn in (AIRPLANE, CAR) for r in PICK[syn]])
    assert [(e.category, e.model_id) for e in entries] == want
    name = "model.obj" if version == 1 else "model_normalized.obj"
    assert all(e.path.name == name for e in entries)
    assert len(problems) == 1 and "without its mesh" in problems[0]["reason"]
    assert discover_meshes(trees[version], categories="airplane")[1] == []   # car's problem not ours


def test_render_shapenet_v1_categories_by_name_r2n2_split(trees, tmp_path):
    out = tmp_path / "v1"
    render(["--meshes", trees[1], "--out", out, "--categories", "airplane,car", "--split", "r2n2"])
    index = load_index(out)
    assert index["split"]["method"] == "r2n2"
    # r2n2: 2 airplanes -> int(1.6) = 1 train, 1 test; 1 car -> test
    assert index["counts"]["by_category"] == {AIRPLANE: {"test": 1, "train": 1}, CAR: {"test": 1}}
    assert any("without its mesh" in f["reason"] for f in index["failures"])
    objs = list(iter_objects(out, fields=("masks",)))
    assert {o["category"] for o in objs} == {AIRPLANE, CAR}
    assert all(o["masks"].shape == (24, 64, 64) and 0.01 < o["masks"].mean() < 0.6 for o in objs)
    train = sorted(model_id(r) for r in PICK[AIRPLANE])[0]
    assert {o["model_id"]: o["split"] for o in objs}[train] == "train"


def test_render_shapenet_v2_with_ptn_split_files(trees, tmp_path):
    splits = tmp_path / "splits"
    splits.mkdir()
    a0, a1 = (model_id(r) for r in PICK[AIRPLANE])
    (splits / f"{AIRPLANE}_trainids.txt").write_text(f"{AIRPLANE}/{a0}\n")
    (splits / f"{AIRPLANE}_testids.txt").write_text(f"{AIRPLANE}/{a1}\n{AIRPLANE}/{'f' * 32}\n")
    out = tmp_path / "v2"
    render(["--meshes", trees[2], "--out", out, "--categories", AIRPLANE, "--split-file", splits])
    index = load_index(out)
    assert index["split"]["method"] == "file"
    assert {o["model_id"]: o["split"] for o in index["objects"]} == {a0: "train", a1: "test"}
    assert not any("without its mesh" in f["reason"] for f in index["failures"])   # a car folder
    problems = index["failures"] + index["skipped"]
    assert any("f" * 32 in p["reason"] and "matches no mesh" in p["reason"] for p in problems)


@pytest.mark.parametrize("version", [1, 2])
def test_render_turns_shapenet_front_to_plus_z(trees, tmp_path, version):
    """With the default --front auto, a ShapeNet v1 (front +X) or v2 (front -Z) file ends up
    with its front at +Z: its voxels match the voxels of the original sample mesh (front +Z).
    Negative control: the file taken as canonical (front +Z) leaves the chair turned."""
    from sc3d_data.io.meshes import load_mesh_triangles
    from sc3d_data.geometry.normalize import apply_transform, to_canonical_transform
    from sc3d_data.voxel.voxelize import voxelize_triangles

    def voxels(path, front):
        v, f = load_mesh_triangles(path)
        return voxelize_triangles(apply_transform(v, to_canonical_transform(v, f, front=front)), f, 32)

    def iou(a, b):
        return (a & b).sum() / (a | b).sum()

    rel = PICK[CHAIR][0]
    ref = voxels(SAMPLES / rel, "+Z")
    out = tmp_path / "out"
    render(["--meshes", trees[version], "--out", out, "--categories", "chair", "--views", "1", "--voxelize"])
    obj = next(iter_objects(out, fields=("voxels", "source")))
    assert iou(obj["voxels"].astype(bool), ref) > 0.9
    assert iou(voxels(obj["source"], "+Z"), ref) < 0.7
