"""Find a working headless OpenGL backend by rendering a box with sc3d's own renderer.

``resolve_backend("auto")`` probes EGL, then OSMesa, each in a short-lived subprocess (so the
calling process never holds a GL context and may still fork), and raises ``BackendError``
naming the Debian packages to install when neither works. Kept apart from ``gl_backend`` so
that the renderer can import ``gl_backend`` without a cycle.
"""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

from sc3d_data.render.gl_backend import BACKENDS, BackendError, activate, install_hint

PROBE_TIMEOUT_S = 120


def check_backend(backend: str) -> None:
    """In THIS process: activate ``backend`` and render a box with sc3d's renderer (8x8, 2
    views); raises ``BackendError`` with the install hint on failure or an empty image."""
    activate(backend)
    try:
        import trimesh

        from sc3d_data.geometry.camera import ViewSettings
        from sc3d_data.render.renderer import MeshRenderer

        r = MeshRenderer(ViewSettings(num_views=2, image_size=8), backend=backend)
        masks = r.render(trimesh.Scene(trimesh.creation.box(extents=(0.5, 0.5, 0.5))), np.eye(4))["masks"]
        r.close()
        if not masks.any():
            raise RuntimeError("a test box rendered empty")
    except Exception as e:
        raise BackendError(f"OpenGL backend {backend!r} does not work ({type(e).__name__}: {e}); "
                           f"{install_hint()}") from e


def resolve_backend(backend: str = "auto") -> str:
    """Return a working backend name. ``auto`` tries EGL then OSMesa (each in a subprocess);
    a named backend is checked the same way. Raises ``BackendError`` listing every error and
    the Debian packages to install."""
    candidates = BACKENDS if backend == "auto" else (backend,)
    if backend != "auto" and backend not in BACKENDS:
        raise ValueError(f"backend must be auto, egl or osmesa, not {backend!r}")
    errors = []
    for name in candidates:
        env = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}
        code = f"from sc3d_data.render.probe import check_backend; check_backend({name!r})"
        try:
            proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                                  text=True, timeout=PROBE_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            errors.append(f"{name}: probe timed out after {PROBE_TIMEOUT_S} s")
            continue
        if proc.returncode == 0:
            return name
        last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        errors.append(f"{name}: {last}")
    raise BackendError("no headless OpenGL backend works:\n  " + "\n  ".join(errors) + "\n" + install_hint())
