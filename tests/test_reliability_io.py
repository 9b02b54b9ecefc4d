"""Input checks of the measurement/anchor readers and exact output of `locate`."""

from __future__ import annotations

import io
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import InputError
from radioloc.io.logs import read_anchors, read_measurements, write_estimates
from reliability_helpers import assert_one_line_error, invoke

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
HEAD = "time,node,peer,kind,value\n"


def write(tmp_path, text, name="m.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("text, pattern", [
    ("time,node,peer,kind,value,value\n0,t,A,range,1,2\n",
     "line 1: column 'value' appears twice \\(columns 5 and 6\\)"),
    ("time,node,peer,KIND,value,kind\n0,t,A,range,1,rss\n", "column 'kind' appears twice"),
    (HEAD + "0,t,A,range,1,7\n", "line 2: 6 cells, the header \\(line 1\\) has 5"),
    (HEAD + "0,t,A,range\n", "line 2: 4 cells, the header \\(line 1\\) has 5"),
    (HEAD + "0,t,A,range,2e7\n", "line 2, column 'value': range 2e\\+07 m is beyond the limit"),
    (HEAD + "0,t,A,rss,100\n", "line 2, column 'value': rss 100 dBm is above the plausible "
                               "maximum of 30 dBm \\(\\+100 dBm is the 'not detected' marker"),
    (HEAD + "0,t,A,rss,45\n", "rss 45 dBm is above the plausible maximum of 30 dBm$"),
    (HEAD + "0,t,A,rss,-400\n", "rss -400 dBm is below the plausible minimum"),
    (HEAD + "1e13,t,A,range,3\n", "line 2, column 'time': 1e\\+13 s is beyond the limit"),
    (HEAD + "0,t,A,range," + "9" * 400 + "\n", "line 2, column 'value': 9+ is not a finite"),
    (HEAD + "0,t,A,range,1.7e308\n", "line 2, column 'value': range 1.7e\\+308 m is beyond"),
    (HEAD + "0,t,A,range,1e400\n", "line 2, column 'value': 1e400 is not a finite number"),
    ("", "the file is empty"),
    ("\n\n  \n", "the file is empty"),
    (HEAD + "0,t,A,range,3\n0,nan,A,range,3\n", "line 3, column 'node': id 'nan' reads as a "
                                                "missing value"),
    (HEAD + "0,t,NULL,range,3\n", "line 2, column 'peer': id 'NULL' reads as a missing value"),
])
def test_bad_measurements_are_refused_naming_line_and_column(tmp_path, text, pattern):
    with pytest.raises(InputError, match=pattern):
        read_measurements(write(tmp_path, text))


def test_line_numbers_count_blank_lines_and_quoted_line_breaks(tmp_path):
    text = HEAD + "\n0,t,A,range,1\n\n0,\"t\nx\",A,range,2\n0,t,A,range,oops\n"
    with pytest.raises(InputError, match="line 7, column 'value': not a number: 'oops'"):
        read_measurements(write(tmp_path, text))
    ok = read_measurements(write(tmp_path, HEAD + "\n0,t,A,range,1\n\n1,t,A,range,2\n"))
    assert ok["line"].tolist() == [3, 5]


def test_byte_order_mark_and_case_and_spaces_in_header(tmp_path):
    p = tmp_path / "m.csv"
    p.write_bytes("\ufeffTime, Node ,peer,kind,VALUE\n0, t ,A,range, 1.5\n".encode())
    m = read_measurements(p)
    assert m["node"].tolist() == ["t"] and m["value"].tolist() == [1.5]


def test_empty_trailing_column_is_ignored_but_a_nameless_column_with_values_is_not(tmp_path):
    m = read_measurements(write(tmp_path, "time,node,peer,kind,value,\n0,t,A,range,1,\n"))
    assert list(m.columns) == ["time", "node", "peer", "kind", "value", "line"]
    with pytest.raises(InputError, match="column 6 holds values but has no name"):
        read_measurements(write(tmp_path, "time,node,peer,kind,value,\n0,t,A,range,1,9\n"))


def test_not_utf8_and_folder_inputs(tmp_path):
    p = tmp_path / "m.csv"
    p.write_bytes(HEAD.encode() + b"0,t\xff\xfe,A,range,1\n")
    with pytest.raises(InputError, match="line 2: not UTF-8 text"):
        read_measurements(p)
    with pytest.raises(InputError, match="is a folder, not a file"):
        read_measurements(tmp_path)


def test_anchor_magnitude_and_duplicate_column(tmp_path):
    with pytest.raises(InputError, match="line 3, column 'y': -2e\\+08 m is beyond the limit"):
        read_anchors(write(tmp_path, "id,x,y\nA,0,0\nB,1,-2e8\n", "a.csv"))
    with pytest.raises(InputError, match="column 'x' appears twice"):
        read_anchors(write(tmp_path, "id,x,y,x\nA,0,0,1\n", "a.csv"))


def test_written_times_and_positions_round_trip_exactly(tmp_path):
    rng = np.random.default_rng(3)
    t = 1.7e9 + np.cumsum(rng.uniform(1e-6, 1e-5, 200))       # distinct at 1e-6 s
    frame = pd.DataFrame({"time": t, "node": "n", "x": rng.standard_normal(200) * 1e3,
                          "y": rng.standard_normal(200) * 1e-9,
                          "uncertainty_m": rng.random(200) * 1e-5})
    p = tmp_path / "est.csv"
    write_estimates(frame, p)
    back = pd.read_csv(p)
    for c in ("time", "x", "y", "uncertainty_m"):
        np.testing.assert_array_equal(back[c].to_numpy(), frame[c].to_numpy())
    assert back["time"].nunique() == 200
    buf = io.StringIO()
    old, sys.stdout = sys.stdout, buf
    try:
        write_estimates(frame, None)
    finally:
        sys.stdout = old
    np.testing.assert_array_equal(pd.read_csv(io.StringIO(buf.getvalue()))["time"], t)


def test_locate_output_keeps_distinct_epochs_exact(tmp_path):
    anchors = read_anchors(EXAMPLES / "anchors.csv")
    xy = anchors[["x", "y"]].to_numpy()
    times = 1.7e9 + np.array([0.0, 1e-6, 2e-6, 3.5e-6])
    truth = np.array([10.0, 12.0])
    rows = [f"{float(t)!r},tag,{a},range,{float(np.hypot(*(p - truth)))!r}"
            for t in times for a, p in zip(anchors["id"], xy)]
    meas = write(tmp_path, HEAD + "\n".join(rows) + "\n")
    out = tmp_path / "est.csv"
    res = invoke(["locate", meas, "--anchors", EXAMPLES / "anchors.csv", "--out", out])
    assert res.exit_code == 0, res.output
    est = pd.read_csv(out)
    np.testing.assert_array_equal(np.sort(est["time"].to_numpy()), times)
    np.testing.assert_allclose(est[["x", "y"]].to_numpy(), np.tile(truth, (4, 1)), atol=1e-6)


def test_locate_refuses_sentinel_rss_on_one_line(tmp_path):
    meas = write(tmp_path, HEAD + "0,t,A1,rss,100\n")
    line = assert_one_line_error(invoke(["locate", meas, "--anchors", EXAMPLES / "anchors.csv"]))
    assert "not detected" in line and "line 2" in line
