"""Choose the headless OpenGL backend (EGL, else OSMesa) before anything imports OpenGL.

``PYOPENGL_PLATFORM`` is read once, when PyOpenGL is first imported, so the choice must be
made before ``import pyrender``. ``activate(backend)`` sets it (and ``PYGLET_HEADLESS`` plus the
``np.infty`` alias pyrender needs under numpy 2) and must be called first in a fresh process
(the render workers do so). Probing which backend works is ``sc3d_data.render.probe``.
"""
from __future__ import annotations

import os
import sys

import numpy as np

BACKENDS = ("egl", "osmesa")
DEBIAN_PACKAGES = {
    "egl": "libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 libglu1-mesa libxrender1",
    "osmesa": "libosmesa6 libgl1 libglu1-mesa libxrender1",
}


class BackendError(RuntimeError):
    """No usable headless OpenGL backend."""


class DeviceError(RuntimeError):
    """An EGL device index (``--gpus``, ``EGL_DEVICE_ID``) that this machine does not have: no
    package to install and no other backend to try, the message alone says what to change."""


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
