"""Quantized glTF attributes given to the loader as the numbers they mean.

trimesh's glTF loader (5.x) reads every accessor's integers as they are stored, never applying
``normalized`` (an unsigned short 65535 means 1.0): texture coordinates stored as integers (core
glTF allows normalized unsigned bytes and shorts, ``KHR_mesh_quantization`` also signed and plain
ones; gltfpack and gltf-transform's ``quantize`` write them) came out thousands of times too large
(then wrapped, as the loader flips v in the integer type), and positions quantized as normalized
integers made their part up to 32767 times too large. Such files were refused.

The decision: in the copy of the document the loader is given (``io.gltf_loader_doc``), every
accessor that a primitive uses as its ``POSITION`` stored as normalized integers, or as its
``TEXCOORD_0`` stored as integers, holds the numbers it means (``io.gltf_buffers.read_accessor``:
normalized integers scaled to [0, 1] or [-1, 1], plain integers their values) as float32 in a
new buffer; every use of the accessor reads the same numbers as before, now as floats. Positions
stored as plain integers are read right by the loader and stay as they are, as do integer
attributes the loader does not use (``TEXCOORD_1``, normals: shading uses face normals). A
sparse accessor is not converted (``io.gltf_check`` refuses a sparse POSITION or textured
``TEXCOORD_0`` of a drawn mesh), and a file whose accessor cannot be read is refused
(:func:`dequantize_problems`).
"""
from __future__ import annotations

from pathlib import Path

from sc3d_data.io.gltf_buffers import AccessorError, Buffers, FloatBuffer, read_accessor
from sc3d_data.io.gltf_draco import DRACO

__all__ = ["dequantize", "dequantize_problems", "quantized_accessors"]

_INTEGER_TYPES = (5120, 5121, 5122, 5123, 5125)


def quantized_accessors(doc: dict) -> dict[int, str]:
    """``{accessor: its use}`` of the accessors of ``doc`` to convert (module doc): a primitive's
    ``POSITION`` stored as normalized integers or ``TEXCOORD_0`` stored as integers, not sparse,
    of a primitive that is not Draco-compressed; the use names the first primitive found
    (``"TEXCOORD_0 of mesh 2"``)."""
    accessors, meshes, found = doc.get("accessors", []), doc.get("meshes", []), {}
    if not isinstance(accessors, list) or not isinstance(meshes, list):
        return found  # a malformed document: the loader reports it
    for m, mesh in enumerate(meshes):
        prims = mesh.get("primitives", []) if isinstance(mesh, dict) else []
        for prim in prims if isinstance(prims, list) else []:
            if not isinstance(prim, dict) or (isinstance(prim.get("extensions"), dict) and DRACO in prim["extensions"]):
                continue  # a Draco primitive's attributes come from its bitstream (io.gltf_draco)
            attributes = prim.get("attributes", {})
            for role in ("POSITION", "TEXCOORD_0"):
                a = attributes.get(role) if isinstance(attributes, dict) else None
                if not isinstance(a, int) or not 0 <= a < len(accessors) or a in found:
                    continue
                acc = accessors[a]
                if isinstance(acc, dict) and acc.get("componentType") in _INTEGER_TYPES and "sparse" not in acc \
                        and (role == "TEXCOORD_0" or acc.get("normalized") is True):
                    found[a] = f"{role} of mesh {m}"
    return found


def dequantize_problems(path: Path, doc: dict, binary: bytes | None, resolver=None) -> list[str]:
    """Why accessors :func:`quantized_accessors` names cannot be read (a buffer missing or
    outside the dataset folder, a view too short), one phrase each; ``binary``: a GLB's BIN chunk."""
    buffers, problems = Buffers(path, doc, binary, resolver), []
    for a, use in quantized_accessors(doc).items():
        try:
            read_accessor(doc, buffers, a, use)
        except (AccessorError, KeyError, IndexError, TypeError, ValueError, OSError) as e:
            problems.append(f"accessor {a} ({use}) holds quantized integers that cannot be read "
                            f"({type(e).__name__}: {e})")
    return problems


def dequantize(path: Path, doc: dict, binary: bytes | None, resolver=None) -> None:
    """Convert the accessors of ``doc`` (a copy the loader reads; changed in place) that
    :func:`quantized_accessors` names to float32 in a new buffer (module doc); buffers read as
    ``io.gltf_buffers.Buffers`` reads them (``binary``: a GLB's BIN chunk, ``resolver``: the
    loader's). An accessor that cannot be read is left as it is (:func:`dequantize_problems`
    refuses such files first)."""
    buffers, floats = Buffers(path, doc, binary, resolver), FloatBuffer(doc)
    for a, use in quantized_accessors(doc).items():
        try:
            values = read_accessor(doc, buffers, a, use)
        except (AccessorError, KeyError, IndexError, TypeError, ValueError, OSError):
            continue
        acc = doc["accessors"][a]
        view, data = floats.view(values)
        for key in ("byteOffset", "normalized"):
            acc.pop(key, None)
        acc.update(bufferView=view, componentType=5126)
        if len(data) and ("min" in acc or "max" in acc or use.startswith("POSITION")):  # POSITION's are required
            acc.update(min=data.min(axis=0).tolist(), max=data.max(axis=0).tolist())
    floats.close()
