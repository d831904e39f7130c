"""click options generated from the config dataclasses of :mod:`sc3d_train.settings.config`: one
``--name`` per field declared with ``cli=True`` (``--name/--no-name`` for a bool), its type,
choices, default and help taken from the declaration, so the command line cannot drift from
the dataclasses."""
from __future__ import annotations

import typing
from dataclasses import MISSING

import click

from sc3d_train.settings.config_io import cli_fields, default_of, field_types, option_name

CLICK_TYPES = {int: click.INT, float: click.FLOAT, str: click.STRING}



def _base_type(hint):
    """``int`` for ``int | None`` and the like."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    return args[0] if args else hint


def config_option(f, hint, note: str = ""):
    """The click option of dataclass field ``f`` (type hint ``hint``)."""
    default = default_of(f)
    default = None if default is MISSING else default
    help_text = f.metadata["help"] + (f" {note}" if note else "")
    if _base_type(hint) is bool:
        name = option_name(f)
        return click.option(f"{name}/--no-{name[2:]}", f.name, default=default, show_default=True,
                            help=help_text)
    choices = f.metadata.get("choices")
    kind = click.Choice(choices) if choices else CLICK_TYPES[_base_type(hint)]
    return click.option(option_name(f), f.name, type=kind, default=default,
                        show_default=default is not None, help=help_text)


def config_options(cls, notes: dict | None = None):
    """Decorator adding the options of config dataclass ``cls`` (in field order); ``notes``:
    extra help per field name."""
    hints = field_types(cls)
    notes = notes or {}

    def decorate(fn):
        for f in reversed(cli_fields(cls)):
            fn = config_option(f, hints[f.name], notes.get(f.name, ""))(fn)
        return fn
    return decorate


def given_on_command_line(ctx: click.Context, cls) -> dict:
    """``{field: value}`` of the options of ``cls`` that the command line set (the others keep
    the dataclass default, or the config file's value)."""
    source = click.core.ParameterSource.COMMANDLINE
    return {f.name: ctx.params[f.name] for f in cli_fields(cls)
            if ctx.get_parameter_source(f.name) == source}
