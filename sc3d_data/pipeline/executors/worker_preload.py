"""What every local worker process needs before its first object, loaded ONCE per run in the
``forkserver`` process that ``local_pool`` forks its workers from.

A spawned worker imports trimesh (~0.6 CPU-s, scipy included) and loads the voxelizer's
compiled numba kernels (~0.3 CPU-s) by itself; with two workers on two cores that is ~2 of the
~12 CPU-seconds of rendering 195 meshes. Forked from a server that did it once, a worker starts
with both in memory (copy-on-write) and only makes its GL context.

Importing this module has that side effect on purpose: it imports ``trimesh`` and voxelizes an
open unit box at ``8^3`` so that every kernel ``voxelize_triangles`` calls is compiled or read
from numba's cache. Then it moves every object made so far into the garbage collector's
permanent generation (``gc.freeze``): collections in a worker no longer walk the ~240,000
objects of the imported modules (half of its ~0.8 ms of collection per object), nor write to
their pages (shared with the server). ``worker_preload_egl`` adds PyOpenGL and pyrender's EGL
platform module (~0.25 s per worker): imported only, no display or context is made, so no GL
state is ever inherited through a fork; a server that has it serves EGL workers only
(``local_pool.worker_context``), since ``PYOPENGL_PLATFORM`` is fixed at PyOpenGL's import.
"""
from __future__ import annotations

import gc
import time
from importlib import import_module

import numpy as np

from sc3d_data.geometry.triangle_area import triangles_with_area
from sc3d_data.voxel.voxelize import voxelize_triangles


def warm_voxelizer() -> None:
    """Run the area kernel of ``load_mesh`` and the voxelizer once on an open unit box (12
    triangles minus one side: the six axis rays disagree inside it, so the winding-number kernel
    runs too)."""
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4)]  # no +z side
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int64)
    triangles_with_area(corners, faces)  # load_mesh's kernel, compiled with the voxelizer's
    voxelize_triangles(corners, faces, resolution=8)


#: what the server's preload took: ``{step name: seconds}`` plus ``"ended"`` (``time.monotonic``,
#: one clock for every process of the machine); the workers inherit it through the fork, and
#: ``benchmarks/stage_profile.py`` reads it there to split a worker's wait for its start
PRELOAD_SECONDS: dict[str, float] = {}


def best_effort(step, *args) -> None:
    """Run ``step(*args)``; an error is dropped. The forkserver only swallows ImportError, and a
    server that dies at start-up fails every worker of the run; a worker that needs what
    failed here does it again itself and reports the error with its object."""
    t0 = time.monotonic()
    try:
        step(*args)
    except Exception:  # noqa: BLE001 - see above
        pass
    PRELOAD_SECONDS[getattr(step, "__name__", str(step)) + "".join(f" {a}" for a in args)] = time.monotonic() - t0
    PRELOAD_SECONDS["ended"] = time.monotonic()


def import_gl(backend: str) -> None:
    """Import PyOpenGL and pyrender's platform module for ``backend`` (no context is made)."""
    from sc3d_data.render.gl_backend import activate

    activate(backend)
    import_module(f"pyrender.platforms.{backend}")


best_effort(import_module, "trimesh")  # the import is the point: workers inherit it
best_effort(warm_voxelizer)
gc.freeze()
