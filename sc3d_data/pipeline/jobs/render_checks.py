"""What ``sc3d-data render`` refuses before any work, in one line naming the option: values out
of what the renderer draws or this machine's memory holds, so that a typo fails at once and not
as one worker failure per object blaming the mesh.

Among them, the camera: a camera inside the object's unit cube (``--distance`` at most
``sqrt(3) / 2``), elevations outside [-90, 90] degrees (a camera past the pole sees the object
upside down, while the shards would record the elevation as given) or listed twice (every view
stored, and trained on, twice), and a camera that shows the
object smaller than a pixel (the object, normalised to at most 1 unit, spans ``f / distance``
pixels at the focal length ``f = (S / 2) / tan(fov / 2)``: with ``--fov 179.9`` or ``--distance
1e6`` every silhouette would be empty and every object fail as if its mesh were broken).
"""
from __future__ import annotations

import math

#: largest framebuffer side the renderer asks for (GL_MAX_RENDERBUFFER_SIZE of Mesa and NVIDIA)
MAX_ATLAS_SIDE = 16384
MAX_VOXEL_RESOLUTION = 512


def object_pixels(fov_deg: float, distance: float, image_size: int) -> float:
    """Pixels that 1 unit at the object's centre spans in an ``image_size`` image taken from
    ``distance`` with the field of view ``fov_deg`` (degrees)."""
    return (image_size / 2) / math.tan(math.radians(fov_deg) / 2) / distance


#: the error of ``--gpus`` (EGL devices) with ``--backend osmesa`` (the CPU)
GPUS_NEED_EGL = "--gpus names EGL devices and --backend osmesa renders on the CPU: give one of them"


def check_render_config(config, n_workers: int = 1) -> None:
    """Raise ``ValueError`` naming the option when a value of ``config`` (a ``RenderConfig``) is
    out of what the renderer or this machine's memory can do (module doc)."""
    if config.gpus and config.backend == "osmesa":  # for every executor, before any work is sent
        raise ValueError(GPUS_NEED_EGL)
    if not config.elevations:  # `--elevations ''` or `,`: no view to render (and no atlas to size)
        raise ValueError("--elevations: give at least one elevation")
    views = config.num_views * len(config.elevations)
    cols = math.ceil(math.sqrt(views))
    side = config.image_size * max(cols, math.ceil(views / cols))
    if side > MAX_ATLAS_SIDE:
        most = MAX_ATLAS_SIDE // max(cols, math.ceil(views / cols))
        raise ValueError(f"--image-size {config.image_size}: {views} views need a {side}x{side} framebuffer, "
                         f"over the renderer's limit of {MAX_ATLAS_SIDE}; at most --image-size {most} "
                         f"with {views} views")
    if not 2 <= config.voxel_resolution <= MAX_VOXEL_RESOLUTION:
        raise ValueError(f"--voxel-resolution {config.voxel_resolution}: must be 2 to {MAX_VOXEL_RESOLUTION}")
    if not 0 < config.fov_deg < 180:
        raise ValueError(f"--fov {config.fov_deg}: must be between 0 and 180 degrees")
    if not 0 < config.distance < math.inf:
        raise ValueError(f"--distance {config.distance}: must be a positive number")
    from sc3d_data.geometry.camera import MIN_DISTANCE

    if config.distance <= MIN_DISTANCE:
        raise ValueError(f"--distance {config.distance}: must be more than {MIN_DISTANCE:.3f} (sqrt(3)/2, the "
                         "farthest corner of the object's unit cube): a nearer camera can be inside the object")
    if not all(math.isfinite(e) for e in config.elevations):
        raise ValueError(f"--elevations {','.join(map(str, config.elevations))}: must be finite numbers")
    if not all(-90 <= e <= 90 for e in config.elevations):
        raise ValueError(f"--elevations {','.join(map(str, config.elevations))}: must lie between -90 and 90 "
                         "degrees (past the pole the camera sees the object upside down)")
    if len(set(config.elevations)) < len(config.elevations):  # the same views stored twice, trained on twice
        raise ValueError(f"--elevations {','.join(map(str, config.elevations))}: lists an elevation twice; "
                         "each elevation gives its own views")
    if (px := object_pixels(config.fov_deg, config.distance, config.image_size)) < 1:
        raise ValueError(f"--fov {config.fov_deg} with --distance {config.distance} and --image-size "
                         f"{config.image_size}: the object (at most 1 unit) would span {px:.2g} pixels; every "
                         "silhouette would be empty")
    from sc3d_data.formats.shapenet import check_axes

    check_axes(config.up, config.front)
    if not config.timeout_s > 0:
        raise ValueError(f"--timeout {config.timeout_s}: must be > 0 seconds")
    if config.objects_per_shard < 1 or config.max_faces < 1 or config.max_file_mib < 1:
        raise ValueError("--objects-per-shard, --max-faces and --max-file-mib must be >= 1")
    per_object = views * config.image_size ** 2 * (4 + (4 if config.depth else 0))
    if config.voxelize:
        per_object += config.voxel_resolution ** 3
    # the main process holds up to 2 chunks + one object per worker (see render_dataset)
    held = per_object * (2 * config.objects_per_shard + n_workers)
    # each worker: one object's arrays + framebuffer + voxelizer work space (~16 B/voxel)
    held += n_workers * (2 * per_object + (16 * config.voxel_resolution ** 3 if config.voxelize else 0))
    import psutil

    avail = psutil.virtual_memory().available
    if held > avail:
        raise ValueError(f"--views {config.num_views} x {len(config.elevations)} elevation(s) / --image-size "
                         f"{config.image_size} / --voxel-resolution {config.voxel_resolution} / "
                         f"--objects-per-shard {config.objects_per_shard} / --workers {n_workers}: "
                         f"would need about {held / 2**30:.1f} GiB of memory, {avail / 2**30:.1f} GiB available")
