"""Typed config dataclasses <-> plain data (YAML files, checkpoints), and the field helper that
puts a setting's default and its help text in one place.

A config dataclass (:mod:`sc3d_train.settings.config`) declares each setting once with :func:`setting`:
its type (the annotation), its default and the help line the command line shows. Everything
else is derived from that declaration: the ``fit`` options (``cli/config_options.py``), the
YAML file of a run, the config inside a checkpoint.

Plain data is what ``yaml.safe_load`` / ``torch.load(weights_only=True)`` can return: dicts,
lists, str, int, float, bool, None. :func:`from_plain` rebuilds a dataclass from it, nested
dataclasses included, refusing unknown keys and values of the wrong type with the key's path
in the message.
"""
from __future__ import annotations

import types
import typing
from dataclasses import MISSING, field, fields, is_dataclass
from pathlib import Path


class ConfigError(ValueError):
    """A config file or dict that does not describe a valid configuration (one line)."""


def setting(default=MISSING, help: str = "", *, cli: bool = True, choices=None,
            default_factory=MISSING, option: str | None = None):
    """A dataclass field carrying its help text. ``cli``: the command gets an option for it
    (named ``option``, default ``--field-name``); ``choices``: the allowed values."""
    meta = {"help": help, "cli": cli, "choices": tuple(choices) if choices else None, "option": option}
    if default_factory is not MISSING:
        return field(default_factory=default_factory, metadata=meta)
    return field(default=default, metadata=meta)


def cli_fields(cls) -> list:
    """The fields of config dataclass ``cls`` that its command has an option for."""
    return [f for f in fields(cls) if f.metadata.get("cli")]


def option_name(f) -> str:
    """The option of field ``f``: ``--field-name``, or the name its declaration gives."""
    return f.metadata.get("option") or "--" + f.name.replace("_", "-")


def default_of(f):
    """The default value of dataclass field ``f`` (``MISSING`` when it has none)."""
    if f.default_factory is not MISSING:
        return f.default_factory()
    return f.default


def defaults_of(cls) -> dict:
    """``{field name: default}`` of a config dataclass (fields without a default left out)."""
    return {f.name: default_of(f) for f in fields(cls) if default_of(f) is not MISSING}


def field_types(cls) -> dict:
    """``{field name: resolved type hint}`` (the annotations are strings under
    ``from __future__ import annotations``)."""
    return typing.get_type_hints(cls)


def _type_name(hint) -> str:
    return getattr(hint, "__name__", None) or str(hint).replace("typing.", "")


