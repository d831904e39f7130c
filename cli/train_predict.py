"""``sc3d-train predict``: option parsing only; the work is ``sc3d_train.evaluation.predict.predict``."""
from __future__ import annotations

from pathlib import Path

import click

from sc3d_cli.folder_path import FolderPath
from sc3d_cli.config_options import config_options
from sc3d_train.settings.command_config import PredictConfig


@click.command()
@click.option("--checkpoint", type=click.Path(path_type=Path), required=True,
              help="A run folder of `sc3d-train fit` (its --pick checkpoint) or a checkpoint file "
              "(e.g. RUN_DIR/checkpoints/last.pt).")
@click.argument("images", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", type=FolderPath(), default=None,
              help="Output directory [RUN_DIR/predictions beside the checkpoint].")
@config_options(PredictConfig)
@click.pass_context
def predict(ctx, checkpoint, images, out, pose_from, device, threshold, pick):
    """Voxels (.binvox, .npz), mesh (.obj), pose (.json) and a picture (.png) per IMAGE."""
    from sc3d_data.io.outlock import LockError
    from sc3d_train.loop.checkpoint import CheckpointError, run_checkpoint
    from sc3d_train.evaluation.predict import ImageError, predict as run_predict

    pick_given = ctx.get_parameter_source("pick") == click.core.ParameterSource.COMMANDLINE
    try:
        checkpoint = run_checkpoint(checkpoint, pick, pick_given)
        results = run_predict(checkpoint, list(images), out, device, threshold, pose_from, pick)
    except (ImageError, CheckpointError, ValueError, OSError, LockError) as e:  # LockError: another eval/predict writes to --out
        from sc3d_data.io.shards import one_line

        raise click.ClickException(one_line(e)) from e
    from sc3d_data.io.names import printable

    for r in results:
        click.echo(f"{printable(r['image'])}: azimuth {r['azimuth_deg']:.1f} deg, elevation {r['elevation_deg']:.1f} deg, "
                   f"{r['occupied_voxels']} voxels -> {printable(Path(r['files']['json']).with_suffix('.*'))}")
