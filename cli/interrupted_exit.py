"""How a ``sc3d-train`` process ends after Ctrl-C or SIGTERM, and a torchrun rank after any end:
at once, without Python's finalisation.

After a Ctrl-C (a ``KeyboardInterrupt`` unwound through a training step, a validation, a
TensorBoard write), the interpreter's finalisation sometimes never ended: the process had
printed its last lines (``interrupted ...``, ``Aborted!``) and then spun at 100% CPU until
killed. gdb showed its one thread in the collector's final pass (``Py_FinalizeEx`` ->
``finalize_modules`` -> ``_PyGC_CollectNoFail``), looping over a corrupted object list (the
tuple free list; ``subtract_refs``): 4 of 55 runs of the Ctrl-C test's ``fit`` (``tests/
test_faults_train_round14.py``) pinned to one core beside three busy loops, and the CI flake of
that test; never after a command that ended otherwise. What corrupts the list lies below sc3d
(PyTorch or CPython); the command has written everything by then (checkpoints atomically,
``metrics.csv`` line by line, TensorBoard closed in ``fit``'s ``finally``), so nothing is lost by
not finalising: :func:`run_console` flushes the output, stops this process's child processes
(``--workers`` loader workers) and leaves with ``os._exit`` and the status click gives (1).

A torchrun rank (a process that joined a process group: ``fit`` on several GPUs or gloo ranks)
leaves the same way after any end, once it has left its group: a DDP model keeps the group's
gloo threads (``pt_gloo_runloop``, ``gloo_tcp_loop``) alive after ``destroy_process_group``
(measured: present after it and a collection with DDP, gone without), so they ran on through the
interpreter's finalisation and the C++ static destructors, where a rank that had finished its
work aborted, rarely ("terminate called without an active exception"; torchrun then stopped
the other ranks and the job failed: once in five full test-suite runs, 2026-12-07).
"""
from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import traceback

import click

__all__ = ["console_script", "ignore_child_deaths", "leave_now", "left_process_group", "run_console"]


def run_console(group: click.Group) -> None:
    """Run console script ``group`` (standalone, as click runs it); after a Ctrl-C (SIGINT) or a
    SIGTERM (``docker stop``, a scheduler's preemption, ``kill``), leave at once (module doc)
    instead of finalising. SIGTERM is made a Ctrl-C, so the command says what it kept
    (``interrupted ...; last good checkpoint ...``; before, it died without a word), and the
    status is then 143 (128 + SIGTERM), what a scheduler reads of a terminated job. A signal this
    process inherited ignored (``nohup`` ignores SIGINT) stays ignored. A torchrun rank leaves
    at once after any end, having left its process group (module doc)."""
    interrupted: list[int] = []

    def on_signal(signum, frame):
        interrupted.append(signum)
        ignore_child_deaths()
        raise KeyboardInterrupt

    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, on_signal)
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, on_signal)
    try:
        group()
    except SystemExit as e:
        if interrupted:
            # a second Ctrl-C (or SIGTERM) from here on, while a child is stopped or an output flushed, would
            # raise KeyboardInterrupt out of this function: a traceback and the finalisation skipped here
            for signum in (signal.SIGINT, signal.SIGTERM):
                signal.signal(signum, signal.SIG_IGN)
            leave_now(128 + signal.SIGTERM if interrupted[0] == signal.SIGTERM else e.code if isinstance(e.code, int)
                      else 1)
        if left_process_group():
            leave_now(e.code if isinstance(e.code, int) else 0 if e.code is None else 1)
        raise
    except BaseException:  # a bug's traceback (click reports the others as SystemExit)
        if left_process_group():
            traceback.print_exc()
            leave_now(1)
        raise


def left_process_group() -> bool:
    """Whether this process had joined a torchrun process group, which it has now left (module
    doc). Imports nothing: a command that never trained has not loaded the runtime."""
    runtime = sys.modules.get("sc3d_train.loop.runtime")
    if runtime is None or not runtime.joined_process_group():
        return False
    runtime.teardown_distributed()
    return True


def leave_now(code: int) -> None:
    """Flush the output, stop this process's child processes and end it with status ``code``,
    without Python's finalisation (module doc)."""
    ignore_child_deaths()  # the children it stops here would otherwise be reported as failed workers
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    for child in multiprocessing.active_children():
        child.terminate()
        child.join(5)
    os._exit(code)


def ignore_child_deaths() -> None:
    """Take PyTorch's SIGCHLD handler off (a DataLoader's): a signal sent to the whole process
    group (torchrun's agent stopping a rank's session, ``timeout``, a scheduler) also ends the
    ``--workers`` processes, and that handler reported their deaths as a ``RuntimeError``
    ("DataLoader worker ... killed by signal") that replaced the interrupt: a traceback and status
    1 (also from inside :func:`leave_now`'s ``join``, into the finalisation), or 'a loader worker
    process died ... out of memory?'. After an interrupt no worker's death is news. A handler
    that does nothing, not ``SIG_DFL``: a SIGCHLD already pending would be reported on stderr as
    "Signal 17 ignored due to race condition"."""
    signal.signal(signal.SIGCHLD, lambda signum, frame: None)


def console_script(group: click.Group):
    """The console-script function of ``group``: :func:`run_console` of it; its ``group``
    attribute is ``group`` (what tools reading the entry point, the docs' checker, inspect)."""
    def run() -> None:
        run_console(group)

    run.group = group
    return run
