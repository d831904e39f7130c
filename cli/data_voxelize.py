"""``sc3d-data voxelize``: solid voxels for existing shards, or one .binvox per mesh."""
from __future__ import annotations

import os
import sys

import click

from sc3d_cli.folder_path import FolderPath
from sc3d_data.io.names import printable, shell_word
from sc3d_cli.scale_options import axis_value, check_executor_options, executor_options, part_from_slurm_note, part_option, run_scaled, timeout_option


#: options that only ``--meshes`` reads (shards carry their frame and are written in place)
MESHES_ONLY = ("out", "normalize", "up", "front")


def meshes_only_options_given(ctx: click.Context) -> list[str]:
    """The ``--meshes``-only options given on the command line (not left at their defaults)."""
    return [f"--{name}" for name in MESHES_ONLY
            if ctx.get_parameter_source(name) is not click.core.ParameterSource.DEFAULT]


@click.command("voxelize")
@click.argument("shards", required=False, type=click.Path(exists=True, file_okay=False))
@click.option("--meshes", type=click.Path(exists=True),
              help="Instead of shards: a folder of meshes; writes one .binvox per mesh to --out.")
@click.option("--out", type=FolderPath(), help="Output folder of --meshes (same structure).")
@click.option("--resolution", default=32, show_default=True, type=click.IntRange(2, 512),
              help="Voxels per side over [-0.5, 0.5]^3 (32, 64, 128 ...).")
@click.option("--normalize", type=click.Choice(["fit", "diagonal"]), default="fit", show_default=True,
              help="--meshes only: normalisation into the grid cube (as `render`).")
@click.option("--up", default="+Y", show_default=True, callback=axis_value, help="--meshes only: source up axis.")
@click.option("--front", default="auto", show_default=True, callback=axis_value,
              help="--meshes only: source front axis (auto: as `render`, ShapeNetCore v1 +X, v2 -Z, else +Z).")
@click.option("--workers", default=1, show_default=True, type=click.IntRange(0),
              help="Processes, 0 = number of CPU cores (--meshes --executor ray: CPU slots, 0 = the cluster's).")
@click.option("--overwrite", is_flag=True, help="Redo shards/files that already have voxels.")
@click.option("--progress/--no-progress", default=True, show_default=True)
@part_option
@timeout_option
@executor_options
def voxelize(shards, meshes, out, resolution, normalize, up, front, workers, overwrite, progress, part, slurm,
             **scale):
    """Add solid `voxels` [N,G,G,G] to every object of the shards in SHARDS (from the source mesh
    and the object's stored to_canonical, exactly as rendered), or with --meshes DIR --out DIR2
    write one .binvox per mesh. Reruns skip finished shards/files; failures go to the index
    (shards) or DIR2/failures.json (meshes). --meshes runs on the local pool, Ray or a SLURM job
    array (--executor); both have a per-object --timeout."""
    from sc3d_data.pipeline.jobs.voxel_meshes import voxelize_on_slurm
    from sc3d_data.pipeline.jobs.voxel_job import voxelize_shards
    from sc3d_data.pipeline.jobs.voxel_meshes import VoxelMeshesConfig, failures_name, voxelize_meshes

    if (shards is None) == (meshes is None):
        raise click.UsageError("give either SHARDS or --meshes DIR --out DIR2")
    if meshes is not None and not out:
        raise click.UsageError("--meshes needs --out")
    if shards is not None and not part.whole:
        if part_from_slurm_note(part) is not None:  # no --part: the job array's environment gave one
            raise click.UsageError(f"this is a SLURM job array task (SLURM_ARRAY_TASK_ID/COUNT: part {part}), but "
                                   "shards are voxelized whole: run `voxelize SHARDS` in one task, or give --part 0/1")
        raise click.UsageError("--part is for --meshes; for shards, voxelize each part folder of a partitioned "
                               "render (or render with --voxelize), then merge")
    if shards is not None and (given := meshes_only_options_given(click.get_current_context())):
        raise click.UsageError(f"{', '.join(given)}: for --meshes only; shards are voxelized in the frame they "
                               "were rendered in (each object's stored to_canonical), into their own files")
    if shards is not None and scale["executor"] != "local":
        raise click.UsageError("--executor is for --meshes; shards are voxelized by a local pool (--workers)")
    if shards is not None:
        check_executor_options("local", "shards are voxelized by a local pool (--workers): leave them out")
    try:
        if shards is not None:
            from sc3d_data.io.shards import load_index

            s = voxelize_shards(shards, resolution, workers or os.cpu_count() or 1, overwrite, progress,
                                scale["timeout_s"], scale["retries"])
            if not s.shards_done and not s.shards_skipped and load_index(shards).get("failures"):  # not an empty part
                raise click.ClickException(f"{shards}: holds no shard, so nothing was voxelized (no object was rendered "
                                           f"into it: `sc3d-data info {shell_word(shards)}` lists why)")
            click.echo(f"voxelized {s.objects - s.failed} objects in {s.shards_done} shards ({s.shards_skipped} shards "
                       f"already done), {s.failed} failed, {s.seconds:.1f} s")
            if s.failed and s.failed == s.objects and not s.reused:
                grids = (f"earlier grid kept for {s.kept}, the others' are empty" if s.kept
                         else "their grids are empty")
                raise click.ClickException(f"no object was voxelized: all {s.failed} failed ({grids}; "
                                           f"reasons: `sc3d-data info {shell_word(shards)}`)")
        else:
            config = VoxelMeshesConfig(meshes=meshes, out=out, resolution=resolution, normalize=normalize, up=up,
                                       front=front, workers=workers, overwrite=overwrite, progress=progress,
                                       part=part, **scale)
            s = run_scaled(config, slurm, lambda c: voxelize_meshes(c).as_dict(), voxelize_on_slurm)
            stale = "".join(f", {s[k]} of them again: {why}" for k, why in (
                ("stale", "their mesh is newer"), ("remade", "made by another mesh or with other settings")) if s.get(k))
            click.echo(f"wrote {s['done']} .binvox files to {printable(out)}{stale} ({s['resumed']} already there), "
                       f"{s['failed']} failed, {s['seconds']:.1f} s")
            if (note := part_from_slurm_note(part)) is not None:
                click.echo(note)
            if s["failed"] and not s["done"] and not s["resumed"]:
                raise click.ClickException(f"no .binvox was written: all {s['failed']} failed (reasons in "
                                           f"{os.path.join(out, failures_name(part))})")
    except (ValueError, RuntimeError, OSError) as e:  # bad shard/index, lock held, disk full: one line
        from sc3d_data.io.shards import one_line

        raise click.ClickException(one_line(e))
    sys.exit(0)
