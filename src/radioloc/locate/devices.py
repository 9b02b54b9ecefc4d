"""Device readers for ``radioloc locate --follow``: rows read from a radio module's own output.

``serial://DEVICE[?baud=115200&node=tag&send=lec]`` reads the UART of a Qorvo (Decawave)
DWM1001 module in its shell's ``lec`` mode, which prints one line per ranging round::

    DIST,3,AN0,1151,0.00,0.00,1.20,2.35,AN1,0CA8,5.00,0.00,1.20,3.91,AN2,...,POS,1.52,1.73,0.98,87

that is ``DIST``, the number ``n`` of anchors, then for each anchor its label (``AN0``,
``AN1``...), its node id (hexadecimal), its position as configured in the module (m, not
read here: the ``--anchors`` file holds the positions, its ids the modules' hexadecimal
ids as printed, e.g. ``1151``) and the range to it (m); then optionally the module's own
position estimate (``POS``, x, y, z, quality factor; not read). Each range becomes a row
``time, node, peer, kind=range, value``: ``time`` is the host's clock (Unix seconds) when
the line was read (the module prints none; two lines read at once are kept in order,
a microsecond apart), ``node`` the ``node`` parameter.

A line that is not a complete ``DIST`` line (the shell's prompt and echo, a ``POS`` line
of the ``lep`` mode, the garbled lines the module prints at high update rates, a range
that is not a finite number >= 0) is skipped and counted; the first of them is kept for
the summary (``device``).

``send=lec`` (or another shell command) wakes the shell (two carriage returns, then a
second's wait) and sends the command once the port is open. Left out, nothing is sent:
``lec`` toggles, so a module already printing would stop.

Reading a serial port needs the optional dependency pyserial (``pip install
'radioloc[devices]'``); the port is used through its file descriptor (POSIX).
"""

from __future__ import annotations

import math
import os
import re
import termios
import time
from urllib.parse import parse_qs

from radioloc.core.errors import ConfigError, InputError

__all__ = ["DWM1001_BAUD", "Dwm1001Lines", "open_serial"]

#: The DWM1001 UART's speed (8 data bits, no parity, 1 stop bit).
DWM1001_BAUD = 115200
#: Seconds the DWM1001 shell needs after the two carriage returns that wake it.
WAKE_S = 1.0
#: Parameters a ``serial://`` source takes.
SERIAL_PARAMETERS = ("baud", "node", "send")
_HEX = re.compile(r"[0-9A-Fa-f]{1,16}")


class Dwm1001Lines:
    """Measurement rows from DWM1001 ``lec`` lines (module docstring), with the same
    :meth:`rows` as :class:`radioloc.locate.follow.RowParser`.

    Parameters
    ----------
    node : str
        The node the ranges are of.
    clock : callable
        Returns the time to stamp a line with (default :func:`time.time`).
    """

    def __init__(self, node: str = "tag", clock=time.time) -> None:
        self.node = node
        self.clock = clock
        self.line = 0
        self.last = -math.inf
        self.counts = {"lines": 0, "lines_with_ranges": 0, "lines_skipped": 0}
        self.first_skipped: str | None = None

    def ranges(self, text: str) -> list[tuple[str, float]] | None:
        """``(anchor id, range)`` of one ``lec`` line, or None when it is not one."""
        cells = [c.strip() for c in text.split(",")]
        if len(cells) < 2 or cells[0] != "DIST" or not cells[1].isdigit():
            return None
        n = int(cells[1])
        tail = cells[2 + 6 * n:]
        if n == 0 or len(cells) < 2 + 6 * n or tail and (tail[0] != "POS" or len(tail) != 5):
            return None
        out = []
        for k in range(n):
            label, ident, *_, dist = cells[2 + 6 * k: 8 + 6 * k]
            try:
                value = float(dist)
            except ValueError:
                return None
            if label != f"AN{k}" or not _HEX.fullmatch(ident) or not (
                    math.isfinite(value) and value >= 0):
                return None
            out.append((ident.upper(), value))
        return out

    def rows(self, lines: list[bytes]) -> dict[str, list]:
        """The rows of ``lines`` by column, with their ``line`` numbers."""
        columns: dict[str, list] = {k: [] for k in ("time", "node", "peer", "kind", "value",
                                                     "line")}
        for raw in lines:
            self.line += 1
            text = raw.decode("ascii", errors="replace").strip()
            if not text:
                continue
            self.counts["lines"] += 1
            found = self.ranges(text)
            if found is None:
                self.counts["lines_skipped"] += 1
                if self.first_skipped is None:
                    self.first_skipped = f"line {self.line}: {text[:120]}"
                continue
            self.counts["lines_with_ranges"] += 1
            t = max(float(self.clock()), self.last + 1e-6)
            self.last = t
            for peer, value in found:
                for key, cell in zip(columns, (t, self.node, peer, "range", value, self.line)):
                    columns[key].append(cell)
        return columns

    def summary(self) -> dict:
        """The lines read, with ranges and skipped (and the first skipped)."""
        return {"format": "dwm1001-lec", **self.counts,
                **({"first_skipped": self.first_skipped} if self.first_skipped else {})}


def open_serial(source: str):
    """``(port, parser, name)`` for a ``serial://DEVICE[?...]`` source (module docstring),
    or None for another source. ``port`` is an open ``serial.Serial`` whose file
    descriptor blocks on read.

    Raises
    ------
    ConfigError
        pyserial is missing, or a parameter is unknown or not a number.
    InputError
        The device cannot be opened (naming it and why).
    """
    # a path argument folds serial:///dev/x into serial:/dev/x
    match = re.fullmatch(r"serial:(?://)?([^?]+)(?:\?(.*))?", source)
    if match is None:
        return None
    device, query = match[1], parse_qs(match[2] or "", keep_blank_values=True)
    unknown = sorted(set(query) - set(SERIAL_PARAMETERS))
    if unknown:
        raise ConfigError(f"measurements {source}: unknown parameter {unknown[0]!r} "
                          f"(known: {', '.join(SERIAL_PARAMETERS)})")
    get = {k: v[-1] for k, v in query.items()}
    try:
        baud = int(get.get("baud", DWM1001_BAUD))
    except ValueError:
        raise ConfigError(f"measurements {source}: baud: expected a whole number, "
                          f"got {get['baud']!r}") from None
    try:
        import serial
    except ImportError:
        raise ConfigError("serial:// sources need pyserial: pip install "
                          "'radioloc[devices]'") from None
    try:
        port = serial.Serial(device, baudrate=baud, timeout=0)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise InputError(f"measurements {source}: cannot open {device} "
                         f"({getattr(exc, 'strerror', None) or exc})") from None
    # a read waits for a byte (pyserial leaves VMIN at 0, where a read with no byte
    # waiting returns nothing, which would read as the end of input)
    os.set_blocking(port.fileno(), True)
    attrs = termios.tcgetattr(port.fileno())
    attrs[6][termios.VMIN], attrs[6][termios.VTIME] = 1, 0
    termios.tcsetattr(port.fileno(), termios.TCSANOW, attrs)
    if get.get("send"):
        port.write(b"\r\r")
        time.sleep(WAKE_S)
        port.write(get["send"].encode("ascii", errors="replace") + b"\r")
    name = f"serial://{device}"
    return port, Dwm1001Lines(get.get("node") or "tag"), name
