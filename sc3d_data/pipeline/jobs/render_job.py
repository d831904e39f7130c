"""One object's work for ``sc3d-data render``: the run's settings (:class:`RenderConfig`), the
unit of work (``run.plan.Task``), the function every executor runs on it (:func:`render_task`)
and the job that runs it (:data:`RENDER`).

Executors (``local_pool``, ``ray_executor``, ``slurm_executor``) only move tasks and results;
what happens to one object is defined here once: load, validate, normalise into the canonical
frame, render ``V`` views (``[V,S,S,3]`` uint8 RGB, ``[V,S,S]`` masks, explicit cameras
``K [V,3,3]``, ``R [V,3,3]``, ``t [V,3]``, OpenCV, world = canonical frame) and optionally
voxelize (``[G,G,G]``). A worker process keeps one ``MeshRenderer`` (one GL context) for all
the objects it handles (:func:`cached_renderer`).
"""
from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from sc3d_data.geometry.camera import DEFAULT_DISTANCE, DEFAULT_FOV_DEG, DEFAULT_IMAGE_SIZE, DEFAULT_NUM_VIEWS, ViewSettings
from sc3d_data.io.meshes import DEFAULT_MAX_FACES, DEFAULT_MAX_FILE_BYTES
from sc3d_data.pipeline.executors.job import THREAD_ENV, Job, crash_if_asked
from sc3d_data.pipeline.run.partition import Part
from sc3d_data.pipeline.run.plan import Task
from sc3d_data.io.shards import ObjectRecord, border_clipped, encode_arrays

REPO_ROOT = Path(__file__).resolve().parents[3]
SAMPLE_MESHES = REPO_ROOT / "assets" / "sample_meshes"
#: settings that do not change the output; they may differ between a run and its resume
RUNTIME_ONLY = ("workers", "progress", "timeout_s", "retry_failed", "part", "executor", "address",
                "retries", "gpus")


@dataclass
class RenderConfig:
    """Every option of ``sc3d-data render`` (see ``cli/data_render.py`` for their meaning)."""

    out: Path
    meshes: Path = SAMPLE_MESHES
    num_views: int = DEFAULT_NUM_VIEWS
    elevations: tuple[float, ...] = (30.0,)
    image_size: int = DEFAULT_IMAGE_SIZE
    fov_deg: float = DEFAULT_FOV_DEG
    distance: float = DEFAULT_DISTANCE
    background: tuple[int, int, int] = (255, 255, 255)
    depth: bool = False
    normalize: str = "fit"
    up: str = "+Y"
    front: str = "auto"
    backend: str = "auto"
    voxelize: bool = False
    voxel_resolution: int = 32
    categories: str | None = None
    category: str | None = None
    split: str = "random:0.7,0.1,0.2"
    split_file: str | list[str] | None = None  # a file, a directory of them, or several (splits.split_files_of)
    seed: int = 0
    objects_per_shard: int = 256
    chunks: str = "view"  # HDF5 chunk layout of the images (sc3d_data.io.shards.CHUNK_LAYOUTS)
    max_faces: int = DEFAULT_MAX_FACES
    max_file_mib: int = DEFAULT_MAX_FILE_BYTES // 2**20  # mesh files over this are not parsed
    bad_texture: str = "fail"
    outside_textures: str = "warn"
    timeout_s: float = 120.0
    workers: int = 0  # 0 = number of CPU cores
    overwrite: bool = False
    progress: bool = True
    retry_failed: bool = True
    part: Part = Part(0, 1)  # this run's share of the plan (run/partition.py)
    executor: str = "local"  # local | ray (slurm runs parts through slurm_executor)
    address: str | None = None  # ray: cluster address, None = a local cluster for the run
    retries: int = 3  # re-runs of an object whose worker process died
    gpus: tuple[int, ...] = ()  # EGL devices the workers are spread over (executors/devices.py); () = as today

    def validate(self, n_workers: int = 1) -> None:
        """Raise ``ValueError`` naming the option when a value is out of what the renderer or
        this machine's memory can do (``render_checks.check_render_config``)."""
        from sc3d_data.pipeline.jobs.render_checks import check_render_config

        check_render_config(self, n_workers)

    def view_settings(self) -> ViewSettings:
        return ViewSettings(num_views=self.num_views, elevations_deg=tuple(self.elevations),
                            distance=self.distance, fov_deg=self.fov_deg, image_size=self.image_size)

    def settings(self, backend: str) -> dict:
        """JSON-able record of every setting that shapes the output (stored in shards and index)."""
        from sc3d_data.formats.splits import absolute_split_file

        d = {k: v for k, v in asdict(self).items() if k not in RUNTIME_ONLY + ("out", "overwrite")}
        d["meshes"] = str(Path(self.meshes).resolve())
        d["split_file"] = absolute_split_file(self.split_file)
        d["elevations"] = [float(e) for e in self.elevations]
        d["background"] = [int(c) for c in self.background]
        d["backend"] = backend
        d["requested_backend"] = self.backend
        from sc3d_data.render.renderer import RenderSettings

        rs = RenderSettings()
        d["lighting"] = {"headlight_intensity": rs.light_intensity, "ambient": rs.ambient, "shading": rs.shading,
                         "msaa_samples": 0}
        return d



