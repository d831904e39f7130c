"""The text of OBJ material files (``.mtl``): how it is decoded, the file name a map statement
gives, and which materials a file defines with which textures.

Conventions:

- **Decoding** (:func:`decode_obj_text`, also of OBJ text): UTF-8, a leading UTF-8 mark (Notepad's) dropped;
  bytes that are not UTF-8 (a Latin-1 or cp1252 file from an old exporter) are kept as lone
  surrogates (``surrogateescape``, as Python names files: ``io.names``), so a texture name
  written in such bytes names the file of exactly those bytes on disk.
- **Map file names** (:func:`map_file_name`): the statement's options (``-s 1 1 1``, ``-clamp
  on``, ``-imfchan r``) are dropped, a name in double quotes loses them, Windows separators become
  ``/``.
- **Materials** (:func:`mtl_materials`): a material is named as trimesh names it (the words after
  ``newmtl`` joined by one space); only its ``map_Kd`` texture is drawn (trimesh reads no other
  map), so a material whose only texture is ``map_Ka`` is noted (``ambient_only``). A ``map_Kd``
  moved by ``-o``/``-s`` is noted with its move (:func:`texture_move`), which the loader applies
  to the texture coordinates of the material's faces.
- **What the loader reads** (:func:`loader_mtl_text`): a colour of one value (``Kd 0.8``) is that
  value three times, as the format says (trimesh dropped the material: default grey). A comment
  after a statement of numbers (``Kd 1.000 1.000 1.000  # white``, as PyTorch3D's tutorial cow
  has it) is cut off: trimesh dropped that colour, so the texture was drawn at 40%. A material
  with a ``map_Kd`` texture but no ``Kd`` is noted (``texture_only``): its texture is drawn as it
  is once loaded (``io.loader_visuals.texture_as_is``), as Blender and MeshLab show it.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["MtlMaterials", "TextureMove", "decode_obj_text", "loader_mtl_text", "loader_reading", "map_file_name",
           "mtl_materials", "read_obj_text", "texture_move"]

#: numbers and switches that follow an option of an MTL map statement (``-s 1 1 1``, ``-clamp on``)
_OPTION_VALUE = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^(on|off)$")
#: options whose value is a word: ``-imfchan r|g|b|m|l|z``, ``-type sphere|cube_top|...``
_WORD_OPTIONS = ("-imfchan", "-type")


def decode_obj_text(data: bytes) -> str:
    """``data`` (an OBJ's or material file's bytes) as text (module doc): UTF-8 without its
    mark, other bytes as lone surrogates."""
    return data.removeprefix(b"\xef\xbb\xbf").decode("utf-8", errors="surrogateescape")


def loader_reading(data: bytes) -> tuple[str, bool]:
    """``(text, utf8)``: an OBJ's or material file's bytes as the loader is given them, UTF-8
    where they are (``utf8`` True), else their Latin-1 reading (each byte one character, so that
    an OBJ and its material files agree on names, and a name keeps the bytes it was written in:
    ``io.texture_resolver``)."""
    try:
        return data.decode("utf-8"), True
    except UnicodeDecodeError:
        return data.decode("latin-1"), False


def read_obj_text(path: Path) -> str:
    """The text of OBJ or material file ``path`` (:func:`decode_obj_text`)."""
    return decode_obj_text(Path(path).read_bytes())


@dataclass(frozen=True)
class TextureMove:
    """How a map statement's ``-o u v w`` (``offset``) and ``-s u v w`` (``scale``) options move
    its texture on the surface: a texture coordinate ``uv`` reads the texture at ``scale * uv +
    offset`` (u and v; w, the depth of 3D textures, does not apply to images), as Blender's OBJ
    importer (a Mapping node: Location, Scale) and three.js's ``MTLLoader`` (``offset``,
    ``repeat``) apply them. Values left out are 0 for ``-o`` and 1 for ``-s`` (the format's
    defaults)."""

    offset: tuple[float, float] = (0.0, 0.0)
    scale: tuple[float, float] = (1.0, 1.0)


def texture_move(value: str) -> TextureMove | None:
    """The :class:`TextureMove` of a map statement's ``value`` (options, then the file name), or
    None where it does not move its texture (no ``-o``/``-s``, or ``-o 0 0 0``, ``-s 1 1 1``)."""
    tokens, found = value.split(), {"-o": [0.0, 0.0], "-s": [1.0, 1.0]}
    for i, token in enumerate(tokens[:-1]):  # the last word is the file name
        if token.lower() in found:
            for k, t in enumerate(tokens[i + 1:min(i + 3, len(tokens) - 1)]):
                if not _OPTION_VALUE.match(t) or t in ("on", "off"):
                    break
                found[token.lower()][k] = float(t)
    move = TextureMove(tuple(found["-o"]), tuple(found["-s"]))
    return None if move == TextureMove() else move


def _clamps_texture(value: str) -> bool:
    """Whether a map statement's options clamp its texture (``-clamp on``)."""
    tokens = [t.lower() for t in value.split()]
    return any(t == "-clamp" and tokens[i + 1:i + 2] == ["on"] for i, t in enumerate(tokens))


