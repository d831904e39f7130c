"""``sc3d-data render``: meshes -> rendered views (+ voxels) in HDF5 shards. Thin wrapper over
``sc3d_data.pipeline.jobs.render_run.render_dataset`` (or, with ``--executor slurm``,
``sc3d_data.pipeline.jobs.render_run.render_on_slurm``)."""
from __future__ import annotations

from pathlib import Path

import click

from sc3d_cli.folder_path import FilePath, FolderPath
from sc3d_data.geometry.camera import DEFAULT_DISTANCE, DEFAULT_FOV_DEG, DEFAULT_IMAGE_SIZE, DEFAULT_NUM_VIEWS
from sc3d_data.io.meshes import DEFAULT_MAX_FACES, DEFAULT_MAX_FILE_BYTES
from sc3d_cli.scale_options import axis_value, executor_options, part_from_slurm_note, part_option, run_render
from sc3d_data.pipeline.jobs.render_job import SAMPLE_MESHES, RenderConfig
from sc3d_data.formats.splits import SPLIT_FILE_HELP, SPLIT_HELP


def _gpus(text: str | None) -> tuple[int, ...]:
    from sc3d_data.pipeline.executors.devices import parse_gpus

    try:
        return parse_gpus(text)
    except ValueError as e:
        raise click.BadParameter(str(e)) from None


def _not_blank(text: str | None, param) -> str | None:
    if text is not None and not text.strip():
        raise click.BadParameter("is empty: give a category name (an unset variable?)", param=param)
    return text


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise click.BadParameter(f"expected comma-separated numbers, got {text!r}")


def _rgb(text: str) -> tuple[int, int, int]:
    parts = text.split(",")
    if len(parts) != 3 or not all(p.strip().isdigit() and 0 <= int(p) <= 255 for p in parts):
        raise click.BadParameter(f"expected R,G,B with values 0-255, got {text!r}")
    return tuple(int(p) for p in parts)


@click.command()
@click.option("--meshes", type=click.Path(exists=True, path_type=Path), default=SAMPLE_MESHES,
              show_default="bundled assets/sample_meshes", help="Folder of meshes (ShapeNetCore layout, CATEGORY/NAME.ext, ...) or one mesh file.")
@click.option("--out", type=FolderPath(file_okay=True), required=True, help="Output folder for shards and index.json.")
@click.option("--views", "num_views", type=click.IntRange(1), default=DEFAULT_NUM_VIEWS, show_default=True, help="Azimuths per elevation (evenly spaced from 0).")
@click.option("--elevations", default="30", show_default=True, help="Comma-separated elevations in degrees.")
@click.option("--image-size", type=click.IntRange(8), default=DEFAULT_IMAGE_SIZE, show_default=True)
@click.option("--fov", "fov_deg", type=float, default=DEFAULT_FOV_DEG, show_default=True, help="Field of view, degrees.")
@click.option("--distance", type=float, default=DEFAULT_DISTANCE, show_default=True, help="Camera distance from the origin.")
@click.option("--background", default="255,255,255", show_default=True, help="Background colour R,G,B.")
@click.option("--depth/--no-depth", default=False, show_default=True, help="Also store depth maps.")
@click.option("--normalize", type=click.Choice(["fit", "diagonal"]), default="fit", show_default=True)
@click.option("--up", default="+Y", show_default=True, callback=axis_value, help="Source axis that is up (e.g. +Z, with --front -Y).")
@click.option("--front", default="auto", show_default=True, callback=axis_value,
              help="Source axis the object's front faces (e.g. -X); turned to +Z. auto: +X for ShapeNetCore "
                   "v1 model.obj, -Z for v2 model_normalized.obj, +Z for other meshes.")
@click.option("--backend", type=click.Choice(["auto", "egl", "osmesa"]), default="auto", show_default=True)
@click.option("--voxelize/--no-voxelize", default=False, show_default=True, help="Also store solid voxel grids.")
@click.option("--voxel-resolution", type=click.IntRange(2, 512), default=32, show_default=True)
@click.option("--categories", default=None, help="Only these categories (names or synset ids, comma-separated).")
@click.option("--category", default=None, callback=lambda ctx, param, v: _not_blank(v, param),
              help="Give every mesh this category instead of the folder's.")
@click.option("--split", default="random:0.7,0.1,0.2", show_default=True, help=SPLIT_HELP)
@click.option("--split-file", multiple=True, type=FilePath("a split file", dir_okay=True), help=SPLIT_FILE_HELP + " Repeatable.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--objects-per-shard", type=click.IntRange(1), default=256, show_default=True)
@click.option("--chunks", type=click.Choice(["view", "object"]), default="view", show_default=True,
              help="HDF5 chunks of images and masks: one view each (cheap random-view reads for training) "
                   "or one object each (~1/3 smaller files). Values are the same either way.")
@click.option("--max-faces", type=click.IntRange(1), default=DEFAULT_MAX_FACES, show_default=True, help="Reject meshes with more triangles.")
@click.option("--max-file-mib", type=click.IntRange(1), default=DEFAULT_MAX_FILE_BYTES // 2**20, show_default=True,
              help="Reject mesh files larger than this many MiB before parsing them.")
@click.option("--bad-texture", type=click.Choice(["fail", "fallback"]), default="fail", show_default=True,
              help="A texture that is named but cannot be read or loaded: skip the object (fail) or render "
                   "with material colours and record a warning (fallback).")
