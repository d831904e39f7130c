"""One writer per dataset folder: an exclusive, non-blocking ``flock`` on ``FOLDER/.sc3d.lock``.

``render``, ``voxelize`` (shards and ``--meshes``), ``import-r2n2``, ``merge`` and ``sc3d-train
fit`` (on its run folder) hold it for their whole run (the parts of ``voxelize --meshes --part
I/N``, which share one folder, hold it shared, and each its own part's lock exclusively); a second writer is refused at once with one line naming the folder
(and the PID that holds it), and the first one is not disturbed. The lock is released by the
kernel when the holder exits, also on SIGKILL, so a stale lock file never blocks a rerun.
Readers take no lock; ``writer_of`` tells them who is writing, when what they read looks broken.
"""
from __future__ import annotations

import errno
import fcntl
import os
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Iterator

LOCK_NAME = ".sc3d.lock"
#: descriptors of the locks this process holds; a forked child (a DataLoader worker, ...) closes
#: its copies at once, so that a child outliving the command never keeps the folder locked
_HELD: set[int] = set()


def _close_in_child() -> None:
    for fd in _HELD:
        try:
            os.close(fd)
        except OSError:
            pass
    _HELD.clear()


os.register_at_fork(after_in_child=_close_in_child)


class LockError(RuntimeError):
    """Another process is writing to the same folder."""


def open_lock_file(path: Path) -> int:
    """A read-write descriptor of lock file ``path``, created if missing, never through a
    symbolic link (one planted there would have the holder's PID written over its target):
    ``LockError`` naming it instead."""
    try:
        return os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise LockError(f"{path}: a symbolic link where sc3d keeps its lock file; sc3d does not write "
                            "through it: remove it") from None
        raise


def missing_folders(folder: Path) -> list[Path]:
    """``folder`` and those of its parents that do not exist, deepest first (of the path with
    ``..`` resolved: ``new/../data`` is ``data``, which may exist)."""
    folder = Path(os.path.abspath(folder))
    return [f for f in (folder, *folder.parents) if not f.exists()]


def remove_made_folders(made: list[Path]) -> None:
    """Remove the folders of ``made`` (:func:`missing_folders`, deepest first) that are empty; a
    folder that holds anything (another run's files, the user's) stays, and so do its parents."""
    for f in made:
        try:
            f.rmdir()
        except OSError:
            continue


@contextmanager
def exclusive_lock(folder: Path, command: str = "sc3d-data", create: bool = False, shared: bool = False,
                   name: str = LOCK_NAME, made: list[Path] | None = None,
                   advice: str = "wait for it to finish or use another --out") -> Iterator[Path]:
    """Hold the write lock of ``folder`` for the ``with`` block; raises ``LockError`` when another
    process holds it. ``create``: make ``folder`` (and its parents) if missing, and remove it
    and the parents it made again at the end when the block left nothing in it but the lock file
    (a command that failed on its inputs leaves no empty folder behind). ``shared``: a lock that other shared holders
    may hold at the same time but no exclusive one (the parts of one ``voxelize --meshes
    --part I/N`` job, each of which also holds an exclusive lock of its own ``name``). ``made``: the
    folders the caller made for this run, ``folder`` first (:func:`missing_folders` before making
    them), removed as those of ``create`` are."""
    folder = Path(folder)
    made = missing_folders(folder) if create else list(made or [])
    if create:
        Path(os.path.abspath(folder)).mkdir(parents=True, exist_ok=True)  # as missing_folders: no "new" of new/..
    path = folder / name
    fd = open_lock_file(path)
    held = False
    try:
        try:
            fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
        except BlockingIOError:
            raise LockError(f"{holder_problem(folder, path)}; {advice}") from None
        held = True
        _HELD.add(fd)
        if not shared:  # shared holders leave the file alone: the last one's line would win
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()} {command}\n".encode(), 0)
        yield path
    finally:
        _HELD.discard(fd)
        if made and held and os.listdir(folder) == [LOCK_NAME]:
            path.unlink()  # still held: nobody else can have taken it
            remove_made_folders(made)
        os.close(fd)  # closing the descriptor releases the lock


