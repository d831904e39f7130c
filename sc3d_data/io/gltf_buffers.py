"""The data of a glTF/GLB document's buffers and accessors, read as the format defines them (for
what sc3d computes from a file itself: ``io.gltf_skins``).

A GLB's buffer 0 without ``uri`` is its BIN chunk; a base64 data URI is decoded; another uri names
a file, read through the loader's resolver where one is given (``io.texture_resolver``: inside
the dataset folder), else beside the document inside its folder; nothing else is opened. An
accessor honours its bufferView's ``byteOffset`` and ``byteStride`` and its own ``byteOffset``;
normalized integers are scaled to [0, 1] (unsigned) or [-1, 1] (signed); an accessor without a
bufferView reads as zeros. A sparse accessor is refused (``AccessorError``), not applied.

:class:`FloatBuffer` adds float32 data to a copy of a document (what sc3d computes for the loader:
posed skins, dequantized attributes) in one new buffer, a base64 data URI, which the loader reads
in a .gltf and a .glb alike.
"""
from __future__ import annotations

import base64
import os
import stat
import urllib.parse
from pathlib import Path

import numpy as np

from sc3d_data.io.gltf_accessors import COMPONENT_BYTES, TYPE_COMPONENTS

__all__ = ["AccessorError", "Buffers", "FloatBuffer", "read_accessor"]

#: numpy types of glTF's component types (little-endian)
_DTYPES = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}


class AccessorError(ValueError):
    """Data of the document that cannot be read as it is; the message is the reason."""


class Buffers:
    """The bytes of ``doc``'s buffers, read once each when first asked: a GLB's buffer 0 without
    ``uri`` is ``binary`` (its BIN chunk), a base64 data URI is decoded, another uri names a file
    read through ``resolver`` (``io.texture_resolver.make_resolver``: as the loader reads it,
    inside the dataset folder), else beside ``path`` inside its folder (nothing else is opened)."""

    def __init__(self, path: Path, doc: dict, binary: bytes | None, resolver=None):
        self.path, self.doc, self.binary, self.resolver, self.read = Path(path), doc, binary, resolver, {}

    def __getitem__(self, i: int) -> bytes:
        if i not in self.read:
            uri = self.doc["buffers"][i].get("uri")
            if uri is None and i == 0 and self.binary is not None:
                self.read[i] = self.binary
            elif isinstance(uri, str) and "base64," in uri:
                self.read[i] = base64.b64decode(uri.split("base64,", 1)[1])
            elif isinstance(uri, str):
                self.read[i] = self._file(uri, i)
            else:
                raise AccessorError(f"buffer {i} has no data")
        return self.read[i]

    def _file(self, uri: str, i: int) -> bytes:
        if self.resolver is not None:
            return self.resolver.get(uri)
        folder = Path(os.path.realpath(self.path)).parent
        for name in dict.fromkeys((uri.strip(), urllib.parse.unquote(uri.strip()))):
            file = (folder / name).resolve()
            try:
                if file.is_relative_to(folder) and stat.S_ISREG(os.stat(file).st_mode):
                    return file.read_bytes()
            except OSError:
                continue
        raise AccessorError(f"buffer {i}'s file {uri} cannot be read inside the mesh's folder")


def read_accessor(doc: dict, buffers: Buffers, a: int, what: str) -> np.ndarray:
    """``[count, components]`` of accessor ``a`` (``what`` names its use): float64 where it holds
    floats or ``normalized`` integers (scaled to [0, 1] or [-1, 1]), int64 otherwise; zeros
    without a bufferView (glTF). Honours the view's ``byteOffset``/``byteStride`` and the
    accessor's ``byteOffset``. Raises ``AccessorError`` for a sparse accessor."""
    acc = doc["accessors"][a]
    if "sparse" in acc:
        raise AccessorError(f"accessor {a} ({what}) is sparse")
    ctype, n, count = acc["componentType"], TYPE_COMPONENTS[acc["type"]], acc["count"]
    dtype = np.dtype(_DTYPES[ctype])
    if "bufferView" not in acc:
        raw = np.zeros((count, n), dtype)
    else:
        view = doc["bufferViews"][acc["bufferView"]]
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        data = memoryview(buffers[view["buffer"]])[start:view.get("byteOffset", 0) + view["byteLength"]]
        stride = view.get("byteStride") or COMPONENT_BYTES[ctype] * n
        raw = np.ndarray((count, n), dtype, buffer=data, strides=(stride, dtype.itemsize)) if count else \
            np.zeros((0, n), dtype)
    if ctype == 5126:
        return raw.astype(np.float64)
    if acc.get("normalized") is True:
        return np.maximum(raw.astype(np.float64) / np.iinfo(dtype).max, -1.0)
    return raw.astype(np.int64)


class FloatBuffer:
    """One new buffer of document ``doc`` (changed in place) holding float32 data, appended to
    ``doc["buffers"]`` by :meth:`close` where data was added; make, fill and close one before the
    next (its index is the buffer count when it is made)."""

    def __init__(self, doc: dict):
        self.doc, self.blob, self.index = doc, bytearray(), len(doc.setdefault("buffers", []))

    def view(self, values: np.ndarray) -> tuple[int, np.ndarray]:
        """``(bufferView index, data as stored)`` of ``values [count, components]`` stored as
        little-endian float32 at the end of this buffer (4-byte aligned: float32 is)."""
        data = np.ascontiguousarray(values, dtype="<f4")
        views = self.doc.setdefault("bufferViews", [])
        views.append({"buffer": self.index, "byteOffset": len(self.blob), "byteLength": data.nbytes})
        self.blob += data.tobytes()
        return len(views) - 1, data

    def accessor(self, values: np.ndarray, kind: str) -> int:
        """Index of a new accessor of ``values [count, components]`` (glTF ``type`` ``kind``,
        e.g. ``"VEC3"``) stored as float32, with its ``min``/``max``."""
        view, data = self.view(values)
        accessors = self.doc.setdefault("accessors", [])
        accessors.append({"bufferView": view, "componentType": 5126, "count": len(data), "type": kind,
                          **_bounds(data)})
        return len(accessors) - 1

    def close(self) -> None:
        """Append the buffer to the document, where data was added."""
        if self.blob:
            self.doc["buffers"].append({"byteLength": len(self.blob), "uri": "data:application/octet-stream;base64,"
                                        + base64.b64encode(bytes(self.blob)).decode()})


def _bounds(data: np.ndarray) -> dict:
    """``{"min", "max"}`` per component of ``data [count, components]`` (zeros when empty)."""
    n = data.shape[1]
    return {"min": data.min(axis=0).tolist() if len(data) else [0] * n,
            "max": data.max(axis=0).tolist() if len(data) else [0] * n}
