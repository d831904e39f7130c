"""``sc3d-train``: train, evaluate and run the 2D-3D self-consistency model."""
from sc3d_cli.lazy_group import lazy_main

COMMANDS = {
    "fit": "sc3d_cli.train_fit:fit",
    "eval": "sc3d_cli.train_eval:eval_cmd",
    "predict": "sc3d_cli.train_predict:predict",
    "claims": "sc3d_cli.train_claims:claims",
}


main = lazy_main(COMMANDS, """Train the single-image 3D reconstruction model of Liao et al. (2D-3D self-consistency)
    on sc3d shards, evaluate it and predict from images.""")
