"""``sc3d-data check``: projected voxels vs rendered masks, per object and view."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from sc3d_cli.folder_path import FilePath
from sc3d_data.io.names import printable, shell_word


@click.command("check")
@click.argument("shards_arg", required=False, metavar="SHARDS", type=click.Path(exists=True, file_okay=False))
@click.option("--shards", "shards_opt", type=click.Path(exists=True, file_okay=False),
              help="Shard directory (same as the SHARDS argument).")
@click.option("--min-coverage", default=0.98, show_default=True, type=click.FloatRange(0, 1),
              help="Exit 1 when any object's mean coverage (share of mask pixels inside the projected "
                   "voxels) is below this.")
@click.option("--min-near", default=0.98, show_default=True, type=click.FloatRange(0, 1),
              help="Exit 1 when any object's mean near (share of projected-voxel pixels within one "
                   "projected voxel diagonal of the mask) is below this.")
@click.option("--min-iou", default=0.0, show_default=True, type=click.FloatRange(0, 1),
              help="Also exit 1 when any object's mean IoU is below this (0: IoU is only reported; "
                   "thin objects score low IoU at 32^3 even when correct).")
@click.option("--worst", default=10, show_default=True, type=click.IntRange(1), help="Worst objects listed (the picture draws the first 8 of them).")
@click.option("--png", type=FilePath(),
              help="Picture of the worst views (image | mask | voxels | diff); default SHARDS/check_worst.png "
                   "(not written there when the dataset is read-only: a warning, not an error).")
@click.option("--json", "json_out", type=FilePath(), help="Write per-object scores as JSON.")
@click.option("--progress/--no-progress", default=True, show_default=True)
def check(shards_arg, shards_opt, min_coverage, min_near, min_iou, worst, png, json_out, progress):
    """Project every object's voxels through each stored camera and compare with the rendered
    mask (coverage, near, IoU); report per category and the worst objects, draw the worst views.
    Exits 1 when any object's mean coverage is below --min-coverage or its mean near below
    --min-near (a consistent dataset scores 1.000 on both, thin objects included: voxels cover
    every mask pixel and reach no further than one voxel from the mask)."""
    from sc3d_data.qa.check import check_shards, write_worst_png

    if shards_opt and shards_arg and Path(shards_opt).resolve() != Path(shards_arg).resolve():
        raise click.UsageError(f"two shard directories: {shards_arg} and --shards {shards_opt}; give one "
                               "(check one dataset at a time)")
    shards = shards_opt or shards_arg
    if shards is None:
        raise click.UsageError("give the shard directory (SHARDS or --shards)")
    from sc3d_data.io.pictures import check_figure_format
    from sc3d_data.io.shards import load_index, one_line, refuse_dataset_file

    default_png = not png
    png = Path(png) if png else Path(shards) / "check_worst.png"
    try:
        for option, path in (("--png", png), ("--json", json_out)):
            if path:
                refuse_dataset_file(Path(shards), Path(path), option)
        try:  # refused now, not after the check (whose --json would then be lost too)
            check_figure_format(png)
        except ValueError as e:
            raise click.ClickException(f"--png {png}: {one_line(e)}")
        report = check_shards(Path(shards), min_iou=min_iou, min_coverage=min_coverage, progress=progress,
                              min_near=min_near)
    except (FileNotFoundError, ValueError, OSError) as e:
        raise click.ClickException(one_line(e))
    left_out = (f"{len(report.left_out)} object(s) left out, their voxelization failed (index.json failures; "
                f"`sc3d-data info {shell_word(shards)}` gives the reasons): " + ", ".join(map(printable, report.left_out[:3]))
                + (", ..." if len(report.left_out) > 3 else ""))
    if not report.objects:
        raise click.ClickException(f"{shards}: no objects to check" + (f" ({left_out})" if report.left_out else ""))
    click.echo(report.text(worst))
    if report.left_out:
        click.echo(f"note: {left_out}", err=True)
    if not load_index(Path(shards)).get("complete"):  # the verdict covers only what the shards hold
        click.echo(f"note: {printable(shards)} is incomplete (the command that writes it stopped before its end; rerun it to "
                   "finish): the verdict is on the objects written so far", err=True)
    try:
        png_path = write_worst_png(Path(shards), report, png, n=min(worst, 8))
    except OSError as e:  # a folder that cannot be made or written (the message names the file)
        if not default_png:
            raise click.ClickException(one_line(e))
        # the default picture in a read-only dataset: the verdict stands without it
        click.echo(f"warning: {one_line(e)}: the picture of the worst views was not written; "
                   "give --png PATH to write it elsewhere", err=True)
        png_path = None
    except ValueError as e:  # matplotlib: a format it cannot write
        raise click.ClickException(f"--png {png}: {one_line(e)}")
    if png_path is not None:
        click.echo(f"worst views: {printable(png_path)}")
    if json_out:
        try:
            Path(json_out).parent.mkdir(parents=True, exist_ok=True)  # as --png's folder is made
            Path(json_out).write_text(json.dumps(
                {"min_iou": min_iou, "min_coverage": min_coverage, "min_near": min_near, "passed": report.passed, "per_category": report.per_category(),
                 "left_out_voxelize_failed": report.left_out,
                 "objects": [{"category": o.category, "model_id": o.model_id, "shard": o.shard, "row": o.row,
                              "behind_camera_views": list(o.behind), "mean_iou": o.mean_iou, "mean_coverage": o.mean_coverage, "mean_near": o.mean_near,
                              "near": o.near.round(4).tolist(), "iou": o.iou.round(4).tolist(),
                              "coverage": o.coverage.round(4).tolist()} for o in report.objects]}, indent=1))
        except OSError as e:
            raise click.ClickException(one_line(e))
    sys.exit(0 if report.passed else 1)
