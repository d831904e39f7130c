"""Start multiprocessing's forkserver so that a Ctrl-C during its start-up prints no traceback
(``local_pool`` forks its workers from it)."""
from __future__ import annotations

import signal
import threading
from multiprocessing import forkserver


def ensure_server(ctx) -> None:
    """With ``ctx`` (a multiprocessing context) of the ``forkserver`` start method, start this
    process's forkserver unless it runs, with Ctrl-C (SIGINT) ignored from the
    server's first instruction: multiprocessing ignores it only after the server's preload, so a
    Ctrl-C during its seconds of imports printed their traceback. The disposition is inherited
    through exec and fork; ``pool_worker.worker_main`` gives each worker Python's handler back."""
    if ctx.get_start_method() != "forkserver":
        return
    if threading.current_thread() is not threading.main_thread():
        forkserver.ensure_running()  # signal handlers can only be set from the main thread
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        forkserver.ensure_running()
    finally:
        signal.signal(signal.SIGINT, previous)
