"""A ``fit --config FILE``'s settings as a new run takes them, with the options given beside it
(later wins, docs/config.md): the file is loaded (each setting checked, an error naming the file
and the key) with the options it is checked against already in place, its default-looking
pretraining made this run's default, and the settings only its mode reads reset where
``--semi``/``--labeled-only`` switch the mode."""
from __future__ import annotations

from pathlib import Path

from sc3d_train.settings.config import RunConfig
from sc3d_train.settings.config_io import defaults_of, load_yaml

#: options that only some modes read, and those modes
MODE_ONLY_OPTIONS = {"labeled_fraction": ("semi", "labeled-only"), "pretrain_steps": ("semi",),
                     "semi_lr": ("semi",), "semi_labeled_share": ("semi",),
                     "semi_batch_size": ("semi",)}
#: settings a ``--config`` file's own are checked against (``RunConfig``'s checks across settings)
CHECKED_ACROSS = ("split", "val_split", "val_every", "steps", "pretrain_steps")


def given_paths(options: dict) -> dict:
    """What of ``options`` replaces a ``--config`` file's settings as it is loaded: ``shards`` and
    ``out`` where given (they stand in where a hand-written file leaves them out), and the
    settings its others are checked against (:data:`CHECKED_ACROSS`: a file's ``split: val`` with
    ``--val-every 0``, its ``pretrain_steps: 2500`` with ``--steps 3000``, were refused as if the
    option had not been given)."""
    return {k: options[k] for k in ("shards", "out", *CHECKED_ACROSS) if options.get(k) is not None}


def defaulted_pretraining(in_file, file_steps: int | None, options: dict) -> bool:
    """Whether a ``--config`` file's ``pretrain_steps`` (``in_file``; ``file_steps``: the file's
    ``steps``, None where it has none) is the default's value that should follow this run's
    ``--steps`` (``options``): left out of the file, or, with another ``--steps`` given, half the
    file's steps, which a run's own ``config.yaml`` records for a default (docs/config.md); a
    file that gives no ``steps`` wrote its ``pretrain_steps`` by hand."""
    if in_file is None:
        return True
    new_steps = options.get("steps")
    if type(file_steps) is not int:  # no steps, or a wrong type that the file's load names
        return False
    return new_steps is not None and new_steps != file_steps and in_file == file_steps // 2


def file_settings(config_file: Path, options: dict) -> dict:
    """The settings of ``config_file`` (plain data, as ``RunConfig.to_dict``) a new run with
    ``options`` starts from (module doc); ``ConfigError`` naming the file and the key for a
    setting that is not valid, or that contradicts another with the options in place."""
    in_file, given, defaults = load_yaml(config_file), given_paths(options), defaults_of(RunConfig)
    # --semi / --labeled-only switch the file's mode: the settings only its mode reads go back to defaults
    file_mode = in_file.get("mode", defaults["mode"])
    mode = options.get("mode", file_mode)
    reset = [k for k, modes in MODE_ONLY_OPTIONS.items() if file_mode in modes and mode not in modes]
    if defaulted_pretraining(in_file.get("pretrain_steps"), in_file.get("steps"), options):
        reset.append("pretrain_steps")  # [steps // 2] of this run's steps, not the file's
    plain = RunConfig.load(config_file, {**given, "mode": mode}, without=tuple(reset)).to_dict()
    plain.update({k: defaults[k] for k in reset})
    return plain


def data_changes(in_file: dict, plain: dict, facts: dict) -> list[str]:
    """How the shards' ``facts`` (``loop.resolve.shard_facts``) differ from those a run's
    ``config.yaml`` (``in_file``) recorded, one phrase each (``"camera_distance 2.0 -> 3.0"``):
    its shards re-rendered in place, or other ``--shards``. A new run (``plain``: its settings)
    trains on them, but is then no repeat of that run, which ``fit`` says in a note. Facts a
    hand-written file leaves out are not compared, nor the objects of a split the run renames."""
    was = {**in_file, **{f"model.{k}": v for k, v in (in_file.get("model") or {}).items()}}
    skip = {"objects_sha256": plain.get("split") != in_file.get("split"),
            "val_objects_sha256": not plain.get("val_every") or plain.get("val_split") != in_file.get("val_split")}
    return [(f"the objects of split {plain.get('split' if k == 'objects_sha256' else 'val_split')!r}"
             if k in skip else f"{k} {was[k]!r} -> {now!r}")
            for k, now in facts.items() if was.get(k) is not None and was[k] != now and not skip.get(k)]
