"""``sc3d-data preview``: a contact sheet PNG of a shard directory."""
from __future__ import annotations

from pathlib import Path

import click

from sc3d_data.io.names import printable


@click.command()
@click.argument("shard_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), default=Path("sheet.png"), show_default=True)
@click.option("--objects", "max_objects", type=click.IntRange(1), default=8, show_default=True)
@click.option("--views", type=click.IntRange(1), default=6, show_default=True, help="Views per object.")
@click.option("--scale", type=click.IntRange(1, 8), default=None,
              help="Pixel magnification [auto: 2 for views up to 64 pixels, 1 up to 256; larger views are "
                   "drawn at every k-th pixel, at most 256 a side].")
def preview(shard_dir: Path, out: Path, max_objects: int, views: int, scale: int | None):
    """Write a contact sheet of SHARD_DIR: per object, images, masks and (with voxels) voxel
    silhouettes (dark blue = voxels over the mask, light blue = voxels outside it, grey = mask
    not covered by voxels) of several views."""
    from PIL import Image

    from sc3d_data.io.pictures import write_image
    from sc3d_data.io.shards import one_line, refuse_dataset_file
    from sc3d_data.qa.preview import contact_sheet

    try:
        refuse_dataset_file(shard_dir, out, "--out")
        notes: list[str] = []
        sheet = contact_sheet(shard_dir, max_objects, views, scale, notes)
    except (FileNotFoundError, ValueError) as e:
        raise click.ClickException(one_line(e))
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        write_image(Image.fromarray(sheet), out)
    except OSError as e:  # a folder that cannot be made or written (the message names the file)
        raise click.ClickException(one_line(e))
    except ValueError as e:  # PIL: an extension it cannot write
        raise click.ClickException(f"--out {out}: {one_line(e)}")
    for note in notes:
        click.echo(f"warning: {note}", err=True)
    click.echo(f"wrote {printable(out)} ({sheet.shape[1]}x{sheet.shape[0]})")
