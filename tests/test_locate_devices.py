"""Device readers of `radioloc locate --follow` (radioloc.locate.devices): a DWM1001 module's
`lec` lines become range rows; a simulated module on a pseudo-terminal gives the batch run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import tty

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.locate.devices import Dwm1001Lines, open_serial

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


def test_serial_sources_are_named_in_their_errors():
    assert open_serial("udp://127.0.0.1:0") is None and open_serial("log.csv") is None
    pytest.importorskip("serial")
    with pytest.raises(ConfigError, match="unknown parameter 'speed'"):
        open_serial("serial:///dev/ttyACM0?speed=9600")
    with pytest.raises(ConfigError, match="baud: expected a whole number"):
        open_serial("serial:///dev/ttyACM0?baud=fast")
    with pytest.raises(InputError, match="cannot open /dev/no-such-tty"):
        open_serial("serial:///dev/no-such-tty")


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
