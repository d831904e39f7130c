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
