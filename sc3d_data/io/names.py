"""Names from disk: which ones sc3d can store, and how they are printed.

Conventions
-----------
- Python gives a file name whose bytes are not valid UTF-8 as a ``str`` holding lone surrogates
  (``os.fsdecode``'s ``surrogateescape``: byte ``0xff`` becomes ``'\\udcff'``);
  ``os.fsencode(name)`` gives the exact bytes back. ``index.json`` stores such a name as that
  ``str`` (JSON writes the surrogate as ``\\udcff``), so ``os.fsencode(entry["source"])`` is the
  file's exact name: nothing is lost. Shards store names as UTF-8 text, which such a name cannot
  be: ``render`` and ``import-r2n2`` record those objects as failures (:func:`not_utf8`).
- Text that reaches a terminal or a log goes through :func:`printable`: control characters
  (newline, escape, ...) and undecodable bytes are written as backslash escapes (``\\n``,
  ``\\x1b``, ``\\xff``), so a name cannot move the cursor, clear the screen or split a line.
- A path inside a command that a message suggests goes through :func:`shell_word`, so the
  command can be pasted into a shell as it is printed (a space, a quote, a newline).

Example::

    >>> printable("bad\\udcff\\x1b[2J.obj")
    'bad\\\\xff\\\\x1b[2J.obj'
"""
from __future__ import annotations

import unicodedata

__all__ = ["not_utf8", "printable", "shell_word", "split_not_utf8", "normal_forms", "normal_form_note"]

_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}
_CONTROL = ("Cc", "Cf", "Cs", "Zl", "Zp")


def not_utf8(name: str) -> bool:
    """True when ``name`` (a path or file name as ``os`` returns it) holds bytes that are not
    valid UTF-8, i.e. lone surrogates of ``surrogateescape``."""
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        return True
    return False


def _escape(ch: str, keep_newlines: bool) -> str:
    if ch == "\n" and keep_newlines:
        return ch
    if ch in _NAMED:
        return _NAMED[ch]
    code = ord(ch)
    if 0xDC80 <= code <= 0xDCFF:  # a byte that was not UTF-8 (surrogateescape)
        return f"\\x{code - 0xDC00:02x}"
    if code < 0x100:
        return f"\\x{code:02x}"
    return f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}"


def printable(text, keep_newlines: bool = False) -> str:
    """``str(text)`` with every control character (Unicode categories ``Cc``, ``Cf``: newline,
    escape, DEL, bidi overrides; line and paragraph separators) and every undecodable byte
    written as a backslash escape; everything else (accents, CJK, spaces) is kept.
    ``keep_newlines``: leave ``\\n`` as it is (for messages that are several lines by design)."""
    text = str(text)
    if text.isprintable():
        return text
    return "".join(_escape(ch, keep_newlines) if unicodedata.category(ch) in _CONTROL else ch
                   for ch in text)


def shell_word(text) -> str:
    """``str(text)`` as one word that a POSIX shell reads back as it is, for a command printed to be
    pasted: unchanged where it needs no quoting, ``shlex.quote``'s single quotes where every
    character is printable, else bash's ANSI-C quoting ``$'...'`` with :func:`printable`'s escapes
    (an undecodable byte as ``\\xff``, which bash turns back into that byte). A relative path
    that starts with ``-`` (a folder named ``-out``) gets ``./`` before it, so that the command
    reads it as a path, not as options.

    >>> shell_word("my data/out"), shell_word("a\\nb"), shell_word("-out")
    ("'my data/out'", "$'a\\\\nb'", './-out')
    """
    import shlex

    text = str(text)
    if text.startswith("-"):
        text = "./" + text
    if text.isprintable():
        return shlex.quote(text)
    return "$'" + "".join(_shell_escape(ch) for ch in text) + "'"


def _shell_escape(ch: str) -> str:
    """One character inside bash's ``$'...'``: quotes and backslashes escaped, control characters
    as :func:`printable` writes them, except a character from U+0080 to U+00FF as ``\\u00XX``
    (bash's ``\\xXX`` is a byte, which only an undecodable byte is)."""
    if ch in "\\'":
        return "\\" + ch
    if unicodedata.category(ch) not in _CONTROL:
        return ch
    if 0x80 <= ord(ch) < 0x100:
        return f"\\u{ord(ch):04x}"
    return _escape(ch, False)


def split_not_utf8(items: list, path_of, root, verb: str = "not rendered") -> tuple[list, list[dict]]:
    """``(kept, problems)``: the ``items`` whose path ``path_of(item)`` is valid UTF-8 below
    ``root``, and one problem ``{"source", "reason"}`` per outermost file or folder name that is
    not (a folder's problem counts the items under it). ``source`` keeps the name losslessly
    (module doc); the reason names it in :func:`printable` form. ``ValueError`` when ``root``
    itself is not valid UTF-8."""
    from pathlib import Path

    root = Path(root)
    if not_utf8(str(root)):
        raise ValueError(f"{printable(root)}: the path is not valid UTF-8 (shards store names as UTF-8 "
                         "text); rename it")
    kept, bad = [], {}
    for item in items:
        path = Path(path_of(item))
        parts = path.relative_to(root).parts if path != root else ()
        first = next((i for i, part in enumerate(parts) if not_utf8(part)), None)
        if first is None:
            kept.append(item)
        else:
            prefix = root.joinpath(*parts[:first + 1])
            bad[prefix] = bad.get(prefix, 0) + (0 if prefix == path else 1)
    problems = []
    for prefix, under in bad.items():
        what = f" ({under} under this folder)" if under else ""
        problems.append({"source": str(prefix), "reason": f"{printable(prefix)}: the name is not valid UTF-8 "
                         f"(shards store names as UTF-8 text); {verb}{what}: rename it, e.g. with convmv"})
    return kept, problems


def normal_forms(names) -> dict[str, str]:
    """``{NFC form: name}`` of ``names``, for :func:`normal_form_note` (built once: a split file
    may name thousands of ids that match no mesh)."""
    return {unicodedata.normalize("NFC", n): n for n in names}


def normal_form_note(name: str, forms: dict[str, str]) -> str:
    """``"; the meshes have 'cafe\\u0301', ..."`` where ``name`` matches none of the names of ``forms``
    (:func:`normal_forms`) but is one of them in another Unicode normalisation, else ``""``: ``café``
    typed in an editor (NFC, one code point for ``é``) and a file named ``café`` on macOS or in a zip made
    there (NFD, ``e`` and a combining accent) look alike in every message but are different names."""
    twin = forms.get(unicodedata.normalize("NFC", name))
    if twin is None or twin == name:
        return ""
    return (f"; the meshes have {ascii(twin)}, the same text in another Unicode normalisation (NFC/NFD; "
            f"{ascii(name)} here), which looks alike but is another name: write it as the mesh is named")
