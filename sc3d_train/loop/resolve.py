"""The full :class:`~sc3d_train.settings.config.RunConfig` of a ``fit`` command: the dataclass defaults,
a config file, the tiny preset, the options given, and the facts of the shards."""
from __future__ import annotations

import os
from pathlib import Path

from sc3d_train.loop.config_file import MODE_ONLY_OPTIONS, data_changes, file_settings
from sc3d_train.loop.run_folder import check_no_foreign_files, check_no_linked_files, check_path_names
from sc3d_train.settings.config import CONFIG_NAME, OBJECT_ORDERS, RESUMABLE_FIELDS, TINY_MODEL, RunConfig
from sc3d_train.settings.config_io import defaults_of, load_yaml


def resolve_config(options: dict, model_options: dict | None = None, resume: bool = False,
                   config_file: Path | None = None) -> RunConfig:
    """The run's config from the settings given explicitly.

    ``options``: :class:`RunConfig` fields set on the command line (or by a caller such as
    ``claims``); ``model_options``: :class:`~sc3d_train.settings.config.ModelConfig` fields set likewise,
    plus ``tiny`` (bool): the :data:`~sc3d_train.settings.config.TINY_MODEL` preset.

    New run, later wins: the dataclass defaults, ``config_file`` (a run's ``config.yaml``;
    ``loop.config_file.file_settings``), the tiny preset,
    ``model_options`` and ``options``; then the facts of the shards (:func:`shard_facts`). ``resume``: the run's
    saved config, where ``options`` may change only :data:`~sc3d_train.settings.config.RESUMABLE_FIELDS` and
    ``model_options`` nothing."""
    from sc3d_train.loop.checkpoint import CheckpointError
    from sc3d_train.data.dataset import DataError

    model_options = dict(model_options or {})
    tiny = model_options.pop("tiny", False)
    options = absolute_paths(options)
    if resume:
        return _resumed(options, model_options, tiny)
    plain = file_settings(config_file, options) if config_file is not None else {}
    in_file = load_yaml(config_file) if config_file is not None else {}
    if plain.get("steps_before") and "steps" in options and options["steps"] != in_file.get("steps"):
        if os.environ.get("RANK", "0") == "0":
            print(f"note: {config_file} is of a run extended with --resume --steps (steps_before "
                  f"{plain['steps_before']}); with --steps {options['steps']} this run follows one schedule of "
                  f"{options['steps']} steps")
        plain["steps_before"] = None
    if "object_order" not in in_file:  # a run's config of an earlier version keeps its order: the repeat is exact
        plain["object_order"] = "shards" if "objects_sha256" in in_file else OBJECT_ORDERS[0]
    plain.update(options)
    if plain.get("out") is None or plain.get("shards") is None:
        raise ValueError("a new run needs --shards and --out (or a --config file that names them)")
    plain = absolute_paths(plain)  # a --config file's relative paths too
    check_path_names(plain)
    out = Path(plain["out"])
    if plain.get("split") == "test":
        raise DataError("refusing to train on the test split: its evaluation would then measure "
                        "objects the model was trained on; train on 'train' (or 'val')")
    if (out / "checkpoints" / "last.pt").is_file():
        raise CheckpointError(f"{out}: already holds a run (checkpoints/last.pt); use --resume "
                              f"to continue it or choose another --out")
    from sc3d_train.loop.validation import best_of_an_early_stop

    stale = [] if best_of_an_early_stop(out) else sorted(f.name for f in (out / "checkpoints").glob("*.pt"))
    if stale:  # a run without last.pt (deleted, or its write failed): eval/--resume would read these
        raise CheckpointError(f"{out}: already holds checkpoints of a run ({', '.join(stale)}) but no "
                              f"last.pt; use --resume to continue it, or choose another --out")
    check_no_linked_files(out)
    check_no_foreign_files(out)
    facts = shard_facts(Path(plain["shards"]), plain.get("split", "train"), plain.get("val_split", "val"))
    changes = data_changes(in_file, plain, facts) if config_file is not None else []
    if changes and os.environ.get("RANK", "0") == "0":  # trained on, but no repeat of the file's run
        print(f"note: {plain['shards']}: not the data the run of {config_file} was trained on "
              f"({', '.join(changes)}); this run does not repeat it")
    if (size := facts["model.image_size"]) % 32:  # ModelConfig's own refusal named no shards
        from sc3d_train.data.dataset import DataError

        raise DataError(f"{plain['shards']}: its views are {size}x{size} px; the model takes a multiple of 32 "
                        "(5 stride-2 blocks): render them with --image-size 64 (or 32, 128)")
    model = dict(plain.get("model", {}))
    if tiny:
        model.update(TINY_MODEL)
    model.update(model_options, image_size=facts.pop("model.image_size"),
                 voxel_resolution=facts.pop("model.voxel_resolution"))
    plain.update(model=model, **facts)
    return RunConfig.from_dict(plain)


