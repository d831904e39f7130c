"""The types of the folder options of ``sc3d-train`` and ``sc3d-data`` (``--shards``, ``--out``,
...): a folder path that refuses an empty value. ``--out ''`` (an unset ``$RUN``) would otherwise be the current
folder, and a run, an evaluation or predictions would land among the user's files. ``FilePath``: the same for
file options (``check --json``, ``render --split-file``)."""
from __future__ import annotations

from pathlib import Path

import click


class FilePath(click.Path):
    """``click.Path(dir_okay=False)`` that fails on an empty (or blank) value: a report file
    (``check --json "$REPORT"``) or a split list given through an unset variable was taken as not
    given (no report written, the default split used) instead of refused. ``what`` the option
    wants, for the message."""

    def __init__(self, what: str = "a file", **kwargs):
        kwargs.setdefault("dir_okay", False)
        super().__init__(**kwargs)
        self.what = what

    def convert(self, value, param, ctx):
        if isinstance(value, str) and value.strip() == "":
            self.fail(f"is empty: give {self.what} (an unset variable?)", param, ctx)
        return super().convert(value, param, ctx)


class FolderPath(FilePath):
    """``click.Path(file_okay=False, path_type=Path)`` that fails on an empty (or blank) value
    (``file_okay=True``: the command names a file given for the folder with its own message)."""

    def __init__(self, file_okay: bool = False):
        super().__init__("a folder", file_okay=file_okay, dir_okay=True, path_type=Path)