def _convert(value, hint, key: str):
    """``value`` as type ``hint``; ``ConfigError`` naming ``key`` when it is not one."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in (a for a in args if a is not type(None)):
            try:
                return _convert(value, arg, key)
            except ConfigError as e:
                errors.append(e)
        raise errors[0]
    if is_dataclass(hint):
        if isinstance(value, hint):
            return value
        return from_plain(hint, value, key + ".")
    if hint is float and isinstance(value, str):
        try:  # YAML 1.1 reads 2e-4 (no dot) as a string
            return float(value)
        except ValueError:
            pass
    ok = {bool: lambda v: isinstance(v, bool),
          int: lambda v: isinstance(v, int) and not isinstance(v, bool),
          float: lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
          str: lambda v: isinstance(v, str)}
    check = ok.get(hint) or ok.get(origin) or (lambda v: isinstance(v, origin or hint))
    if not check(value):
        raise ConfigError(f"{key}: expected {_type_name(hint)}, got {value!r}")
    if hint is not float:
        return value
    try:
        return float(value)
    except OverflowError:  # an int of 400 digits (YAML reads 1000...0 as int): float() cannot hold it
        raise ConfigError(f"{key}: expected float, got an integer too large for one (above 1.8e308)") from None


def from_plain(cls, data, prefix: str = ""):
    """An instance of config dataclass ``cls`` from plain data: missing keys take their defaults,
    nested dataclass fields are rebuilt from dicts, unknown keys and wrong types raise
    :class:`ConfigError` (``prefix``: the key path of ``data`` in its file, e.g. ``"model."``)."""
    if not isinstance(data, dict):
        raise ConfigError(f"{prefix.rstrip('.') or cls.__name__}: expected a mapping of "
                          f"{cls.__name__} keys, got {type(data).__name__}")
    known = [f.name for f in fields(cls) if f.init]
    unknown = sorted((str(k) for k in set(data) - set(known)), key=str)  # YAML keys may be numbers, true...
    if unknown:
        raise ConfigError(f"unknown {cls.__name__} keys {[prefix + k for k in unknown]}; "
                          f"known: {sorted(known)}")
    missing = [k for k in known if k not in data and default_of(cls.__dataclass_fields__[k]) is MISSING]
    if missing:
        raise ConfigError(f"missing {cls.__name__} keys {[prefix + k for k in missing]}")
    hints = field_types(cls)
    try:
        return cls(**{k: _convert(v, hints[k], prefix + k) for k, v in data.items()})
    except ConfigError:
        raise
    except (ValueError, TypeError) as e:  # __post_init__ checks
        where = prefix.rstrip(".")
        raise ConfigError((f"{where}: " if where else "") + " ".join(str(e).split())) from e


def check_choices(obj) -> None:
    """``ValueError`` when a field of config dataclass ``obj`` declared with ``choices`` holds
    another value."""
    for f in fields(obj):
        choices = f.metadata.get("choices")
        if choices and getattr(obj, f.name) not in choices:
            raise ValueError(f"{f.name} must be one of {', '.join(choices)}, got {getattr(obj, f.name)!r}")


def dump_yaml(data: dict, header: str = "") -> str:
    """``data`` (plain) as YAML text: keys in field order, one per line, lists inline."""
    import yaml

    class Dumper(yaml.SafeDumper):
        pass

    Dumper.add_representer(list, lambda d, v: d.represent_sequence("tag:yaml.org,2002:seq", v, flow_style=True))
    text = yaml.dump(data, Dumper=Dumper, sort_keys=False, default_flow_style=False, width=100)
    return "".join(f"# {line}\n" for line in header.splitlines()) + text


def _unique_keys_loader():
    """yaml's ``SafeLoader`` refusing a key given twice in one mapping (``steps: 700`` and, lines
    below, ``steps: 7000``: safe_load kept the last without a word)."""
    import yaml

    class UniqueKeysLoader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            seen = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":  # "<<: *anchor": keys merged, not repeated
                    continue
                key = self.construct_object(key_node, deep=deep)
                if not isinstance(key, (str, int, float, bool)):
                    continue  # an unhashable key: the base constructor names it
                if (type(key), key) in seen:  # by type too: 1 and true are two keys
                    raise yaml.constructor.ConstructorError(None, None, f"key {key!r} given twice",
                                                            key_node.start_mark)
                seen.add((type(key), key))
            return super().construct_mapping(node, deep)

    return UniqueKeysLoader


def load_yaml(path: Path) -> dict:
    """The mapping in YAML (or JSON) file ``path``; ``ConfigError`` naming the file when it is
    missing, unreadable, not text (a checkpoint given as ``--config``), not YAML or not a mapping."""
    import yaml

    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise ConfigError(f"{path}: cannot read config ({e.strerror or e})") from e
    except UnicodeDecodeError as e:  # a checkpoint or a picture given as --config
        raise ConfigError(f"{path}: not a YAML config file (not UTF-8 text: byte {e.object[e.start]:#04x} at "
                          f"offset {e.start}; a checkpoint is resumed with --resume, not --config)") from e
    try:
        data = yaml.load(text, Loader=_unique_keys_loader())
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{path}: not valid YAML{where} ({getattr(e, 'problem', None) or e})") from e
    except ValueError as e:  # a value its reader cannot build: an int over Python's 4300-digit limit
        raise ConfigError(f"{path}: a value that YAML cannot read ({' '.join(str(e).split(';')[0].split())[:160]})") from e
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of settings, got {type(data).__name__}")
    return data


def markdown_table(cls) -> str:
    """The fields of config dataclass ``cls`` as a markdown table (key, default, ``fit``
    option, meaning): the tables of docs/config.md, which a test compares with this."""
    import json

    rows = ["| key | default | option | meaning |", "|---|---|---|---|"]
    for f in fields(cls):
        d = default_of(f)
        default = ("required" if d is MISSING else "see below" if is_dataclass(d)
                   else f"`{json.dumps(d)}`")
        name = option_name(f)
        option = "-"
        if f.metadata.get("cli"):
            option = f"`{name}/--no-{name[2:]}`" if isinstance(d, bool) else f"`{name}`"
        rows.append(f"| `{f.name}` | {default} | {option} | {f.metadata.get('help', '')} |")
    return "\n".join(rows) + "\n"
