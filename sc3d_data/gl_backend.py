"""Choose the headless OpenGL backend (EGL, else OSMesa) before anything imports OpenGL.

``PYOPENGL_PLATFORM`` is read once, when PyOpenGL is first imported, so the choice must be
made before ``import pyrender``. ``activate(backend)`` sets it (and ``PYGLET_HEADLESS`` plus the
``np.infty`` alias pyrender needs under numpy 2) and must be called first in a fresh process
(the render workers do so). ``resolve_backend("auto")`` probes EGL, then OSMesa, each in a
short-lived subprocess (so the calling process never holds a GL context and may still fork),
and raises ``BackendError`` naming the Debian packages to install when neither works.
"""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

BACKENDS = ("egl", "osmesa")
DEBIAN_PACKAGES = {
    "egl": "libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 libxrender1",
    "osmesa": "libosmesa6 libgl1 libxrender1",
}
PROBE_TIMEOUT_S = 120


class BackendError(RuntimeError):
    """No usable headless OpenGL backend."""


def install_hint() -> str:
    return ("install the system packages, e.g. on Debian/Ubuntu: "
            f"`sudo apt-get install {DEBIAN_PACKAGES['egl']}` (EGL, preferred) or "
            f"`sudo apt-get install {DEBIAN_PACKAGES['osmesa']}` (OSMesa fallback)")


def activate(backend: str) -> None:
    """Set up this process for headless rendering with ``backend`` (``egl``/``osmesa``).
    Call before importing pyrender/OpenGL; raises ``BackendError`` if OpenGL was already
    imported with another platform."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, not {backend!r}")
    current = os.environ.get("PYOPENGL_PLATFORM")
    if "OpenGL" in sys.modules and current != backend:
        raise BackendError(f"OpenGL was already imported with PYOPENGL_PLATFORM={current!r}; "
                           f"cannot switch to {backend!r} in this process")
    os.environ["PYOPENGL_PLATFORM"] = backend
    os.environ.setdefault("PYGLET_HEADLESS", "1")
    if not hasattr(np, "infty"):  # removed in numpy 2, still used by pyrender 0.1.45
        np.infty = np.inf


def check_backend(backend: str) -> None:
    """In THIS process: activate ``backend`` and render a box with sc3d's renderer (8x8, 2
    views); raises ``BackendError`` with the install hint on failure or an empty image."""
    activate(backend)
    try:
        import trimesh

        from sc3d_data.camera import ViewSettings
        from sc3d_data.render import MeshRenderer

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
        code = f"from sc3d_data.gl_backend import check_backend; check_backend({name!r})"
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