def _flock_holders(path: Path) -> list[tuple[int, str]] | None:
    """``[(pid, "WRITE" or "READ")]`` of the ``flock`` locks held on ``path`` (waiters left out),
    from ``/proc/locks`` (Linux); None where it, or ``path``, cannot be read. Takes no lock."""
    try:
        st = os.stat(path, follow_symlinks=False)
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return None
    key, holders = (os.major(st.st_dev), os.minor(st.st_dev), st.st_ino), []
    for line in lines:  # "1: FLOCK  ADVISORY  WRITE 4814 fe:00:2146343 0 EOF" (a waiter's has "->")
        f = line.split()
        if len(f) < 6 or f[1] != "FLOCK" or f[3] not in ("WRITE", "READ") or f[5].count(":") != 2:
            continue
        major, minor, inode = f[5].split(":")
        try:
            if (int(major, 16), int(minor, 16), int(inode)) == key:
                holders.append((int(f[4]), f[3]))
        except ValueError:
            continue
    return holders


def _lock_file_line(path: Path) -> tuple[str, str]:
    """``(pid, command)`` as the last exclusive holder of lock file ``path`` wrote them ("" where unread)."""
    try:
        first, _, what = path.read_text(errors="replace").strip().partition(" ")
    except OSError:
        return "", ""
    return first, what


def _described(path: Path, pid: int) -> str:
    """``"PID n: command"``: the lock file's line where it names ``pid`` (an exclusive holder
    writes one), else the process's command line (a shared holder writes none), else ``unknown``."""
    first, what = _lock_file_line(path)
    if first == str(pid) and what:
        return f"PID {pid}: {what}"
    try:
        argv = [a.decode(errors="replace") for a in Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0") if a]
    except OSError:
        argv = []
    if len(argv) > 1 and Path(argv[0]).name.startswith("python"):
        argv = argv[1:]  # "python .../sc3d-data merge ..." -> "sc3d-data merge ..."
    command = " ".join([Path(argv[0]).name, *argv[1:]])[:120] if argv else "unknown"
    return f"PID {pid}: {command}"


def holder_problem(folder: Path, path: Path) -> str:
    """The line of a lock on ``path`` (``folder``'s lock file) refused because another process
    holds it: the writer (an exclusive holder), else a process that shares it (a ``merge``
    reading its parts, a part of ``voxelize --meshes --part``)."""
    holders = _flock_holders(path)
    if not holders:  # /proc/locks unreadable: the lock file's line, as its last writer wrote it
        first, what = _lock_file_line(path)
        return f"{folder}: another process (PID {first or '?'}: {what or 'unknown'}) is writing to this folder"
    writer = next((pid for pid, kind in holders if kind == "WRITE"), None)
    if writer is None:
        return f"{folder}: another process ({_described(path, holders[0][0])}) is using this folder"
    return f"{folder}: another process ({_described(path, writer)}) is writing to this folder"


@contextmanager
def reading_lock(folder: Path, command: str, advice: str) -> Iterator[None]:
    """A shared hold of ``folder``'s lock for the ``with`` block, for a command that reads a
    dataset folder another command may write (``merge`` reading its parts): a writer is refused
    while it is held, and it is refused while one writes (``LockError`` naming it, then
    ``advice``). A folder where the lock file cannot be opened for writing (read-only storage)
    is read without it: nobody writes there either."""
    with ExitStack() as stack:
        try:
            stack.enter_context(exclusive_lock(folder, command, shared=True, advice=advice))
        except OSError as e:
            if e.errno not in (errno.EACCES, errno.EPERM, errno.EROFS):
                raise
        yield


def writer_of(folder: Path, name: str = LOCK_NAME) -> str | None:
    """``"PID n: command"`` of another process that holds ``folder``'s lock exclusively (a writer
    at work), else None. Reads ``/proc/locks`` (Linux; None where it cannot be read) and takes no
    lock itself, so a writer starting at that moment is not refused because of the question."""
    path = Path(folder) / name
    for pid, kind in _flock_holders(path) or []:
        if kind == "WRITE" and pid != os.getpid():
            return _described(path, pid)
    return None
