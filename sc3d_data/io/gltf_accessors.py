"""The data layout of a glTF/GLB document (buffers, bufferViews, accessors) judged from its JSON,
so that a layout the loader cannot read is refused in one line, not in the loader's own words.

trimesh's glTF loader (``trimesh.exchange.gltf``, 5.x) slices every bufferView out of its buffer
and reads every accessor, drawn or not, before it builds a single mesh; a layout it cannot follow
stops the whole file with ``KeyError: 'uri'``, ``IndexError: list index out of range``, ``cannot
reshape array of size 9 into shape (1000000000,3)`` or a bare ``AssertionError``. So every buffer,
bufferView and accessor is judged here, and every primitive's accessor references
(:func:`layout_problems`); an accessor is named with its first use (``POSITION of mesh 0``).

Judged: a buffer of a .gltf without ``uri``; in a .glb, buffer 0 without ``uri`` and no BIN
chunk, or another buffer without ``uri``; a buffer whose ``data:`` URI has no ``base64,`` or a
base64 that does not decode, and an image whose ``data:`` URI has no ``base64,``
(:func:`data_uri_fault`: the loader said "FileNotFoundError: data:...: not found" or binascii's
"Invalid base64-encoded string", naming neither); a bufferView naming no buffer of the file or reaching
beyond its buffer's ``byteLength`` (or the data there is: the BIN chunk's header, the length of
a base64 data URI, or the size of an external file named as written that lies in the mesh's own
folder; nothing else is opened, no uri is followed out of the folder, a missing file is left to
the loader, which names it); an
accessor naming no bufferView of the file, with a ``count`` that is not a whole number >= 0, an
unknown ``componentType`` or ``type``, or elements reaching beyond its bufferView (accessor
``byteOffset`` + ``count`` elements, at the view's ``byteStride`` when it has one); a primitive
naming no accessor of the file, or without POSITION where the loader reads it. An accessor
without ``bufferView`` is legal (it reads as zeros, which the loader does) and left alone, except
as a primitive's POSITION: all its points at the origin, nothing to draw, and the loader stopped
with ``UnboundLocalError`` (a Draco-compressed file's accessors have none: its own refusal says why).
"""
from __future__ import annotations

import base64
import binascii
import json
import os
import stat
import struct
from pathlib import Path

from sc3d_data.io.lfs_pointers import file_lfs_pointer

__all__ = ["COMPONENT_BYTES", "TYPE_COMPONENTS", "data_uri_fault", "layout_problems"]

#: bytes of one component of each glTF ``componentType``
COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
#: components of one element of each glTF accessor ``type``
TYPE_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
#: primitive modes whose POSITION the loader reads (points, lines, triangles, strips)
_POSITION_MODES = (0, 1, 4, 5)