def absolute_paths(settings: dict) -> dict:
    """``settings`` with ``shards`` and ``decoded_cache`` absolute, a relative one read from the
    current folder (given as an option or in a ``--config`` file), so that the run's
    ``config.yaml`` resumes from anywhere."""
    return {**settings, **{k: str(Path(settings[k]).resolve()) for k in ("shards", "decoded_cache") if settings.get(k)}}


def shard_facts(shards: Path, split: str, val_split: str) -> dict:
    """What a run takes from its shards, keyed like :func:`run_facts`: the model's image size
    and voxel resolution, the dataset facts (views, background, intrinsics, camera distance),
    ``objects_sha256``, the SHA-256 of the sorted ``category/model_id`` of the objects of
    ``split`` (the objects the run trains on), and ``val_objects_sha256``, that of ``val_split``
    (the objects ``best.pt`` is chosen on). ``DataError`` when the shards have no voxels, voxels of
    two resolutions, or a render left them incomplete."""
    from sc3d_train.data.completeness import require_complete
    from sc3d_train.data.dataset import DataError, background_of, require_one_voxel_resolution, scan_objects
    from sc3d_train.loop.front_axis import front_as_auto

    require_complete(Path(shards))
    refs, info = scan_objects(Path(shards))
    require_one_voxel_resolution(Path(shards), info)
    if info["voxel_resolution"] is None:
        raise DataError(f"{shards}: shards have no voxels; run `sc3d-data voxelize` first")
    return {"model.image_size": info["image_size"], "model.voxel_resolution": info["voxel_resolution"],
            "image_size": info["image_size"], "num_views": info["num_views"], "background": background_of(info),
            "intrinsics": info["K"], "camera_distance": info["distance"], "camera_distance_range": info["distance_range"],
            "objects_sha256": objects_digest(refs, split), "val_objects_sha256": objects_digest(refs, val_split),
            "view_setup": view_setup(front_as_auto(info["settings"], shards))}


#: render settings that change the images without changing their size, camera K or distance
VIEW_SETUP_KEYS = ("elevations", "up", "front", "normalize")


def view_setup(settings: dict) -> str:
    """One line of the render settings (``index.json`` ``settings``) that shape what the views
    show beyond their size and camera: elevations, up and front axes, normalisation, shading
    (``None`` for a setting the shards do not record, as 3D-R2N2's imports)."""
    lighting = settings.get("lighting")
    shading = lighting.get("shading") if isinstance(lighting, dict) else None
    return "; ".join([f"{k} {settings.get(k)}" for k in VIEW_SETUP_KEYS] + [f"shading {shading}"])


def view_setup_but_elevations(setup: str) -> str:
    """A :func:`view_setup` line without its elevations (the first part): what ``eval`` notes
    as a difference from the training data, whose elevations get a note of their own where they
    lie outside the pose grid."""
    return setup.split("; ", 1)[-1]


def objects_digest(refs, split: str) -> str:
    """SHA-256 (hex) of the sorted ``category/model_id`` of the objects of ``split`` among
    ``refs`` (``ObjectRef``s): a run's ``objects_sha256``."""
    import hashlib

    objects = "\n".join(sorted(f"{r.category}/{r.model_id}" for r in refs if r.split == split))
    return hashlib.sha256(objects.encode()).hexdigest()


def run_facts(cfg: RunConfig) -> dict:
    """The facts that run ``cfg`` took from its shards when it started (:func:`shard_facts`)."""
    return {"model.image_size": cfg.model.image_size, "model.voxel_resolution": cfg.model.voxel_resolution,
            "image_size": cfg.image_size, "num_views": cfg.num_views, "background": cfg.background,
            "intrinsics": cfg.intrinsics, "camera_distance": cfg.camera_distance, "camera_distance_range": cfg.camera_distance_range,
            "objects_sha256": cfg.objects_sha256, "val_objects_sha256": cfg.val_objects_sha256, "view_setup": cfg.view_setup}


