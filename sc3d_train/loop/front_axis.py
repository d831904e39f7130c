"""A render's ``--front``, as its views show it: ``auto`` gives each mesh its own front
(``sc3d_data.formats.shapenet.resolve_front``: +Z for any mesh outside ShapeNet), so an explicit
``--front +Z`` over such meshes renders exactly what ``auto`` renders. The view setup that ``fit
--resume`` and ``eval`` compare (``loop.resolve.view_setup``) reads it as ``auto`` there, rather
than calling identical data other data."""
from __future__ import annotations

import json
from pathlib import Path


def auto_fronts(shards: Path) -> set[str]:
    """The fronts ``auto`` gives the objects of ``shards`` (from each object's ``source`` in
    ``index.json``); empty where the index lists none or an object has no source (an import) or
    one that is no text (a hand-edited or foreign index: no front can be read from it)."""
    from sc3d_data.formats.shapenet import AUTO_FRONT, resolve_front
    from sc3d_data.geometry.normalize import axis_name

    try:
        objects = json.loads((Path(shards) / "index.json").read_text()).get("objects") or []
    except (OSError, ValueError, AttributeError):
        return set()
    sources = [o.get("source") if isinstance(o, dict) else None for o in objects]
    if not sources or not all(isinstance(s, str) for s in sources):
        return set()
    return {axis_name(resolve_front(AUTO_FRONT, s)) for s in sources}


def front_as_auto(settings: dict, shards: Path | None) -> dict:
    """``settings`` (``index.json``'s) with ``front`` read as ``auto`` where the explicit front is
    the one ``auto`` gives every object of ``shards`` (None: as given): the same views, so the same view setup."""
    from sc3d_data.formats.shapenet import AUTO_FRONT
    from sc3d_data.geometry.normalize import axis_name

    front = settings.get("front")
    if shards is None or not isinstance(front, str) or front.strip().lower() == AUTO_FRONT:
        return settings
    try:
        name = axis_name(front)
    except ValueError:
        return settings
    return {**settings, "front": AUTO_FRONT} if auto_fronts(shards) == {name} else settings