#: a comment after an image file's name (``map_Kd tex.png  # diffuse``): the name ends at its extension
_TRAILING_COMMENT = re.compile(r'(?i)^(.*?\.(?:png|jpe?g|tga|bmp|tiff?|gif|webp|dds|exr|hdr|ktx2?|p[bgp]m)"?)\s+#.*$')


def map_file_name(value: str) -> str:
    """The file name of an MTL map statement's value, without its options and without a comment
    after an image file's name: ``"-s 1 1 1 -clamp on tex.png"`` -> ``"tex.png"``,
    ``'"my tex.png"'`` -> ``"my tex.png"``, ``"tex.png  # diffuse"`` -> ``"tex.png"``; Windows
    separators become ``/``. The loader's resolver reads the file this names
    (``io.texture_resolver``), so the loader reads it too."""
    tokens = value.split()
    while len(tokens) > 1 and tokens[0].startswith("-") and not _OPTION_VALUE.match(tokens[0]):
        if tokens.pop(0).lower() in _WORD_OPTIONS and len(tokens) > 1:
            tokens.pop(0)
        while len(tokens) > 1 and _OPTION_VALUE.match(tokens[0]):
            tokens.pop(0)
    name = _TRAILING_COMMENT.sub(r"\1", " ".join(tokens))
    if len(name) >= 2 and name[0] == name[-1] == '"':
        name = name[1:-1]
    return name.replace("\\", "/")


@dataclass
class MtlMaterials:
    """What one material file defines: ``names`` of its materials (in order), ``textures``
    ``[(material, map_Kd file name)]``, ``ambient_only`` ``[(material, map_Ka file name)]`` of
    the materials whose only texture is ``map_Ka``, which is not drawn, ``moves`` ``{material:
    TextureMove}`` of the ``map_Kd`` textures offset or scaled by ``-o``/``-s`` (applied by the
    loader: ``io.loader_visuals.move_texture``), ``clamped`` ``[(material, map_Kd file name)]``
    of those clamped by ``-clamp on``, which the loader does not read (``io.texture_wraps``
    applies it), and ``texture_only``: the materials with a ``map_Kd`` and no ``Kd``."""

    names: list[str] = field(default_factory=list)
    textures: list[tuple[str, str]] = field(default_factory=list)
    ambient_only: list[tuple[str, str]] = field(default_factory=list)
    moves: dict[str, TextureMove] = field(default_factory=dict)
    clamped: list[tuple[str, str]] = field(default_factory=list)
    texture_only: list[str] = field(default_factory=list)


def mtl_materials(text: str) -> MtlMaterials:
    """The materials of material-file ``text`` (module doc). Statements are matched without
    regard to case (``map_kd``, ``NEWMTL``), as trimesh reads them."""
    found, ambient, current, coloured = MtlMaterials(), {}, None, set()
    for line in text.splitlines():
        words = line.split(maxsplit=1)
        if len(words) < 2:
            continue
        key, value = words[0].lower(), words[1].strip()
        if key == "newmtl":
            current = " ".join(value.split())
            found.names.append(current)  # a material defined again is replaced whole, as by the loader
            found.moves.pop(current, None)
            found.clamped = [c for c in found.clamped if c[0] != current]
        elif key == "map_kd":
            found.textures.append((current, map_file_name(value)))
            if (move := texture_move(value)) is not None:
                found.moves[current] = move
            else:  # a later map_Kd of the material replaces an earlier one, as in the loader
                found.moves.pop(current, None)
            found.clamped = [c for c in found.clamped if c[0] != current]  # the loader draws the last map_Kd
            if _clamps_texture(value):
                found.clamped.append(found.textures[-1])
        elif key == "map_ka":
            ambient.setdefault(current, map_file_name(value))
        elif key == "kd":
            coloured.add(current)
    drawn = {material for material, _ in found.textures}
    found.ambient_only = [(m, name) for m, name in ambient.items() if m not in drawn]
    found.texture_only = [m for m in dict.fromkeys(m for m, _ in found.textures) if m not in coloured]
    return found


#: statements of numbers only, after which a ``#`` can only start a comment (``Kd 1 1 1  # white``)
_NUMBER_KEYS = frozenset({"kd", "ka", "ks", "ke", "ns", "ni", "d", "tr", "tf", "illum"})


def loader_mtl_text(text: str) -> str:
    """Material-file ``text`` as the loader is given it (module doc): a comment after a statement
    of numbers cut off, colours of one value spread to three; lines joined by ``\\n``."""
    out = []
    for line in text.splitlines():
        words = line.split()
        if "#" in line and words and words[0].lower() in _NUMBER_KEYS:
            line = line.partition("#")[0].rstrip()
            words = line.split()
        if len(words) == 2 and words[0].lower() in ("kd", "ka", "ks") and _OPTION_VALUE.match(words[1]):
            line = " ".join([words[0]] + [words[1]] * 3)
        out.append(line)
    return "\n".join(out) + "\n"