def check_same_shards(cfg: RunConfig, out: Path) -> None:
    """``CheckpointError`` when the shards of run ``cfg`` (folder ``out``) no longer hold the data
    the run started on (re-rendered at another size, camera, background, elevations, axes,
    normalisation or shading, or with other training objects, or, for a run that validates, other
    validation objects: its best.pt would be chosen by scores on other objects): a resumed run
    would continue on other data. Facts a run of an earlier version did not record (``None``)
    are not compared."""
    from sc3d_train.loop.checkpoint import CheckpointError

    was, now = run_facts(cfg), shard_facts(Path(cfg.shards), cfg.split, cfg.val_split)
    if not cfg.val_every:
        was["val_objects_sha256"] = None  # no validation from here: the split is not read
    if was["camera_distance_range"] is None and len(set(now["camera_distance_range"])) > 1:
        was["camera_distance"] = None  # an earlier version recorded one view's of distances that vary by view
    changed = [k for k, v in was.items() if v is not None and v != now[k]]
    digests = {"objects_sha256": cfg.split, "val_objects_sha256": cfg.val_split}
    if changed:
        names = ", ".join(f"the objects of split {digests[k]!r}" if k in digests else f"{k} {was[k]!r} -> {now[k]!r}"
                          for k in changed)
        raise CheckpointError(f"{cfg.shards}: the shards changed since run {out} started ({names}); --resume "
                              f"continues only on the data the run started on: train a new run on them "
                              f"(--config {RunConfig.path_in(out)} --out NEW_DIR)")


def _resumed(options: dict, model_options: dict, tiny: bool = False) -> RunConfig:
    """The saved config of run ``options["out"]`` with the resumable ``options`` applied (``--shards``
    may name a moved copy: :func:`check_same_shards` holds it to the run's data); ``CheckpointError``
    listing any other option that differs from the run's (``tiny``: the tiny preset asked for, an
    error unless the run's model already is it)."""
    from sc3d_train.loop.checkpoint import CheckpointError
    from sc3d_train.loop.runtime import same_in_effect

    out = Path(options["out"])
    check_no_linked_files(out)
    cfg = saved_config(out)
    changed = []
    for k, v in sorted(options.items()):
        current = getattr(cfg, k)
        same = Path(v).resolve() == Path(current).resolve() if k == "shards" else v == current
        if k == "shards" and not same and cfg.objects_sha256 is None:  # a run of an earlier version
            changed.append(f"--shards {v!r} (run has {current!r}, and records no digest of its objects to compare)")
        elif k in RESUMABLE_FIELDS:
            setattr(cfg, k, v)
        elif not same and not same_in_effect(cfg, k, v, options.get("device", cfg.device)):
            changed.append(f"--{k.replace('_', '-')} {v!r} (run has {current!r})")
    asked = {**(TINY_MODEL if tiny else {}), **model_options}  # the tiny preset, then explicit options
    for k, v in sorted(asked.items()):
        if v != getattr(cfg.model, k):
            via = "" if k in model_options else " (from --tiny)"
            changed.append(f"--{k.replace('_', '-')} {v!r}{via} (run has {getattr(cfg.model, k)!r})")
    if changed:
        raise CheckpointError(f"{out}: cannot change on --resume: " + ", ".join(changed))
    if cfg.mode == "semi" and cfg.steps < (cfg.pretrain_steps or 0):
        raise CheckpointError(f"{out}: --steps {cfg.steps} ends inside this semi run's pretraining "
                              f"({cfg.pretrain_steps} steps), which --resume cannot shorten; to train further give a "
                              f"--steps above both {cfg.pretrain_steps} and the step its last checkpoint reached")
    cfg = RunConfig.from_dict(cfg.to_dict())  # the new values pass the checks a new run's do
    if not Path(cfg.shards).is_dir():
        raise CheckpointError(f"{cfg.shards}: the shard folder of run {out} does not exist; if it moved, resume "
                              "with --shards NEW_FOLDER (held to the data the run started on)")
    check_same_shards(cfg, out)
    return cfg


