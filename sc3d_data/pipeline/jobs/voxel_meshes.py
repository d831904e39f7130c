"""``sc3d-data voxelize --meshes DIR --out DIR2`` as a library: one ``.binvox`` per mesh.

Every mesh under ``meshes`` (``sc3d_data.formats.discover`` layouts) is normalised like
``render`` does (``--normalize``/``--up``/``--front``) and written to
``out/<same relative path>.binvox`` (sc3d header: translate -0.5, scale 1) by the worker
that voxelized it (job ``VOXELIZE_MESH`` on the local pool or Ray, ``executor.py``, with
the per-mesh time limit ``--timeout``; ``--executor slurm``: ``slurm_executor``). Existing
``.binvox`` files are complete (written atomically) and skipped on a rerun when their header has
the run's resolution (another is done again) and their mesh file is not newer than they are (an
edited mesh is done again: :func:`mesh_is_newer`) and ``binvox_sources``' record names this mesh and
the run's settings for them (else done again), so a crash or
Ctrl-C loses no finished file; failures (with the reason: error, time limit, worker
killed) go to ``out/failures.json``, sorted by source. The settings that decide a grid
(resolution, normalisation, axes) are recorded in ``out/voxelize.json``; a rerun with others is
refused (``--overwrite`` redoes every file with the new ones). With ``part`` (``--part I/N``) only
the meshes of that part (``sc3d_data.pipeline.run.partition``) are done and failures go to
``out/failures.part-00I-of-00N.json``, so N jobs can share one ``out`` folder.
(Shards: voxelize each part folder of a partitioned render, or render with ``--voxelize``.)
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sc3d_data.io.binvox import binvox_intact
from sc3d_data.io.shards import write_json_atomic
from sc3d_data.pipeline.jobs.binvox_sources import mesh_identity, record_sources, recorded_sources
from sc3d_data.pipeline.executors.job import ExecOptions, Job
from sc3d_data.pipeline.executors.slurm_executor import SlurmOptions, run_array, summed_parts
from sc3d_data.pipeline.run.partition import Part
from sc3d_data.pipeline.run.plan import Task
from sc3d_data.pipeline.jobs.voxel_job import VoxelizeSummary, limit_threads, voxelize_canonical


@dataclass
class VoxelMeshesConfig(ExecOptions):
    """Every option of ``sc3d-data voxelize --meshes DIR --out DIR2`` (and, from
    ``ExecOptions``, where and how long each mesh runs)."""

    meshes: Path
    out: Path
    resolution: int = 32
    normalize: str = "fit"
    up: str = "+Y"
    front: str = "auto"
    overwrite: bool = False
    progress: bool = True  # a progress bar / log lines on stderr
    part: Part = Part(0, 1)
    workers: int = field(default=1, kw_only=True)  # voxelize's --workers default (ExecOptions: 0)


def mesh_name(config: VoxelMeshesConfig, path) -> str:
    """The mesh ``path`` relative to ``config.meshes`` (its name for one mesh file), as ``binvox_sources`` records it."""
    meshes = Path(config.meshes)
    return (Path(path).relative_to(meshes) if meshes.is_dir() else Path(Path(path).name)).as_posix()


def binvox_target(config: VoxelMeshesConfig, path: str) -> Path:
    """``out/<path relative to meshes>.binvox`` (``out/<name>.binvox`` for one mesh file)."""
    return Path(config.out) / Path(mesh_name(config, path)).with_suffix(".binvox")


def voxelize_mesh_task(config: VoxelMeshesConfig, backend: str, task: Task):
    """The job of one mesh (``executor.Job``, run by a worker): load, normalise as ``render``
    does, voxelize to ``[G, G, G]`` and write its ``.binvox`` (atomically). ``(pos, "ok",
    (target path, []))`` or ``(pos, "fail", reason)``."""
    limit_threads()
    try:
        from sc3d_data.io.binvox import write_binvox
        from sc3d_data.io.meshes import load_mesh_triangles
        from sc3d_data.geometry.normalize import to_canonical_transform
        from sc3d_data.formats.shapenet import resolve_front

        vertices, faces = load_mesh_triangles(Path(task.path))
        T = to_canonical_transform(vertices, faces, mode=config.normalize, up=config.up,
                                   front=resolve_front(config.front, task.path))
        target = binvox_target(config, task.path)
        target.parent.mkdir(parents=True, exist_ok=True)
        write_binvox(target, voxelize_canonical(vertices, faces, T, config.resolution))
        return task.pos, "ok", (str(target), [])
    except Exception as e:  # noqa: BLE001 - recorded per mesh, never aborts the run
        return task.pos, "fail", f"{type(e).__name__}: {e}"


def warm_voxelizer(config: VoxelMeshesConfig, backend: str) -> str:
    """Load the voxelizer's compiled kernels in this worker (one tetrahedron at ``config.resolution``)
    so that it does not count against the first mesh's time limit."""
    from sc3d_data.voxel.voxelize import voxelize_triangles

    if config.resolution not in _WARM:
        limit_threads()
        tet = np.array([[-0.3, -0.3, -0.3], [0.3, -0.3, -0.3], [0, 0.3, -0.3], [0, 0, 0.3]])
        voxelize_triangles(tet, np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]]), config.resolution)
        _WARM.add(config.resolution)
    return backend


