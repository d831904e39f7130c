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

LABEL_WIDTH = 150


def pick_objects(shard_dir: Path, max_objects: int) -> list[dict]:
    """Up to ``max_objects`` objects, round-robin over categories (index order within each), as
    dicts of their strings, ``shard``, ``row`` and arrays (images, masks, K, R, t; voxels where the
    shards hold them). The choice is made from ``index.json``: only the picked objects are read
    (a contact sheet of a ShapeNet-sized dataset costs the memory of its rows, not the dataset's)."""
    from sc3d_data.io.shard_reader import ShardReader
    from sc3d_data.io.shards import shard_path

    by_cat = defaultdict(list)
    with ShardReader(shard_dir) as reader:
        for entry in reader.index.get("objects", []):
            if len(by_cat[entry["category"]]) < max_objects:
                by_cat[entry["category"]].append(entry)
        picked, k = [], 0
        while len(picked) < max_objects and any(k < len(v) for v in by_cat.values()):
            picked.extend(v[k] for v in by_cat.values() if k < len(v))
            k += 1
        objects = []
        for entry in picked[:max_objects]:
            path = shard_path(Path(shard_dir), entry["shard"])
            fields = ("images", "masks", "K", "R", "t") + (("voxels",) if reader.holds(path, "voxels") else ())
            objects.append({**{k: entry.get(k, "") for k in ("category", "model_id", "split")},
                            "shard": path.name, "row": int(entry["row"]), **reader.read(path, int(entry["row"]), fields)})
    return objects


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
