"""Which GPU each render worker draws on (``sc3d-data render --gpus``).

A device is an EGL device index (the order of ``eglQueryDevicesEXT``; on a machine with
NVIDIA's EGL, one per GPU). The renderer makes its context on device ``EGL_DEVICE_ID`` of its
process environment (default 0: one GPU, or Mesa's device on a CPU machine), the variable
pyrender uses too. ``--gpus 0,1,2,3`` spreads a local run's workers over those devices round
robin (worker slot ``i`` draws on ``gpus[i % len(gpus)]``; a worker that replaces a dead one
keeps its slot's device); no ``--gpus`` leaves the environment as it is (today's behaviour).
On a cluster each task draws on one GPU: Ray tasks request a share of one GPU and draw on the
one Ray assigns; each SLURM array task requests ``len(gpus)`` GPUs and spreads its own workers
over them. The device never changes the output's settings (``RUNTIME_ONLY``).
"""
from __future__ import annotations

#: the environment variable the renderer reads its EGL device index from (pyrender's name)
DEVICE_ENV = "EGL_DEVICE_ID"


def parse_gpus(text: str | None) -> tuple[int, ...]:
    """``"0,1,3"`` -> ``(0, 1, 3)``; None or ``""`` -> ``()`` (no assignment). ``ValueError``
    naming the option for anything but distinct non-negative integers."""
    if not text:
        return ()
    try:
        gpus = tuple(int(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"--gpus {text}: expected EGL device indices separated by commas, e.g. 0,1") from None
    if any(g < 0 for g in gpus) or len(set(gpus)) != len(gpus):
        raise ValueError(f"--gpus {text}: device indices must be distinct and >= 0")
    return gpus


def device_of_slot(slot: int, gpus: tuple[int, ...]) -> int | None:
    """The EGL device of worker slot ``slot`` (0-based): ``gpus`` round robin; None without
    ``gpus`` (the worker keeps the environment's ``EGL_DEVICE_ID`` or device 0)."""
    return gpus[slot % len(gpus)] if gpus else None


def worker_environ(environ: dict, slot: int, gpus: tuple[int, ...]) -> dict:
    """A copy of ``environ`` for worker slot ``slot``, with ``EGL_DEVICE_ID`` set to its device
    when ``gpus`` are given (else unchanged)."""
    env = dict(environ)
    device = device_of_slot(slot, gpus)
    if device is not None:
        env[DEVICE_ENV] = str(device)
    return env
