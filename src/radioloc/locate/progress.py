"""A progress bar on standard error for long ``radioloc locate`` runs.

Methods report their progress through :func:`progress`; nothing is shown unless the command
line switched it on (:func:`show_progress`, off with ``--quiet``), and then only once a run
has lasted ``DELAY_S`` seconds, so short runs print nothing. The bar is drawn by rich on
standard error, never on standard output (which may hold the estimates).
"""

from __future__ import annotations

import contextlib
import time
from typing import Iterator

#: Seconds a run lasts before its bar appears.
DELAY_S = 2.0

_STATE = {"on": False}


@contextlib.contextmanager
def show_progress(on: bool) -> Iterator[None]:
    """Within the block, :func:`progress` bars are drawn (``on``) or not."""
    before = _STATE["on"]
    _STATE["on"] = bool(on)
    try:
        yield
    finally:
        _STATE["on"] = before


class _Bar:
    def __init__(self, total: int, what: str) -> None:
        self.total, self.what = max(int(total), 1), what
        self.done = 0
        self.start = time.monotonic()
        self.bar = None
        self.task = None

    def advance(self, n: int = 1) -> None:
        """Count ``n`` more units done."""
        self.done += n
        if not _STATE["on"]:
            return
        if self.bar is None and time.monotonic() - self.start >= DELAY_S:
            from rich.console import Console
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                       TimeRemainingColumn)

            self.bar = Progress(TextColumn("{task.description}"), BarColumn(),
                                MofNCompleteColumn(), TimeRemainingColumn(),
                                console=Console(stderr=True), transient=True)
            self.bar.start()
            self.task = self.bar.add_task(self.what, total=self.total, completed=self.done)
        elif self.bar is not None:
            self.bar.update(self.task, completed=self.done)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()


@contextlib.contextmanager
def progress(total: int, what: str) -> Iterator[_Bar]:
    """A bar over ``total`` units (time steps, tracks) described by ``what``.

    Parameters
    ----------
    total : int
        Units of work.
    what : str
        Description, e.g. ``"pf: steps"``.

    Yields
    ------
    object
        With ``advance(n=1)``.
    """
    bar = _Bar(total, what)
    try:
        yield bar
    finally:
        bar.close()
