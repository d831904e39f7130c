"""``sc3d-train``'s exit after Ctrl-C (cli/interrupted_exit.py), in-process: ``os._exit`` and the
process's children are replaced by fakes, so the test sees which status it would leave with."""
import multiprocessing
import os
import signal
import time

import click
import pytest

from sc3d_cli import interrupted_exit


class Left(Exception):
    """What the fake ``os._exit`` raises: the status the process would have left with."""


def ctrl_c() -> None:
    """A Ctrl-C to this process, its Python handler run before returning."""
    os.kill(os.getpid(), signal.SIGINT)
    for _ in range(100):
        time.sleep(0.01)


@pytest.fixture
def sigint_restored():
    """Python's Ctrl-C handler and SIGTERM's default for the test (run_console replaces both),
    this process's own restored afterwards."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler), signal.signal(signal.SIGTERM, signal.SIG_DFL)
    yield
    signal.signal(signal.SIGINT, before[0])
    signal.signal(signal.SIGTERM, before[1])


def test_a_second_ctrl_c_while_leaving_does_not_escape_into_finalisation(monkeypatch, sigint_restored):
    """Ctrl-C pressed twice: the second one landed while the exit path stopped the loader workers
    (``terminate``/``join`` of a child, or a flush to a slow pipe) and raised ``KeyboardInterrupt``
    out of ``run_console``: a traceback, exit status 130, and the interpreter's finalisation that
    the exit path exists to skip (it could spin forever after an interrupt)."""
    class Child:
        def terminate(self):
            ctrl_c()  # the user's second Ctrl-C

        def join(self, timeout=None):
            pass

    def leave(code):
        raise Left(code)

    monkeypatch.setattr(multiprocessing, "active_children", lambda: [Child()])
    monkeypatch.setattr(interrupted_exit.os, "_exit", leave)

    @click.group()
    def group():
        pass

    @group.command()
    def work():
        ctrl_c()  # the first Ctrl-C

    monkeypatch.setattr("sys.argv", ["sc3d-train", "work"])
    try:
        interrupted_exit.run_console(group)
    except KeyboardInterrupt:
        pytest.fail("the second Ctrl-C escaped run_console (traceback, Python's finalisation)")
    except Left as left:
        assert left.args == (1,)
    else:
        pytest.fail("run_console returned instead of leaving")


#: a console script whose command has a loader worker (a child PyTorch watches with its SIGCHLD
#: handler, as a DataLoader's) and receives SIGTERM with it, sent to the whole process group
GROUP_SIGTERM_SCRIPT = """import multiprocessing, os, signal, sys, time
import click, torch
from torch.utils.data._utils import signal_handling
from sc3d_cli.interrupted_exit import run_console

def worker():
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a DataLoader worker dies of SIGTERM
    time.sleep(60)

@click.group()
def group():
    pass

@group.command()
def work():
    child = multiprocessing.Process(target=worker, daemon=True)
    child.start()
    torch._C._set_worker_pids(1, (child.pid,))
    signal_handling._set_SIGCHLD_handler()
    time.sleep(0.5)
    try:
        os.killpg(0, signal.SIGTERM)
        time.sleep(10)
    except KeyboardInterrupt:
        print("interrupted; last good checkpoint: ...", flush=True)
        time.sleep(1)  # the worker's death is reported meanwhile
        raise

sys.argv = ["sc3d-train", "work"]
run_console(group)
"""


def test_sigterm_to_the_process_group_is_not_reported_as_a_dead_loader_worker(tmp_path):
    """SIGTERM to the whole process group (torchrun's agent stopping its ranks: each rank's
    session, loader workers included; ``timeout``; a scheduler) also ends the ``--workers``
    processes, and PyTorch's SIGCHLD handler reported their deaths as a ``RuntimeError`` that
    replaced the interrupt: a traceback, status 1 instead of 143 (raised even inside the exit
    path's ``join``, into Python's finalisation), or 'a loader worker process died ... out of
    memory?' (measured: 3 of 4 SIGTERMs to a 2-rank torchrun fit with --workers 2)."""
    import subprocess
    import sys
    from pathlib import Path

    script = tmp_path / "group_sigterm.py"
    script.write_text(GROUP_SIGTERM_SCRIPT)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60, env=env,
                       start_new_session=True)
    assert (r.returncode, "Traceback" in r.stderr) == (143, False), r.stdout + r.stderr
    assert "interrupted" in r.stdout
