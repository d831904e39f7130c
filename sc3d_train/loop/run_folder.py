"""Checks of the folder a ``fit`` run writes (``--out``) before anything is written: its name, files
of someone else's that a new run would replace, and links that a run would write through."""
from __future__ import annotations

from pathlib import Path

from sc3d_train.settings.config import RunConfig


#: what a run writes into its folder besides ``checkpoints/`` (a new run replaces them)
RUN_FILES = ("config.yaml", "metrics.csv", "validation.csv", "curves.png", "labeled_objects.txt", "tb")


def check_path_names(plain: dict) -> None:
    """``ValueError`` when a new run's ``out`` is not valid UTF-8 (config.yaml and TensorBoard's
    event files store it as text), before anything is written. (Empty folder options are refused
    by the command line: ``cli/folder_path.FolderPath``.)"""
    from sc3d_data.io.names import printable

    try:
        str(plain["out"]).encode("utf-8")
    except UnicodeEncodeError as e:
        raise ValueError(f"--out {printable(str(plain['out']))}: the name is not valid UTF-8 (byte "
                         f"0x{ord(str(plain['out'])[e.start]) - 0xDC00:02x}), which config.yaml and TensorBoard "
                         "store as text; choose another name") from e


def check_no_linked_files(out: Path) -> None:
    """``CheckpointError`` when a file that a run (re)writes in its folder (:data:`RUN_FILES`;
    folders such as ``checkpoints/`` may be links, to a larger disk) is a symbolic link: the run
    would write through it to whatever file it names, anywhere."""
    from sc3d_train.loop.checkpoint import CheckpointError

    linked = [name for name in RUN_FILES if (out / name).is_symlink() and not (out / name).is_dir()]
    if linked:
        raise CheckpointError(f"{out}: {', '.join(linked)} {'is a symbolic link' if len(linked) == 1 else 'are symbolic links'}; "
                              "a run writes its own files and never through a link (it could name a file "
                              "anywhere): move the link away (copy the file in its place to keep it)")


def check_no_foreign_files(out: Path) -> None:
    """``CheckpointError`` when the folder of a new run holds files named like the ones the run
    writes (:data:`RUN_FILES`) that are not the leftovers of an sc3d run: a new run would replace
    them. A ``config.yaml`` that loads as a run's config marks the leftovers of a run stopped
    before its first checkpoint, which the new run may replace (as rerunning its command does)."""
    from sc3d_train.loop.checkpoint import CheckpointError

    present = [name for name in RUN_FILES if (out / name).exists()]
    if not present:
        return
    try:
        RunConfig.load(RunConfig.path_in(out))
        return
    except Exception:  # noqa: BLE001 - missing, unreadable or not a run's config: not ours to replace
        pass
    raise CheckpointError(f"{out}: holds {', '.join(present)}, not from an sc3d-train run, which a new run would "
                          "overwrite; choose another --out (or move them)")
