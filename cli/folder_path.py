"""The type of the folder options of ``sc3d-train`` (``--shards``, ``--out``, ...): a folder path
that refuses an empty value. ``--out ''`` (an unset ``$RUN``) would otherwise be the current
folder, and a run, an evaluation or predictions would land among the user's files."""
from __future__ import annotations

from pathlib import Path

import click


class FolderPath(click.Path):
    """``click.Path(file_okay=False, path_type=Path)`` that fails on an empty (or blank) value."""

    def __init__(self):
        super().__init__(file_okay=False, path_type=Path)

    def convert(self, value, param, ctx):
        if isinstance(value, str) and value.strip() == "":
            self.fail("is empty: give a folder (an unset variable?)", param, ctx)
        return super().convert(value, param, ctx)