_WARM: set = set()  # resolutions warmed up in this process


VOXELIZE_MESH = Job("voxelize", voxelize_mesh_task, setup=warm_voxelizer)


def voxelize_meshes(config: VoxelMeshesConfig) -> VoxelizeSummary:
    """One ``.binvox`` per mesh under ``config.meshes``, same relative paths under ``config.out``
    (module doc), on the executor of ``config.executor`` (local pool or Ray; per-mesh time
    limit ``config.timeout_s``)."""
    from sc3d_data.formats.discover import discover_meshes, no_meshes_found

    from sc3d_data.formats.shapenet import check_axes

    check_axes(config.up, config.front)
    t0 = time.monotonic()
    out, part = Path(config.out), config.part
    entries, problems = discover_meshes(Path(config.meshes))
    if not entries and not problems:
        raise no_meshes_found(config.meshes)
    out.mkdir(parents=True, exist_ok=True)
    with folder_locks(out, part):
        return _voxelize_entries(config, out, part, entries, problems, t0)


def folder_locks(out: Path, part: Part):
    """The write locks of ``out`` (``sc3d_data.io.outlock``) for ``voxelize --meshes``: a whole run
    holds the folder's lock alone; a part shares it with the other parts of its job and holds
    its own part's lock alone (two runs of one part, or a whole run beside a part, would
    write the same files)."""
    from contextlib import ExitStack

    from sc3d_data.io.outlock import LOCK_NAME, exclusive_lock

    stack = ExitStack()
    command = "sc3d-data voxelize --meshes" + ("" if part.whole else f" --part {part.index}/{part.count}")
    try:
        stack.enter_context(exclusive_lock(out, command, shared=not part.whole))
        if not part.whole:
            stack.enter_context(exclusive_lock(out, command, name=f"{LOCK_NAME}.{part.dirname()}"))
    except BaseException:
        stack.close()
        raise
    return stack


def _voxelize_entries(config: VoxelMeshesConfig, out: Path, part: Part, entries: list, problems: list,
                      t0: float) -> VoxelizeSummary:
    """:func:`voxelize_meshes` once ``out``'s locks are held."""
    from sc3d_data.pipeline.run.partition import part_of

    check_grid_settings(config)
    summary = VoxelizeSummary()
    if not part.whole:
        entries = [e for e in entries if part_of(e.category, e.model_id, part.count) == part.index]
        problems = problems if part.index == 0 else []
    # stale: pos -> (the .binvox there, why it is redone: "stale" (a newer mesh), "remade" (binvox_sources), None (--overwrite))
    todo, stale = [], {}
    recorded, now, record, names = recorded_sources(out), grid_settings(config), {}, []
    for e in entries:  # a file of another resolution, cut short or unreadable is done again
        target = binvox_target(config, str(e.path))
        name, source = target.relative_to(out).as_posix(), mesh_identity(mesh_name(config, e.path), e.path)
        there = target.is_file()
        if not config.overwrite and there and binvox_intact(target, config.resolution):
            newer, same = mesh_is_newer(e.path, target), recorded.get(name, (source, now)) == (source, now)
            if same and not newer:
                summary.shards_skipped += 1
                record[name] = (source, now)
                continue
            stale[len(todo)] = (target, "stale" if newer else "remade")
        elif there and config.overwrite:
            stale[len(todo)] = (target, None)
        if there:  # until it is done again (a stopped run): its old record, or one no run keeps
            record[name] = recorded.get(name, (source, None))
        todo.append(Task(len(todo), str(e.path), e.category, e.model_id, ""))
        names.append((name, source))
    failures = [dict(p) for p in problems]
    summary.failed = sum(1 for p in problems if not p.get("skipped"))  # counted as render counts them
    try:
        _run_todo(config, todo, stale, names, now, record, failures, summary)
    finally:  # also when stopped: the files done so far
        record_sources(out, part, record)
    failures.sort(key=lambda f: f["source"])
    write_json_atomic(out / failures_name(part), failures)
    if part.whole:  # it covered every part's meshes: the parts' lists are out of date
        for stale_list in out.glob("failures.part-*-of-*.json"):
            stale_list.unlink(missing_ok=True)
    summary.seconds = time.monotonic() - t0
    return summary


