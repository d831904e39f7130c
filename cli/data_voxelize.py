"""``sc3d-data voxelize``: solid voxels for existing shards, or one .binvox per mesh."""
from __future__ import annotations

import sys

import click

from sc3d_cli.scale_options import part_option


@click.command("voxelize")
@click.argument("shards", required=False, type=click.Path(exists=True, file_okay=False))
@click.option("--meshes", type=click.Path(exists=True),
              help="Instead of shards: a folder of meshes; writes one .binvox per mesh to --out.")
@click.option("--out", type=click.Path(file_okay=False), help="Output folder of --meshes (same structure).")
@click.option("--resolution", default=32, show_default=True, type=click.IntRange(2, 512),
              help="Voxels per side over [-0.5, 0.5]^3 (32, 64, 128 ...).")
@click.option("--normalize", type=click.Choice(["fit", "diagonal"]), default="fit", show_default=True,
              help="--meshes only: normalisation into the grid cube (as `render`).")
@click.option("--up", default="+Y", show_default=True, help="--meshes only: source up axis.")
@click.option("--front", default="auto", show_default=True,
              help="--meshes only: source front axis (auto: as `render`, ShapeNetCore v1 +X, v2 -Z, else +Z).")
@click.option("--workers", default=1, show_default=True, type=click.IntRange(1), help="Processes.")
@click.option("--overwrite", is_flag=True, help="Redo shards/files that already have voxels.")
@click.option("--progress/--no-progress", default=True, show_default=True)
@part_option
def voxelize(shards, meshes, out, resolution, normalize, up, front, workers, overwrite, progress, part):
    """Add solid `voxels` [N,G,G,G] to every object of the shards in SHARDS (from the source mesh
    and the object's stored to_canonical, exactly as rendered), or with --meshes DIR --out DIR2
    write one .binvox per mesh. Reruns skip finished shards/files; failures go to the index
    (shards) or DIR2/failures.json (meshes)."""
    from sc3d_data.pipeline.voxel_job import voxelize_meshes, voxelize_shards

    if (shards is None) == (meshes is None):
        raise click.UsageError("give either SHARDS or --meshes DIR --out DIR2")
    if meshes is not None and not out:
        raise click.UsageError("--meshes needs --out")
    if shards is not None and not part.whole:
        raise click.UsageError("--part is for --meshes; for shards, voxelize each part folder of a partitioned "
                               "render (or render with --voxelize), then merge")
    try:
        if shards is not None:
            s = voxelize_shards(shards, resolution, workers, overwrite, progress)
            click.echo(f"voxelized {s.objects} objects in {s.shards_done} shards ({s.shards_skipped} shards "
                       f"already done), {s.failed} failed, {s.seconds:.1f} s")
        else:
            s = voxelize_meshes(meshes, out, resolution, normalize, up, front, workers, overwrite, progress, part)
            click.echo(f"wrote {s.objects} .binvox files to {out} ({s.shards_skipped} already there), "
                       f"{s.failed} failed, {s.seconds:.1f} s")
    except (ValueError, RuntimeError, OSError) as e:  # bad shard/index, lock held, disk full: one line
        from sc3d_data.io.shards import one_line

        raise click.ClickException(one_line(e))
    sys.exit(0)