def render_one(renderer, task: Task, config: RenderConfig) -> tuple[ObjectRecord, list[str]]:
    """Load, validate, normalise, render (and voxelize) one object in this process: the draws
    are submitted first and the pixels read after voxelizing (``MeshRenderer.draw`` / ``read``),
    so a GPU renders while the CPU voxelizes; an empty silhouette is reported before an error of
    the voxelizer, as when the two ran in turn. Returns the shard record and warnings; raises on
    bad input."""
    from sc3d_data.formats.shapenet import resolve_front
    from sc3d_data.geometry.triangle_area import all_needles
    from sc3d_data.geometry.normalize import to_canonical_transform
    from sc3d_data.io.materials import dataset_folder
    from sc3d_data.io.meshes import MeshError, load_mesh
    from sc3d_data.io.source_fingerprint import fingerprint, material_fingerprints
    from sc3d_data.pipeline.jobs.voxel_job import voxelize_canonical

    source_file = fingerprint(task.path)  # before reading: an edit during the render counts as a change
    root = dataset_folder(config.meshes)
    if source_file is not None and source_file["bytes"] <= config.max_file_mib * 2**20:  # a larger one is refused unread
        source_file["materials"] = material_fingerprints(task.path, root)
    scene, vertices, faces, warnings = load_mesh(Path(task.path), config.max_faces, config.bad_texture, root=root,
                                                 outside_textures=config.outside_textures,
                                                 max_file_bytes=config.max_file_mib * 2**20)
    try:
        to_canonical = to_canonical_transform(vertices, faces, config.normalize, config.up,
                                              resolve_front(config.front, task.path))
    except ValueError as e:
        raise MeshError(f"{task.path}: {e}") from e
    renderer.draw(scene, to_canonical)  # a GPU draws while this process voxelizes
    voxels, voxel_error = None, None
    try:
        voxels = voxelize_canonical(vertices, faces, to_canonical, config.voxel_resolution) if config.voxelize else None
    except Exception as e:  # noqa: BLE001 - raised after the pixels are read and checked
        voxel_error = e
    arrays = renderer.read()
    if not np.asarray(arrays["masks"]).any():
        if all_needles(vertices, faces):
            raise MeshError(f"{task.path}: every triangle of it has its corners on one line (but for rounding), so it "
                            "has no surface to draw")
        raise MeshError(f"{task.path}: the silhouette is empty in every view after normalisation (geometry "
                        "collapsed to under a pixel, e.g. by an outlier vertex far from the rest)")
    if voxel_error is not None:
        raise voxel_error
    cams = renderer.cameras
    arrays.update({k: cams[k] for k in ("K", "R", "t", "azimuth", "elevation", "distance")})
    arrays["clipped"] = border_clipped(arrays["masks"])
    arrays["to_canonical"] = to_canonical
    if voxels is not None:
        arrays["voxels"] = voxels
    record = ObjectRecord(model_id=task.model_id, category=task.category, split=task.split,
                          source=task.path, arrays=arrays, source_file=source_file)
    return record, warnings


