"""Device readers for ``radioloc locate --follow``: rows from a radio module or a message broker.

Each opener returns a :class:`Device` (a file descriptor the rows' lines are read from as
they arrive, the parser of those lines, a name and how to close it), or None for a source
that is not its own; :func:`open_device` tries them in turn.

**MQTT.** ``mqtt://[USER[:PASSWORD]@]HOST[:PORT]/TOPIC[?qos=1]`` subscribes to ``TOPIC``
(wildcards ``+`` and ``#`` allowed) at the broker (port 1883 by default); each message's
payload is whole lines of CSV (a header line on top of the first message; a header line that
comes again is skipped) or JSON lines, as a UDP datagram's. The messages are handed from
paho-mqtt's network thread to the run through a pipe. A lost connection is made again by
paho-mqtt (the run goes on until Ctrl-C); one refused at the start (wrong address, refused
credentials) is an error naming the broker.

**Serial.** ``serial://DEVICE[?baud=115200&node=tag&send=lec]`` reads the UART of a Qorvo (Decawave)
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

Both need the optional extra ``devices`` (pyserial, paho-mqtt: ``pip install
'radioloc[devices]'``); a serial port is used through its file descriptor (POSIX).
"""

from __future__ import annotations

import importlib
import math
import os
import re
import termios
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from urllib.parse import parse_qs, unquote

from radioloc.core.errors import ConfigError, InputError

__all__ = ["DWM1001_BAUD", "Device", "Dwm1001Lines", "open_device", "open_mqtt", "open_serial"]

#: The DWM1001 UART's speed (8 data bits, no parity, 1 stop bit).
DWM1001_BAUD = 115200
#: Seconds the DWM1001 shell needs after the two carriage returns that wake it.
WAKE_S = 1.0
#: Parameters a ``serial://`` source takes.
SERIAL_PARAMETERS = ("baud", "node", "send")
#: Parameters an ``mqtt://`` source takes.
MQTT_PARAMETERS = ("qos",)
#: The MQTT broker's default port.
MQTT_PORT = 1883
#: Seconds to wait for the broker to accept the connection and the subscription.
MQTT_WAIT_S = 10.0
_HEX = re.compile(r"[0-9A-Fa-f]{1,16}")


@dataclass
class Device:
    """An open source of rows: ``fd`` to read their lines from, ``parser`` of the lines (None:
    CSV or JSON lines, :class:`radioloc.locate.follow.RowParser`), ``name`` for the summary,
    ``close`` to let it go."""

    fd: int
    name: str
    close: Callable[[], None]
    parser: object | None = None


def open_device(source: str) -> Device | None:
    """The :class:`Device` of a ``serial://`` or ``mqtt://`` source, or None for another."""
    return open_serial(source) or open_mqtt(source)


def _parameters(source: str, query: str | None, known: tuple) -> dict[str, str]:
    """A source's ``?key=value`` parameters (the last of each), an unknown key refused."""
    given = parse_qs(query or "", keep_blank_values=True)
    unknown = sorted(set(given) - set(known))
    if unknown:
        raise ConfigError(f"measurements {source}: unknown parameter {unknown[0]!r} "
                          f"(known: {', '.join(known)})")
    return {k: v[-1] for k, v in given.items()}


def _whole(source: str, key: str, text: str, allowed=None) -> int:
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or (allowed is not None and value not in allowed):
        raise ConfigError(f"measurements {source}: {key}: expected a whole number"
                          + (f" in {sorted(allowed)}" if allowed else "") + f", got {text!r}")
    return value


def _module(name: str, what: str):
    try:
        return importlib.import_module(name)
    except ImportError:
        raise ConfigError(f"{what} sources need the optional extra devices: pip install "
                          "'radioloc[devices]'") from None


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


def open_serial(source: str) -> Device | None:
    """The :class:`Device` of a ``serial://DEVICE[?...]`` source (module docstring), or
    None for another source. Its descriptor blocks on read until a byte comes.

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
    device = match[1]
    get = _parameters(source, match[2], SERIAL_PARAMETERS)
    baud = _whole(source, "baud", get.get("baud", str(DWM1001_BAUD)))
    serial = _module("serial", "serial://")
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
    return Device(port.fileno(), f"serial://{device}", port.close,
                  Dwm1001Lines(get.get("node") or "tag"))


def open_mqtt(source: str) -> Device | None:
    """The :class:`Device` of an ``mqtt://...`` source (module docstring), or None for
    another source: subscribed, its messages' payloads arriving as lines on the
    descriptor.

    Raises
    ------
    ConfigError
        paho-mqtt is missing, or a parameter is unknown or out of range.
    InputError
        The broker cannot be reached, refuses the connection or the subscription (naming
        it and why).
    """
    # a path argument folds mqtt://host/topic into mqtt:/host/topic
    match = re.fullmatch(r"mqtt:/{1,2}(?:([^:@/]*)(?::([^@/]*))?@)?(\[[^\]]*\]|[^:/\[\]@]+)"
                         r"(?::(\d+))?/([^?]+)(?:\?(.*))?", source)
    if match is None:
        return None
    user, password, host, port, topic, query = match.groups()
    host, port = host.strip("[]"), int(port or MQTT_PORT)
    qos = _whole(source, "qos", _parameters(source, query, MQTT_PARAMETERS).get("qos", "1"),
                 {0, 1, 2})
    mqtt = _module("paho.mqtt.client", "mqtt://")
    name = f"mqtt://{f'[{host}]' if ':' in host else host}:{port}/{topic}"
    read, write = os.pipe()
    state = {"connected": threading.Event(), "subscribed": threading.Event(), "why": None}

    def on_connect(client, userdata, flags, reason, properties):
        if reason.is_failure:
            state["why"] = f"connection refused: {reason}"
            state["connected"].set()
            return
        client.subscribe(topic, qos)          # again on every reconnection
        state["connected"].set()

    def on_subscribe(client, userdata, mid, reasons, properties):
        bad = [str(r) for r in reasons if r.is_failure]
        state["why"] = f"subscription refused: {bad[0]}" if bad else None
        state["subscribed"].set()

    def on_message(client, userdata, message):
        payload = message.payload
        if payload:
            os.write(write, payload if payload.endswith(b"\n") else payload + b"\n")

    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    client.on_connect, client.on_subscribe, client.on_message = (on_connect, on_subscribe,
                                                                 on_message)
    if user:
        client.username_pw_set(unquote(user), unquote(password) if password else None)

    def close():
        client.disconnect()
        client.loop_stop()
        for fd in (write, read):
            os.close(fd)

    try:
        client.connect(host, port)
    except (OSError, ValueError) as exc:
        for fd in (write, read):
            os.close(fd)
        raise InputError(f"measurements {name}: cannot connect to the broker "
                         f"({getattr(exc, 'strerror', None) or exc})") from None
    client.loop_start()
    for step in ("connected", "subscribed"):
        if not state[step].wait(MQTT_WAIT_S) or state["why"]:
            close()
            raise InputError(f"measurements {name}: "
                             f"{state['why'] or f'the broker did not answer in {MQTT_WAIT_S:g} s'}")
    return Device(read, name, close)
