"""Contact sheet of a shard directory (for ``sc3d-data preview``).

One row per object: ``views`` rendered images, then the masks of the same views, then (when
the shards hold ``voxels``) the silhouettes of the voxels through the same stored cameras
(``sc3d_data.geometry.projection``), each tile the stored image size times ``scale`` (default:
:func:`auto_scale`). A label on the left names the category, model id and split
(``io.drawn_names``: a tab is drawn ``\\t``, a character PIL's default font has no glyph for as
``\\uXXXX``, a name too long for it is cut with ``...``), the row
at least as tall as the label. Objects are picked round-robin over categories so every category
shows up. An object whose voxelization failed (an empty placeholder grid, ``io.failed_grids``)
gets no voxel tiles, "voxels failed" in its label and a line in ``notes``. A view
whose camera has occupied voxels behind it (a ``--distance`` under sqrt(3)/2 that an earlier
sc3d accepted) gets an empty voxel tile, and a line naming the object and its views is added
to ``notes``.
"""
from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from sc3d_data.formats.shapenet import category_name
from sc3d_data.io.drawn_names import pil_name
from sc3d_data.io.names import printable

LABEL_WIDTH = 150
#: tiles of the default scale are at most this many pixels a side (:func:`auto_scale`)
MAX_AUTO_TILE = 256


def auto_scale(image_size: int) -> int:
    """The default ``scale``: 2 (a 64x64 view drawn 128 pixels a side) up to 64 pixels, 1 up to
    :data:`MAX_AUTO_TILE`, and above it ``-k``, every ``k``-th pixel of images, masks and voxel
    silhouettes alike: a sheet of 1024-pixel views at scale 2 was 37,086 pixels wide, more than
    image viewers and browsers open."""
    if image_size <= 64:
        return 2
    return 1 if image_size <= MAX_AUTO_TILE else -math.ceil(image_size / MAX_AUTO_TILE)


def pick_objects(shard_dir: Path, max_objects: int) -> list[dict]:
    """Up to ``max_objects`` objects, round-robin over categories (index order within each), as
    dicts of their strings, ``shard``, ``row`` and arrays (images, masks, K, R, t; voxels where the
    shards hold them). The choice is made from ``index.json``: only the picked objects are read
    (a contact sheet of a ShapeNet-sized dataset costs the memory of its rows, not the dataset's)."""
    from sc3d_data.io.shard_reader import ShardReader
    from sc3d_data.io.shards import shard_path

    from sc3d_data.io.failed_grids import voxelize_failures

    by_cat = defaultdict(list)
    with ShardReader(shard_dir) as reader:
        failed = voxelize_failures(reader.index)
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
            check_row(reader, shard_dir, path, entry)
            voxels_failed = (path.name, int(entry["row"])) in failed
            held = reader.holds(path, "voxels") and not voxels_failed
            fields = ("images", "masks", "K", "R", "t") + (("voxels",) if held else ())
            objects.append({**{k: entry.get(k, "") for k in ("category", "model_id", "split")},
                            "shard": path.name, "row": int(entry["row"]), "voxels_failed": voxels_failed,
                            **reader.read(path, int(entry["row"]), fields)})
    return objects


def check_row(reader, shard_dir: Path, path: Path, entry: dict) -> None:
    """``ShardError`` naming the index when the row of index object ``entry`` is not one of shard
    file ``path``: the index's own check (``index_check.row_problems``) needs the file's object
    count from ``shards``, which a hand-edited index may lack; h5py would read row -1 as the last
    object and fail on row 99 of 3 with a traceback."""
    from sc3d_data.io.names import printable
    from sc3d_data.io.shards import ShardError, index_path

    rows = reader.num_rows(path)
    if not 0 <= entry["row"] < rows:  # an integer: index_check.row_problems refused any other
        raise ShardError(f"{index_path(shard_dir)}: malformed: {printable(entry['category'] + '/' + entry['model_id'])} "
                         f"has row {entry['row']} in {path.name}, which holds {rows} objects (hand-edited?)")


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


def contact_sheet(shard_dir: Path, max_objects: int = 8, views: int = 6, scale: int | None = None,
                  notes: list[str] | None = None) -> np.ndarray:
    """RGB uint8 ``[H, W, 3]`` contact sheet (see module doc; ``scale`` None: :func:`auto_scale`, a
    negative one shrinks by its size); lines for the user go to ``notes``."""
    objects = pick_objects(shard_dir, max_objects)
    if not objects:
        raise ValueError(f"{shard_dir}: no objects in the shards")
    rows = []
    for o in objects:
        V, S = o["images"].shape[:2]
        k = auto_scale(S) if scale is None else scale
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
        if o["voxels_failed"] and notes is not None:
            notes.append(f"{printable(o['category'] + '/' + o['model_id'])} ({o['shard']} row {o['row']}): its "
                         "voxelization failed (index.json failures): no voxel tiles")
        if k < 0:  # every -k-th pixel: images, masks and silhouettes stay aligned
            tiles = [t[::-k, ::-k] for t in tiles]
        row = np.concatenate([np.pad(t, ((1, 1), (1, 1), (0, 0)), constant_values=200) for t in tiles], 1)
        row = np.kron(row, np.ones((max(k, 1), max(k, 1), 1), np.uint8))
        rows.append(_labelled(row, [category_name(o["category"]), o["model_id"], o["split"]]
                              + (["voxels failed"] if o["voxels_failed"] else [])))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    return np.concatenate(rows, 0)


def _labelled(row: np.ndarray, lines: list[str]) -> np.ndarray:
    """``row`` with a label of ``lines`` (``io.drawn_names.pil_name``: escaped where the font has no
    glyph, each cut to :data:`LABEL_WIDTH`) on its left, padded below with white where the label is taller (16-pixel views at scale 2 are 36
    pixels high: the split line was cut off)."""
    from PIL import Image, ImageDraw

    draw = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    font = draw.getfont()  # PIL's default font
    text = "\n".join(pil_name(s, LABEL_WIDTH - 8, font) for s in lines)
    height = max(row.shape[0], draw.multiline_textbbox((4, 4), text, font=font)[3] + 4)
    label = Image.new("RGB", (LABEL_WIDTH, height), "white")
    ImageDraw.Draw(label).text((4, 4), text, fill="black", font=font)
    row = np.pad(row, ((0, height - row.shape[0]), (0, 0), (0, 0)), constant_values=255)
    return np.concatenate([np.asarray(label), row], 1)