#: a worker gives freed heap back to the OS once its resident memory has grown this much (bytes)
#: since it last did: bounds what one big mesh or texture keeps, without trimming after every
#: object (``malloc_trim`` walks the whole heap: ~1.7 ms, 3% of an object's work)
TRIM_GROWTH = 64 * 2**20
_trim_state = {"libc": None, "rss_after_trim": 0}


def _release_memory() -> None:
    """Give freed heap pages back to the OS (glibc ``malloc_trim``) when the resident set has
    grown by ``TRIM_GROWTH`` since the last trim, so that one big mesh or texture does not keep a
    worker's RSS high for the rest of the run; no-op where there is no glibc."""
    import ctypes

    import psutil

    if psutil.Process().memory_info().rss < _trim_state["rss_after_trim"] + TRIM_GROWTH:
        return
    try:
        if _trim_state["libc"] is None:
            _trim_state["libc"] = ctypes.CDLL("libc.so.6")
        _trim_state["libc"].malloc_trim(0)
    except (OSError, AttributeError):
        return
    _trim_state["rss_after_trim"] = psutil.Process().memory_info().rss


def _backend_order(backend: str) -> tuple[str, ...]:
    from sc3d_data.render.gl_backend import BACKENDS

    return tuple(BACKENDS) if backend == "auto" else (backend,)


_RENDERERS: dict = {}


def cached_renderer(config: RenderConfig, backend: str):
    """``(renderer, backend)`` of this process for ``config``'s view/render settings, made on
    first use and kept (one GL context per worker process). ``backend="auto"`` tries EGL, then
    OSMesa; ``BackendError`` naming the packages when none works."""
    from sc3d_data.render.gl_backend import BackendError, DeviceError, install_hint
    from sc3d_data.render.renderer import MeshRenderer, RenderSettings

    key = (config.view_settings(), tuple(config.background), config.depth, backend)
    if key not in _RENDERERS:
        for k, v in THREAD_ENV.items():
            os.environ.setdefault(k, v)
        errors = []
        for name in _backend_order(backend):
            try:
                r = MeshRenderer(config.view_settings(), RenderSettings(background=tuple(config.background),
                                                                        depth=config.depth), name)
            except DeviceError:  # a named device: no other backend to try, nothing to install
                raise
            except Exception as e:  # noqa: BLE001 - next backend; all reasons are reported
                errors.append(f"{name}: {type(e).__name__}: {e}")
                continue
            _RENDERERS[key] = (r, name)
            break
        else:
            raise BackendError("no headless OpenGL backend works:\n  " + "\n  ".join(errors) + "\n" + install_hint())
    return _RENDERERS[key]


def failure_reason(task: Task, e: BaseException) -> str:
    """One line for a failed object: the ``MeshError`` message (names the file) or the file plus
    the exception."""
    return str(e) if type(e).__name__ == "MeshError" else f"{task.path}: {type(e).__name__}: {e}"


def render_task(config: RenderConfig, backend: str, task: Task) -> tuple[int, str, object]:
    """The unit of work of every executor: ``(pos, "ok", (record, warnings))`` or
    ``(pos, "fail", reason)``; the record's bulk arrays come compressed as the shard stores
    them (``shards.encode_arrays``: compression runs in the workers, not in the writer). Bad
    input never raises; a crash or hang of this process is the
    executor's to catch (it kills and replaces the worker)."""
    renderer, _ = cached_renderer(config, backend)
    crash_if_asked(task.model_id)  # tests only
    try:
        record, warnings = render_one(renderer, task, config)
        return task.pos, "ok", (encode_arrays(record, config.chunks), warnings)
    except Exception as e:  # noqa: BLE001 - recorded per object, never aborts the run
        return task.pos, "fail", failure_reason(task, e)
    finally:
        _release_memory()


def render_setup(config: RenderConfig, backend: str) -> str:
    """Make this worker's renderer (:func:`cached_renderer`); the GL backend it got."""
    return cached_renderer(config, backend)[1]


def drop_renderers() -> None:
    """Close and forget this process's cached renderers."""
    for renderer, _ in _RENDERERS.values():
        try:
            renderer.close()
        except Exception:  # noqa: BLE001 - it is being dropped
            pass
    _RENDERERS.clear()


RENDER = Job("render", render_task, setup=render_setup, drop=drop_renderers, gl=True)
