"""Progress of long ``radioloc locate`` runs, on standard error.

Methods report their progress through :func:`progress`, counting the rows of the log (or
epochs) they have processed; nothing is shown unless the command line switched it on
(:func:`show_progress`, off with ``--quiet``), and then only once a run has lasted
``DELAY_S`` seconds, so short runs print nothing. On a terminal the bar is drawn by rich;
when standard error is not a terminal (a log file, a pipe) one line is written per
``LINE_EVERY_S`` seconds of work instead (``gn: 120,000 of 1,000,000 rows (12 %) after 10 s``).
Never on standard output, which may hold the estimates.
"""

from __future__ import annotations

import contextlib
import sys
import time
from typing import Callable, Iterable, Iterator, TypeVar

T = TypeVar("T")

#: Seconds a run lasts before its bar appears.
DELAY_S = 2.0
#: Seconds between two lines of progress when standard error is not a terminal.
LINE_EVERY_S = 10.0

_STATE = {"on": False, "terminal": False}


@contextlib.contextmanager
def show_progress(on: bool) -> Iterator[None]:
    """Within the block, :func:`progress` is shown (``on``) or not: a bar on a terminal,
    a line per ``LINE_EVERY_S`` seconds otherwise."""
    before = dict(_STATE)
    _STATE["on"] = bool(on)
    _STATE["terminal"] = bool(on) and sys.stderr.isatty()
    try:
        yield
    finally:
        _STATE.update(before)


class _Bar:
    def __init__(self, total: int, what: str, unit: str) -> None:
        self.total, self.what, self.unit = max(int(total), 1), what, unit
        self.done = 0
        self.start = self.last_line = time.monotonic()
        self.bar = None
        self.task = None

    def advance(self, n: int = 1) -> None:
        """Count ``n`` more units done."""
        self.done += int(n)
        if not _STATE["on"]:
            return
        now = time.monotonic()
        if not _STATE["terminal"]:
            if now - self.last_line >= LINE_EVERY_S:
                self.last_line = now
                sys.stderr.write(self.line(now) + "\n")
                sys.stderr.flush()
            return
        if self.bar is None and now - self.start >= DELAY_S:
            from rich.console import Console
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                       TimeRemainingColumn)

            self.bar = Progress(TextColumn("{task.description}"), BarColumn(),
                                MofNCompleteColumn(), TimeRemainingColumn(),
                                console=Console(stderr=True), transient=True)
            self.bar.start()
            self.task = self.bar.add_task(f"{self.what}: {self.unit}", total=self.total,
                                          completed=self.done)
        elif self.bar is not None:
            self.bar.update(self.task, completed=self.done)

    def line(self, now: float) -> str:
        """``what: done of total unit (percent) after seconds``."""
        done = min(self.done, self.total)
        return (f"{self.what}: {done:,} of {self.total:,} {self.unit} "
                f"({100.0 * done / self.total:.0f} %) after {now - self.start:.0f} s")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()


@contextlib.contextmanager
def progress(total: int, what: str, unit: str = "rows") -> Iterator[_Bar]:
    """Progress over ``total`` units of ``what`` (a method's name).

    Parameters
    ----------
    total : int
        Units of work: the rows of the log the method processes (or its epochs).
    what : str
        Who works, e.g. ``"pf"``.
    unit : str
        What is counted (``"rows"``, ``"epochs"``).

    Yields
    ------
    object
        With ``advance(n=1)``.
    """
    bar = _Bar(total, what, unit)
    try:
        yield bar
    finally:
        bar.close()


def counted(items: Iterable[T], total: int, size: Callable[[T], int], what: str,
            unit: str = "rows") -> Iterator[T]:
    """``items`` one by one, :func:`progress` counting ``size(item)`` units done once the
    work on an item is over (when the next is asked for).

    Parameters
    ----------
    items : iterable
        E.g. the nodes of a log.
    total : int
        Units of work of all the items.
    size : callable
        Units of one item (its rows).
    what, unit : str
        As :func:`progress`.

    Yields
    ------
    The items.
    """
    with progress(total, what, unit) as bar:
        for item in items:
            yield item
            bar.advance(size(item))
