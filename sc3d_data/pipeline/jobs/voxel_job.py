"""``sc3d-data voxelize SHARDS`` as a library (``voxelize_shards``): add ``voxels`` to existing shards; and the
voxelization of one mesh file shared with ``voxel_meshes.py`` (``voxelize --meshes``).

    For every object the source mesh recorded in the shard (``source``) is loaded with
    ``sc3d_data.io.meshes.load_mesh_triangles`` (exactly the geometry the renderer drew), moved
    into the canonical frame with the object's stored ``to_canonical`` and voxelized with
    ``sc3d_data.voxel.voxelize.voxelize_triangles``. The ``voxels`` dataset ``[N, G, G, G]`` is added
    to each shard atomically (``shards.replace_dataset_atomically``), one shard at a time.
    Resume: a shard that already holds ``voxels`` at the requested resolution is skipped
    unless objects of it failed (their ``voxelize`` failures): those objects are voxelized again
    and the shard rewritten with the other objects' grids kept (as ``render`` retries its
    failures); ``overwrite=True`` redoes every shard. The objects run on the local pool
    (``executor.py``: ``workers`` processes; a worker past ``--timeout``, or dying on all ``--retries``
    runs of its object, costs that object, retried by the next run) and the shards are the chunks of
    the loop ``render`` and ``import-r2n2`` write with (``shard_output.py``): the index's
    ``bytes``/``sha256`` of a shard are written right after it is rewritten, and the run holds
    the folder's write lock. An object that fails (mesh missing or unreadable) gets an all-empty
    grid so the shard stays rectangular, and is recorded in the index under ``failures`` with
    ``"stage": "voxelize"``, its shard, row and reason. The index and each rewritten shard (a file
    attribute, JSON) get ``"voxels": {"resolution": G, "occupancy": ...}``, over the render
    settings' voxel entries. When none of the source meshes exists (shards moved
    without their meshes) nothing is changed: one line names the folder, and no shard's grids
    are replaced by empty ones. A dataset of ``import-r2n2`` (R2N2's own voxels, no meshes) is refused in one line.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sc3d_data.io.shards import index_path, replace_dataset_atomically, voxels_attr
from sc3d_data.io.shard_reader import read_strings, refuse_changed
from sc3d_data.pipeline.executors.job import ExecOptions, Job, crash_if_asked
from sc3d_data.pipeline.run.plan import Task

#: why a shard to rewrite (its chunks copied undecoded) must be the one indexed (``refuse_changed``)
REWRITE_REFUSAL = ("voxelize would copy the damage into the rewritten shard and record it as good, so no shard "
                   "was changed: restore the file or render it again (render --overwrite)")
OCCUPANCY_RULE = ("surface-touching voxels + spanned voxel centres with |winding number| >= 0.5 "
                  "+ enclosed voxels (sc3d_data/voxel/voxelize.py)")


def limit_threads() -> None:
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


@dataclass
class VoxelizeShardsConfig(ExecOptions):
    """What the workers of ``voxelize SHARDS`` need (``ExecOptions``: ``workers`` and the
    per-object time limit ``timeout_s``, ``--timeout``): the resolution ``G`` and the dataset's
    face limit (index settings ``max_faces``)."""

    resolution: int = 32
    max_faces: int | None = None


@dataclass(frozen=True, eq=False)
class RowTask(Task):
    """One object of a shard: ``path`` its mesh file (``resolve_source``), ``source`` as the
    shard records it, ``row`` its row, ``to_canonical`` its stored 4x4 transform, ``source_file``
    the fingerprint its index entry recorded (None for shards of earlier versions)."""

    source: str = ""
    row: int = 0
    to_canonical: np.ndarray | None = None
    source_file: dict | None = None  # the mesh's fingerprint when it was rendered (io.source_fingerprint)


def voxelize_row_task(config: VoxelizeShardsConfig, backend: str, task: RowTask):
    """The job of one shard row (``executor.Job``, run by a worker): ``(pos, "ok", (voxels
    [G, G, G] bool, []))`` or ``(pos, "fail", reason)``; a mesh that changed since its object was
    rendered fails (its voxels would not match the images)."""
    from sc3d_data.io.source_fingerprint import source_change

    limit_threads()
    crash_if_asked(task.model_id)  # tests only
    if task.source_file is not None and (why := source_change(task.path, dict(task.source_file))) is not None:
        return task.pos, "fail", (f"{task.path}: changed since it was rendered ({why}); its voxels would not "
                                  "match its images: render it again, then voxelize")
    try:
        voxels = voxelize_source(task.path, task.to_canonical, config.resolution, config.max_faces)
        return task.pos, "ok", (voxels, [])
    except Exception as e:  # noqa: BLE001 - recorded per object, never aborts the shard
        return task.pos, "fail", f"{type(e).__name__}: {e}"


VOXELIZE_ROW = Job("voxelize", voxelize_row_task)


def resolve_source(source: str, meshes_root: str | None) -> str:
    """The mesh file of a shard's ``source``: an absolute one as recorded; a relative one (the
    render ran on a relative ``--meshes``) first as the longest tail of it that exists under the
    dataset's ``meshes`` root (index settings, absolute), and only then relative to the current
    folder, where another tree may hold a file of the same relative name."""
    p = Path(source)
    if p.is_absolute() or not meshes_root:
        return source
    parts = p.parts
    for k in range(len(parts)):
        candidate = Path(meshes_root) / Path(*parts[k:])
        if candidate.is_file():
            return str(candidate)
    return source


@dataclass
class VoxelizeSummary:
    """Counts of a voxelize run (``objects`` voxelized by this run, ``failed`` of them; ``--meshes``: ``objects`` files
    written, ``stale`` of them for a newer mesh, ``remade`` for another's or other settings, ``shards_skipped`` kept)."""

    shards_done: int = 0
    shards_skipped: int = 0
    objects: int = 0
    failed: int = 0
    kept: int = 0  # failed objects that kept the grid they had (``grid_kept``)
    seconds: float = 0.0
    reused: int = 0  # objects of retried shards whose grids an earlier run made, kept
    stale: int = 0
    remade: int = 0

    def as_dict(self) -> dict:
        """``done``/``resumed``/``failed`` (the keys of a part's summary) plus the fields."""
        return dict(vars(self), done=self.objects, resumed=self.shards_skipped)


def voxelize_shards(shard_dir: Path, resolution: int = 32, workers: int = 1, overwrite: bool = False,
                    progress: bool = False, timeout_s: float = 120.0, retries: int = 3) -> VoxelizeSummary:
    """Add ``voxels [N, G, G, G]`` to every shard of ``shard_dir`` (module doc); ``timeout_s``:
    the per-object time limit, seconds (``--timeout``); ``retries``: of an object whose worker died."""
    from sc3d_data.pipeline.jobs.shard_output import locked_output

    with locked_output(Path(shard_dir), "sc3d-data voxelize", create=False):
        return _voxelize_shards_locked(Path(shard_dir), resolution, workers, overwrite, progress, timeout_s, retries)


def _earlier_grid(path: Path, row: int) -> np.ndarray | None:
    """Row ``row`` of the ``voxels`` the shard ``path`` holds now, or None where it cannot be read."""
    from sc3d_data.io.shard_reader import open_shard

    try:
        with open_shard(path) as f:
            return f["voxels"][row]
    except (OSError, KeyError, ValueError):
        return None


def _read_rows(path: Path, resolution: int) -> tuple[bool, list, list, list, np.ndarray]:
    """``(has voxels at resolution, sources, model ids, categories, to_canonical [N, 4, 4])``
    of the shard ``path``; one line naming it when it is missing or broken."""
    from sc3d_data.io.shards import ShardError, io_reason
    from sc3d_data.io.shard_reader import open_shard

    if not path.is_file():
        raise FileNotFoundError(f"{path}: listed in {index_path(path.parent)} but missing")
    with open_shard(path) as f:
        if "to_canonical" not in f or "source" not in f:
            raise ValueError(f"{path}: no to_canonical/source datasets; cannot find the meshes")
        try:
            has = "voxels" in f and f["voxels"].shape[1:] == (resolution,) * 3
            return has, read_strings(f["source"]), read_strings(f["model_id"]), read_strings(f["category"]), \
                f["to_canonical"][()]
        except (OSError, KeyError, RuntimeError) as e:
            raise ShardError(f"{path}: broken shard ({io_reason(e)}); see `sc3d-data info --verify`") from e


def _kept_voxels(path: Path) -> np.ndarray:
    """The ``voxels [N, G, G, G]`` uint8 the shard ``path`` holds (a rerun retrying its failed
    objects keeps the others' grids); one line naming it when they cannot be read."""
    from sc3d_data.io.shards import ShardError, io_reason
    from sc3d_data.io.shard_reader import open_shard

    with open_shard(path) as f:
        try:
            return np.asarray(f["voxels"][()], dtype=np.uint8)
        except (OSError, KeyError, RuntimeError) as e:
            raise ShardError(f"{path}: broken shard ({io_reason(e)}); see `sc3d-data info --verify`") from e


def _voxelize_shards_locked(shard_dir: Path, resolution, workers, overwrite, progress, timeout_s, retries):
    """The shards are the chunks of ``shard_output.write_chunks``: row ``r`` of the ``c``-th
    shard listed is plan position ``c * K + r`` (``K`` = the most rows of a shard)."""
    from sc3d_data.io.shards import shard_path
    from sc3d_data.pipeline.executors.executor import start_executor
    from sc3d_data.pipeline.jobs.shard_output import ShardIndex, write_chunks

    t0 = time.monotonic()
    index = ShardIndex.load(shard_dir, lazy=False)
    settings = index.settings
    if settings.get("source") == "3D-R2N2":  # import-r2n2 (r2n2_job.ImportConfig.settings)
        g = settings.get("voxel_resolution", 32)
        raise ValueError(f"{shard_dir}: imported from 3D-R2N2 (sc3d-data import-r2n2): its objects carry R2N2's own "
                         f"{g}^3 voxels and it has no source meshes, so there is nothing to voxelize; nothing was "
                         "changed")
    paths = [shard_path(shard_dir, s["file"]) for s in index.shards]
    rows = [_read_rows(path, resolution) for path in paths]
    K = max([1] + [len(r[1]) for r in rows])
    summary = VoxelizeSummary()
    base = [f for f in index.failures if f.get("stage") != "voxelize"]
    by_shard = [[f for f in index.failures if f.get("stage") == "voxelize" and f.get("shard") == p.name]
                for p in paths]  # the voxelize failures of each shard, kept for a skipped shard
    todo, entries = [], {(o.get("shard"), o.get("row")): o for o in index.objects}
    retried: dict[int, set] = {}  # shard -> the rows whose voxelize failed, done again (the others kept)
    replaced = set()  # shards a voxelize killed before writing the index replaced: not checked, redone
    for c, (has, sources, ids, cats, to_canonical) in enumerate(rows):
        rows_todo = range(len(sources))
        # a shard whose size is not the index's was replaced by a voxelize killed before it wrote
        # the index (its voxels are whole: the replacement is atomic): done again, index recorded
        if has and index.shards[c].get("bytes") not in (None, paths[c].stat().st_size):
            replaced.add(c)
        elif has and not overwrite:
            rows_todo = retried[c] = {f.get("row") for f in by_shard[c]} & set(rows_todo)
            summary.reused += len(sources) - len(rows_todo)
            if not rows_todo:
                summary.shards_skipped += 1
                continue
        todo += [RowTask(c * K + r, resolve_source(sources[r], settings.get("meshes")), cats[r], ids[r], "",
                         sources[r], r, to_canonical[r], entries.get((paths[c].name, r), {}).get("source_file"))
                 for r in sorted(rows_todo)]
    refuse_changed(shard_dir, [index.shards[c] for c in sorted({t.pos // K for t in todo} - replaced)], REWRITE_REFUSAL)
    fresh = [t for t in todo if t.pos // K not in retried]  # a retried failure may well fail again
    if fresh and not any(Path(t.path).is_file() for t in fresh):
        under = f", also looked for under {settings['meshes']}" if settings.get("meshes") else ""
        raise ValueError(f"{shard_dir}: none of the {len(fresh)} source meshes its shards record exists (first: "
                         f"{fresh[0].source}{under}); no shard was changed: voxelize where the meshes are")
    bar = None
    if progress:
        from sc3d_data.pipeline.run.progress import progress_bar

        bar = progress_bar(total=len(paths), unit="shard", desc="voxelize")
        bar.update(summary.shards_skipped)

    made = {"resolution": resolution, "occupancy": OCCUPANCY_RULE}  # the index's and each shard's voxels record

    def store(c: int, results: list, last: bool) -> None:
        path = paths[c]
        # a retried shard keeps the grids of the objects not retried
        grids = _kept_voxels(path) if c in retried else np.zeros((len(rows[c][1]),) + (resolution,) * 3, np.uint8)
        by_shard[c] = [f for f in by_shard[c] if f.get("row") not in {t.row for t, _, _ in results}]
        for t, status, payload in results:
            if status == "ok":
                grids[t.row] = payload[0]
                continue
            failure = {"stage": "voxelize", "source": t.source, "category": t.category,
                       "model_id": t.model_id, "shard": path.name, "row": t.row, "reason": payload}
            # a retried shard's grids are the ones it holds (this row untouched yet): no second read
            earlier = grids[t.row] if c in retried else _earlier_grid(path, t.row) if rows[c][0] else None
            if earlier is not None and earlier.any():  # a grid made before from the mesh as rendered
                grids[t.row] = earlier
                failure.update(reason=f"{payload}; its earlier grid is kept", grid_kept=True)
                summary.kept += 1
            by_shard[c].append(failure)
        index.shards[c]["sha256"] = replace_dataset_atomically(path, "voxels", grids, False, voxels_attr(made))
        index.shards[c]["bytes"] = path.stat().st_size
        index.failures = base + [f for fails in by_shard for f in fails]
        summary.shards_done += 1
        summary.objects += len(results)
        summary.failed += len(by_shard[c])
        if bar is not None:
            bar.update(1)

    config = VoxelizeShardsConfig(resolution=resolution, max_faces=settings.get("max_faces"), workers=workers,
                                  timeout_s=timeout_s, retries=retries)
    n_workers = max(1, min(workers, len(todo)))
    pool = start_executor(config, n_workers, VOXELIZE_ROW) if todo else None
    try:
        write_chunks(index, pool, todo, K, n_workers, store)
    finally:
        if pool is not None:
            pool.close()
        if bar is not None:
            bar.close()
    index.failures = base + [f for fails in by_shard for f in fails]
    index.extra["voxels"] = {**made, "failed": sum(map(len, by_shard))}
    index.write()
    summary.seconds = time.monotonic() - t0
    return summary
