"""Device readers of `radioloc locate --follow` (radioloc.locate.devices): a DWM1001 module's
`lec` lines become range rows, and a simulated module on a pseudo-terminal gives the batch
run; rows published to an MQTT broker (mosquitto, started by the test) give the batch run."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import tty

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.locate.devices import Dwm1001Lines, open_device

ANCHORS = pd.DataFrame({"id": ["1151", "0CA8", "22F3", "9A0B"], "x": [0.0, 6.0, 6.0, 0.0],
                        "y": [0.0, 0.0, 5.0, 5.0], "z": [2.4, 0.4, 2.4, 0.6]})
TAG = np.array([2.0, 3.0, 1.0])


def lec_line(ranges, pos=True) -> str:
    """A `lec` line for the anchors of ANCHORS with these ranges."""
    cells = ["DIST", str(len(ranges))]
    for k, ((_, a), r) in enumerate(zip(ANCHORS.iterrows(), ranges)):
        cells += [f"AN{k}", a["id"], f"{a['x']:.2f}", f"{a['y']:.2f}", f"{a['z']:.2f}",
                  f"{r:.3f}"]
    return ",".join(cells + (["POS", "2.01", "2.98", "1.10", "87"] if pos else []))


def test_lec_lines_become_range_rows_and_other_lines_are_counted():
    clock = iter([100.0, 100.0, 100.5])
    parser = Dwm1001Lines("tag7", clock=lambda: next(clock))
    good = lec_line([3.1, 4.2, 3.3, 2.9]).encode()
    lines = [b"dwm> lec", good + b"\r", b"", b"POS,2.01,2.98,1.10,87",
             (b"DIST,4,AN0,0090,0.00,0.00,0.00,3.25,AN1,D91E,0.00,0.00,0.00,3.33,AN2,0487,"
              b"0.00,0.00,0.00,0.18,AN3,15BA,0.00,0,AN3,15BA,0.00,0.00,0.00,0.00"),
             lec_line([3.0, 4.0], pos=False).encode(), lec_line([3.0, -1.0, 2.0]).encode(),
             lec_line([3.0, 4.0, float("nan")]).encode()]
    rows = parser.rows(lines)
    assert rows["peer"] == ["1151", "0CA8", "22F3", "9A0B", "1151", "0CA8"]
    assert rows["value"] == [3.1, 4.2, 3.3, 2.9, 3.0, 4.0]
    assert set(rows["node"]) == {"tag7"} and set(rows["kind"]) == {"range"}
    # two lines read at the same clock reading stay in order, a microsecond apart
    assert rows["time"][:4] == [100.0] * 4 and rows["time"][4] == pytest.approx(100.000001)
    assert rows["line"] == [2, 2, 2, 2, 6, 6]
    summary = parser.summary()
    assert summary["lines"] == 7 and summary["lines_with_ranges"] == 2
    assert summary["lines_skipped"] == 5 and summary["first_skipped"] == "line 1: dwm> lec"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_other_sources_are_not_devices():
    for source in ("udp://127.0.0.1:0", "log.csv", "-"):
        assert open_device(source) is None


@pytest.mark.parametrize("module, source, error, match", [
    ("serial", "serial:///dev/ttyACM0?speed=9600", ConfigError, "unknown parameter 'speed'"),
    ("serial", "serial:///dev/ttyACM0?baud=fast", ConfigError, "baud: expected a whole number"),
    ("serial", "serial:///dev/no-such-tty", InputError, "cannot open /dev/no-such-tty"),
    ("paho.mqtt", "mqtt://127.0.0.1/radioloc/tag1?qos=3", ConfigError,
     r"qos: expected a whole number in \[0, 1, 2\]"),
    ("paho.mqtt", "mqtt://127.0.0.1/radioloc/tag1?retain=1", ConfigError,
     "unknown parameter 'retain'"),
    ("paho.mqtt", "mqtt://127.0.0.1:{port}/t", InputError,      # nothing listens there
     "mqtt://127.0.0.1:{port}/t: cannot connect to the broker"),
])
def test_device_sources_are_named_in_their_errors(module, source, error, match):
    pytest.importorskip(module)
    port = free_port()
    with pytest.raises(error, match=match.format(port=port)):
        open_device(source.format(port=port))


@pytest.mark.slow   # a subprocess on a pseudo-terminal
def test_a_simulated_dwm1001_on_a_pseudo_terminal_gives_the_batch_run(tmp_path):
    """A module printing `lec` lines (with a garbled line among them) on a pseudo-terminal:
    `--follow serial://...` writes one estimate per line, equal to the batch causal run on
    the rows those lines make at the times it stamped, near the tag; the summary counts the
    lines."""
    pytest.importorskip("serial")
    ANCHORS.to_csv(tmp_path / "anchors.csv", index=False)
    master, slave = os.openpty()
    tty.setraw(slave)
    out = tmp_path / "est.csv"
    options = ["-o", "tune=0", "-o", "init_s=0.2"]
    proc = subprocess.Popen([sys.executable, "-m", "radioloc.cli", "locate",
                             f"serial://{os.ttyname(slave)}?node=tag7", "--anchors",
                             str(tmp_path / "anchors.csv"), "--method", "ekf-track", "--follow",
                             *options, "--out", str(out)], stderr=subprocess.PIPE, text=True)
    rng = np.random.default_rng(5)
    true = np.linalg.norm(ANCHORS[["x", "y", "z"]].to_numpy() - TAG, axis=1)
    sent = [true + 0.05 * rng.standard_normal(4) for _ in range(120)]
    try:
        reading = proc.stderr.readline()
        assert reading.startswith("reading serial://"), reading + proc.stderr.read()
        for i, r in enumerate(sent):
            text = lec_line(r) + "\r\n"
            if i == 60:
                text = "DIST,4,AN0,1151,0.00,0.00,2.40\r\n" + text      # garbled
            os.write(master, text.encode())
            time.sleep(0.002)
        time.sleep(0.2)
        os.close(master)                      # the device goes away: end of input
        assert proc.wait(timeout=120) == 0, proc.stderr.read()
    finally:
        proc.kill()
        os.close(slave)
    got = pd.read_csv(out)
    assert len(got) == len(sent) and (got["node"] == "tag7").all()
    summary = json.loads((tmp_path / "est.summary.json").read_text())
    assert summary["end"] == "end of input" and summary["rows_in"] == 4 * len(sent)
    assert summary["device"]["lines_with_ranges"] == len(sent)
    assert summary["device"]["lines_skipped"] == 1
    # the batch causal run on the rows these lines make, at the stamped times
    rows = pd.DataFrame({"time": np.repeat(got["time"].to_numpy(), 4), "node": "tag7",
                         "peer": np.tile(ANCHORS["id"], len(sent)), "kind": "range",
                         "value": np.round(np.concatenate(sent), 3)})
    rows.to_csv(tmp_path / "rows.csv", index=False)
    subprocess.run([sys.executable, "-m", "radioloc.cli", "locate", str(tmp_path / "rows.csv"),
                    "--anchors", str(tmp_path / "anchors.csv"), "--method", "ekf-track",
                    *options, "--out", str(tmp_path / "batch.csv"), "-q"],
                   check=True, timeout=120, capture_output=True)
    batch = pd.read_csv(tmp_path / "batch.csv")
    pd.testing.assert_frame_equal(got, batch, check_exact=False, rtol=0, atol=1e-9)
    assert np.linalg.norm(got[["x", "y"]].to_numpy()[-1] - TAG[:2]) < 0.2


@pytest.fixture
def broker(tmp_path):
    """A mosquitto broker on a free port of 127.0.0.1 (the test is skipped without it)."""
    exe = shutil.which("mosquitto") or shutil.which("mosquitto", path="/usr/sbin:/sbin")
    if exe is None:
        pytest.skip("mosquitto (Debian's package) is not installed; `make test` installs it")
    port = free_port()
    conf = tmp_path / "mosquitto.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\n")
    proc = subprocess.Popen([exe, "-c", str(conf)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 20
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                break
            except OSError:
                assert proc.poll() is None and time.monotonic() < deadline, "mosquitto failed"
                time.sleep(0.05)
        yield port
    finally:
        proc.kill()
        proc.wait(timeout=20)


@pytest.mark.slow   # a broker and a subprocess
def test_rows_published_to_an_mqtt_topic_give_the_batch_run(tmp_path, broker):
    """CSV rows published to a topic (a few time stamps per message, the header on top of
    each): `--follow mqtt://...` writes the batch causal run's estimates."""
    paho = pytest.importorskip("paho.mqtt.client")
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 20.0, 0.1)
    path = np.c_[1.0 + 0.15 * t, 1.0 + 0.1 * t, np.ones_like(t)]
    anchors = ANCHORS[["x", "y", "z"]].to_numpy()
    true = np.linalg.norm(path[:, None, :] - anchors[None], axis=2)
    log = pd.DataFrame({"time": np.repeat(np.round(t, 3), 4), "node": "tag1",
                        "peer": np.tile(ANCHORS["id"], t.size), "kind": "range",
                        "value": np.round((true + 0.05 * rng.standard_normal(true.shape)).ravel(),
                                          4)})
    log.to_csv(tmp_path / "log.csv", index=False)
    ANCHORS.to_csv(tmp_path / "anchors.csv", index=False)
    options = ["-o", "tune=0", "-o", "init_s=1"]
    subprocess.run([sys.executable, "-m", "radioloc.cli", "locate", str(tmp_path / "log.csv"),
                    "--anchors", str(tmp_path / "anchors.csv"), "--method", "ekf-track",
                    *options, "--out", str(tmp_path / "batch.csv"), "-q"],
                   check=True, timeout=120, capture_output=True)
    expected = pd.read_csv(tmp_path / "batch.csv")
    out = tmp_path / "est.csv"
    proc = subprocess.Popen([sys.executable, "-m", "radioloc.cli", "locate",
                             f"mqtt://127.0.0.1:{broker}/radioloc/+", "--anchors",
                             str(tmp_path / "anchors.csv"), "--method", "ekf-track", "--follow",
                             *options, "--reorder-s", "0", "--idle-s", "0.01", "--out", str(out)],
                            stderr=subprocess.PIPE, text=True)
    try:
        reading = proc.stderr.readline()
        assert reading.startswith(f"reading mqtt://127.0.0.1:{broker}/radioloc/+"), (
            reading + proc.stderr.read())
        sender = paho.Client(paho.CallbackAPIVersion.VERSION2)
        sender.connect("127.0.0.1", broker)
        sender.loop_start()
        header = "time,node,peer,kind,value\n"
        stamps = [rows for _, rows in log.groupby("time", sort=True)]
        for i in range(0, len(stamps), 5):
            text = pd.concat(stamps[i:i + 5]).to_csv(index=False, header=False)
            sender.publish("radioloc/tag1", header + text, qos=1).wait_for_publish(10)
        sender.disconnect()
        sender.loop_stop()
        deadline = time.monotonic() + 60
        while not out.exists() or len(out.read_text().splitlines()) < len(expected) + 1:
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=60) == 0, proc.stderr.read()
    finally:
        proc.kill()
    got = pd.read_csv(out).sort_values(["time", "node"], kind="stable").reset_index(drop=True)
    pd.testing.assert_frame_equal(got, expected, check_exact=False, rtol=0, atol=1e-9)
    summary = json.loads((tmp_path / "est.summary.json").read_text())
    assert summary["end"] == "interrupted" and summary["rows_in"] == len(log)
    assert summary["measurements"] == f"mqtt://127.0.0.1:{broker}/radioloc/+"
