"""Find a working headless OpenGL backend by rendering a box with sc3d's own renderer.

``resolve_backend("auto")`` probes EGL, then OSMesa, each in a short-lived subprocess (so the
calling process never holds a GL context and may still fork), and raises ``BackendError``
naming the Debian packages to install when neither works. Kept apart from ``gl_backend`` so
that the renderer can import ``gl_backend`` without a cycle.

The probe's verdict is the line it prints after rendering, not its exit status: the child ends
with ``os._exit`` right after that line, as the render workers do, because some GL drivers
(NVIDIA's EGL among them) can crash in their own teardown when a process that held a context
exits normally, which says nothing about whether rendering works.
"""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

from sc3d_data.render.gl_backend import BACKENDS, BackendError, activate, install_hint

PROBE_TIMEOUT_S = 120
#: what a probe child prints once its box rendered
PROBE_OK = "sc3d-probe-ok"


def check_backend(backend: str) -> str:
    """In THIS process: activate ``backend`` and render a box with sc3d's renderer (8x8, 2
    views); returns the driver's ``GL_RENDERER`` string (e.g. ``llvmpipe (LLVM 15.0.6, 256
    bits)`` or ``NVIDIA H100 80GB HBM3/PCIe/SSE2``); raises ``BackendError`` with the install
    hint on failure or an empty image."""
    activate(backend)
    try:
        import trimesh

        from sc3d_data.geometry.camera import ViewSettings
        from sc3d_data.render.renderer import MeshRenderer

        r = MeshRenderer(ViewSettings(num_views=2, image_size=8), backend=backend)
        masks = r.render(trimesh.Scene(trimesh.creation.box(extents=(0.5, 0.5, 0.5))), np.eye(4))["masks"]
        name = r.gl.glGetString(r.gl.GL_RENDERER)
        r.close()
        if not masks.any():
            raise RuntimeError("a test box rendered empty")
        return name.decode(errors="replace") if isinstance(name, bytes) else str(name)
    except Exception as e:
        raise BackendError(f"OpenGL backend {backend!r} does not work ({type(e).__name__}: {e}); "
                           f"{install_hint()}") from e


def resolve_backend(backend: str = "auto") -> str:
    """Return a working backend name. ``auto`` tries EGL then OSMesa (each in a subprocess);
    a named backend is checked the same way. Raises ``BackendError`` listing every error and
    the Debian packages to install."""
    return probe_backend(backend)[0]


def probe_backend(backend: str = "auto") -> tuple[str, str]:
    """``(backend, GL_RENDERER)`` of the first working backend, as :func:`resolve_backend`."""
    candidates = BACKENDS if backend == "auto" else (backend,)
    if backend != "auto" and backend not in BACKENDS:
        raise ValueError(f"backend must be auto, egl or osmesa, not {backend!r}")
    errors = []
    for name in candidates:
        env = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}
        code = ("import os, sys; from sc3d_data.render.probe import check_backend; "
                f"gl = check_backend({name!r}); print({PROBE_OK!r}, gl, flush=True); "
                "sys.stderr.flush(); os._exit(0)")
        try:
            proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                                  text=True, timeout=PROBE_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            errors.append(f"{name}: probe timed out after {PROBE_TIMEOUT_S} s")
            continue
        ok = [line for line in proc.stdout.splitlines() if line.startswith(PROBE_OK)]
        if ok:
            return name, ok[-1][len(PROBE_OK):].strip()
        last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        errors.append(f"{name}: {last} ({exit_status(proc.returncode)})")
    raise BackendError("no headless OpenGL backend works:\n  " + "\n  ".join(errors) + "\n" + install_hint())


def exit_status(code: int) -> str:
    """``exit status 1``, ``killed by signal 11 (SIGSEGV)`` or ``killed by signal 9 (SIGKILL: out
    of memory or killed from outside)`` for a ``subprocess`` or ``multiprocessing`` exit code."""
    if code >= 0:
        return f"exit status {code}"
    import signal

    try:
        name = signal.Signals(-code).name
    except ValueError:
        return f"killed by signal {-code}"
    return f"killed by signal {-code} ({name}" + (": out of memory or killed from outside)" if name == "SIGKILL" else ")")
