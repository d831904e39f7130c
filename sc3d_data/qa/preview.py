"""Contact sheet of a shard directory (for ``sc3d-data preview``).

One row per object: ``views`` rendered images, then the masks of the same views, then (when
the shards hold ``voxels``) the silhouettes of the voxels through the same stored cameras
(``sc3d_data.geometry.projection``), each tile the stored image size times ``scale``. A label on
the left names the category, model id and split (``io.names.printable``: a tab is drawn
``\\t``). Objects are picked round-robin over categories so every category shows up. A view
whose camera has occupied voxels behind it (a ``--distance`` under sqrt(3)/2 that an earlier
sc3d accepted) gets an empty voxel tile, and a line naming the object and its views is added
to ``notes``.
"""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from sc3d_data.formats.shapenet import category_name
from sc3d_data.io.names import printable
from sc3d_data.io.shard_reader import iter_objects

LABEL_WIDTH = 150


def pick_objects(shard_dir: Path, max_objects: int) -> list[dict]:
    """Up to ``max_objects`` objects, round-robin over categories (plan order within each)."""
    by_cat = defaultdict(list)
    for o in iter_objects(shard_dir, fields=("images", "masks", "voxels", "K", "R", "t")):
        by_cat[o["category"]].append(o)
    picked, k = [], 0
    while len(picked) < max_objects and any(k < len(v) for v in by_cat.values()):
        picked.extend(v[k] for v in by_cat.values() if k < len(v))
        k += 1
    return picked[:max_objects]


def _silhouettes(o: dict, S: int, sel, notes: list[str] | None) -> np.ndarray:
    """Voxel silhouettes ``[len(sel), S, S]`` of object ``o`` (arrays of ``iter_objects``) in
    views ``sel``; empty where voxels lie behind the camera (named in ``notes``)."""
    from sc3d_data.geometry.projection import project_voxels_views

    behind: list[int] = []
    sil = project_voxels_views(o["voxels"].astype(bool), *(o[k].astype(np.float64) for k in "KRt"), S, sel, behind)
    if behind and notes is not None:
        notes.append(f"{printable(o['category'] + '/' + o['model_id'])} ({o['shard']} row {o['row']}): view(s) "
                     f"{', '.join(map(str, behind))} have voxels behind the camera (its distance is under "
                     "sqrt(3)/2); their voxel tiles are empty")
    return sil


def contact_sheet(shard_dir: Path, max_objects: int = 8, views: int = 6, scale: int = 2,
                  notes: list[str] | None = None) -> np.ndarray:
    """RGB uint8 ``[H, W, 3]`` contact sheet (see module doc); lines for the user go to ``notes``."""
    from PIL import Image, ImageDraw

    objects = pick_objects(shard_dir, max_objects)
    if not objects:
        raise ValueError(f"{shard_dir}: no objects in the shards")
    rows = []
    for o in objects:
        V, S = o["images"].shape[:2]
        sel = np.linspace(0, V, min(views, V), endpoint=False).astype(int)
        tiles = [o["images"][v] for v in sel]
        tiles += [np.repeat(o["masks"][v][..., None] * 255, 3, -1).astype(np.uint8) for v in sel]
        if "voxels" in o:
            sil = _silhouettes(o, S, sel, notes)
            # voxel silhouette in blue, the rendered mask's outline-free overlay in grey
            for s, v in zip(sil, sel):
                tile = np.full((S, S, 3), 255, np.uint8)
                tile[o["masks"][v].astype(bool)] = (170, 170, 170)
                tile[s & ~o["masks"][v].astype(bool)] = (90, 140, 255)
                tile[s & o["masks"][v].astype(bool)] = (30, 60, 200)
                tiles.append(tile)
        row = np.concatenate([np.pad(t, ((1, 1), (1, 1), (0, 0)), constant_values=200) for t in tiles], 1)
        row = np.kron(row, np.ones((scale, scale, 1), np.uint8))
        label = Image.new("RGB", (LABEL_WIDTH, row.shape[0]), "white")
        draw = ImageDraw.Draw(label)
        draw.text((4, 4), "\n".join(printable(s) for s in (category_name(o["category"]), o["model_id"][:22], o["split"])),
                  fill="black")
        rows.append(np.concatenate([np.asarray(label), row], 1))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    return np.concatenate(rows, 0)
