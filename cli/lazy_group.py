"""A click group whose subcommands are imported only when used (fast ``--help``, and a
subcommand's heavy imports, OpenGL or torch, never load for another one)."""
from __future__ import annotations

import importlib
import importlib.util

import click


class LazyGroup(click.Group):
    """``lazy_commands`` maps a command name to ``"module.path:attribute"``."""

    def __init__(self, *args, lazy_commands: dict[str, str] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.lazy_commands = dict(lazy_commands or {})

    def list_commands(self, ctx):
        available = {name for name, target in self.lazy_commands.items()
                     if importlib.util.find_spec(target.split(":")[0]) is not None}
        return sorted(set(super().list_commands(ctx)) | available)

    def get_command(self, ctx, name):
        if name in self.lazy_commands:
            module_name, attr = self.lazy_commands[name].split(":")
            return getattr(importlib.import_module(module_name), attr)
        return super().get_command(ctx, name)


def lazy_main(commands: dict[str, str], doc: str) -> click.Group:
    """The ``main`` of a console script: a versioned :class:`LazyGroup` of ``commands``
    (name -> ``"module.path:attribute"``) whose help text is ``doc``."""

    def main():
        pass

    main.__doc__ = doc
    return click.version_option(package_name="sc3d")(
        click.group(cls=LazyGroup, lazy_commands=commands)(main))
