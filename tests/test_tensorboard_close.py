"""Closing the run's TensorBoard writer after a Ctrl-C waited up to 2 minutes: a ``KeyboardInterrupt``
raised inside its queue's ``Condition.notify`` (CPython 3.11: between a waiter's release and its
removal) leaves a stale, re-acquired waiter first in the condition's list, which takes the next
notify; the writer thread then slept through the sentinel of ``close`` until its flush interval
(TensorBoard's default 120 s) ran out. Here that stale waiter is put in place by hand, as the
interrupted notify leaves it, and ``close`` must return within the (now 5 s) interval."""
from __future__ import annotations

import threading
import time

from sc3d_train.loop.metrics_log import MetricsLog


def test_closing_after_an_interrupted_notify_waits_at_most_the_flush_interval(tmp_path):
    log = MetricsLog(tmp_path, start_step=0)
    log.log(1, {"total": 1.0})  # its first write is flushed at once; the writer thread then sleeps
    time.sleep(0.5)
    queue = log.tb.file_writer.event_writer._async_writer._byte_queue
    stale = threading.Lock()
    stale.acquire()  # a waiter whose thread was woken and took it: a notify releasing it wakes nobody
    with queue.mutex:
        queue.not_empty._waiters.appendleft(stale)
    t0 = time.monotonic()
    log.close()
    assert time.monotonic() - t0 < 15