@click.option("--outside-textures", type=click.Choice(["warn", "refuse"]), default="warn", show_default=True,
              help="Material/texture files outside --meshes (absolute paths, ../), judged from the path "
                   "and never opened: render without them and record a warning, or refuse the object.")
@click.option("--retry-failed/--no-retry-failed", default=True, show_default=True,
              help="On a rerun, render the recorded failures again (a killed worker, ...); the index "
                   "counts attempts.")
@click.option("--timeout", "timeout_s", type=click.FloatRange(0, min_open=True), default=120.0, show_default=True, help="Per-object time limit, seconds.")
@click.option("--workers", type=click.IntRange(0), default=0, show_default="number of CPU cores")
@click.option("--gpus", callback=lambda ctx, param, v: _gpus(v), default=None, metavar="0,1,...",
              help="EGL devices (GPUs) to spread the workers over, round robin; default: device "
                   "EGL_DEVICE_ID or 0. Ray: each task takes a share of one GPU; slurm: each array task "
                   "asks for this many GPUs. See docs/scale.md.")
@click.option("--overwrite", is_flag=True, help="Delete existing shards in --out instead of resuming.")
@click.option("--progress/--no-progress", default=True, show_default=True)
@part_option
@executor_options
def render(elevations, background, part, slurm, **options):
    """Render every mesh under --meshes into HDF5 shards under --out (resumable)."""
    config = RenderConfig(elevations=_floats(elevations), background=_rgb(background), part=part,
                          split_file=_split_files(options.pop("split_file")), **options)
    s = run_render(config, slurm)
    from sc3d_data.io.names import printable, shell_word

    for note in s["notes"]:
        click.echo(f"warning: {printable(note)}", err=True)
    retried = (f", retried {s['retried']}" if s["retried"] else "") + (f", added {s['added']}" if s.get("added") else "")
    where = f"part {s['part']}, " if s.get("part", "0/1") != "0/1" else ""
    warned = f", {s['warned']} with warnings" if s.get("warned") else ""
    click.echo(f"{where}done {s['done']}, resumed {s['resumed']}{retried}, skipped {s['skipped']}, failed {s['failed']}"
               f"{warned} in {s['seconds']:.1f} s ({_rate(s)}backend {s['backend']}); index: {printable(Path(s['out']) / 'index.json')}")
    listed = " and ".join(w for w, n in (("failures", s["failed"]), ("warnings", s.get("warned"))) if n)
    if listed:
        click.echo(f"{listed} are listed with reasons by `sc3d-data info {shell_word(s['out'])}`")
    if (note := part_from_slurm_note(part)) is not None:
        click.echo(note)
    if (note := _clipped_note(Path(s["out"]))) is not None:
        click.echo(note, err=True)
    if s["failed"] and not s["done"] and not s["resumed"]:
        raise click.ClickException(f"no object was rendered: all {s['failed']} failed{_first_reason(s['out'])}")
    if s["skipped"] and not (s["done"] or s["resumed"] or s["failed"]) and s.get("part", "0/1") == "0/1":
        raise click.ClickException(f"no object was rendered: all {s['skipped']} were skipped"
                                   f"{_first_reason(s['out'], 'skipped')}; `sc3d-data info {shell_word(s['out'])}` lists them")


def _clipped_note(out: Path) -> str | None:
    """A ``warning:`` line counting the dataset's clipped views (the mask touches the image
    border), or None: only ``info`` counted them, so a ``--fov`` given in radians (every mask the
    whole image, which ``check`` passes and ``fit`` trains on) rendered with exit 0 and no word."""
    from sc3d_data.io.shards import load_index

    try:
        index = load_index(out, listing=False)
    except Exception:  # no index (a --part run of another machine, nothing rendered): nothing to count
        return None
    clipped, st = index.get("clipped") or {}, index["settings"]
    if not clipped.get("views"):
        return None
    objects = len(index.get("objects") or [])
    views = objects * st["num_views"] * len(st["elevations"])
    return (f"warning: {clipped['views']} of {views} views ({clipped.get('objects', 0)} of {objects} objects) are "
            f"clipped: the object leaves the frame (--fov is in degrees, {st['fov_deg']:g} here; a wider "
            f"--fov or a larger --distance fits it); `sc3d-data preview` shows them")


def _rate(s: dict) -> str:
    """``"N views/s, W workers, "`` of a run that rendered; nothing where every object was kept
    (no worker started: a rate of 0 views/s would read as a fault)."""
    return f"{s['views_per_s']:.0f} views/s, {s['workers']} workers, " if s["workers"] else "nothing to render, "


def _split_files(values) -> str | list[str] | None:
    """``--split-file``'s values as ``RenderConfig.split_file``: None, the one file, or the list
    (every file's ids count, as ``import-r2n2`` takes them)."""
    files = list(values or ())
    return files[0] if len(files) == 1 else files or None


def _first_reason(out, listed: str = "failures") -> str:
    """``" (first: REASON)"`` of the first entry of the index of ``out``'s list ``listed``
    (``failures`` or ``skipped``), or ``""``."""
    from sc3d_data.io.names import printable
    from sc3d_data.io.shards import load_index

    try:
        reason = load_index(Path(out))[listed][0]["reason"]
    except (OSError, ValueError, LookupError, TypeError):
        return ""
    return f" (first: {printable(str(reason))})"
