"""Checkpoints of ``sc3d-train fit``: what they hold, how they are written and read (a model is
rebuilt from one by :mod:`~sc3d_train.loop.checkpoint_model`, for ``--resume``, ``eval`` and ``predict``).

A checkpoint (``torch.save`` dict) holds ``model`` (state dict of the unwrapped network),
``optimizer``, ``scaler`` (AMP GradScaler or None), ``rng`` (one entry per DDP rank: torch CPU,
CUDA, numpy and python states), ``step`` (optimiser steps done), ``config`` (the
:class:`~sc3d_train.settings.config.RunConfig` as plain data: nested dicts of numbers, strings and lists,
the model config and loss weights inside; :func:`checkpoint_config` rebuilds the typed
dataclasses, so checkpoints of earlier versions, which stored the same dict, still load), ``data_position``
(phase, phase start and samples consumed by each rank in that phase) and ``format_version``.
Files are written under a temporary name and renamed, so ``step_XXXXXX.pt`` and ``last.pt``
are always complete; a write that fails (disk full) removes its temporary file and raises
``CheckpointError`` naming the file (a Ctrl-C during it: the ``KeyboardInterrupt``), and
``checkpoint_resume.resume_checkpoint`` picks the newest complete checkpoint (``last.pt`` or a newer
``step_XXXXXX.pt``).

Loading never runs code from the file: ``torch.load(weights_only=True)`` with an allow-list of
exactly the non-tensor types a checkpoint holds (``CHECKPOINT_GLOBALS``: the numpy array and
dtype types of numpy's RNG state). A file needing anything else is refused with a clear
message; nothing in it is executed.
"""
from __future__ import annotations

import os
import pickle
import random
import shutil
from contextlib import suppress
from pathlib import Path

import numpy as np
import torch

from sc3d_train.loop.atomic_save import save_atomically
from sc3d_train.settings.config import RunConfig
from sc3d_train.settings.torch_floor import SAFE_TORCH, torch_is_safe

FORMAT_VERSION = 1


def _numpy_globals() -> list:
    """The numpy callables/types ``np.random.get_state()`` pickles to (an ndarray of uint32)."""
    try:
        from numpy._core.multiarray import _reconstruct
    except ImportError:  # numpy < 2
        from numpy.core.multiarray import _reconstruct
    types = [_reconstruct, np.ndarray, np.dtype]
    types += [type(np.dtype(t)) for t in (np.uint32, np.int64, np.float64, np.float32, np.uint8, np.bool_)]
    return types


#: the only non-tensor globals ``load_checkpoint`` lets the unpickler build
CHECKPOINT_GLOBALS = _numpy_globals()


class CheckpointError(ValueError):
    """A checkpoint that cannot be used (missing, corrupt, or from another configuration)."""


def checkpoint_dir(run_dir: Path) -> Path:
    return Path(run_dir) / "checkpoints"


def step_path(run_dir: Path, step: int) -> Path:
    return checkpoint_dir(run_dir) / f"step_{step:06d}.pt"


def last_path(run_dir: Path) -> Path:
    return checkpoint_dir(run_dir) / "last.pt"


def best_path(run_dir: Path) -> Path:
    """The run's best checkpoint on its validation split (:mod:`sc3d_train.loop.validation`)."""
    return checkpoint_dir(run_dir) / "best.pt"


def run_checkpoint(path: Path, pick: str = "best", pick_given: bool = False) -> Path:
    """The checkpoint file that ``path`` names: ``path`` itself when it is a file; for a run folder
    ``checkpoints/best.pt`` (``pick="best"``; ``last.pt`` where the run kept no best, e.g. with
    validation off) or ``checkpoints/last.pt`` (``pick="last"``). A run's ``checkpoints`` folder
    stands for its run folder. ``pick_given`` (``--pick`` on the command line) with a file:
    ``CheckpointError``, since ``--pick`` chooses inside a run folder and a file leaves nothing to
    choose (it would be ignored)."""
    path = Path(path)
    if path.is_dir():
        from sc3d_train.settings.command_config import CHECKPOINT_PICKS

        if pick not in CHECKPOINT_PICKS:
            raise ValueError(f"pick must be one of {CHECKPOINT_PICKS}, got {pick!r}")
        if path.name == "checkpoints" and not checkpoint_dir(path).is_dir():  # RUN/checkpoints: RUN
            path = path.parent
        best = best_path(path)
        return best if pick == "best" and best.is_file() else last_path(path)
    if pick_given and path.is_file():
        run = path.parent.parent if path.parent.name == "checkpoints" else "RUN_DIR"
        raise CheckpointError(f"--pick {pick}: {path} is a checkpoint file, and --pick chooses a checkpoint of a run "
                              f"folder; give the run folder (--checkpoint {run} --pick {pick}) or leave --pick out")
    return path


def rng_state(device: torch.device | None = None) -> dict:
    """This process's RNG states: torch's CPU generator, the CUDA generator of ``device`` (the
    training device, where it is a CUDA device; not every visible GPU's, which a machine with
    fewer GPUs could not restore), numpy's and python's."""
    cuda = device is not None and device.type == "cuda"
    return {"torch": torch.get_rng_state(), "cuda": torch.cuda.get_rng_state(device) if cuda else None,
            "numpy": np.random.get_state(), "python": random.getstate()}


