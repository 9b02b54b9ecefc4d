"""Fuzz of `radioloc locate` against the truth: every input file re-encoded (BOM, UTF-16,
CRLF, CR, quoting, spaces, blank lines: the same numbers, so a success must land on the
scenario's truth; Latin-1 and invalid bytes: an error naming the right line; other
separators: an error) and the plausible-but-wrong units (ranges in mm/cm/km, anchors in
km/degrees, RSS in mW, time in ms, time backwards, coincident or collinear anchors): a
one-line error, or a success the truth oracle accepts (``fuzz_harness.oracle``)."""

from __future__ import annotations

import csv
import io

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from fuzz_harness import FUZZ, check, render

METHODS = ["gn", "gn3", "ekf-track", "pf", "gmm", "grid-rssi", "rls", "ekf"]
PRESERVING = ["bom", "utf16", "crlf", "cr", "quote_all", "spaces", "blank_lines"]
BAD_BYTES = ["latin1", "invalid_byte"]
SEPARATORS = ["semicolon", "tab"]
JSON_OK = {"bom", "utf16", "crlf", "cr", "latin1", "invalid_byte", "blank_lines"}


def _rows(text: str) -> list[list[str]]:
    return [r for r in csv.reader(io.StringIO(text))]


def encode(text: str, how: str, line: int, is_json: bool) -> bytes:
    """The file's text re-encoded; ``line`` (1-based) is where a bad byte goes."""
    if how == "bom":
        return b"\xef\xbb\xbf" + text.encode()
    if how == "utf16":
        return text.encode("utf-16")
    if how == "crlf":
        return text.replace("\n", "\r\n").encode()
    if how == "cr":
        return text.replace("\n", "\r").encode()
    if how == "blank_lines":
        lines = text.split("\n")
        return ("\n".join(lines[:1] + ([""] if not is_json else []) + lines[1:]) + "\n\n").encode()
    if how in ("latin1", "invalid_byte"):
        lines = text.encode().split(b"\n")
        bad = "é".encode("latin-1") if how == "latin1" else b"\xff"
        lines[line - 1] = lines[line - 1] + bad
        return b"\n".join(lines)
    rows = _rows(text)
    if how == "quote_all":
        buf = io.StringIO()
        csv.writer(buf, quoting=csv.QUOTE_ALL, lineterminator="\n").writerows(rows)
        return buf.getvalue().encode()
    sep = {"spaces": ", ", "semicolon": ";", "tab": "\t"}[how]
    return "".join(sep.join(r) + "\n" for r in rows).encode()


@FUZZ
@given(data=st.data(), method=st.sampled_from(METHODS),
       how=st.sampled_from(PRESERVING + BAD_BYTES + SEPARATORS))
def test_fuzz_encodings_of_every_input_file(scenarios, workdir, data, method, how):
    sc = scenarios[method]
    targets = ["measurements"] + sorted(sc.files)
    target = data.draw(st.sampled_from(targets))
    meas = workdir / "meas.csv"
    meas.write_text(render(sc.rows))
    files = dict(sc.files)
    source = meas if target == "measurements" else sc.files[target]
    is_json = source.suffix == ".json"
    if is_json and how not in JSON_OK:
        how = "bom"
    text = source.read_text()
    n_lines = len(text.rstrip("\n").split("\n"))
    line = data.draw(st.integers(1, n_lines))
    out = workdir / f"enc-{target}{source.suffix}"
    out.write_bytes(encode(text, how, line, is_json))
    if target == "measurements":
        meas = out
    else:
        files[target] = out
    sc2 = type(sc)(**{**sc.__dict__, "files": files})

    def names_line(msg: str) -> str | None:
        if how in BAD_BYTES and f"line {line}" not in msg:
            return f"expected the line of the bad byte ({line})"
        return None

    check(sc2.args(meas), sc2, meas, truth=True, valid=how in PRESERVING,
          error_check=names_line)


RANGE_MISTAKES = ["ranges_mm", "ranges_cm", "ranges_km", "anchors_km", "anchors_degrees",
                  "anchors_coincident", "anchors_collinear", "time_ms", "time_backwards"]
RSS_MISTAKES = ["rss_mw", "time_ms", "time_backwards"]
NETWORK_MISTAKES = ["ranges_mm", "ranges_km", "time_ms", "time_backwards"]
MISTAKES = {"gn": RANGE_MISTAKES, "gn3": RANGE_MISTAKES, "ekf-track": RANGE_MISTAKES,
            "pf": RANGE_MISTAKES, "gmm": RSS_MISTAKES, "grid-rssi": RSS_MISTAKES,
            "rls": NETWORK_MISTAKES, "ekf": NETWORK_MISTAKES}


def _anchor_file(path, out, fn):
    rows = _rows(path.read_text())
    head, body = rows[0], rows[1:]
    xy = np.array([[float(r[1]), float(r[2])] for r in body])
    xy = fn(xy)
    for r, p in zip(body, xy):
        r[1], r[2] = repr(float(p[0])), repr(float(p[1]))
    out.write_text(render([head] + body))
    return out


@FUZZ
@given(data=st.data(), method=st.sampled_from(METHODS))
def test_fuzz_wrong_units(scenarios, workdir, data, method):
    """A unit slip or a degenerate layout: a one-line error, or a success on the truth."""
    sc = scenarios[method]
    mistake = data.draw(st.sampled_from(MISTAKES[method]))
    factor = data.draw(st.sampled_from([0.5, 1.0, 2.0]))    # vary the slip's size a little
    rows = [list(r) for r in sc.rows]
    files = dict(sc.files)
    time_scale = 1.0
    body = rows[1:]
    if mistake.startswith("ranges_"):
        k = {"ranges_mm": 1e3, "ranges_cm": 1e2, "ranges_km": 1e-3}[mistake] * factor
        for r in body:
            if r[3] == "range":
                r[4] = repr(float(r[4]) * k)
    elif mistake == "rss_mw":
        for r in body:
            r[4] = repr(10 ** (float(r[4]) / 10) * factor)
    elif mistake == "time_ms":
        time_scale = 1e3
        for r in body:
            r[0] = repr(float(r[0]) * time_scale)
    elif mistake == "time_backwards":
        perm = data.draw(st.permutations(range(len(body))))
        body = [body[i] for i in perm]
    else:
        fn = {"anchors_km": lambda xy: xy / 1e3,
              "anchors_degrees": lambda xy: np.c_[26.9 + xy[:, 1] / 111e3,
                                                  119.1 + xy[:, 0] / 99e3],
              "anchors_coincident": lambda xy: np.repeat(xy[:1], len(xy), axis=0),
              "anchors_collinear": lambda xy: np.c_[xy[:, 0] + 0.37 * xy[:, 1],
                                                    np.zeros(len(xy))]}[mistake]
        files["anchors"] = _anchor_file(sc.files["anchors"], workdir / "anchors-wrong.csv", fn)
    meas = workdir / "meas.csv"
    meas.write_text(render(rows[:1] + body))
    sc2 = type(sc)(**{**sc.__dict__, "files": files})
    # a success must still be right: the oracle compares it with the scene the file meant
    # (an anchor-file mistake moves the frame, so only an error or the truth is right)
    check(sc2.args(meas), sc2, meas, truth=True, time_scale=time_scale)
