"""Progress display for long jobs that suits where the output goes.

On a terminal: a tqdm bar (redrawn in place). Anywhere else (a log file, a pipe, CI, a batch
scheduler): one plain line each time another ``every_percent`` of the total is done or
``every_s`` seconds have passed, whichever comes first, and a final line on ``close``, so a
log gets a handful of readable lines instead of thousands of carriage-return redraws::

    render: 120/1200 (10%) in 0:00:35, 3.4 obj/s, ETA 0:05:15

Use :func:`progress_bar` wherever a bar is made; it returns an object with tqdm's ``update``,
``set_postfix``, ``close`` and iteration (the subset sc3d uses).
"""
from __future__ import annotations

import sys
import time
from typing import IO, Iterable

EVERY_PERCENT = 10.0
EVERY_S = 60.0


def _is_tty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def _hms(seconds: float) -> str:
    s = int(max(seconds, 0))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


class LineProgress:
    """tqdm-like progress for non-terminals: prints a line per ``every_percent`` of ``total``
    (or per ``every_s`` seconds when the total is unknown or progress is slow)."""

    def __init__(self, iterable: Iterable | None = None, total: int | None = None, initial: int = 0,
                 unit: str = "it", desc: str = "", file: IO | None = None,
                 every_percent: float = EVERY_PERCENT, every_s: float = EVERY_S):
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)
        self.iterable, self.total, self.n, self.unit, self.desc = iterable, total, initial, unit, desc
        self.file = file if file is not None else sys.stderr
        self.every_percent, self.every_s = every_percent, every_s
        self.start = self.last_time = time.monotonic()
        self.initial = initial
        self.last_pct_step = self._pct_step()
        self.postfix = ""
        self.closed = False

    def _pct_step(self) -> int:
        if not self.total:
            return 0
        return int(100.0 * self.n / self.total // self.every_percent)

    def _line(self) -> str:
        elapsed = time.monotonic() - self.start
        rate = (self.n - self.initial) / elapsed if elapsed > 0 else 0.0
        head = f"{self.desc}: " if self.desc else ""
        if self.total:
            text = f"{head}{self.n}/{self.total} ({100.0 * self.n / self.total:.0f}%) in {_hms(elapsed)}"
        else:
            text = f"{head}{self.n} {self.unit} in {_hms(elapsed)}"
        text += f", {rate:.3g} {self.unit}/s"
        if self.total and rate > 0 and self.n < self.total:
            text += f", ETA {_hms((self.total - self.n) / rate)}"
        return text + (f" ({self.postfix})" if self.postfix else "")

    def _emit(self) -> None:
        print(self._line(), file=self.file, flush=True)
        self.last_time = time.monotonic()
        self.last_pct_step = self._pct_step()

    def update(self, n: int = 1) -> None:
        self.n += n
        if self._pct_step() > self.last_pct_step or time.monotonic() - self.last_time >= self.every_s:
            self._emit()

    def set_postfix(self, **values) -> None:
        self.postfix = ", ".join(f"{k}={v}" for k, v in values.items())

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._emit()

    def __iter__(self):
        try:
            for item in self.iterable:
                yield item
                self.update(1)
        finally:
            self.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def progress_bar(iterable: Iterable | None = None, total: int | None = None, initial: int = 0,
                 unit: str = "it", desc: str = "", file: IO | None = None):
    """A tqdm bar when ``file`` (default ``sys.stderr``, where tqdm writes) is a terminal, else
    a :class:`LineProgress` printing a line per 10 % or per minute."""
    stream = file if file is not None else sys.stderr
    if _is_tty(stream):
        from tqdm import tqdm

        return tqdm(iterable, total=total, initial=initial, unit=unit, desc=desc or None, file=stream,
                    dynamic_ncols=True)
    return LineProgress(iterable, total=total, initial=initial, unit=unit, desc=desc, file=stream)