def _run_todo(config: VoxelMeshesConfig, todo: list, stale: dict, names: list, now: dict, record: dict,
              failures: list, summary: VoxelizeSummary) -> None:
    """Voxelize ``todo`` on the run's executor: each file made goes into ``record`` (``names``: the
    ``(binvox name, mesh name)`` of each task), each failure into ``failures`` (a ``stale`` file
    of a mesh that fails is removed, and its record with it)."""
    import os

    from sc3d_data.pipeline.executors.executor import start_executor

    if not todo:
        return
    n = max(1, min(config.workers or os.cpu_count() or 1, len(todo)))
    pool, bar = start_executor(config, n, VOXELIZE_MESH), None
    try:
        if config.progress:
            from sc3d_data.pipeline.run.progress import progress_bar

            bar = progress_bar(total=len(todo), unit="mesh", desc="voxelize")
        for pos, status, payload in pool.run(todo):
            name, source = names[pos]
            if status == "ok":
                summary.objects += 1
                if pos in stale and stale[pos][1]:
                    setattr(summary, stale[pos][1], getattr(summary, stale[pos][1]) + 1)
                record[name] = (source, now)
            else:
                failures.append({"source": todo[pos].path, "reason": payload})
                summary.failed += 1
                if pos in stale:  # the grid of a mesh that is no more (or of another) would pass for this one's
                    stale[pos][0].unlink(missing_ok=True)
                    record.pop(name, None)
                    why = {"stale": "of the mesh before it changed", "remade": "made by another mesh or with other "
                           "settings", None: "made before --overwrite"}[stale[pos][1]]
                    failures[-1]["removed"] = f"{stale[pos][0]} ({why})"
            if bar is not None:
                bar.update(1)
    finally:
        pool.close()
        if bar is not None:
            bar.close()


def mesh_is_newer(mesh: Path, binvox: Path) -> bool:
    """Whether ``mesh`` was modified after ``binvox`` was written (``make``'s rule: an edited or
    re-exported mesh is voxelized again; a file whose times cannot be read counts as newer)."""
    try:
        return Path(mesh).stat().st_mtime_ns > binvox.stat().st_mtime_ns
    except OSError:
        return True


#: the file under ``--out`` recording the settings that decide every grid in the folder
GRID_SETTINGS_NAME = "voxelize.json"


def grid_settings(config: VoxelMeshesConfig) -> dict:
    """The settings that decide a ``.binvox`` grid: resolution and the frame it is taken in."""
    return {"resolution": config.resolution, "normalize": config.normalize, "up": config.up, "front": config.front}


def check_grid_settings(config: VoxelMeshesConfig) -> None:
    """Record :func:`grid_settings` in ``out/voxelize.json``; ``ValueError`` naming the folder and
    the differences when it already holds grids made with other settings (a rerun would skip
    the existing files and leave a folder of mixed grids), unless ``config.overwrite``."""
    import json

    path = Path(config.out) / GRID_SETTINGS_NAME
    now = grid_settings(config)
    try:
        was = json.loads(path.read_text())
    except (OSError, ValueError):
        was = None
    if was == now:
        return
    if isinstance(was, dict) and not config.overwrite:
        changed = ", ".join(f"--{k} {was.get(k)!r} -> {now[k]!r}" for k in now if was.get(k) != now[k])
        raise ValueError(f"{config.out}: holds .binvox files voxelized with other settings ({changed}); a rerun "
                         "skips existing files, so the folder would mix grids: use another --out, or --overwrite "
                         "to redo them all")
    write_json_atomic(path, now, shared=True)  # --part jobs may write it at the same time


def failures_name(part: Part) -> str:
    """The file under ``--out`` listing the failures of ``part``: ``failures.json`` for a whole run."""
    return "failures.json" if part.whole else f"failures.{part.dirname()}.json"


def voxelize_part(config) -> dict:
    """What one array task of ``voxelize --meshes`` runs."""
    return voxelize_meshes(config).as_dict()


def voxelize_on_slurm(config, options: SlurmOptions) -> dict:
    """``voxelize --meshes`` of ``config`` (``voxel_meshes.VoxelMeshesConfig``) as a job array whose
    parts share ``config.out`` (one ``.binvox`` per mesh; failures in
    ``failures.part-00I-of-00N.json``); the summed ``VoxelizeSummary`` fields."""
    t0 = time.monotonic()
    _, summaries = run_array(voxelize_part, config, options, shared_out=True)
    return summed_parts(summaries, ("done", "resumed", "failed"), t0, config)
