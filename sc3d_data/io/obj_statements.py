"""Statements of OBJ and MTL text: the lines ``KEYWORD VALUE`` (``mtllib``, ``map_Kd``), found
without a regex over the whole text, which for an OBJ of megabytes costs more than reading it."""
from __future__ import annotations

import re

__all__ = ["statement_values"]


def statement_values(text: str, keyword: str) -> list[str]:
    """The values of the lines of ``text`` that are the statement ``keyword`` (the line
    ``keyword VALUE``, spaces around trimmed), in order. Found with ``str.find``, then each line
    matched: an OBJ of megabytes holds a few such lines, and a regex over its whole text took
    ~20 ms for 3 MB."""
    values, i = [], text.find(keyword)
    pattern = re.compile(rf"\s*{re.escape(keyword)}\s+(.+?)\s*$")
    while i != -1:
        start, end = text.rfind("\n", 0, i) + 1, text.find("\n", i)
        end = len(text) if end == -1 else end
        if (found := pattern.match(text, start, end)) is not None:
            values.append(found.group(1))
        i = text.find(keyword, end)
    return values
