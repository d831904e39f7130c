"""The pictures of round 29 (check, preview, curves, claims) on unusual but legitimate data: a
picture shows what the docs say whatever the image size, the number of logged steps or of
categories, and a picture that cannot be written is refused before the work it shows."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sc3d_cli.data import main as data_main
from tests.conftest import one_error, run_cli
from test_faults import CUBE_F, CUBE_V, FAST, obj_text


def _cube_dataset(tmp_path: Path, name: str, *options: str) -> Path:
    """A one-cube dataset (category ``chair``), rendered and voxelized with ``options``."""
    meshes = tmp_path / f"m_{name}" / "chair"
    meshes.mkdir(parents=True)
    (meshes / "cube.obj").write_text(obj_text(CUBE_V, CUBE_F))
    out = tmp_path / name
    run_cli(data_main, ["render", "--meshes", meshes.parent, "--out", out, *FAST, "--voxelize", *options])
    return out


@pytest.fixture(scope="module")
def cube_shards(tmp_path_factory) -> Path:
    return _cube_dataset(tmp_path_factory.mktemp("pictures"), "cube")


def test_check_refuses_a_png_format_it_cannot_write_before_checking(cube_shards, tmp_path):
    """``check --png worst.txt --json c.json`` ran the whole check (hours on a large dataset),
    printed its verdict, then failed on the picture's format, and the --json was never written.
    Now the format is refused first, in one line, and nothing is checked."""
    res = run_cli(data_main, ["check", cube_shards, "--png", tmp_path / "worst.txt", "--json", tmp_path / "c.json",
                              "--no-progress"], expect_exit=1)
    assert one_error(res.output).startswith(f"Error: --png {tmp_path / 'worst.txt'}: Format 'txt'")
    assert "PASS" not in res.output and "worst objects" not in res.output


def test_check_writes_its_json_into_a_folder_it_makes(cube_shards, tmp_path):
    """``--png new/w.png`` made its folder; ``--json new2/c.json`` failed after the check
    ("No such file or directory"), the scores lost. Both folders are made now."""
    js = tmp_path / "new2" / "c.json"
    run_cli(data_main, ["check", cube_shards, "--png", tmp_path / "new" / "w.png", "--json", js, "--no-progress"])
    assert json.loads(js.read_text())["passed"]


def _coloured(pixels: np.ndarray) -> int:
    """Pixels of a colour (not grey, black or white): what a plotted line or marker leaves."""
    rgb = pixels[..., :3].astype(int)
    return int(((rgb.max(-1) - rgb.min(-1)) > 60).sum())


def test_curves_of_a_run_that_logged_one_step_show_that_step(tmp_path):
    """``fit --steps 3`` (one logged step) drew curves.png with empty loss and samples/s panels:
    a line through one point draws nothing. Its point is drawn now."""
    from sc3d_train.loop.metrics_log import plot_curves

    csv = tmp_path / "metrics.csv"
    csv.write_text("step,phase,total,l3d,lr,samples_per_s,data_wait\n2,supervised,6.99,2.38,0.001,0.87,0.005\n")
    plot_curves(csv, tmp_path / "curves.png")
    picture = np.asarray(Image.open(tmp_path / "curves.png").convert("RGB"))
    assert _coloured(picture[:, picture.shape[1] // 2:]) > 20  # the samples/s panel (no legend): its point


@pytest.mark.parametrize("validated", [False, True])
def test_curves_keep_the_loss_axis_labels_inside_the_picture(tmp_path, validated):
    """Without validation (``--val-every 0``, shards without a val split) curves.png is two panels,
    11 inches wide, with the three-panel figure's 5% left margin: the log axis' labels
    ("6x10^-1") were cut at the picture's left edge. The edge is blank now, in both layouts."""
    from sc3d_train.loop.metrics_log import plot_curves

    csv = tmp_path / "metrics.csv"
    csv.write_text("step,phase,total,l3d,lr,samples_per_s,data_wait\n"
                   + "".join(f"{s},supervised,{6 - s},{0.6 - s / 10},0.001,1.0,0.0\n" for s in range(4)))
    if validated:
        (tmp_path / "validation.csv").write_text("step,val_iou,val_rot_median,val_rot_acc30,val_score,seconds,best\n"
                                                 "4,0.1,90,0.2,0.3,1.0,1\n")
    plot_curves(csv, tmp_path / "curves.png")
    picture = np.asarray(Image.open(tmp_path / "curves.png").convert("L"))
    assert picture[:, :3].min() > 200, "something is drawn at the picture's left edge (cut labels)"


