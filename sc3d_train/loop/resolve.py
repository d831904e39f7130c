"""The full :class:`~sc3d_train.settings.config.RunConfig` of a ``fit`` command: the dataclass defaults,
a config file, the tiny preset, the options given, and the facts of the shards."""
from __future__ import annotations

from pathlib import Path

from sc3d_train.settings.config import RESUMABLE_FIELDS, TINY_MODEL, RunConfig


def resolve_config(options: dict, model_options: dict | None = None, resume: bool = False,
                   config_file: Path | None = None) -> RunConfig:
    """The run's config from the settings given explicitly.

    ``options``: :class:`RunConfig` fields set on the command line (or by a caller such as
    ``claims``); ``model_options``: :class:`~sc3d_train.settings.config.ModelConfig` fields set likewise,
    plus ``tiny`` (bool): the :data:`~sc3d_train.settings.config.TINY_MODEL` preset.

    New run, later wins: the dataclass defaults, ``config_file`` (a run's ``config.yaml``), the
    tiny preset, ``model_options`` and ``options``; then the model's ``image_size`` and
    ``voxel_resolution`` and the dataset facts (views, background, intrinsics, camera distance)
    are read from the shards. ``resume``: the run's saved config, where ``options`` may change
    only :data:`~sc3d_train.settings.config.RESUMABLE_FIELDS` and ``model_options`` nothing."""
    from sc3d_train.loop.checkpoint import CheckpointError
    from sc3d_train.data.dataset import DataError, background_of, scan_objects

    model_options = dict(model_options or {})
    tiny = model_options.pop("tiny", False)
    if resume:
        return _resumed(options, model_options)
    plain = RunConfig.load(config_file).to_dict() if config_file is not None else {}
    plain.update(options)
    if plain.get("out") is None or plain.get("shards") is None:
        raise ValueError("a new run needs --shards and --out (or a --config file that names them)")
    out = Path(plain["out"])
    if plain.get("split") == "test":
        raise DataError("refusing to train on the test split: its evaluation would then measure "
                        "objects the model was trained on; train on 'train' (or 'val')")
    if (out / "checkpoints" / "last.pt").is_file():
        raise CheckpointError(f"{out}: already holds a run (checkpoints/last.pt); use --resume "
                              f"to continue it or choose another --out")
    _, info = scan_objects(Path(plain["shards"]))
    if info["voxel_resolution"] is None:
        raise DataError(f"{plain['shards']}: shards have no voxels; run `sc3d-data voxelize` first")
    model = dict(plain.get("model", {}))
    if tiny:
        model.update(TINY_MODEL)
    model.update(model_options, image_size=info["image_size"], voxel_resolution=info["voxel_resolution"])
    plain.update(model=model, image_size=info["image_size"], num_views=info["num_views"],
                 background=background_of(info), intrinsics=info["K"], camera_distance=info["distance"])
    return RunConfig.from_dict(plain)


def _resumed(options: dict, model_options: dict) -> RunConfig:
    """The saved config of run ``options["out"]`` with the resumable ``options`` applied;
    ``CheckpointError`` listing any other option that differs from the run's."""
    from sc3d_train.loop.checkpoint import CheckpointError

    out = Path(options["out"])
    saved_path = RunConfig.path_in(out)
    if not saved_path.is_file():
        raise CheckpointError(f"{out}: nothing to resume (no {saved_path.name})")
    cfg = RunConfig.load(saved_path)
    changed = []
    for k, v in sorted(options.items()):
        current = getattr(cfg, k)
        same = Path(v).resolve() == Path(current).resolve() if k == "shards" else v == current
        if k in RESUMABLE_FIELDS:
            setattr(cfg, k, v)
        elif not same:
            changed.append(f"--{k.replace('_', '-')} {v!r} (run has {current!r})")
    for k, v in sorted(model_options.items()):
        if v != getattr(cfg.model, k):
            changed.append(f"--{k.replace('_', '-')} {v!r} (run has {getattr(cfg.model, k)!r})")
    if changed:
        raise CheckpointError(f"{out}: cannot change on --resume: " + ", ".join(changed))
    return cfg
