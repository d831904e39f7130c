"""``torch.save`` to a file that appears whole or not at all, and whose failed write names its
cause: checkpoints (:mod:`sc3d_train.loop.checkpoint`) are written through it."""
from __future__ import annotations

import os
from pathlib import Path

import torch

from sc3d_data.io.shards import create_new_file


def save_atomically(payload: dict, tmp: Path, path: Path) -> None:
    """``torch.save(payload)`` to ``tmp``, then renamed to ``path``. Written through a file
    object whose writes are watched: ``torch.save`` reports a failed write (a full disk) only as
    "unexpected pos 704 vs 598", so the write's own ``OSError`` ("No space left on device") is
    raised instead; a Ctrl-C that lands in a write (``KeyboardInterrupt``, which ``torch.save``
    turns into the same ``RuntimeError``) is raised as itself, ``tmp`` removed, so the run says it
    was interrupted, not that the disk is full; so is any other error raised in a write (PyTorch's
    report of a dead loader worker comes from a signal handler, wherever the main process is)."""
    with create_new_file(tmp) as f:  # never through a link planted at the temporary name
        out = _WatchedFile(f)
        try:
            torch.save(payload, out)
        except RuntimeError as e:
            if out.error is not None:
                if not isinstance(out.error, OSError):  # Ctrl-C, a loader worker's death: the run stops
                    tmp.unlink(missing_ok=True)
                raise out.error from e
            raise
    os.replace(tmp, path)


class _WatchedFile:
    """A binary file for ``torch.save`` that keeps what made a write fail (an ``OSError``, or a
    ``KeyboardInterrupt`` or other error raised during it)."""

    def __init__(self, f):
        self.f, self.error = f, None

    def write(self, data) -> int:
        try:
            return self.f.write(data)
        except BaseException as e:  # noqa: BLE001 - also a dead loader worker's RuntimeError (SIGCHLD)
            self.error = e
            raise

    def flush(self) -> None:
        self.f.flush()
