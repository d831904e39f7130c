"""Which checkpoint ``fit --resume`` continues from, and what a resume checks and repairs: the
newest complete checkpoint (``last.pt`` or a newer ``step_XXXXXX.pt`` whose copy to ``last.pt`` a
stop cut off, then made ``last.pt`` again), the number of ranks it was saved with, and the line
``fit`` prints on Ctrl-C. Checkpoints themselves: :mod:`sc3d_train.loop.checkpoint`."""
from __future__ import annotations

import re
from pathlib import Path

from sc3d_train.loop.checkpoint import CheckpointError, checkpoint_dir, copy_to_last, last_path, load_checkpoint
from sc3d_train.loop.validation import final_validation_owed
from sc3d_train.settings.config import RunConfig

__all__ = ["RESUME_KEYS", "check_saved_ranks", "finished_run", "interrupted_line", "restore_last", "resume_checkpoint"]


RESUME_KEYS = ("optimizer", "rng", "step", "data_position")


def _resumable(path: Path, ckpt: dict) -> dict:
    """``ckpt``, or ``CheckpointError`` naming ``path`` when it lacks what a resume needs (a
    ``best.pt`` holds the weights only)."""
    missing = [k for k in RESUME_KEYS if k not in ckpt]
    if missing:
        raise CheckpointError(f"{path}: holds no {', '.join(missing)} (weights only, like best.pt): --resume "
                              "continues from a last.pt or step_*.pt that fit wrote")
    return ckpt


def resume_checkpoint(run_dir: Path, say=None) -> tuple[Path, dict]:
    """``(path, checkpoint)`` of the newest complete checkpoint of a run: ``last.pt`` unless a
    ``step_XXXXXX.pt`` with a higher step exists (``last.pt`` not updated because the disk
    filled up, say); unreadable files, and files without the training state
    (:data:`RESUME_KEYS`), are passed over. ``CheckpointError`` when none is left. ``say``
    (a callable taking one line), where given, hears which file other than ``last.pt`` is
    resumed from and why (``last.pt`` unreadable: the reason; or older)."""
    folder = checkpoint_dir(run_dir)
    steps = sorted(((int(m.group(1)), p) for p in folder.glob("step_*.pt")
                    if (m := re.fullmatch(r"step_(\d+)\.pt", p.name))), reverse=True)
    errors, last = [], None
    if last_path(run_dir).is_file():
        try:
            last = _resumable(last_path(run_dir), load_checkpoint(last_path(run_dir)))
        except CheckpointError as e:
            errors.append(str(e))
    for step, p in steps:
        if last is not None and int(last.get("step", -1)) >= step:
            break
        try:
            ckpt = _resumable(p, load_checkpoint(p))
        except CheckpointError as e:
            errors.append(str(e))
            continue
        if say is not None:
            why = (f"{last_path(run_dir).name} is older (step {last['step']})" if last is not None else
                   f"{last_path(run_dir).name} unreadable: {errors[0]}" if last_path(run_dir).is_file() else
                   f"no {last_path(run_dir).name}")
            say(f"resuming from {p} (step {ckpt['step']}): {why}")
        return p, ckpt
    if last is not None:
        return last_path(run_dir), last
    early = not errors and not steps and (Path(run_dir) / "config.yaml").is_file()  # stopped before its first
    if errors:  # every checkpoint there was refused: say why, not "not found"
        raise CheckpointError(f"no checkpoint of {run_dir} can be resumed: {errors[0]}"
                              + (f" (and {len(errors) - 1} more refused)" if len(errors) > 1 else ""))
    raise CheckpointError(f"{last_path(run_dir)}: checkpoint not found"
                          + ("; the run stopped before its first checkpoint: start it again without --resume"
                             if early else ""))


def finished_run(cfg: RunConfig, step: int, ckpt_file: Path) -> dict | None:
    """``fit``'s summary of a run resumed at ``step`` (from ``ckpt_file``) with nothing left to do: at or
    past ``cfg.steps``, and the last step's validation done (``already_done``: the CLI says so, and said
    no 'training ...' line before); None where steps, or that validation, remain."""
    if step > cfg.steps or (step == cfg.steps and not final_validation_owed(cfg, step)):
        return {"step": step, "last_losses": {}, "samples_per_s": 0.0, "checkpoint": str(ckpt_file),
                "best": None, "already_done": True}
    return None


def check_saved_ranks(path: Path, ckpt: dict, world_size: int) -> None:
    """``CheckpointError`` when checkpoint ``ckpt`` (read from ``path``) was saved by another
    number of ranks than ``world_size``: a run resumes with the ranks it was trained with (one
    random state and one data position per rank), and the line says how many."""
    saved = len(ckpt["rng"])
    if saved != world_size:
        raise CheckpointError(f"{path}: saved with {saved} ranks, now {world_size}; "
                              f"resume with {saved} (torchrun --nproc_per_node, or none for 1)")


def restore_last(run_dir: Path, ckpt_file: Path) -> None:
    """``last.pt`` made a copy of ``ckpt_file``, the newer step file a resume continues from (a stop cut off
    its copy): a resume with nothing left to train left ``last.pt``, which eval and predict read, older."""
    try:
        copy_to_last(run_dir, ckpt_file)
    except OSError as e:
        raise CheckpointError(f"{last_path(run_dir)}: cannot write checkpoint ({e.strerror or e}); free space and "
                              "rerun with --resume") from e


def interrupted_line(run_dir: Path, resume_hint: str) -> str:
    """What ``fit`` prints on Ctrl-C: the run's ``last.pt`` (written atomically after the loss was
    checked: a good checkpoint, also when the interrupt came before the loop noted it), or the
    step file ``--resume`` reads where there is none yet, and ``resume_hint`` (how the caller's
    command resumes); or that there is nothing to resume."""
    last = last_path(run_dir)
    steps = [p.stat().st_mtime_ns for p in checkpoint_dir(run_dir).glob("step_*.pt")]
    if last.is_file() and max(steps, default=0) <= last.stat().st_mtime_ns:  # last.pt is copied after its step file
        return f"interrupted; last good checkpoint: {last} ({resume_hint})"
    try:  # stopped between a step's step_XXXXXX.pt and its last.pt: --resume reads the step file
        return f"interrupted; last good checkpoint: {resume_checkpoint(run_dir)[0]} ({resume_hint})"
    except CheckpointError:
        return "interrupted before the first checkpoint: nothing to resume (start the run again)"