def set_rng_state(state: dict, device: torch.device | None = None) -> None:
    """Restore :func:`rng_state`'s ``state``; its CUDA state to ``device``'s generator, where it is
    a CUDA device (a checkpoint written before the state was per device holds one per visible GPU:
    ``device``'s is taken, where it has one)."""
    torch.set_rng_state(state["torch"])
    cuda = state.get("cuda")
    if isinstance(cuda, (list, tuple)):
        index = (device.index or 0) if device is not None else 0
        cuda = cuda[index] if index < len(cuda) else None
    if cuda is not None and device is not None and device.type == "cuda":
        torch.cuda.set_rng_state(cuda, device)
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])


def save_best(run_dir: Path, payload: dict) -> Path:
    """Write ``payload`` (``model``, ``step``, ``config``, ``validation``: no optimiser or RNG, it
    is not resumed from) as ``checkpoints/best.pt``, atomically."""
    path = best_path(run_dir)
    tmp = path.with_name(path.name + ".tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        save_atomically({"format_version": FORMAT_VERSION, **payload}, tmp, path)
    except (OSError, RuntimeError) as e:
        tmp.unlink(missing_ok=True)
        raise CheckpointError(f"{path}: cannot write checkpoint ({' '.join(str(e).split())})") from e
    return path


def save_checkpoint(run_dir: Path, payload: dict) -> Path:
    """Write ``payload`` as ``checkpoints/step_XXXXXX.pt`` and copy it to ``last.pt``
    (both atomically). A copy, not a hard link: a ``last.pt`` damaged later (truncated,
    overwritten in place) then leaves the step file whole, and ``--resume`` falls back to it
    (``checkpoint_resume.resume_checkpoint``). Returns the step file."""
    path = step_path(run_dir, payload["step"])
    payload = {"format_version": FORMAT_VERSION, **payload}
    tmp = path.with_name(path.name + ".tmp")
    last = last_path(run_dir)
    target = path
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        save_atomically(payload, tmp, path)
        target = last
        copy_to_last(run_dir, path)
    except (OSError, RuntimeError, KeyboardInterrupt) as e:
        with suppress(OSError):
            tmp.unlink()
        if isinstance(e, KeyboardInterrupt):  # Ctrl-C: the run says it was interrupted (trainer)
            raise
        reason = e.strerror if isinstance(e, OSError) and e.strerror else " ".join(str(e).split())
        kept = f"; {path} is complete" if target == last else ""
        then = ("rerun with --resume" if target == last or last.is_file() else
                "start the run again (the same command: no checkpoint of it was written, so --resume has "
                "nothing to continue)")
        raise CheckpointError(f"{target}: cannot write checkpoint ({reason}){kept}; free space and {then}") from e
    return path


def copy_to_last(run_dir: Path, step_file: Path) -> None:
    """``last.pt`` of ``run_dir`` made a copy of ``step_file``, atomically (a temporary file
    renamed into place); a failed copy (``OSError``, Ctrl-C) leaves no temporary file."""
    last = last_path(run_dir)
    tmp = last.with_name(last.name + ".tmp")
    try:
        shutil.copyfile(step_file, tmp)
        os.replace(tmp, last)
    except BaseException:
        with suppress(OSError):
            tmp.unlink()
        raise


#: what ``torch.save`` writes: a zip archive
ZIP_MAGIC = b"PK\x03\x04"


def load_checkpoint(path: Path, map_location="cpu") -> dict:
    """Read a checkpoint with a clear error for a missing or foreign file, or a torch too old to
    read one without running code from it."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: checkpoint not found")
    if not torch_is_safe(torch.__version__):
        raise CheckpointError(f"{path}: not loaded: torch {torch.__version__} is older than "
                              f"{'.'.join(map(str, SAFE_TORCH))}, whose weights_only loading can run code from a "
                              "crafted file (CVE-2025-32434); upgrade torch")
    with open(path, "rb") as f:
        if f.read(len(ZIP_MAGIC)) != ZIP_MAGIC:
            raise CheckpointError(f"{path}: not a checkpoint file (torch.save writes a zip archive; give a run "
                                  "folder or a .pt file that fit wrote)")
    try:
        with torch.serialization.safe_globals(CHECKPOINT_GLOBALS):
            ckpt = torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as e:  # weights_only refused a global: nothing was run
        first = " ".join(str(e).split("\n")[-1].split())[:200]
        raise CheckpointError(f"{path}: refused: the file holds Python objects outside the checkpoint "
                              f"allow-list (not written by this sc3d-train, or crafted); not loaded ({first})") from e
    except Exception as e:  # noqa: BLE001 - any other failure means "not ours" or truncated
        import zipfile

        if not zipfile.is_zipfile(path):  # a zip archive ends with its directory: a cut-short file has none
            raise CheckpointError(f"{path}: a checkpoint cut short or damaged (its zip archive has no end: a write or "
                                  "copy that did not finish?); not loaded") from e
        raise CheckpointError(f"{path}: not a readable checkpoint ({type(e).__name__}: "
                              f"{' '.join(str(e).split())[:200]})") from e
    if not isinstance(ckpt, dict) or "model" not in ckpt or "config" not in ckpt:
        raise CheckpointError(f"{path}: not an sc3d-train checkpoint (no model/config)")
    weights = ckpt["model"]
    if not isinstance(weights, dict) or not all(torch.is_tensor(v) for v in weights.values()):
        raise CheckpointError(f"{path}: not an sc3d-train checkpoint (its model is no state dict of tensors)")
    return ckpt


#: what a checkpoint needs besides the weights and config to continue a run exactly
def checkpoint_config(path: Path, ckpt: dict) -> RunConfig:
    """The typed run config stored in checkpoint ``ckpt`` (read from ``path``)."""
    try:
        return RunConfig.from_dict(ckpt["config"])
    except ValueError as e:
        raise CheckpointError(f"{path}: its config is not one this version reads ({e})") from e