def test_preview_rows_are_as_tall_as_their_label(tmp_path):
    """16-pixel views at the default scale made 36-pixel rows, and the label's third line (the
    split) was cut off at the row's bottom. The row is as tall as its label now."""
    out = _cube_dataset(tmp_path, "s16", "--image-size", "16")
    run_cli(data_main, ["preview", out, "--out", tmp_path / "sheet.png"])
    sheet = np.asarray(Image.open(tmp_path / "sheet.png").convert("L"))
    label = sheet[:, :150]
    assert label[-3:].min() > 200, "the label reaches the sheet's bottom edge (cut)"
    assert (label[sheet.shape[0] * 2 // 3:] < 100).any(), "no text in the label's lower third (no split line)"


def test_preview_of_large_views_stays_a_picture_a_viewer_opens(tmp_path):
    """1024-pixel views (``--image-size 1024`` is accepted) made a 37,086-pixel-wide sheet at the
    default scale 2. The default draws them at most 256 pixels a side."""
    out = _cube_dataset(tmp_path, "s1024", "--image-size", "1024")
    res = run_cli(data_main, ["preview", out, "--out", tmp_path / "sheet.png"])
    width, height = Image.open(tmp_path / "sheet.png").size
    assert width <= 150 + 12 * 260 and height <= 260, (width, height, res.output)


def test_preview_names_objects_whose_voxelization_failed(tmp_path):
    """An object whose ``voxelize SHARDS`` failed (an empty placeholder grid) was drawn with voxel
    tiles all grey, "mask not covered by voxels", as if its voxels missed the object, and nothing
    said why. It gets no voxel tiles now, and a warning names it."""
    meshes = tmp_path / "m" / "chair"
    meshes.mkdir(parents=True)
    (meshes / "cube.obj").write_text(obj_text(CUBE_V, CUBE_F))
    out = tmp_path / "vf"
    run_cli(data_main, ["render", "--meshes", meshes.parent, "--out", out, *FAST])
    (meshes / "cube.obj").write_text(obj_text(CUBE_V, CUBE_F, header="# re-exported"))  # changed since rendered
    run_cli(data_main, ["voxelize", out, "--no-progress"], expect_exit=1)
    res = run_cli(data_main, ["preview", out, "--out", tmp_path / "sheet.png", "--scale", "1"])
    assert "03001627/cube" in res.output and "voxelization failed" in res.output, res.output
    assert Image.open(tmp_path / "sheet.png").size[0] == 150 + 2 * 4 * 66  # images and masks only


def test_claims_picture_of_the_13_r2n2_categories_has_readable_labels(tmp_path, monkeypatch):
    """claims.png of the paper's 13 categories ran their names into each other along the x axis
    ("lamploudspeakerrifle") and its legend covered the last categories' bars. The names are
    slanted and do not overlap, and the legend lies outside the panels."""
    import sc3d_train.evaluation.claims_report as report
    from sc3d_data.formats.shapenet import R2N2_SYNSETS

    boxes = {}

    def measure(fig, path, dpi, metadata=None):
        renderer = fig.canvas.get_renderer()
        fig.draw(renderer)
        labels = fig.axes[0].get_xticklabels()
        boxes["ticks"] = [t.get_window_extent(renderer) for t in labels]
        boxes["slant"] = [t.get_rotation() for t in labels]
        boxes["line"] = labels[0].get_fontsize() * fig.dpi / 72  # pixels
        boxes["axes"] = [ax.get_window_extent(renderer) for ax in fig.axes]
        boxes["legend"] = fig.legends[0].get_window_extent(renderer) if fig.legends else fig.axes[0].get_legend().get_window_extent(renderer)

    monkeypatch.setattr(report, "write_figure", measure)
    figures = {"per_category": {c: {"voxel_iou_0.4": 0.5, "pose_rotation_acc30": 0.5} for c in R2N2_SYNSETS},
               "mean": {"voxel_iou_0.4": 0.5, "pose_rotation_acc30": 0.5}, "overall": {}}
    report.plot_report({name: figures for name in report.RUNS + report.REFERENCES}, tmp_path / "claims.png")
    ticks = boxes["ticks"]
    assert len(ticks) == 14
    if boxes["slant"][0] == 0:  # level names: their boxes may not overlap
        assert not any(a.overlaps(b) for i, a in enumerate(ticks) for b in ticks[i + 1:]), "category names overlap"
    else:  # slanted (parallel) names: a line's height apart, measured across them
        gap = min(b.x1 - a.x1 for a, b in zip(ticks, ticks[1:])) * np.sin(np.radians(boxes["slant"][0]))
        assert gap >= boxes["line"], (gap, boxes["line"])
    assert not any(boxes["legend"].overlaps(ax) for ax in boxes["axes"]), "the legend covers a panel"
