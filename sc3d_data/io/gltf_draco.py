"""Draco-compressed glTF primitives (``KHR_draco_mesh_compression``: Draco GLBs from gltf-pipeline,
gltf-transform, Blender's "Compression" export option, three.js asset pipelines).

trimesh's glTF loader decodes them through ``DracoPy`` (a dependency of sc3d). A bitstream that
does not decode (a file cut short, a broken export) was read by the loader as zeros and failed
as "zero surface area (all N triangles degenerate)", blaming the mesh. :func:`draco_problems`
decodes the bitstream of each Draco primitive of the drawn meshes first and names the primitive
whose data does not decode, or decodes to another number of vertices than its POSITION accessor
says (the loader would draw other geometry), so the file is refused in one line
(``io.gltf_check``). The loader then decodes it again (a second decode, ~tens of ms per MB).
"""
from __future__ import annotations

from pathlib import Path

from sc3d_data.io.gltf_buffers import AccessorError, Buffers

__all__ = ["DRACO", "draco_primitives", "draco_problems"]

DRACO = "KHR_draco_mesh_compression"


def draco_primitives(doc: dict, drawn: set[int]) -> list[tuple[int, int, dict]]:
    """``[(mesh, primitive index, its KHR_draco_mesh_compression object)]`` of the drawn meshes
    ``drawn`` (mesh indices)."""
    found = []
    for m in sorted(drawn):
        for k, prim in enumerate(doc["meshes"][m].get("primitives", [])):
            draco = prim.get("extensions", {}).get(DRACO) if isinstance(prim.get("extensions"), dict) else None
            if isinstance(draco, dict):
                found.append((m, k, draco))
    return found


def _view_bytes(doc: dict, buffers: Buffers, v: int) -> bytes:
    """The bytes of bufferView ``v`` of ``doc``."""
    view = doc["bufferViews"][v]
    start = view.get("byteOffset", 0)
    data = buffers[view["buffer"]][start:start + view["byteLength"]]
    if len(data) != view["byteLength"]:
        raise AccessorError(f"bufferView {v} runs past the end of buffer {view['buffer']}")
    return bytes(data)


def draco_problems(path: Path, doc: dict, binary: bytes | None, drawn: set[int], resolver=None) -> list[str]:
    """Why the Draco primitives of the drawn meshes ``drawn`` cannot be read (module doc), one
    phrase each; ``binary``: a GLB's BIN chunk, ``resolver``: the loader's (buffer files)."""
    import DracoPy

    buffers, problems = Buffers(path, doc, binary, resolver), []
    for m, k, draco in draco_primitives(doc, drawn):
        where = f"mesh {m} primitive {k}'s Draco-compressed data"
        try:
            decoded = DracoPy.decode(_view_bytes(doc, buffers, draco["bufferView"]))
        except (AccessorError, KeyError, IndexError, TypeError, OSError) as e:
            problems.append(f"{where} cannot be read ({type(e).__name__}: {e})")
            continue
        except Exception as e:  # noqa: BLE001 - DracoPy's decoding errors are of its own types
            problems.append(f"{where} does not decode ({type(e).__name__}: {str(e) or 'no message'})")
            continue
        position = doc["meshes"][m]["primitives"][k].get("attributes", {}).get("POSITION")
        count = doc["accessors"][position].get("count") if isinstance(position, int) else None
        if count is not None and len(decoded.points) != count:
            problems.append(f"{where} decodes to {len(decoded.points):,} vertices where its POSITION accessor "
                            f"says {count:,}")
    return problems
