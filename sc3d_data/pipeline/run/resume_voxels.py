"""What a rerun of ``render`` does with the voxels that ``sc3d-data voxelize SHARDS`` gave a
dataset (its index's ``voxels`` record, which the render's settings do not show): the objects
rendered again are voxelized at the record's resolution (:func:`voxels_as_recorded`), and a
shard that cannot hold grids like the rest's is written without them, the record removed and
the user told (:func:`voxels_after_rewrite`)."""
from __future__ import annotations

from sc3d_data.io.names import shell_word


def uniform_arrays(records: list) -> list[str]:
    """Leave out of every record of ``records`` the arrays that not all of them have with one
    shape (a shard holds each array for all its objects); returns their names, sorted."""
    shapes: dict[str, set] = {}
    for r in records:
        for k, a in r.arrays.items():
            shapes.setdefault(k, set()).add(tuple(a.shape))
    dropped = sorted(k for k, v in shapes.items() if len(v) > 1 or any(k not in r.arrays for r in records))
    for r in records:
        for k in dropped:
            r.arrays.pop(k, None)
    return dropped


def voxels_after_rewrite(index, name: str, records: list, notes: list[str]) -> list[dict]:
    """Before shard ``name`` of ``index`` (a ``jobs.shard_output.ShardIndex``) is written with
    ``records``: arrays that not every record has alike (a kept shard rewritten with retried
    objects: the ``voxels`` that ``voxelize SHARDS`` added to the kept objects, which a render
    without them cannot give the new ones) are left out of all, and so are voxels at another
    resolution than the record's (``render --voxelize`` at its own resolution into a dataset
    that ``voxelize --resolution`` changed; ``render`` voxelizes at the record's resolution,
    :func:`voxels_as_recorded`, but an executor started beforehand may not). When the shard then lacks the
    voxels that the index's ``voxels`` record (of ``voxelize SHARDS``) promises, the record is
    removed and a line for the user added to ``notes``. Returns the index's failures, with the
    shard's ``voxelize`` failures following their object's new row, or gone with the voxels."""
    promised = index.extra.get("voxels", {}).get("resolution")
    mismatched = promised is not None and any(
        "voxels" in r.arrays and r.arrays["voxels"].shape != (promised,) * 3 for r in records)
    if mismatched:  # grids at another resolution than the rest of the dataset's are not kept
        for r in records:
            r.arrays.pop("voxels", None)
    dropped = uniform_arrays(records) + (["voxels"] if mismatched else [])
    shapes = {tuple(r.arrays["voxels"].shape) if "voxels" in r.arrays else None for r in records}
    if promised is not None and records and shapes != {(promised,) * 3}:
        index.extra.pop("voxels")
        notes.append(f"{index.out / name}: written without the {promised}^3 voxels that `sc3d-data voxelize` had "
                     f"given its objects; run `sc3d-data voxelize {shell_word(index.out)} --resolution {promised}` again")
    row = {(r.category, r.model_id): i for i, r in enumerate(records)}
    return [f if f.get("stage") != "voxelize" or f.get("shard") != name
            else dict(f, row=row.get((f.get("category"), f.get("model_id")), f.get("row")))
            for f in index.failures
            if not ("voxels" in dropped and f.get("stage") == "voxelize" and f.get("shard") == name)]


def voxels_as_recorded(config, record: dict | None):
    """``config`` (a ``RenderConfig``) voxelizing at the resolution of a dataset's ``voxels``
    record (``index.json``, written by ``sc3d-data voxelize SHARDS``), so that the objects a
    rerun renders again get grids like the kept ones; ``config`` itself without a record. The
    run's recorded settings are not changed (as ``voxelize SHARDS`` leaves them)."""
    from dataclasses import replace

    resolution = (record or {}).get("resolution")
    if resolution is None or (config.voxelize and config.voxel_resolution == resolution):
        return config
    return replace(config, voxelize=True, voxel_resolution=int(resolution))
