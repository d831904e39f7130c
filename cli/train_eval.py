"""``sc3d-train eval``: option parsing only; the work is ``sc3d_train.evaluation.evaluate.evaluate``."""
from __future__ import annotations

from pathlib import Path

import click

from sc3d_cli.folder_path import FolderPath
from sc3d_cli.config_options import config_options
from sc3d_train.settings.command_config import EvalConfig


@click.command("eval")
@click.option("--checkpoint", type=click.Path(path_type=Path), required=True,
              help="A run folder of `sc3d-train fit` (its --pick checkpoint) or a checkpoint file "
              "(e.g. RUN_DIR/checkpoints/last.pt).")
@click.option("--shards", type=FolderPath(), required=True)
@click.option("--out", type=FolderPath(), default=None,
              help="Directory for metrics.json and predictions.png [RUN_DIR/eval_SPLIT beside the checkpoint].")
@config_options(EvalConfig)
@click.pass_context
def eval_cmd(ctx, checkpoint, shards, out, pose_from, device, split, pick, batch_size, examples):
    """Voxel IoU (0.4, 0.5), mask IoU and pose error per category on a split."""
    from sc3d_data.io.outlock import LockError
    from sc3d_train.loop.checkpoint import CheckpointError, run_checkpoint
    from sc3d_train.data.dataset import DataError
    from sc3d_train.evaluation.evaluate import evaluate

    pick_given = ctx.get_parameter_source("pick") == click.core.ParameterSource.COMMANDLINE
    try:
        result = evaluate(run_checkpoint(checkpoint, pick, pick_given), shards, split, out, device, batch_size,
                          examples, pose_from, pick)
    except (DataError, CheckpointError, ValueError, OSError, LockError) as e:  # LockError: another eval/predict writes to --out
        from sc3d_data.io.shards import one_line

        raise click.ClickException(one_line(e)) from e
    click.echo(f"{result['checkpoint']} (step {result['step']}) on split {split!r} of {shards} (pose: {pose_from}):")
    click.echo(result["table"])
    if not result["shards_complete"]:
        click.echo(f"note: {shards} is incomplete (its render was cut short: index.json complete false): these "
                   "figures are of the objects rendered so far")
    if result["differs_from_training"]:
        click.echo(f"note: these shards differ from the checkpoint's training data: "
                   f"{'; '.join(result['differs_from_training'])}; the figures measure the model across that change")
    if result["outside_pose_grid"]:
        low, high = result["pose_grid_elevations"]
        click.echo(f"note: elevations {result['outside_pose_grid']} deg of these shards lie outside the checkpoint's "
                   f"pose grid [{low:g}, {high:g}] deg (model.elevation_min/max): their pose error has a floor")
    if result["azimuth_grid_floor"] >= 0.05:  # render --views 7, R2N2's azimuths: the pose error has a floor
        # the search's azimuth is a grid azimuth; the head's is refined between bins, but trained towards them
        floor = ("is at least" if pose_from == "search" else "tends towards (the head was trained on grid poses)")
        click.echo(f"note: the views' azimuths lie between the checkpoint's pose grid azimuths (every "
                   f"{result['pose_grid_azimuth_step']:g} deg): their azimuth error {floor} "
                   f"{result['azimuth_grid_floor']:.1f} deg on average however good the model")
    if result["trained_on"] is None:
        click.echo(f"note: the checkpoint's training shards cannot be read or no longer hold the objects it trained on "
                   f"(moved, or re-rendered with another split), and {shards} does not hold them as recorded: whether "
                   "evaluated objects were trained on is unknown")
    elif result["trained_on"]:
        click.echo(f"note: {result['trained_on']} of the {result['overall']['objects']} evaluated objects are objects the "
                   f"checkpoint was trained on: these figures are not of held-out objects")
    if result["categories_not_trained_on"]:
        from sc3d_data.formats.shapenet import category_label

        unseen = ", ".join(category_label(c) for c in result["categories_not_trained_on"])
        click.echo(f"note: the checkpoint's run had no training object of {unseen}: their figures, and the mean over "
                   "categories, measure the model on categories it never saw")
    if result["selected_on_this_split"]:
        click.echo(f"note: {result['checkpoint']} was chosen (best of its validations) on these {split!r} objects, so "
                   "these figures are optimistic; evaluate " + ("on objects it was not chosen on, or " if split == "test"
                                                               else "on --split test or ") + "with --pick last")
    out = Path(result["out"])
    pictures = f" and {out / 'predictions.png'}" if (out / "predictions.png").is_file() else " (--examples 0: no picture)"
    click.echo(f"wrote {out / 'metrics.json'}{pictures}")
