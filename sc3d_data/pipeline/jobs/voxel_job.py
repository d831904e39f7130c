"""``sc3d-data voxelize SHARDS`` as a library: add ``voxels`` to existing shards; and the
voxelization of one mesh file shared with ``voxel_meshes.py`` (``voxelize --meshes``).

Shards (``voxelize_shards``)
    For every object the source mesh recorded in the shard (``source``) is loaded with
    ``sc3d_data.io.meshes.load_mesh_triangles`` (exactly the geometry the renderer drew), moved
    into the canonical frame with the object's stored ``to_canonical`` and voxelized with
    ``sc3d_data.voxel.voxelize.voxelize_triangles``. The ``voxels`` dataset ``[N, G, G, G]`` is added
    to each shard atomically (``shards.replace_dataset_atomically``), one shard at a time.
    Resume: a shard that already holds ``voxels`` at the requested resolution is skipped
    (``overwrite=True`` redoes it). The index's ``bytes``/``sha256`` of a shard are updated
    right after it is rewritten (``replace_dataset_atomically``), and the run holds the folder's write lock
    (``sc3d_data.io.outlock``). An object that fails (mesh missing or unreadable) gets an
    all-empty grid so the shard stays rectangular, and is recorded in the index under
    ``failures`` with ``"stage": "voxelize"``, its shard, row and reason. The index also gets
    ``"voxels": {"resolution": G, "occupancy": ...}``.

Meshes (``voxelize --meshes``): ``voxel_meshes.py``.
"""
from __future__ import annotations

import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sc3d_data.io.shards import load_index, replace_dataset_atomically, shard_files, write_json_atomic, index_path
from sc3d_data.io.shard_reader import read_strings

OCCUPANCY_RULE = ("surface-touching voxels + voxel centres with |winding number| >= 0.5 "
                  "+ enclosed voxels (sc3d_data/voxel/voxelize.py)")


def limit_threads() -> None:
    import os

    for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(k, "1")


def voxelize_source(source: str, to_canonical: np.ndarray, resolution: int, max_faces: int | None = None
                    ) -> np.ndarray:
    """Voxels ``[G, G, G]`` bool of the mesh file ``source`` moved into the canonical frame with
    the 4x4 ``to_canonical`` (as stored in the shard)."""
    from sc3d_data.io.meshes import load_mesh_triangles

    kwargs = {} if max_faces is None else {"max_faces": max_faces}
    vertices, faces = load_mesh_triangles(Path(source), **kwargs)
    return voxelize_canonical(vertices, faces, to_canonical, resolution)


def voxelize_canonical(vertices: np.ndarray, faces: np.ndarray, to_canonical: np.ndarray,
                       resolution: int) -> np.ndarray:
    """Source-frame triangles -> canonical frame (4x4 ``to_canonical``) -> voxels [G, G, G]."""
    from sc3d_data.geometry.normalize import apply_transform
    from sc3d_data.voxel.voxelize import voxelize_triangles

    return voxelize_triangles(apply_transform(vertices, to_canonical), faces, resolution)


def _job(args):
    source, to_canonical, resolution, max_faces = args
    limit_threads()
    try:
        return "ok", voxelize_source(source, to_canonical, resolution, max_faces)
    except Exception as e:  # recorded per object, never aborts the shard
        return "failed", f"{type(e).__name__}: {e}"


def _map(jobs, workers: int):
    if workers <= 1 or len(jobs) <= 1:
        return [_job(j) for j in jobs]
    from sc3d_data.pipeline.executors.local_pool import worker_context

    with ProcessPoolExecutor(max_workers=workers, mp_context=worker_context(None),
                             initializer=limit_threads) as ex:
        return list(ex.map(_job, jobs, chunksize=1))


def resolve_source(source: str, meshes_root: str | None) -> str:
    """The mesh file of a shard's ``source``: as recorded when it exists (absolute, or relative
    to the current folder), else the longest tail of it that exists under the dataset's
    ``meshes`` root (index settings), so shards rendered from a relative path still work."""
    p = Path(source)
    if p.exists() or p.is_absolute() or not meshes_root:
        return source
    parts = p.parts
    for k in range(len(parts)):
        candidate = Path(meshes_root) / Path(*parts[k:])
        if candidate.is_file():
            return str(candidate)
    return source


