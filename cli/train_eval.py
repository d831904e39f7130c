"""``sc3d-train eval``: option parsing only; the work is ``sc3d_train.evaluate.evaluate``."""
from __future__ import annotations

from pathlib import Path

import click


@click.command("eval")
@click.option("--checkpoint", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="A checkpoint of `sc3d-train fit` (e.g. RUN_DIR/checkpoints/last.pt).")
@click.option("--shards", type=click.Path(file_okay=False, path_type=Path), required=True)
@click.option("--split", default="test", show_default=True)
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Directory for metrics.json and predictions.png.")
@click.option("--batch-size", type=int, default=64, show_default=True)
@click.option("--examples", type=int, default=6, show_default=True, help="Objects shown in predictions.png.")
@click.option("--device", default="auto", show_default=True)
def eval_cmd(checkpoint, shards, split, out, batch_size, examples, device):
    """Voxel IoU (0.4, 0.5), mask IoU and pose error per category on a split."""
    from sc3d_train.checkpoint import CheckpointError
    from sc3d_train.data import DataError
    from sc3d_train.evaluate import evaluate

    try:
        result = evaluate(checkpoint, shards, split, out, device, batch_size, examples)
    except (DataError, CheckpointError, ValueError, OSError) as e:
        from sc3d_data.shards import one_line

        raise click.ClickException(one_line(e)) from e
    click.echo(f"{checkpoint} (step {result['step']}) on split {split!r} of {shards}:")
    click.echo(result["table"])
    click.echo(f"wrote {Path(out) / 'metrics.json'} and {Path(out) / 'predictions.png'}")
