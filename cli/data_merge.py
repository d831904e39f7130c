"""``sc3d-data merge``: part folders of a partitioned run -> one dataset folder."""
from __future__ import annotations

from pathlib import Path

import click

from sc3d_data.io.names import printable

from sc3d_cli.folder_path import FolderPath


@click.command("merge")
@click.argument("out", type=FolderPath())
@click.argument("parts", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--copy", is_flag=True, help="Copy the shard files instead of hard-linking them.")
@click.option("--overwrite", is_flag=True, help="Replace a dataset in OUT that is not a merge or is a merge of other "
              "settings or splits, and files named like its shards that OUT's index does not list.")
def merge(out, parts, copy, overwrite):
    """Combine the folders of `render/import-r2n2 --part I/N` runs (PARTS, all N of them) into one
    dataset in OUT with one index. Refuses parts made with other settings, missing or unfinished
    parts and duplicate objects; shard files are hard-linked (or copied) into OUT; rerunnable."""
    from sc3d_data.pipeline.jobs.recorded_defaults import recorded_defaults
    from sc3d_data.pipeline.run.merge import merge_parts
    from sc3d_data.io.shards import one_line

    try:
        s = merge_parts(out, list(parts), copy=copy, overwrite=overwrite, defaults_of=recorded_defaults)
    except (ValueError, RuntimeError, OSError) as e:
        raise click.ClickException(one_line(e))
    click.echo(f"merged {s.parts} parts into {printable(s.out)}: {s.objects} objects in {s.shards} shards "
               f"({s.linked} linked, {s.copied} copied, {s.kept} already there), {s.failed} failures; "
               f"{s.seconds:.1f} s; index: {printable(Path(s.out) / 'index.json')}")