@dataclass
class VoxelizeSummary:
    """Counts of a voxelize run (``--meshes``: ``objects`` files written, ``shards_skipped``
    files already there)."""

    shards_done: int = 0
    shards_skipped: int = 0
    objects: int = 0
    failed: int = 0
    seconds: float = 0.0

    def as_dict(self) -> dict:
        """``done``/``resumed``/``failed`` (the keys of a part's summary) plus the fields."""
        return dict(vars(self), done=self.objects, resumed=self.shards_skipped)


def voxelize_shards(shard_dir: Path, resolution: int = 32, workers: int = 1, overwrite: bool = False,
                    progress: bool = False) -> VoxelizeSummary:
    """Add ``voxels [N, G, G, G]`` to every shard of ``shard_dir`` (module doc)."""
    from sc3d_data.io.outlock import exclusive_lock

    with exclusive_lock(Path(shard_dir), "sc3d-data voxelize"):
        return _voxelize_shards_locked(shard_dir, resolution, workers, overwrite, progress)


def _voxelize_shards_locked(shard_dir, resolution, workers, overwrite, progress) -> VoxelizeSummary:
    from sc3d_data.io.shards import ShardError, io_reason
    from sc3d_data.io.shard_reader import open_shard

    t0 = time.monotonic()
    shard_dir = Path(shard_dir)
    index = load_index(shard_dir)
    max_faces = index.get("settings", {}).get("max_faces")
    meshes_root = index.get("settings", {}).get("meshes")
    summary = VoxelizeSummary()
    paths = shard_files(shard_dir)
    failures = [f for f in index.get("failures", []) if f.get("stage") != "voxelize"]
    old_voxel_failures = [f for f in index.get("failures", []) if f.get("stage") == "voxelize"]
    bar = None
    if progress:
        from sc3d_data.pipeline.run.progress import progress_bar

        bar = progress_bar(total=len(paths), unit="shard", desc="voxelize")
    new_failures = []
    for path in paths:
        if not path.is_file():
            raise FileNotFoundError(f"{path}: listed in {index_path(shard_dir)} but missing")
        with open_shard(path) as f:
            if "to_canonical" not in f or "source" not in f:
                raise ValueError(f"{path}: no to_canonical/source datasets; cannot find the meshes")
            try:
                has = "voxels" in f and f["voxels"].shape[1:] == (resolution,) * 3
                sources = read_strings(f["source"])
                ids = read_strings(f["model_id"])
                cats = read_strings(f["category"])
                to_canonical = f["to_canonical"][()]
            except (OSError, KeyError, RuntimeError) as e:
                raise ShardError(f"{path}: broken shard ({io_reason(e)}); see `sc3d-data info --verify`") from e
        if has and not overwrite:
            summary.shards_skipped += 1
            new_failures += [x for x in old_voxel_failures if x.get("shard") == path.name]
        else:
            results = _map([(resolve_source(s, meshes_root), T, resolution, max_faces)
                            for s, T in zip(sources, to_canonical)], workers)
            grids = np.zeros((len(sources),) + (resolution,) * 3, dtype=np.uint8)
            for row, (status, payload) in enumerate(results):
                if status == "ok":
                    grids[row] = payload
                else:
                    new_failures.append({"stage": "voxelize", "source": sources[row], "category": cats[row],
                                         "model_id": ids[row], "shard": path.name, "row": row,
                                         "reason": payload})
                    summary.failed += 1
            replace_dataset_atomically(path, "voxels", grids)  # also updates the index checksum
            summary.shards_done += 1
            summary.objects += len(sources)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    index = load_index(shard_dir)  # re-read: only our keys change
    index["failures"] = failures + new_failures
    index["voxels"] = {"resolution": resolution, "occupancy": OCCUPANCY_RULE,
                       "failed": len(new_failures)}
    write_json_atomic(index_path(shard_dir), index)
    summary.seconds = time.monotonic() - t0
    return summary
