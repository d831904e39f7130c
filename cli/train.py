"""``sc3d-train``: train, evaluate and run the 2D-3D self-consistency model."""
import click

from cli.lazy_group import LazyGroup

COMMANDS = {
    "fit": "cli.train_fit:fit",
    "eval": "cli.train_eval:eval_cmd",
    "predict": "cli.train_predict:predict",
    "claims": "cli.train_claims:claims",
}


@click.group(cls=LazyGroup, lazy_commands=COMMANDS)
@click.version_option(package_name="sc3d")
def main():
    """Train the single-image 3D reconstruction model of Liao et al. (2D-3D self-consistency)
    on sc3d shards, evaluate it and predict from images."""
