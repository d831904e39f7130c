"""ShapeNet synsets used by 3D-R2N2 / PTN, and name <-> synset-id resolution.

``--categories airplane,car,chair`` and ``--categories 02691156,02958343`` mean the same thing.
Names that are neither a known category name nor a synset id are kept as given (so folders of
non-ShapeNet meshes such as ``spaceship/`` can still be selected by their folder name).
"""
from __future__ import annotations

import re
from typing import Iterable

#: the 13 ShapeNetCore synsets of 3D-R2N2 (Choy et al. 2016): synset id -> name
R2N2_SYNSETS: dict[str, str] = {
    "02691156": "airplane",
    "02828884": "bench",
    "02933112": "cabinet",
    "02958343": "car",
    "03001627": "chair",
    "03211117": "display",
    "03636649": "lamp",
    "03691459": "loudspeaker",
    "04090263": "rifle",
    "04256520": "sofa",
    "04379243": "table",
    "04401088": "telephone",
    "04530566": "watercraft",
}

#: other spellings users (and other datasets) use for the same synsets: name -> synset id
ALIASES: dict[str, str] = {
    "plane": "02691156", "aeroplane": "02691156",
    "monitor": "03211117", "tv": "03211117",
    "speaker": "03691459",
    "cellphone": "04401088", "phone": "04401088",
    "vessel": "04530566", "boat": "04530566", "ship": "04530566",
    "couch": "04256520",
}

_NAME_TO_SYNSET = {name: sid for sid, name in R2N2_SYNSETS.items()} | ALIASES
_SYNSET_RE = re.compile(r"^\d{8}$")


def is_synset_id(name: str) -> bool:
    """True for an 8-digit WordNet offset such as ``"02691156"`` (a ShapeNet category folder)."""
    return bool(_SYNSET_RE.match(name))


def category_name(category: str) -> str:
    """Readable name of a synset id (``"02691156"`` -> ``"airplane"``), else ``category`` unchanged."""
    return R2N2_SYNSETS.get(category, category)


def category_label(category: str) -> str:
    """``"airplane (02691156)"`` for a known synset id, else the category as stored: the label
    the reports (``info``, ``check``, ``eval``) print."""
    name = category_name(category)
    return f"{name} ({category})" if name != category else category


def resolve_category(name: str) -> str:
    """One category name or synset id -> synset id where known (case-insensitive for names),
    else the name unchanged (stripped)."""
    name = name.strip()
    if is_synset_id(name):
        return name
    return _NAME_TO_SYNSET.get(name.lower(), name)


def resolve_categories(spec: str | Iterable[str]) -> set[str]:
    """``"airplane,car,03001627"`` (or an iterable of such items, each possibly comma separated)
    -> ``{"02691156", "02958343", "03001627"}``. Unknown names are kept as given; a spec that
    names no category at all (``","``) is a ``ValueError``, not a filter that keeps nothing."""
    items = [spec] if isinstance(spec, str) else list(spec)
    out: set[str] = set()
    for item in items:
        for part in str(item).split(","):
            if part.strip():
                out.add(resolve_category(part))
    if not out:
        raise ValueError(f"--categories {spec!r} names no category (give names or synset ids, comma-separated, "
                         "e.g. chair,02691156)")
    return out


# ----------------------------------------------------------------------------- front axes
#: front axis of ShapeNetCore OBJ files (+Y up in both; docs/data.md): v1
#: ``SYNSET/MODEL_ID/model.obj`` faces +X (3D-R2N2's renders and ShapeNetVox32 voxels), v2
#: ``SYNSET/MODEL_ID/models/model_normalized.obj`` faces -Z (public v2 samples: airplane nose,
#: rifle muzzle, helmet visor, desk drawers all at -Z)
SHAPENET_V1_FRONT = "+X"
SHAPENET_V2_FRONT = "-Z"
#: sc3d's canonical front, and the default for every other mesh
CANONICAL_FRONT = "+Z"
AUTO_FRONT = "auto"


def shapenet_version(path) -> int | None:
    """1 for ``SYNSET/MODEL_ID/model.obj``, 2 for ``SYNSET/MODEL_ID/models/model_normalized.obj``,
    else ``None`` (by the path alone). A ``MODEL_ID`` of 8 digits is no model folder, as
    ``discover`` reads it (a folder of plain meshes in a synset folder)."""
    import os
    from pathlib import Path

    p = Path(os.path.abspath(path))  # `--meshes .` inside a synset folder: the names above it count
    if p.name == "model.obj" and is_synset_id(p.parent.parent.name) and not is_synset_id(p.parent.name):
        return 1
    if (p.name == "model_normalized.obj" and p.parent.name == "models" and is_synset_id(p.parents[2].name)
            and not is_synset_id(p.parents[1].name)):
        return 2
    return None


def resolve_front(front: str, path) -> str:
    """The source front axis to use for the mesh at ``path``: ``front`` as given, or for
    ``"auto"`` the ShapeNetCore version's front (v1 +X, v2 -Z) and +Z for any other mesh."""
    if front.strip().lower() != AUTO_FRONT:
        return front
    return {1: SHAPENET_V1_FRONT, 2: SHAPENET_V2_FRONT}.get(shapenet_version(path), CANONICAL_FRONT)


def check_axes(up: str, front: str) -> None:
    """Raise ``ValueError`` naming the option when ``--up`` is not an axis, ``--front`` is neither
    an axis nor ``auto``, or the two are not perpendicular, so that a typo fails once instead of
    as one failure per mesh. ``auto`` takes +Z as the front of every mesh outside ShapeNet
    (:func:`resolve_front`), so ``--up`` on the Z axis needs an explicit ``--front``."""
    from sc3d_data.geometry.normalize import axis_vector, canonical_rotation

    auto = front.strip().lower() == AUTO_FRONT
    for option, axis in (("--up", up), ("--front", front)):
        try:
            axis_vector(CANONICAL_FRONT if auto and option == "--front" else axis)
        except ValueError as e:
            raise ValueError(f"{option} {axis}: {e}") from None
    try:
        canonical_rotation(up, CANONICAL_FRONT if auto else front)
    except ValueError:
        if not auto:
            raise
        raise ValueError(f"--up {up} with --front auto: auto takes {CANONICAL_FRONT} as the front of meshes "
                         "that are not ShapeNet's, which is not perpendicular to it; give --front "
                         "(e.g. --front -Y for a Z-up export)") from None
