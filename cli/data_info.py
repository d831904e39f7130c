"""``sc3d-data info``: counts, settings and failures of a shard directory."""
from __future__ import annotations

from pathlib import Path

import click


@click.command()
@click.argument("shard_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--max-failures", type=click.IntRange(0), default=50, show_default=True, help="Failures to list.")
@click.option("--verify", is_flag=True, help="Also check every shard's SHA-256 against the index "
              "(without it only presence and size are checked).")
def info(shard_dir: Path, max_failures: int, verify: bool):
    """Print object counts per category and split, settings and failures of SHARD_DIR.
    Exits 1 when a shard is missing, truncated or (--verify) corrupted."""
    from sc3d_data.qa.index_report import index_report, integrity_report

    try:
        click.echo(index_report(shard_dir, max_failures))
        broken = integrity_report(shard_dir, full=verify)
    except (FileNotFoundError, ValueError) as e:
        from sc3d_data.io.names import printable

        raise click.ClickException(printable(e, keep_newlines=True))
    from sc3d_data.io.shards import load_index

    index = load_index(shard_dir)
    n = len(index.get("shards", []))
    if broken:
        made_by = ("merge command (same parts)" if "merged" in index
                   else "import-r2n2 command" if index.get("settings", {}).get("source") == "3D-R2N2" else "render command")
        if all("voxel grids, its index records" in line for line in broken):  # shard_layout.grid_problem
            made_by = "voxelize command that stopped part-way, to finish it"
        click.echo(f"\nBROKEN shards: {len(broken)} of {n} (rerun the {made_by} to make them again)")
        for line in broken:
            click.echo(f"  {line}")
        raise SystemExit(1)
    click.echo(f"\nshards {'verified (SHA-256)' if verify else 'present with the recorded sizes'}: {n}")

