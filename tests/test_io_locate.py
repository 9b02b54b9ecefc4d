"""The measurement-log schema and `radioloc locate`, tried as a new user would."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from radioloc.cli import app
from radioloc.core.errors import InputError
from radioloc.io.logs import read_anchors, read_measurements

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
runner = CliRunner()


def write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_example_files_locate_close_to_the_truth(tmp_path):
    out = tmp_path / "est.csv"
    res = runner.invoke(app, ["locate", str(EXAMPLES / "measurements.csv"),
                              "--anchors", str(EXAMPLES / "anchors.csv"), "--out", str(out)])
    assert res.exit_code == 0, res.output
    est = pd.read_csv(out)
    assert list(est.columns) == ["time", "node", "x", "y", "uncertainty_m", "cov_xx", "cov_xy",
                                 "cov_yy", "ranges"]
    tag1 = est[est.node == "tag1"].sort_values("time")
    np.testing.assert_allclose(tag1.x, 10 + 2 * tag1.time, atol=0.5)
    np.testing.assert_allclose(tag1.y, 12.0, atol=0.5)
    assert (est.uncertainty_m > 0).all() and (est.uncertainty_m < 1).all()


BAD_CASES = {
    "missing column": ("time,node,peer,value\n0,t,A1,3\n", "missing column\\(s\\) kind"),
    "text in a number column": ("time,node,peer,kind,value\n0,t,A1,range,abc\n",
                                "line 2, column 'value': not a number: 'abc'"),
    "NaN": ("time,node,peer,kind,value\n0,t,A1,range,1\n0,t,A2,range,NaN\n",
            "line 3, column 'value': NaN is not a finite number"),
    "unknown anchor": ("time,node,peer,kind,value\n0,t,A1,range,1\n0,t,A9,range,2\n",
                       "line 3, column 'peer': unknown anchor or node 'A9'"),
    "negative range": ("time,node,peer,kind,value\n0,t,A1,range,-4\n",
                       "line 2, column 'value': negative range"),
    "unknown kind": ("time,node,peer,kind,value\n0,t,A1,toa,4\n", "column 'kind': 'toa'"),
    "empty": ("time,node,peer,kind,value\n", "no data rows"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_malformed_measurements_give_one_line_error(tmp_path, case):
    text, pattern = BAD_CASES[case]
    meas = write(tmp_path, "m.csv", text)
    res = runner.invoke(app, ["locate", str(meas), "--anchors", str(EXAMPLES / "anchors.csv")])
    assert res.exit_code == 2
    lines = [ln for ln in res.output.strip().splitlines() if ln]
    assert len(lines) == 1 and lines[0].startswith("error:"), res.output
    assert "Traceback" not in res.output
    with pytest.raises(InputError, match=pattern):
        read_measurements(meas, anchors=read_anchors(EXAMPLES / "anchors.csv"))


def test_duplicate_anchor_ids_are_rejected(tmp_path):
    p = write(tmp_path, "a.csv", "id,x,y\nA1,0,0\nA2,1,0\nA1,0,1\n")
    with pytest.raises(InputError, match="line 4, column 'id': duplicate anchor id 'A1'"):
        read_anchors(p)


def test_anchor_coordinate_must_be_a_number(tmp_path):
    p = write(tmp_path, "a.csv", "id,x,y\nA1,0,zero\n")
    with pytest.raises(InputError, match="line 2, column 'y'"):
        read_anchors(p)


def test_too_few_anchors_in_the_log_are_named(tmp_path):
    meas = write(tmp_path, "m.csv", "time,node,peer,kind,value\n3,tagX,A1,range,5\n3,tagX,A2,range,6\n")
    res = runner.invoke(app, ["locate", str(meas), "--anchors", str(EXAMPLES / "anchors.csv")])
    assert res.exit_code == 2
    assert "(A1, A2)" in res.output and "3 anchors not on one line are needed" in res.output


def test_missing_file_and_unknown_method(tmp_path):
    res = runner.invoke(app, ["locate", str(tmp_path / "nope.csv")])
    assert res.exit_code == 2 and "not found" in res.output
    res = runner.invoke(app, ["locate", str(EXAMPLES / "measurements.csv"),
                              "--anchors", str(EXAMPLES / "anchors.csv"), "--method", "magic"])
    assert res.exit_code == 2 and "unknown method 'magic'" in res.output


def test_gn_without_anchors_file_says_so():
    res = runner.invoke(app, ["locate", str(EXAMPLES / "measurements.csv")])
    assert res.exit_code == 2 and "--anchors" in res.output


def test_collinear_anchors_are_named(tmp_path):
    anchors = write(tmp_path, "a.csv", "id,x,y\nL1,0,0\nL2,10,0\nL3,20,0\n")
    meas = write(tmp_path, "m.csv", "time,node,peer,kind,value\n"
                 "7,tagC,L1,range,5\n7,tagC,L2,range,5\n7,tagC,L3,range,15\n")
    res = runner.invoke(app, ["locate", str(meas), "--anchors", str(anchors)])
    assert res.exit_code == 2
    assert "(L1, L2, L3)" in res.output and "collinear" in res.output


def test_not_detected_sentinel_rows_are_dropped_on_request(tmp_path):
    """`-o not_detected=100`: rss rows of the sentinel value are stations not received."""
    import warnings as _w

    from radioloc.core.errors import InputError as _InputError
    from radioloc.io.logs import read_measurements as _read

    p = tmp_path / "m.csv"
    p.write_text("time,node,peer,kind,value\n0,phone,ap1,rss,-60\n0,phone,ap2,rss,100\n"
                 "1,phone,ap1,rss,100\n1,phone,ap2,rss,-70\n")
    with pytest.raises(_InputError, match="line 3.*not_detected=100"):
        _read(p)
    with _w.catch_warnings(record=True) as caught:
        _w.simplefilter("always")
        m = _read(p, not_detected=100)
    assert m["value"].tolist() == [-60.0, -70.0] and m["line"].tolist() == [2, 5]
    assert any("2 rss row(s)" in str(c.message) for c in caught)
