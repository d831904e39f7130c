"""Contact sheet of a shard directory (for ``sc3d-data preview``).

One row per object: ``views`` rendered images, then the masks of the same views, then (when
the shards hold ``voxels``) the silhouettes of the voxels through the same stored cameras
(``sc3d_data.geometry.projection``), each tile the stored image size times ``scale``. A label on
the left names the category, model id and split. Objects are picked round-robin over
categories so every category shows up.
"""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from sc3d_data.formats.shapenet import category_name
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


def contact_sheet(shard_dir: Path, max_objects: int = 8, views: int = 6, scale: int = 2) -> np.ndarray:
    """RGB uint8 ``[H, W, 3]`` contact sheet (see module doc)."""
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
            from sc3d_data.geometry.projection import project_voxels_views

            sil = project_voxels_views(o["voxels"].astype(bool), o["K"].astype(np.float64),
                                       o["R"].astype(np.float64), o["t"].astype(np.float64), S, sel)
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
        draw.text((4, 4), f"{category_name(o['category'])}\n{o['model_id'][:22]}\n{o['split']}", fill="black")
        rows.append(np.concatenate([np.asarray(label), row], 1))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    return np.concatenate(rows, 0)
