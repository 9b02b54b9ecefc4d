"""``radioloc locate --follow``: estimates written as the rows arrive.

Rows come from standard input (``-``) or a file that grows (followed like ``tail -f``), as
CSV with a header line or as JSON lines (one object per line; the first line tells which).
They are read as they become available and given to a :class:`radioloc.locate.stream.Tracker`;
every estimate it makes is written at once as a CSV row and the output flushed. End of
input (a pipe closed), Ctrl-C or SIGTERM ends the run cleanly: the rows held are processed,
their estimates written and the summary (the tracker's counts) written to
``OUT-stem.summary.json`` beside ``--out``, or as one JSON line on standard error.

Memory stays bounded on endless input: only the reorder window, the rows of tracks waiting
for their start and the state of each node are kept.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import stat
import sys
import time
from pathlib import Path
from typing import Iterator, TextIO

import numpy as np

from radioloc.core.errors import ConfigError, InputError
from radioloc.io.logs import read_anchors
from radioloc.locate.stream import REORDER_S, Tracker

#: Bytes asked for per read.
READ_BYTES = 1 << 16
#: Seconds between looks at a followed file that has no new line.
POLL_S = 0.05


class _Stop(Exception):
    """Ctrl-C or SIGTERM while waiting for input."""


def input_lines(fd: int, poll_s: float = POLL_S) -> Iterator[list[bytes]]:
    """Complete lines of ``fd`` as they become available (a list per read).

    A pipe or terminal ends at end-of-input; a regular file is followed: at its end it is
    looked at again every ``poll_s`` seconds (the run ends with Ctrl-C).
    """
    follow = stat.S_ISREG(os.fstat(fd).st_mode)
    rest = b""
    while True:
        data = os.read(fd, READ_BYTES)
        if not data:
            if follow:
                time.sleep(poll_s)
                continue
            if rest.strip():
                yield [rest]
            return
        data = rest + data
        cut = data.rfind(b"\n") + 1
        rest = data[cut:]
        if cut:
            yield data[:cut].splitlines()


class RowParser:
    """Measurement rows from lines of CSV (a header line first) or JSON lines."""

    def __init__(self) -> None:
        self.header: list[str] | None = None
        self.json = False
        self.line = 0

    def rows(self, lines: list[bytes]) -> dict[str, list]:
        """The cells of ``lines`` by column (blank lines skipped), with their ``line``
        numbers (a mapping of columns for :meth:`radioloc.locate.Tracker.update`)."""
        texts, numbers = [], []
        for raw in lines:
            self.line += 1
            text = raw.decode("utf-8", errors="replace").strip()
            if not text:
                continue
            if self.header is None and not self.json:
                if text.startswith("{"):
                    self.json = True
                else:
                    self.header = [c.strip().lower() for c in next(csv.reader([text]))]
                    continue
            texts.append(text)
            numbers.append(self.line)
        if self.json:
            records = [self._record(text, line) for text, line in zip(texts, numbers)]
            keys = dict.fromkeys(k for r in records for k in r)
            columns = {k: [r.get(k) for r in records] for k in keys}
        else:
            cells = list(csv.reader(texts, skipinitialspace=True))
            for row, line in zip(cells, numbers):
                if len(row) != len(self.header):
                    raise InputError(f"measurements: line {line}: {len(row)} cells, the header "
                                     f"has {len(self.header)}")
            columns = {h: list(c) for h, c in zip(self.header, zip(*cells))} if cells else {}
        columns["line"] = numbers
        return columns

    @staticmethod
    def _record(text: str, line: int) -> dict:
        try:
            record = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(f"measurements: line {line}: not JSON ({exc.msg})") from None
        if not isinstance(record, dict):
            raise InputError(f"measurements: line {line}: expected a JSON object")
        return record


class CsvOut:
    """Estimates as CSV rows on a text stream (the text of the batch run's CSV: floats in
    their shortest exact form), the header once, flushed after each write."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.writer = csv.writer(stream, lineterminator=os.linesep)
        self.header = False
        self.rows = 0

    def write(self, columns: dict[str, np.ndarray]) -> None:
        """Write estimates given as columns (:meth:`Tracker.update` with ``as_frame=False``)."""
        if not columns:
            return
        if not self.header:
            self.writer.writerow(columns)
            self.header = True
        rows = list(zip(*(c.tolist() for c in columns.values())))
        self.writer.writerows(rows)
        self.stream.flush()
        self.rows += len(rows)


def follow(fd: int, tracker: Tracker, out: CsvOut) -> str:
    """Feed the rows of ``fd`` to ``tracker`` as they arrive, writing its estimates.

    Returns
    -------
    str
        How the run ended: ``"end of input"`` or ``"interrupted"`` (Ctrl-C, SIGTERM).
    """
    waiting = {"now": False}

    def stop(signum, frame):
        waiting["stopped"] = True
        if waiting["now"]:
            raise _Stop

    previous = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    parser, end = RowParser(), "end of input"
    try:
        lines = input_lines(fd)
        while not waiting.get("stopped"):
            waiting["now"] = True
            try:
                batch = next(lines, None)
            except _Stop:
                batch = None
            waiting["now"] = False
            if batch is None:
                break
            out.write(tracker.update(parser.rows(batch), as_frame=False))
        if waiting.get("stopped"):
            end = "interrupted"
        out.write(tracker.close(as_frame=False))
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return end


def follow_locate(measurements: Path, anchors: Path | None, method: str, options: dict,
                  out: Path | None, fmt: str, reorder_s: float | None,
                  unused: dict[str, object]) -> list[Path]:
    """The body of ``radioloc locate --follow``.

    Parameters
    ----------
    measurements : Path
        ``-`` (standard input) or a file, followed as it grows.
    anchors : Path or None
    method : str
    options : dict of str
        The method's ``-o`` options.
    out : Path or None
        CSV output (None or ``-``: standard output).
    fmt : str
        The output format (only ``csv`` streams).
    reorder_s : float or None
        Reorder window, seconds (None: :data:`REORDER_S`).
    unused : dict
        Other ``locate`` flags by name; any given is refused.

    Returns
    -------
    list of Path
        Files written.
    """
    given = [name for name, value in unused.items() if value not in (None, False)]
    if given:
        raise ConfigError(f"{given[0]}: not with --follow (estimates are written as rows "
                          "arrive)")
    if fmt != "csv":
        raise ConfigError(f"--follow writes CSV rows; not --format {fmt}")
    tracker = Tracker(method, None if anchors is None else read_anchors(anchors), options,
                      REORDER_S if reorder_s is None else reorder_s)
    to_stdout = out is None or str(out) == "-"
    source = str(measurements)
    if source != "-" and not Path(source).is_file():
        raise InputError(f"measurements file {source}: not found")
    fd = sys.stdin.fileno() if source == "-" else os.open(source, os.O_RDONLY)
    stream = sys.stdout if to_stdout else open(out, "w", encoding="utf-8", newline="")
    try:
        end = follow(fd, tracker, CsvOut(stream))
    finally:
        if not to_stdout:
            stream.close()
        if source != "-":
            os.close(fd)
    summary = {"method": method, "options": dict(sorted(options.items())),
               "measurements": source, "end": end, **tracker.summary()}
    if to_stdout:
        sys.stderr.write(json.dumps(summary) + "\n")
        return []
    target = Path(out).with_name(Path(out).stem + ".summary.json")
    target.write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    return [Path(out), target]