def saved_config(out: Path) -> RunConfig:
    """The config of run ``out`` for ``--resume``: its ``config.yaml``, or, where that file is
    missing or does not load (deleted, cut short) and the run has a checkpoint, the config the
    newest checkpoint holds (the one ``config.yaml`` must equal anyway: ``--resume`` refuses a
    difference), written back as ``config.yaml`` on rank 0 with one ``note:`` line.
    ``CheckpointError`` when there is neither, or a folder stands where ``config.yaml`` goes."""
    from sc3d_train.loop.checkpoint import CheckpointError, checkpoint_config, checkpoint_dir
    from sc3d_train.loop.checkpoint_resume import resume_checkpoint

    saved_path = RunConfig.path_in(out)
    problem = "is missing"
    if saved_path.exists() and not saved_path.is_file():  # fit writes config.yaml there: it must go first
        raise CheckpointError(f"{saved_path}: is not a file; move it away, and --resume reads the run's config "
                              "from its checkpoints")
    if saved_path.is_file():
        try:
            return RunConfig.load(saved_path)
        except ValueError as e:
            if not any(checkpoint_dir(out).glob("*.pt")):
                raise
            problem = f"does not load ({e})"
    if not any(checkpoint_dir(out).glob("*.pt")):
        raise CheckpointError(f"{out}: nothing to resume (no {saved_path.name} and no checkpoint)")
    ckpt_file, ckpt = resume_checkpoint(out)
    cfg = checkpoint_config(ckpt_file, ckpt)
    if os.environ.get("RANK", "0") == "0":  # one writer under torchrun; config.yaml, never over a legacy file
        cfg.save(Path(out) / CONFIG_NAME)
        written = "written back" if saved_path.name == CONFIG_NAME else f"written to {CONFIG_NAME}"
        print(f"note: {saved_path} {problem}; the run's config is read from {ckpt_file} and {written}")
    return cfg


def check_mode_options(cfg: RunConfig, given: dict, config_file: Path | None = None) -> None:
    """``ValueError`` when an option given on the command line (``given``), or a setting of a new
    run's ``config_file`` that differs from its default, is one that the run's mode does not read
    (``--labeled-fraction`` without ``--semi`` or ``--labeled-only``; ``pretrain_steps: 2`` in a
    file without ``mode: semi``): it would be recorded in ``config.yaml`` and silently ignored.
    (A run's own ``config.yaml`` records these settings at their defaults outside their modes; a
    file's settings of its own ``mode:``, switched by ``--semi``/``--labeled-only``, were reset.)"""
    ignored = [k for k, modes in MODE_ONLY_OPTIONS.items() if k in given and cfg.mode not in modes]
    if ignored:
        names = ", ".join(f"--{k.replace('_', '-')} {_read_by(k)}" for k in ignored)
        modes = sorted({m for k in ignored for m in MODE_ONLY_OPTIONS[k]})
        raise ValueError(f"{names}: not read by a {cfg.mode} run (config.yaml would record it, training ignore it); "
                         f"train in a mode that reads it ({', '.join('--' + m for m in modes)}) or leave it out")
    in_file = load_yaml(config_file) if config_file is not None else {}
    defaults = defaults_of(RunConfig)
    set_there = [k for k, modes in MODE_ONLY_OPTIONS.items() if k in in_file and in_file[k] != defaults[k]
                 and cfg.mode not in modes and in_file.get("mode", defaults["mode"]) not in modes]
    if set_there:
        names = ", ".join(f"{k}: {in_file[k]!r} {_read_by(k)}" for k in set_there)
        raise ValueError(f"{config_file}: {names}: not read by a {cfg.mode} run (config.yaml would record it, training "
                         "ignore it); set the mode that reads it (mode: in the file, or --semi / --labeled-only) or "
                         "leave it out")


def _read_by(setting: str) -> str:
    """``(read by semi and labeled-only runs)``: the modes of a :data:`MODE_ONLY_OPTIONS` setting."""
    return f"(read by {' and '.join(MODE_ONLY_OPTIONS[setting])} runs)"


def pose_grid_warning(cfg: RunConfig) -> str | None:
    """One line when the view elevations of ``cfg.shards`` (``index.json`` ``settings.elevations``,
    degrees) fall outside the run's pose grid ``[model.elevation_min, model.elevation_max]``: the
    pose head cannot predict them (its targets are the best-fitting grid poses, ``pose_search``).
    Not refused (existing datasets stay trainable; a run may mean it); None when all fit."""
    from sc3d_data.io.shards import load_index
    from sc3d_train.paper.pose import PoseGrid

    elevations = load_index(Path(cfg.shards)).get("settings", {}).get("elevations")
    outside = PoseGrid.of(cfg.model).outside(elevations)
    if not outside:
        return None
    m = cfg.model
    return (f"{cfg.shards}: views at elevations {outside} deg lie outside the pose grid "
            f"[{m.elevation_min:g}, {m.elevation_max:g}] deg: the pose head cannot predict them (its targets are the "
            "best-fitting grid poses); to cover them set model.elevation_min / model.elevation_max in a --config file")
