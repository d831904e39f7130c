"""Hostile inputs, round eleven: ``voxelize SHARDS`` given options that only ``--meshes`` reads,
``merge`` of parts voxelized in different ways (or not at all), and the labels of ``eval``'s
example picture. Real renderer, voxelizer, HDF5 and commands; expected values come from a
whole run of the same meshes and from the inputs."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from sc3d_cli.data import main as data_main
from conftest import SAMPLE_MESHES, objects_by_id, one_error, run_cli
from test_faults import FAST


@pytest.fixture(scope="module")
def three_meshes(tmp_path_factory):
    """Three bundled meshes of two categories (a merge of two parts gets objects in both)."""
    root = tmp_path_factory.mktemp("three_meshes")
    for rel in ("car/jeep_psionic.glb", "table/coffee_table_blendswap_ccby.glb", "chair/chair2_blendswap.glb"):
        (root / rel).parent.mkdir(exist_ok=True)
        shutil.copy(SAMPLE_MESHES / rel, root / rel)
    return root


@pytest.mark.parametrize("options", [["--normalize", "diagonal"], ["--up", "+Z", "--front", "+X"],
                                     ["--out", "elsewhere"]], ids=["normalize", "axes", "out"])
def test_voxelize_shards_refuses_the_options_only_meshes_reads(three_meshes, tmp_path, options):
    """``voxelize SHARDS --normalize diagonal`` (or ``--up``/``--front``/``--out``) said it
    voxelized every object and wrote the grids it would have written without them: the options
    are ``--meshes``-only (shards are voxelized in their stored frame, in place)."""
    out = tmp_path / "out"
    run_cli(data_main, ["render", "--meshes", three_meshes / "table", "--out", out, *FAST])
    before = {p.name: p.read_bytes() for p in out.glob("shard-*.h5")}
    res = run_cli(data_main, ["voxelize", out, *options, "--no-progress"], expect_exit=2)
    line = one_error(res.output)
    assert "for --meshes only" in line and all(o in line for o in options if o.startswith("--")), line
    assert {p.name: p.read_bytes() for p in out.glob("shard-*.h5")} == before
    assert not (tmp_path / "elsewhere").exists()
    # the defaults (not given) and --resolution still voxelize the shards
    assert "voxelized 1 objects" in run_cli(data_main, ["voxelize", out, "--resolution", "8", "--no-progress"]).output


def test_merge_takes_parts_voxelized_by_render_and_by_voxelize_alike(three_meshes, tmp_path):
    """``render --voxelize`` and ``render`` + ``voxelize PART`` give the same grids (the docs
    offer both for parts), but merge refused to combine them ("voxelize differ"). Now merged,
    the dataset equals one whole ``render --voxelize`` of the meshes, object for object."""
    whole, p0, p1 = tmp_path / "whole", tmp_path / "p0", tmp_path / "p1"
    run_cli(data_main, ["render", "--meshes", three_meshes, "--out", whole, "--voxelize", *FAST])
    run_cli(data_main, ["render", "--meshes", three_meshes, "--out", p0, "--part", "0/2", *FAST])
    run_cli(data_main, ["voxelize", p0, "--no-progress"])
    run_cli(data_main, ["render", "--meshes", three_meshes, "--out", p1, "--part", "1/2", "--voxelize", *FAST])
    for order in ([p0, p1], [p1, p0]):
        merged = tmp_path / f"merged_{order[0].name}"
        run_cli(data_main, ["merge", merged, *order])
        got, ref = objects_by_id(merged), objects_by_id(whole)
        assert sorted(got) == sorted(ref) and len(ref) == 3
        for key in ref:
            for name in ("images", "masks", "voxels", "K", "R", "t"):
                np.testing.assert_array_equal(got[key][name], ref[key][name], err_msg=f"{order} {key} {name}")
        assert "voxels: 32^3" in run_cli(data_main, ["info", merged]).output


def test_merge_names_a_part_without_voxels_as_such(three_meshes, tmp_path):
    """A part never voxelized beside a voxelized one was refused as "voxelized at another
    resolution"; the reason is that it has no voxels, and the way out is to voxelize it."""
    p0, p1 = tmp_path / "p0", tmp_path / "p1"
    run_cli(data_main, ["render", "--meshes", three_meshes, "--out", p0, "--part", "0/2", "--voxelize", *FAST])
    run_cli(data_main, ["render", "--meshes", three_meshes, "--out", p1, "--part", "1/2", *FAST])
    line = one_error(run_cli(data_main, ["merge", tmp_path / "m", p0, p1], expect_exit=1).output)
    assert f"{p1}: no voxels, {p0}: 32^3 voxels" in line and "sc3d-data voxelize" in line, line
    run_cli(data_main, ["voxelize", p1, "--resolution", "16", "--no-progress"])
    line = one_error(run_cli(data_main, ["merge", tmp_path / "m", p0, p1], expect_exit=1).output)
    assert f"{p1}: 16^3 voxels, {p0}: 32^3 voxels" in line, line


def test_merged_voxels_record_counts_the_failures_of_every_part():
    """The merge's ``voxels`` record was the first part's, failures included: a second part's
    failed grids were not counted in ``info``'s ``voxels:`` line."""
    from sc3d_data.pipeline.run.merge import merged_voxels_record

    record = {"resolution": 32, "occupancy": "solid", "failed": 1}
    parts = [{"voxels": record}, {"settings": {"voxelize": True}}, {"voxels": dict(record, failed=2)}]
    assert merged_voxels_record(parts) == {"resolution": 32, "occupancy": "solid", "failed": 3}
    assert merged_voxels_record([{"settings": {"voxelize": True}}]) is None


def test_eval_picture_labels_keep_the_whole_id_and_the_view(tmp_path):
    """``predictions.png`` cut each label at 26 characters: a ShapeNet example read
    ``03001627/1a38407b3036795d1``, without its view, so two views of one object (or two objects
    sharing a prefix) could not be told apart. The figure under it names its IoU threshold."""
    from sc3d_train.evaluation.evaluate import example_figures, example_label, plot_examples

    K = np.array([[70.0, 0, 32], [0, 70, 32], [0, 0, 1]], np.float32)
    grid = np.zeros((32, 32, 32), bool)
    grid[10:20, 10:20, 10:20] = True
    model_id = "1a38407b3036795d19fb4103277a6b93"
    examples = [dict(category="03001627", model_id=model_id, view=v, image=np.ones((64, 64, 3)),
                     mask_true=np.zeros((64, 64)), mask_pred=np.zeros((64, 64)), voxels_true=grid,
                     voxels_pred=grid * 1.0, K=K, distance=2.0, azimuth_true=0.0, elevation_true=30.0,
                     azimuth_pred=15.0, elevation_pred=30.0, rotation_error=15.0, iou=0.5) for v in (3, 15)]
    labels = [example_label(ex) for ex in examples]
    assert labels == [f"03001627\n{model_id}\nview 3", f"03001627\n{model_id}\nview 15"]
    assert example_figures(examples[0]).startswith("IoU@0.5 0.50 rot 15\n")
    plot_examples(examples, tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 0
