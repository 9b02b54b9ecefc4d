"""``radioloc locate --follow``: estimates written as the rows arrive.

Rows come from standard input (``-``), a file that grows (followed like ``tail -f``) or
UDP datagrams (``udp://HOST:PORT``, each datagram whole lines), as CSV with a header line
or as JSON lines (one object per line; the first line tells which; a CSV header line that
comes again, e.g. at the top of every datagram, is skipped); or from a device
(:mod:`radioloc.locate.devices`: ``serial://DEVICE``, a DWM1001 module's ranging lines;
``mqtt://HOST/TOPIC``, a broker's messages, read as datagrams are). They are read as they become
available and given to a :class:`radioloc.locate.stream.Tracker`; every estimate it makes
is written at once as a CSV row and the output flushed. End of input (a pipe closed),
Ctrl-C or SIGTERM ends the run cleanly: the rows held are processed, their estimates
written and the summary (the tracker's counts) written to ``OUT-stem.summary.json`` beside
``--out``, or as one JSON line on standard error.

A time is processed once a later one has come (rows of one time stamp may arrive apart);
with ``--idle-s`` also once the input has been idle that long (:meth:`Tracker.flush`), so
the latest step's estimate need not wait for the next step.

Memory stays bounded on endless input: only the reorder window, the rows of tracks waiting
for their start and the state of each node are kept.
"""

from __future__ import annotations

import csv
import errno
import json
import math
import os
import re
import select
import signal
import socket
import stat
import sys
import time
from pathlib import Path
from typing import Iterator, TextIO

import numpy as np

from radioloc.core.errors import ConfigError, InputError
from radioloc.io.logs import read_anchors
from radioloc.locate.devices import open_device
from radioloc.locate.stream import REORDER_S, Tracker

#: Bytes asked for per read.
READ_BYTES = 1 << 16
#: Seconds between looks at a followed file that has no new line.
POLL_S = 0.05
#: Receive buffer asked for a UDP socket, bytes (datagrams beyond it are lost by the system).
RECEIVE_BYTES = 1 << 22


class _Stop(Exception):
    """Ctrl-C or SIGTERM while waiting for input."""


def input_lines(fd: int, poll_s: float = POLL_S, idle_s: float | None = None,
                datagrams: bool = False) -> Iterator[list[bytes]]:
    """Complete lines of ``fd`` as they become available (a list per read).

    A pipe or terminal ends at end-of-input; a regular file is followed: at its end it is
    looked at again every ``poll_s`` seconds; a datagram socket (``datagrams``: each
    datagram holds whole lines) never ends (the run ends with Ctrl-C).

    With ``idle_s``, an empty list is yielded once the input has had nothing new for
    ``idle_s`` seconds (once per quiet spell).
    """
    follow = stat.S_ISREG(os.fstat(fd).st_mode)
    rest, quiet = b"", False
    while True:
        if idle_s is not None and not quiet and not follow:
            if not select.select([fd], [], [], idle_s)[0]:
                quiet = True
                yield []
                continue
        try:
            data = os.read(fd, READ_BYTES)
        except OSError as exc:          # a terminal whose other end went away (a device
            if exc.errno != errno.EIO:  # unplugged, a pseudo-terminal's master closed)
                raise
            data = b""
        if datagrams:
            quiet = False
            if data:                          # an empty datagram says nothing
                yield data.splitlines()
            continue
        if not data:
            if follow:
                if idle_s is not None and not quiet:
                    quiet = True
                    yield []
                time.sleep(poll_s)
                continue
            if rest.strip():
                yield [rest]
            return
        quiet = False
        data = rest + data
        cut = data.rfind(b"\n") + 1
        rest = data[cut:]
        if cut:
            yield data[:cut].splitlines()


def udp_socket(source: str) -> socket.socket | None:
    """A datagram socket bound to the address of ``source`` ``udp://HOST:PORT`` (``HOST``
    empty: every interface; ``PORT`` 0: any free port), or None for another source.

    Raises
    ------
    InputError
        The address cannot be listened on (naming it and why).
    """
    # a path argument folds the two slashes of udp:// into one
    match = re.fullmatch(r"udp:/{1,2}(\[[^\]]*\]|[^:/\[\]]*):(\d+)/?", source)
    if match is None:
        return None
    host = match[1].strip("[]") or "0.0.0.0"
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BYTES)
        sock.bind((host, int(match[2])))
    except (OSError, OverflowError) as exc:
        sock.close()
        raise InputError(f"measurements {source}: cannot listen there "
                         f"({getattr(exc, 'strerror', None) or exc})") from None
    return sock


