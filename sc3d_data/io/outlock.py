"""One writer per dataset folder: an exclusive, non-blocking ``flock`` on ``FOLDER/.sc3d.lock``.

``render``, ``voxelize`` (shards) and any other command that rewrites shards or ``index.json``
hold it for their whole run; a second writer is refused at once with one line naming the folder
(and the PID that holds it), and the first one is not disturbed. The lock is released by the
kernel when the holder exits, also on SIGKILL, so a stale lock file never blocks a rerun.
"""
from __future__ import annotations

import fcntl
import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

LOCK_NAME = ".sc3d.lock"


class LockError(RuntimeError):
    """Another process is writing to the same folder."""


@contextmanager
def exclusive_lock(folder: Path, command: str = "sc3d-data") -> Iterator[Path]:
    """Hold the write lock of ``folder`` (created if needed) for the ``with`` block; raises
    ``LockError`` when another process holds it."""
    folder = Path(folder)
    path = folder / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pid, _, what = os.pread(fd, 200, 0).decode(errors="replace").strip().partition(" ")
            raise LockError(f"{folder}: another process (PID {pid or '?'}: {what or 'unknown'}) is writing to this folder; "
                            f"wait for it to finish or use another --out") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()} {command}\n".encode(), 0)
        yield path
    finally:
        os.close(fd)  # closing the descriptor releases the lock