def _whole(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _names(value, n: int) -> bool:
    """Whether ``value`` is the index of one of ``n`` items."""
    return _whole(value) and value < n


def _not_whole(what: str, key: str, value) -> str:
    return f"{what} has {key} {json.dumps(value)}, which is not a whole number >= 0"


def _glb_bin_bytes(path: Path) -> int | None:
    """Bytes of GLB ``path``'s BIN chunk (the chunk after the JSON one) that the file holds, from
    the chunk's header and the file's size (the chunk is not read); None without a BIN chunk."""
    with open(path, "rb") as f:
        f.seek(20 + struct.unpack("<I", f.read(16)[12:])[0])
        head = f.read(8)
        if len(head) < 8 or head[4:] != b"BIN\0":
            return None
        return min(struct.unpack_from("<I", head)[0], os.fstat(f.fileno()).st_size - f.tell())


def _base64_bytes(text: str) -> int:
    """Bytes that base64 ``text`` decodes to (each character holds 6 bits; ``=`` pads the last
    group, or is left out), counted without decoding it."""
    return len(text.strip().rstrip("=")) * 3 // 4


def data_uri_fault(uri: str) -> str | None:
    """Why the loader cannot read the data of ``data:`` URI ``uri``, or None: it decodes what follows
    ``base64,`` (without one it looks for a file of that name, "not found"), and a base64 that does
    not decode stopped it with binascii's words; characters outside base64 it would skip, reading
    other bytes than the file's."""
    if "base64," not in uri:
        return "no 'base64,' before its data: glTF embeds data as base64"
    try:
        base64.b64decode("".join(uri.partition("base64,")[2].split()), validate=True)
    except binascii.Error as e:
        return f"its base64 does not decode: {e}"
    return None


def _image_uri_problems(doc: dict) -> list[str]:
    """The images whose ``data:`` URI has no ``base64,``: the loader asks for a file of that name
    whether a texture draws the image or not. (One whose base64 does not decode is judged where
    it is drawn: ``io.materials``; undrawn, it changes nothing.)"""
    return [f"image {i} has a malformed data URI ({fault})" for i, image in enumerate(doc.get("images", []))
            if isinstance(uri := image.get("uri"), str) and uri.startswith("data:") and "base64," not in uri
            and (fault := data_uri_fault(uri))]


def _file_bytes(path: Path, uri: str) -> int | None:
    """Size of the regular file ``uri`` names beside ``path`` (symlinks resolved), as written:
    the first name the resolver tries, so the file it reads when that lies in this folder; None
    otherwise (missing, elsewhere, percent-encoded: the loader reads, reports or refuses it)."""
    folder = Path(os.path.realpath(path)).parent
    file = (folder / uri.strip()).resolve()
    try:
        st = os.stat(file)
    except OSError:
        return None
    return st.st_size if file.is_relative_to(folder) and stat.S_ISREG(st.st_mode) else None


def _buffer_ends(path: Path, doc: dict, problems: list[str]) -> list[tuple[int, str] | None]:
    """Per buffer, ``(bytes, "buffer N (..)")``: the least of its ``byteLength`` and the data
    known to be there, or None when neither is known; a buffer without data goes to ``problems``."""
    glb, ends = Path(path).suffix.lower() == ".glb", []
    for i, buffer in enumerate(doc.get("buffers", [])):
        known = [(buffer["byteLength"], f"buffer {i} ({buffer['byteLength']:,} bytes)")] \
            if _whole(buffer.get("byteLength")) else []
        uri = buffer.get("uri")
        if uri is None and glb and i == 0:
            if (size := _glb_bin_bytes(path)) is None:
                problems.append("buffer 0 has no uri and the file has no BIN chunk to hold it")
            else:
                known.append((size, f"buffer 0, whose BIN chunk holds {size:,} bytes"))
        elif uri is None:
            problems.append(f"buffer {i} has no uri" + (", and only buffer 0 can be the file's BIN chunk" if glb
                                                        else ", which a .gltf needs to name its data"))
        elif not isinstance(uri, str):
            problems.append(f"buffer {i} has uri {json.dumps(uri)}, which is not text")
        elif uri.startswith("data:") and (fault := data_uri_fault(uri)):
            problems.append(f"buffer {i} has a malformed data URI ({fault})")
        elif uri.startswith("data:"):
            size = _base64_bytes(uri.split("base64,", 1)[1])
            known.append((size, f"buffer {i}, whose data URI holds {size:,} bytes"))
        elif "base64," not in uri and (size := _file_bytes(path, uri)) is not None:
            pointer = file_lfs_pointer(Path(os.path.realpath(path)).parent / uri.strip())
            known.append((size, f"buffer {i}, whose file {uri} holds {size:,} bytes"
                                + (f" ({pointer})" if pointer else "")))
        ends.append(min(known) if known else None)
    return ends


def _view_problems(doc: dict, ends: list, problems: list[str]) -> None:
    for j, view in enumerate(doc.get("bufferViews", [])):
        what, b = f"bufferView {j}", view.get("buffer")
        offset, length, stride = view.get("byteOffset", 0), view.get("byteLength"), view.get("byteStride")
        if not _names(b, len(ends)):
            problems.append(f"{what} names buffer {json.dumps(b)}, but the file has {len(ends)}")
        for key, value in (("byteOffset", offset), ("byteLength", length)):
            if not _whole(value):
                problems.append(f"{what} has no {key}" if value is None else _not_whole(what, key, value))
        if stride is not None and not (_whole(stride) and stride > 0):
            problems.append(f"{what} has byteStride {json.dumps(stride)}, which is not a whole number > 0")
        if _names(b, len(ends)) and ends[b] and _whole(offset) and _whole(length) and offset + length > ends[b][0]:
            problems.append(f"{what} (bytes {offset:,} to {offset + length:,}) reaches beyond the end of {ends[b][1]}")


def _accessor_problems(doc: dict, uses: dict[int, str], problems: list[str]) -> None:
    views = doc.get("bufferViews", [])
    draco = "KHR_draco_mesh_compression" in doc.get("extensionsUsed", [])  # its accessors' data is compressed
    for i, a in enumerate(doc.get("accessors", [])):
        what = f"accessor {i}" + (f" ({uses[i]})" if i in uses else "")
        count, ctype, kind, offset = a.get("count"), a.get("componentType"), a.get("type"), a.get("byteOffset", 0)
        found = []
        if not _whole(count):
            found.append(_not_whole(what, "count", count) if "count" in a else f"{what} has no count")
        if ctype not in COMPONENT_BYTES:
            found.append(f"{what} has componentType {json.dumps(ctype)}, which is none of glTF's "
                         f"({', '.join(map(str, COMPONENT_BYTES))})")
        if kind not in TYPE_COMPONENTS:
            found.append(f"{what} has type {json.dumps(kind)}, which is none of glTF's ({', '.join(TYPE_COMPONENTS)})")
        if not _whole(offset):
            found.append(_not_whole(what, "byteOffset", offset))
        v = a.get("bufferView")
        if "bufferView" in a and not _names(v, len(views)):
            found.append(f"{what} names bufferView {json.dumps(v)}, but the file has {len(views)}")
        if "bufferView" not in a and uses.get(i, "").startswith("POSITION ") and not draco \
                and "sparse" not in a:  # the loader stopped
            found.append(f"{what} has no bufferView, so its positions are all zeros (nothing to draw)")
        problems.extend(found)
        if found or "bufferView" not in a or not _whole(length := views[v].get("byteLength")):
            continue  # judged no further, or no bytes read (zeros), or the view's own problem
        elem, stride = COMPONENT_BYTES[ctype] * TYPE_COMPONENTS[kind], views[v].get("byteStride")
        if not (_whole(stride) and stride > 0):
            stride = None  # absent (tightly packed), or the view's own problem
        elif stride < elem:
            problems.append(f"{what} has elements of {elem} bytes, longer than the byteStride {stride} "
                            f"of bufferView {v}")
            continue
        need = offset + (count - 1) * (stride or elem) + elem if count else offset
        if need > length:
            every = f" every {stride} bytes" if stride else ""
            problems.append(f"{what} reaches beyond the end of bufferView {v} ({length:,} bytes): count {count:,} of "
                            f"{elem}-byte elements{every} from byte {offset:,} needs {need:,} bytes")


def _primitive_uses(doc: dict, problems: list[str]) -> dict[int, str]:
    """``{accessor: "ROLE of mesh M"}`` (its first use) over every primitive of every mesh; a
    reference to no accessor of the file, and a missing POSITION, go to ``problems``."""
    n, uses = len(doc.get("accessors", [])), {}
    for m, mesh in enumerate(doc.get("meshes", [])):
        for k, prim in enumerate(mesh.get("primitives", [])):
            refs = list(prim.get("attributes", {}).items())
            if "indices" in prim:
                refs.append(("indices", prim["indices"]))
            if prim.get("mode", 4) in _POSITION_MODES and "POSITION" not in prim.get("attributes", {}):
                problems.append(f"mesh {m} primitive {k} has no POSITION attribute")
            for role, a in refs:
                if not _names(a, n):
                    problems.append(f"mesh {m} primitive {k}'s {role} names accessor {json.dumps(a)}, "
                                    f"but the file has {n}")
                else:
                    uses.setdefault(a, f"{role} of mesh {m}")
    return uses


def layout_problems(path: Path, doc: dict) -> list[str]:
    """What of glTF/GLB ``path``'s data layout (its JSON ``doc``; module doc) the loader cannot
    read, one phrase each: buffers, bufferViews, accessors, then primitives' references, then images' data URIs."""
    problems, references = [], []
    uses = _primitive_uses(doc, references)
    _view_problems(doc, _buffer_ends(path, doc, problems), problems)
    _accessor_problems(doc, uses, problems)
    return problems + references + _image_uri_problems(doc)
