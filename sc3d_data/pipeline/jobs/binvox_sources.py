"""Which mesh, voxelized with which settings, made each ``.binvox`` of a ``voxelize --meshes``
folder: what a rerun needs besides the file's header (which shows the resolution alone) to
know that a kept file is this mesh's grid.

``out/sources.json`` (a whole run) and ``out/sources.part-00I-of-00N.json`` (part ``I`` of ``N``;
written after the last whole run, so they win over ``sources.json``) each hold ``{"settings":
{"0": grid settings (voxel_meshes.grid_settings), ...}, "files": {binvox path relative to out:
[mesh path relative to --meshes, its size, its mtime in ns, key of its settings]}}``. A kept
file is done again when its record names another mesh (two meshes with one id, ``x.glb`` and
``x.GLB``, write one ``x.binvox``: the one used can change; two meshes swapped by ``mv``; another
``--meshes``) or other settings (a part run again with ``--overwrite``
and another ``--normalize`` re-records the folder's settings; the other parts' files were made
with the old ones). A file no record names (an older sc3d's folder, a run killed before it
wrote its record) is judged by its header and times alone, as before. A run writes its record
at its end, also when stopped by Ctrl-C or an error: the files it made or kept, and for each
file it meant to redo and did not reach its old record, or one of unknown settings (so the
next run redoes it). Under ``--overwrite`` a mesh that fails loses its old file, as an edited one does.
"""
from __future__ import annotations

import json
from pathlib import Path

from sc3d_data.io.shards import write_json_atomic

SOURCES_NAME = "sources.json"


def sources_name(part) -> str:
    """The record of ``part`` (a :class:`~sc3d_data.pipeline.run.partition.Part`): ``sources.json`` for a whole run."""
    return SOURCES_NAME if part.whole else f"sources.{part.dirname()}.json"


def mesh_identity(name: str, path) -> list:
    """``[name, size in bytes, modification time in ns]`` of the mesh file ``path`` (``name``: its
    path relative to ``--meshes``): another mesh under the same name (two swapped by ``mv``,
    which keeps times; another ``--meshes`` folder) differs in size or time."""
    try:
        st = Path(path).stat()
    except OSError:
        return [name, None, None]
    return [name, st.st_size, st.st_mtime_ns]


def _read(path: Path) -> dict[str, tuple[list, dict | None]]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict) or not isinstance(data.get("files"), dict) or not isinstance(data.get("settings"), dict):
        return {}
    return {k: (v[:3], data["settings"].get(v[3])) for k, v in data["files"].items()
            if isinstance(v, list) and len(v) == 4 and isinstance(v[0], str) and isinstance(v[3], str)}


def recorded_sources(out: Path) -> dict[str, tuple[list, dict | None]]:
    """``{binvox path relative to out: (mesh_identity of the mesh that made it, grid settings)}``
    of every record in ``out``; a part's record wins over the whole run's, and of two parts'
    records (of two part counts) the one written last."""
    found = _read(Path(out) / SOURCES_NAME)
    parts = [(p.stat().st_mtime_ns, p) for p in Path(out).glob("sources.part-*-of-*.json")]
    for _, part_record in sorted(parts):
        found.update(_read(part_record))
    return found


def record_sources(out: Path, part, files: dict[str, tuple[list, dict | None]]) -> None:
    """Write ``part``'s record of ``files`` ({binvox path relative to out: (mesh_identity, grid
    settings; None: unknown, the file is done again)}). A whole run's replaces the parts'
    records (it covered every part's meshes)."""
    keys: dict[str, str] = {}  # settings as JSON -> its key
    table, entries = {}, {}
    for name, (source, settings) in sorted(files.items()):
        text = json.dumps(settings, sort_keys=True)
        if text not in keys:
            keys[text] = str(len(keys))
            table[keys[text]] = settings
        entries[name] = [*source, keys[text]]
    write_json_atomic(Path(out) / sources_name(part), {"settings": table, "files": entries})
    if part.whole:
        for stale in Path(out).glob("sources.part-*-of-*.json"):
            stale.unlink(missing_ok=True)