class RowParser:
    """Measurement rows from lines of CSV (a header line first) or JSON lines."""

    def __init__(self) -> None:
        self.header: list[str] | None = None
        self.header_line = ""
        self.json = False
        self.line = 0

    def rows(self, lines: list[bytes]) -> dict[str, list]:
        """The cells of ``lines`` by column (blank lines skipped), with their ``line``
        numbers (a mapping of columns for :meth:`radioloc.locate.Tracker.update`)."""
        first = self.line + 1
        self.line += len(lines)
        texts = b"\n".join(lines).decode("utf-8", errors="replace").split("\n")
        kept = [(n, t) for n, t in enumerate(map(str.strip, texts), first)
                if t and t != self.header_line]
        if kept and self.header is None and not self.json:
            if kept[0][1].startswith("{"):
                self.json = True
            else:
                self.header_line = kept[0][1]
                self.header = [c.strip().lower() for c in next(csv.reader([self.header_line]))]
                kept = [(n, t) for n, t in kept[1:] if t != self.header_line]
        numbers = [n for n, _ in kept]
        texts = [t for _, t in kept]
        if self.json:
            records = [self._record(text, line) for text, line in zip(texts, numbers)]
            keys = dict.fromkeys(k for r in records for k in r)
            columns = {k: [r.get(k) for r in records] for k in keys}
        else:
            quoted = any('"' in t for t in texts)
            cells = (list(csv.reader(texts, skipinitialspace=True)) if quoted
                     else [t.split(",") for t in texts])      # the same cells, sooner
            bad = [i for i, row in enumerate(cells) if len(row) != len(self.header)]
            if bad:
                raise InputError(f"measurements: line {numbers[bad[0]]}: {len(cells[bad[0]])} "
                                 f"cells, the header has {len(self.header)}")
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


def follow(fd: int, tracker: Tracker, out: CsvOut, idle_s: float | None = None,
           datagrams: bool = False, parser=None) -> str:
    """Feed the rows of ``fd`` to ``tracker`` as they arrive, writing its estimates.

    With ``idle_s``, the rows held are processed (:meth:`Tracker.flush`) once the input has
    had nothing new for ``idle_s`` seconds; ``datagrams``: ``fd`` is a datagram socket (see
    :func:`input_lines`); ``parser``: what turns lines into rows (default
    :class:`RowParser`; a device's, :mod:`radioloc.locate.devices`).

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
    parser, end = parser or RowParser(), "end of input"
    try:
        lines = input_lines(fd, idle_s=idle_s, datagrams=datagrams)
        while not waiting.get("stopped"):
            waiting["now"] = True
            try:
                batch = next(lines, None)
            except _Stop:
                batch = None
            waiting["now"] = False
            if batch is None:
                break
            out.write(tracker.update(parser.rows(batch), as_frame=False) if batch
                      else tracker.flush(as_frame=False))
        if waiting.get("stopped"):
            end = "interrupted"
        out.write(tracker.close(as_frame=False))
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return end


def follow_locate(measurements: Path, anchors: Path | None, method: str, options: dict,
                  out: Path | None, fmt: str, reorder_s: float | None,
                  unused: dict[str, object], *, idle_s: float | None = None) -> list[Path]:
    """The body of ``radioloc locate --follow``.

    Parameters
    ----------
    measurements : Path
        ``-`` (standard input), a file, followed as it grows, ``udp://HOST:PORT``:
        datagrams of whole lines received there (port 0: any free port; the address is
        written on standard error), ``serial://DEVICE[?...]``: a DWM1001 module's
        ranging lines, or ``mqtt://HOST[:PORT]/TOPIC``: a broker's messages
        (:mod:`radioloc.locate.devices`).
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
    idle_s : float or None
        Process the rows held once the input has been idle this long (None: only once a
        later time has come).

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
    if idle_s is not None and not (math.isfinite(idle_s) and idle_s >= 0):
        raise ConfigError(f"--idle-s: expected a finite number >= 0 of seconds, got {idle_s!r}")
    tracker = Tracker(method, None if anchors is None else read_anchors(anchors), options,
                      REORDER_S if reorder_s is None else reorder_s)
    to_stdout = out is None or str(out) == "-"
    source = str(measurements)
    device = open_device(source)
    sock = None if device is not None else udp_socket(source)
    if device is not None:
        source = device.name
        sys.stderr.write(f"reading {source}\n")
        sys.stderr.flush()
    elif sock is not None:
        host, port = sock.getsockname()[:2]
        source = f"udp://{f'[{host}]' if ':' in host else host}:{port}"
        sys.stderr.write(f"listening on {source}\n")
        sys.stderr.flush()
    elif source != "-" and not Path(source).is_file():
        raise InputError(f"measurements file {source}: not found")
    parser = device.parser if device is not None and device.parser else RowParser()
    fd = (device.fd if device is not None else sock.fileno() if sock is not None
          else sys.stdin.fileno() if source == "-" else os.open(source, os.O_RDONLY))
    try:
        stream = sys.stdout if to_stdout else open(out, "w", encoding="utf-8", newline="")
        try:
            end = follow(fd, tracker, CsvOut(stream), idle_s, datagrams=sock is not None,
                         parser=parser)
        finally:
            if not to_stdout:
                stream.close()
    finally:
        if device is not None:
            device.close()
        elif sock is not None:
            sock.close()
        elif source != "-":
            os.close(fd)
    summary = {"method": method, "options": dict(sorted(options.items())),
               "measurements": source, "end": end, **tracker.summary(),
               **({"device": parser.summary()} if device is not None and device.parser
                  else {})}
    if to_stdout:
        sys.stderr.write(json.dumps(summary) + "\n")
        return []
    target = Path(out).with_name(Path(out).stem + ".summary.json")
    target.write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    return [Path(out), target]
