"""``sc3d-data import-r2n2``: 3D-R2N2's ShapeNetRendering + ShapeNetVox32 -> sc3d shards."""
from __future__ import annotations

import click

from sc3d_cli.folder_path import FolderPath
from sc3d_cli.scale_options import axis_value, executor_options, part_from_slurm_note, part_option, run_scaled, timeout_option
from sc3d_data.formats.r2n2 import R2N2_FRONT, VOXEL_FRAMES
from sc3d_data.formats.splits import SPLIT_FILE_HELP, SPLIT_HELP


@click.command("import-r2n2")
@click.option("--renderings", required=True, type=click.Path(exists=True, file_okay=False),
              help="ShapeNetRendering/ (SYNSET/MODEL_ID/rendering/{00..23}.png + rendering_metadata.txt).")
@click.option("--voxels", required=True, type=click.Path(exists=True, file_okay=False),
              help="ShapeNetVox32/ (SYNSET/MODEL_ID/model.binvox).")
@click.option("--out", required=True, type=FolderPath(), help="Output shard directory.")
@click.option("--image-size", default=64, show_default=True, type=click.IntRange(8, 1024),
              help="Images and masks are area-resized from 137x137 to this size.")
@click.option("--background", default="255,255,255", show_default=True,
              help="RGB the transparent background is composited on.")
@click.option("--categories", default=None, help="Names or synset ids, e.g. airplane,car,chair (default: all).")
@click.option("--split", default="r2n2", show_default=True, help=SPLIT_HELP)
@click.option("--split-file", multiple=True, type=click.Path(exists=True),
              help=SPLIT_FILE_HELP + " Repeatable.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of random:... splits.")
@click.option("--voxel-frame", type=click.Choice(VOXEL_FRAMES), default="cube", show_default=True,
              help="Where the binvox grid lies in the OBJ frame. cube: the cube scale*[-0.5,0.5]^3 centred "
                   "at the origin (ShapeNetVox32, written with binvox -cb); header: translate + "
                   "scale*[0,1]^3 as the header says (binvox without -cb); unit: [-0.5,0.5]^3.")
@click.option("--front", default=R2N2_FRONT, show_default=True, callback=axis_value,
              help="OBJ axis the objects' front faces (ShapeNetCore v1: +X); turned to sc3d's +Z.")
@click.option("--objects-per-shard", default=256, show_default=True, type=click.IntRange(1))
@click.option("--overwrite", is_flag=True, help="Delete shards already in --out instead of resuming.")
@click.option("--workers", type=click.IntRange(0), default=0, show_default="number of CPU cores",
              help="Processes (--executor ray: Ray CPUs, 0 = the cluster's).")
@click.option("--progress/--no-progress", default=True, show_default=True)
@part_option
@timeout_option
@executor_options
def import_r2n2(renderings, voxels, out, image_size, background, categories, split, split_file, seed,
                voxel_frame, front, objects_per_shard, overwrite, progress, part, slurm, **scale):
    """Build sc3d shards from 3D-R2N2's released renderings and voxels, without re-rendering.

    Cameras are rebuilt from rendering_metadata.txt as explicit K, R, t (see docs/data.md,
    "ShapeNet and 3D-R2N2 conventions, with evidence"); check them with `sc3d-data check --shards OUT`. A rerun
    keeps the finished shards and imports the rest (resumable); runs on the local pool, Ray or
    a SLURM job array (--executor)."""
    from sc3d_data.pipeline.jobs.r2n2_job import ImportConfig, import_r2n2 as run
    from sc3d_data.pipeline.jobs.r2n2_job import import_on_slurm

    try:
        bg = tuple(int(c) for c in background.split(","))
        assert len(bg) == 3 and all(0 <= c <= 255 for c in bg)
    except (ValueError, AssertionError):
        raise click.BadParameter(f"expected R,G,B in 0..255, got {background!r}", param_hint="--background")
    config = ImportConfig(renderings=renderings, voxels=voxels, out=out, image_size=image_size,
                          background=bg, categories=categories, split=split,
                          split_file=list(split_file) or None, seed=seed, voxel_frame=voxel_frame, front=front,
                          objects_per_shard=objects_per_shard, overwrite=overwrite, part=part, progress=progress,
                          **scale)
    from sc3d_data.io.names import printable

    summary = run_scaled(config, slurm, run, import_on_slurm)
    for f in summary["failures"]:
        click.echo(f"failed: {printable(f['source'])}: {printable(f['reason'])}", err=True)
    click.echo(f"imported {summary['done']} of {summary['planned']} models into {printable(summary['out'])} "
               f"({summary['resumed']} already there, {summary['failed']} failed, {summary['skipped']} skipped; "
               f"{summary['seconds']:.1f} s); details in index.json")
    if (note := part_from_slurm_note(part)) is not None:
        click.echo(note)
    if summary["failed"] and not summary["done"] and not summary["resumed"]:
        raise click.ClickException(f"no model was imported: all {summary['failed']} failed")
