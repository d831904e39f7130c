"""``sc3d-train``: train, evaluate and run the 2D-3D self-consistency model. ``main`` is the
command group (tests call it in-process); the console script runs :func:`console_main`."""
from sc3d_cli.interrupted_exit import console_script
from sc3d_cli.lazy_group import lazy_main

COMMANDS = {
    "fit": "sc3d_cli.train_fit:fit",
    "eval": "sc3d_cli.train_eval:eval_cmd",
    "predict": "sc3d_cli.train_predict:predict",
    "claims": "sc3d_cli.train_claims:claims",
}


main = lazy_main(COMMANDS, """Train the single-image 3D reconstruction model of Liao et al. (2D-3D self-consistency)
    on sc3d shards, evaluate it and predict from images.""")


#: the ``sc3d-train`` console script: :data:`main`, left at once after Ctrl-C
#: (``interrupted_exit``: Python's finalisation could spin forever after an interrupt)
console_main = console_script(main)
