"""``sc3d-data info``: counts, settings and failures of a shard directory."""
from __future__ import annotations

from pathlib import Path

import click


@click.command()
@click.argument("shard_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--max-failures", type=int, default=50, show_default=True, help="Failures to list.")
def info(shard_dir: Path, max_failures: int):
    """Print object counts per category and split, settings and failures of SHARD_DIR."""
    from sc3d_data.index_report import index_report

    try:
        click.echo(index_report(shard_dir, max_failures))
    except (FileNotFoundError, ValueError) as e:
        raise click.ClickException(str(e))
