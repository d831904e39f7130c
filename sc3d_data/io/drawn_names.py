"""Names written into pictures (``preview``'s contact sheet, ``check --png``'s worst objects,
``eval``'s predictions.png): what the picture's font cannot draw is escaped, what is too wide is cut.

- A character the font in use has no glyph for was drawn as an empty box ("tofu"), so ``椅子`` and
  ``ジープ`` could not be told apart, and matplotlib printed a ``UserWarning: Glyph ... missing from
  font(s)`` per character onto stderr. It is written as ``\\uXXXX`` (``\\UXXXXXXXX`` above U+FFFF),
  as :func:`~sc3d_data.io.names.printable` writes a byte that is not UTF-8 (control characters go
  through ``printable`` first): ``椅子`` is drawn ``\\u6905\\u5b50``, which names the folder exactly.
- Which characters a font draws is read from that font's own character map, not from a range:
  PIL's default font (``preview``) is a small one without accents, so ``é`` is drawn ``\\u00e9``
  there; matplotlib's font (DejaVu Sans, and the fallbacks its font manager picks for the
  ``font.family`` in use) draws ``é`` but no CJK.
- A name wider than its place is cut and ended with ``...``, measured with the same font.
"""
from __future__ import annotations

import io
import re
from functools import lru_cache
from typing import Callable

from sc3d_data.io.names import printable

__all__ = ["escaped", "fitted", "pil_name", "pil_has_glyph", "mpl_name", "mpl_has_glyph", "mpl_width"]

#: what :func:`fitted` cuts between: an escape of :func:`escaped` or ``printable`` whole, else a character
_TOKEN = re.compile(r"\\(?:u[0-9a-f]{4}|U[0-9a-f]{8}|x[0-9a-f]{2}|[ntr])|.", re.DOTALL)


def _escape(ch: str) -> str:
    code = ord(ch)
    return f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}"


def escaped(text, has_glyph: Callable[[str], bool]) -> str:
    """``printable(text)`` (a tab as ``\\t``...) with every character that ``has_glyph`` says the
    font cannot draw written as ``\\uXXXX``."""
    return "".join(ch if has_glyph(ch) else _escape(ch) for ch in printable(text))


def fitted(text: str, width: float, length: Callable[[str], float]) -> str:
    """``text``, cut and ended with ``...`` where ``length(text)`` (in the unit of ``width``) is
    wider than ``width``; an escape goes whole, never cut in its middle (a half ``\\u59`` would
    read as another name)."""
    if length(text) <= width:
        return text
    tokens = _TOKEN.findall(text)
    low, high = 0, len(tokens)  # the longest fitting cut, by bisection (a 200-letter name: 8 measures)
    while low < high:
        mid = (low + high + 1) // 2
        low, high = (mid, high) if length("".join(tokens[:mid]) + "...") <= width else (low, mid - 1)
    return "".join(tokens[:low]) + "..."


# -- PIL (preview) -----------------------------------------------------------------------------


def pil_has_glyph(font) -> Callable[[str], bool]:
    """Whether PIL font ``font`` draws a character: a FreeType font's character map (read through
    matplotlib's FreeType binding, as PIL has no call for it; PIL's default font is such a font
    held in memory), else, for PIL's bitmap fallback font, printable ASCII only."""
    from PIL import ImageFont

    if not isinstance(font, ImageFont.FreeTypeFont):
        return lambda ch: " " <= ch <= "~"
    path = font.path
    key = path.getvalue() if isinstance(path, io.BytesIO) else str(path)
    return lambda ch: _pil_glyph(key, ch)


@lru_cache(maxsize=4096)
def _pil_glyph(key, ch: str) -> bool:
    return _ft2font(key).get_char_index(ord(ch)) != 0


@lru_cache(maxsize=8)
def _ft2font(key):
    """matplotlib's ``FT2Font`` of a font file's path, or of its bytes (kept open while cached)."""
    from matplotlib.ft2font import FT2Font

    return FT2Font(io.BytesIO(key) if isinstance(key, bytes) else key)


def pil_name(text, width: float, font=None) -> str:
    """``text`` as PIL ``font`` (None: PIL's default font, which ``ImageDraw.text`` draws with)
    draws it: :func:`escaped`, then :func:`fitted` to ``width`` pixels."""
    from PIL import ImageFont

    font = ImageFont.load_default() if font is None else font
    return fitted(escaped(text, pil_has_glyph(font)), width, font.getlength)


# -- matplotlib (check --png, eval) ------------------------------------------------------------


def _font_properties(fontsize: float):
    from matplotlib.font_manager import FontProperties

    return FontProperties(size=fontsize)


def _mpl_font_paths(prop) -> tuple[str, ...]:
    """The font files matplotlib draws ``prop``'s text with: its first choice and the fallbacks
    of the ``font.family`` list (``_find_fonts_by_props``; its first choice alone where a
    matplotlib lacks that call)."""
    from matplotlib import font_manager

    find = getattr(font_manager.fontManager, "_find_fonts_by_props", None)
    paths = find(prop) if find is not None else [font_manager.findfont(prop)]
    return tuple(str(p) for p in paths)


@lru_cache(maxsize=4096)
def _mpl_glyph(paths: tuple[str, ...], ch: str) -> bool:
    from matplotlib import font_manager

    return any(font_manager.get_font(p).get_char_index(ord(ch)) != 0 for p in paths)


def mpl_has_glyph(fontsize: float = 10) -> Callable[[str], bool]:
    """Whether matplotlib's font for text of ``fontsize`` (the rcParams' family) draws a character."""
    paths = _mpl_font_paths(_font_properties(fontsize))
    return lambda ch: _mpl_glyph(paths, ch)


def mpl_width(text: str, fontsize: float) -> float:
    """Width in points of ``text`` drawn by matplotlib at ``fontsize`` (not read as mathtext)."""
    from matplotlib.textpath import TextToPath

    return TextToPath().get_text_width_height_descent(text, _font_properties(fontsize), ismath=False)[0]


def mpl_name(text, width_pt: float, fontsize: float) -> str:
    """``text`` as matplotlib draws it at ``fontsize``: :func:`escaped`, then :func:`fitted` to
    ``width_pt`` points. Draw it with ``parse_math=False``: a name holding two ``$`` is a name,
    not a formula."""
    return fitted(escaped(text, mpl_has_glyph(fontsize)), width_pt, lambda s: mpl_width(s, fontsize))
