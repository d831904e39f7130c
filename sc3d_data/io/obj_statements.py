"""Statements of OBJ and MTL text: the lines ``KEYWORD VALUE`` (``mtllib``, ``map_Kd``), found
without a regex over the whole text, which for an OBJ of megabytes costs more than reading it."""
from __future__ import annotations

import re

from sc3d_data.io.line_ends import lf_lines

__all__ = ["loader_lines", "statement_values"]


def loader_lines(text: str) -> str:
    """OBJ ``text`` with its lines as the loader reads them (``io.obj_loader_text.plain_statements``):
    ended by LF where CRLF or CR alone (classic Mac OS), a line continued by ``\\`` joined to the
    next. The text itself where it needs neither (no copy of an OBJ of megabytes)."""
    if "\r" in text:
        text = lf_lines(text)
    return text.replace("\\\n", "") if "\\\n" in text else text


def statement_values(text: str, keyword: str) -> list[str]:
    """The values of the lines of ``text`` that are the statement ``keyword`` (the line
    ``keyword VALUE``, spaces around trimmed), in order. Found with ``str.find``, then each line
    matched: an OBJ of megabytes holds a few such lines, and a regex over its whole text took
    ~20 ms for 3 MB. Lines are the loader's (:func:`loader_lines`)."""
    text = loader_lines(text)
    values, i = [], text.find(keyword)
    pattern = re.compile(rf"\s*{re.escape(keyword)}\s+(.+?)\s*$")
    while i != -1:
        start, end = text.rfind("\n", 0, i) + 1, text.find("\n", i)
        end = len(text) if end == -1 else end
        if (found := pattern.match(text, start, end)) is not None:
            values.append(found.group(1))
        i = text.find(keyword, end)
    return values
