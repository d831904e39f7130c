"""What the suite's processes make once and share (pytest-xdist runs the suite in two processes:
docs/testing.md): the sample shards, the shared training run and the doc-run pages.

The first process to create a thing's folder under :func:`shared_root` (``mkdir`` is atomic) makes
it; the others wait for its marker (:func:`make_once`). A background command
(:func:`start_shared`) writes its exit code into a file as it ends, so that a process that did not
start it can wait for it (:class:`SharedRun`); the process that started it waits for it at the session's end, unless the
session is stopping on a failure or Ctrl-C, when it kills it. One process (``-n 0``): its own
basetemp, so everything is made in it as before."""
from __future__ import annotations

import os
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

#: seconds a process waits for what another one makes (the slowest, a doc-run page, takes ~1 min)
WAIT_S = 900


def shared_root(tmp_path_factory) -> Path:
    """The folder every process of this session can see: the parent of pytest-xdist's per-worker
    basetemps (``popen-gwN``), else this session's basetemp."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def claim(folder: Path) -> bool:
    """Whether this process makes ``folder`` (it created it) rather than waits for it."""
    try:
        folder.mkdir()
        return True
    except FileExistsError:
        return False


def make_once(folder: Path, make, what: str) -> None:
    """Run ``make()`` when this process claims ``folder``, then mark it ``done`` (or ``failed``,
    with the error); otherwise wait for the process that claimed it."""
    if claim(folder):
        try:
            make()
        except BaseException as e:
            (folder / "failed").write_text(f"{type(e).__name__}: {e}"[-4000:])
            raise
        (folder / "done").touch()
        return
    end = time.monotonic() + WAIT_S
    while not (folder / "done").exists():
        if (folder / "failed").exists():
            raise AssertionError(f"{what} failed in another process of the session: {(folder / 'failed').read_text()}")
        if time.monotonic() > end:
            raise AssertionError(f"{what}: another process of the session did not finish it in {WAIT_S} s")
        time.sleep(0.2)


@dataclass
class SharedRun:
    """A background command of the session, whose exit code lands in file ``rc``: ``proc`` where
    this process started it, else None."""

    rc: Path
    proc: subprocess.Popen | None

    def wait(self, timeout: float | None = None) -> int:
        """Its exit code; ``subprocess.TimeoutExpired`` after ``timeout`` seconds."""
        if self.proc is not None:
            self.proc.wait(timeout)
        end = time.monotonic() + (WAIT_S if timeout is None else timeout)
        while not self.rc.exists():
            if time.monotonic() > end:
                raise subprocess.TimeoutExpired(str(self.rc), timeout or WAIT_S)
            time.sleep(0.2)
        return int(self.rc.read_text())

    def kill(self) -> None:
        """Kill the command and what it started (its process group), where this process started it."""
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()


def start_shared(rc: Path, argv: list[str], log: Path, **popen) -> SharedRun:
    """Start ``argv`` in the background, its output into ``log``, its exit code into ``rc`` as it
    ends (for the processes that wait for it without being its parent)."""
    wrapper = ["sh", "-c", f'"$@"; echo $? > {rc}.tmp && mv {rc}.tmp {rc}', "sh", *argv]
    with log.open("w") as f:  # the child keeps its own descriptor
        proc = subprocess.Popen(wrapper, stdout=f, stderr=subprocess.STDOUT, start_new_session=True, **popen)
    return SharedRun(rc, proc)


def finish(runs: list[SharedRun], session) -> None:
    """At the session's end: wait for the runs this process started (another process may still
    need them), or kill them when the session stops on a failure or an interrupt."""
    for run in runs:
        if run.proc is None:
            continue
        try:
            if not (session.shouldfail or session.shouldstop):
                run.proc.wait(WAIT_S)
        finally:
            run.kill()
