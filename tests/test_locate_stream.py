"""Live tracking (`radioloc.locate.Tracker`, `radioloc locate --follow`): the estimates equal
the batch causal run of the same rows."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.io.logs import subtract_anchor_bias
from radioloc.locate import LocateRequest, Tracker, run_method

ANCHORS = pd.DataFrame({"id": ["A", "B", "C", "D", "E"], "x": [0.0, 20.0, 20.0, 0.0, 10.0],
                        "y": [0.0, 0.0, 15.0, 15.0, 16.0]})
OPTIONS = {"q": "0.5", "init_s": "1.5", "tune": "0"}  # live tracking does not learn
#: Yaw of anchor B's array in :func:`mixed_log`, rad.
YAW_B = 0.3


def simulated_log(seed: int = 3) -> pd.DataFrame:
    """Two tags: ``t1`` asynchronous (one anchor per time stamp) with an outlier range; ``t2``
    synchronous (several anchors per time stamp), silent for 8 s (longer than max_gap_s)."""
    rng = np.random.default_rng(seed)
    frames = []
    for node, n in (("t1", 700), ("t2", 200)):
        t = np.round(np.cumsum(rng.uniform(0.02, 0.08 if node == "t1" else 0.2, n)), 4)
        if node == "t2":
            t = np.where(t > 8, t + 8, t)
        phase = 0.0 if node == "t1" else 2.0
        xy = np.stack([10 + 6 * np.cos(t / 5 + phase), 7.5 + 4 * np.sin(t / 5 + phase)], -1)
        peers = (np.arange(n) % 5)[:, None] if node == "t1" else np.tile(np.arange(4), (n, 1))
        for j in range(peers.shape[1]):
            p = peers[:, j]
            d = np.linalg.norm(xy - ANCHORS[["x", "y"]].to_numpy()[p], axis=1)
            frames.append(pd.DataFrame({"time": t, "node": node, "peer": ANCHORS["id"].to_numpy()[p],
                                        "kind": "range", "value": d + 0.1 * rng.standard_normal(n)}))
    log = pd.concat(frames, ignore_index=True)
    log.loc[300, "value"] += 12.0                     # an outlier the gate refuses
    log = log[rng.random(len(log)) > 0.1]             # rows lost at random
    return log.sort_values(["time", "node", "peer"], kind="stable").reset_index(drop=True)


def batch(rows: pd.DataFrame) -> pd.DataFrame:
    return run_method("ekf-track", LocateRequest(rows.reset_index(drop=True), ANCHORS,
                                                 options=dict(OPTIONS)))


def streamed(tracker: Tracker, chunks) -> pd.DataFrame:
    parts = [tracker.update(c) for c in chunks] + [tracker.close()]
    out = pd.concat([p for p in parts if len(p)], ignore_index=True)
    return out.sort_values(["time", "node"], kind="stable").reset_index(drop=True)


def assert_same(stream: pd.DataFrame, expected: pd.DataFrame) -> None:
    assert list(stream.columns) == list(expected.columns)
    assert len(stream) == len(expected)
    assert (stream["node"].to_numpy() == expected["node"].to_numpy()).all()
    numeric = [c for c in expected.columns if c != "node"]
    np.testing.assert_allclose(stream[numeric].to_numpy(float), expected[numeric].to_numpy(float),
                               rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def log() -> pd.DataFrame:
    return simulated_log()


@pytest.fixture(scope="module")
def expected(log) -> pd.DataFrame:
    out = batch(log)
    assert out["restart"].sum() == 1 and out["gated"].sum() >= 1   # the log exercises both
    return out


def random_chunks(rows: pd.DataFrame, rng) -> list[pd.DataFrame]:
    cuts = np.sort(rng.choice(np.arange(1, len(rows)), size=60, replace=False))
    return [rows.iloc[a:b] for a, b in zip([0, *cuts], [*cuts, len(rows)])]


def test_chunks_of_any_size_give_the_batch_causal_run(log, expected):
    rng = np.random.default_rng(0)
    tracker = Tracker("ekf-track", ANCHORS, OPTIONS)
    assert_same(streamed(tracker, random_chunks(log, rng)), expected)
    summary = tracker.summary()
    assert summary["rows_in"] == len(log) and summary["rows_late"] == 0
    assert summary["rows_out"] == len(expected) and summary["restarts"] == 1


def test_settings_learned_on_a_recorded_log_give_the_batch_run_that_learned_them(log):
    """``Tracker(learned=...)`` with what ``ekf-track`` learns from a recorded log (each
    node its own noise, process noise and anchor offsets): the batch run's tracks, whose
    filter learned them (its covariances may be widened by the health check, which a stream
    does not run)."""
    from radioloc.locate.ekf_track import learn_log

    options = {k: v for k, v in OPTIONS.items() if k not in ("q", "tune")}
    request = LocateRequest(log.reset_index(drop=True), ANCHORS, options=dict(options))
    run_method("ekf-track", request)               # parses the options, as a run does
    learned, short = learn_log(request)
    assert short is None and set(learned) == {"t1", "t2"}
    assert learned["t1"].offset_m is not None
    expected = run_method("ekf-track", LocateRequest(log.reset_index(drop=True), ANCHORS,
                                                     options=dict(options)))
    tracker = Tracker("ekf-track", ANCHORS, options, learned=learned)
    out = streamed(tracker, random_chunks(log, np.random.default_rng(4)))
    assert len(out) == len(expected)
    assert (out["node"].to_numpy() == expected["node"].to_numpy()).all()
    for c in ("time", "x", "y", "gated", "restart"):
        np.testing.assert_allclose(out[c].to_numpy(float), expected[c].to_numpy(float),
                                   rtol=0, atol=1e-9, err_msg=c)


def test_rows_shuffled_within_the_window_are_placed(log, expected):
    rng = np.random.default_rng(1)
    arrival = log["time"].to_numpy() + rng.uniform(0, 0.45, len(log))   # window 0.5 s
    shuffled = log.iloc[np.argsort(arrival, kind="stable")]
    assert not shuffled["time"].is_monotonic_increasing
    records = shuffled.to_dict("records")                              # list of dicts too
    cuts = np.sort(rng.choice(np.arange(1, len(records)), size=200, replace=False))
    chunks = [records[a:b] for a, b in zip([0, *cuts], [*cuts, len(records)])]
    tracker = Tracker("ekf-track", ANCHORS, OPTIONS, reorder_s=0.5)
    assert_same(streamed(tracker, chunks), expected)
    assert tracker.summary()["rows_late"] == 0


def test_rows_later_than_the_window_are_counted_and_left_out(log):
    rng = np.random.default_rng(2)
    arrival = log["time"].to_numpy() + np.where(rng.random(len(log)) < 0.03, 2.0, 0.0)
    order = np.argsort(arrival, kind="stable")
    arrived = log.iloc[order].reset_index(drop=True)
    # chunks of 10 rows: a row is late when it is older than the window behind the latest
    # time of the chunks before it
    chunk = np.arange(len(arrived)) // 10
    times = arrived["time"].to_numpy()
    latest = pd.Series(times).groupby(chunk).max().cummax().shift(1, fill_value=-np.inf)
    late = times < latest.to_numpy()[chunk] - 0.5
    assert late.sum() > 5
    tracker = Tracker("ekf-track", ANCHORS, OPTIONS, reorder_s=0.5)
    out = streamed(tracker, [arrived.iloc[i:i + 10] for i in range(0, len(arrived), 10)])
    assert tracker.summary()["rows_late"] == int(late.sum())
    kept = arrived[~late].sort_values(["time", "node", "peer"], kind="stable")
    assert_same(out, batch(kept))


def test_state_survives_pauses_between_updates(log, expected):
    tracker = Tracker("ekf-track", ANCHORS, OPTIONS)
    first = tracker.update(log.iloc[:400])
    assert len(first) > 0                        # estimates come before the end of input
    rest = [tracker.update(log.iloc[400:]), tracker.update(log.iloc[:0]), tracker.close()]
    out = pd.concat([first, *rest], ignore_index=True).sort_values(["time", "node"],
                                                                    kind="stable")
    assert_same(out.reset_index(drop=True), expected)
    assert tracker.close().empty


def test_tracker_refuses_what_it_cannot_stream():
    with pytest.raises(ConfigError, match="ekf-track"):
        Tracker("pf", ANCHORS)
    with pytest.raises(ConfigError, match="smooth"):
        Tracker("ekf-track", ANCHORS, {"smooth": "1"})
    with pytest.raises(ConfigError, match="unknown option 'bogus'"):
        Tracker("ekf-track", ANCHORS, {"bogus": "1"})
    with pytest.raises(ConfigError, match="reorder_s"):
        Tracker("ekf-track", ANCHORS, reorder_s=-1)
    tracker = Tracker("ekf-track", ANCHORS)
    with pytest.raises(InputError, match="row 1, column 'value'"):
        tracker.update([{"time": 0, "node": "t", "peer": "A", "kind": "range", "value": 1},
                        {"time": 0, "node": "t", "peer": "B", "kind": "range", "value": "x"}])
    with pytest.raises(InputError, match="row 0, column 'peer': unknown anchor or node 'Z'"):
        tracker.update([{"time": 0, "node": "t", "peer": "Z", "kind": "range", "value": 1}])
    with pytest.raises(InputError, match="missing column"):
        tracker.update([{"time": 0, "node": "t", "kind": "range", "value": 1}])
    with pytest.raises(InputError, match="a sequence of cells per column"):
        tracker.update({"time": 0, "node": "t", "peer": "A", "kind": "range", "value": 1})
    with pytest.raises(InputError, match="columns of different lengths"):
        tracker.update({"time": [0, 1], "node": ["t"], "peer": ["A"], "kind": ["range"],
                        "value": [1]})
    with pytest.raises(InputError, match="line 9, column 'std': 'x'"):
        tracker.update({"time": [0], "node": ["t"], "peer": ["A"], "kind": ["range"],
                        "value": [1], "std": ["x"], "line": [9]})
    with pytest.raises(InputError, match="row 0, column 'reference': 'Z' is not an anchor"):
        tracker.update([{"time": 0, "node": "t", "peer": "A", "reference": "Z",
                         "kind": "tdoa", "value": 1}])
    from radioloc.locate.follow import follow_locate
    with pytest.raises(ConfigError, match="--idle-s"):
        follow_locate(Path("-"), None, "ekf-track", {}, None, "csv", None, {}, idle_s=-1.0)


def method_run(name: str, request: LocateRequest) -> pd.DataFrame:
    """The method's own output on the whole log, before the health check of the whole log
    (which may widen a covariance; a stream cannot run it)."""
    from radioloc.locate.base import prepare_method

    return prepare_method(name, request).fn(request)


def mixed_log(seed: int = 5) -> pd.DataFrame:
    """``t1``: ranges to A-D with a per-row std, a fifth of them sent twice (another
    draw), time differences of E against A, and angles of arrival at B (turned by
    :data:`YAW_B`), one of its start window a reflection that the gate lets through;
    ``t2``: ranges without std."""
    rng = np.random.default_rng(seed)
    xy_of = ANCHORS.set_index("id")[["x", "y"]]
    frames = []
    for node, n in (("t1", 300), ("t2", 150)):
        t = np.round(np.cumsum(rng.uniform(0.05, 0.15, n)), 4)
        xy = np.stack([10 + 5 * np.cos(t / 4), 7.5 + 3 * np.sin(t / 4)], -1)
        d = {a: np.linalg.norm(xy - xy_of.loc[a].to_numpy(), axis=1) for a in xy_of.index}
        for a in "ABCD":
            frames.append(pd.DataFrame({"time": t, "node": node, "peer": a, "kind": "range",
                                        "value": d[a] + 0.25 + 0.1 * rng.standard_normal(n),
                                        "std": 0.1 if node == "t1" else np.nan}))
        if node == "t1":
            frames.append(pd.DataFrame({"time": t, "node": node, "peer": "E", "kind": "tdoa",
                                        "reference": "A", "std": 0.2,
                                        "value": d["E"] - d["A"] + 0.2 * rng.standard_normal(n)}))
            rel = xy - xy_of.loc["B"].to_numpy()
            aoa = np.arctan2(rel[:, 1], rel[:, 0]) - YAW_B + 0.05 * rng.standard_normal(n)
            aoa[5] += 0.7                                  # a reflection at the start
            frames.append(pd.DataFrame({"time": t, "node": node, "peer": "B", "kind": "aoa",
                                        "value": np.angle(np.exp(1j * aoa))}))
    log = pd.concat(frames, ignore_index=True)
    log["reference"] = log["reference"].fillna("")
    again = log[(log["node"] == "t1") & (rng.random(len(log)) < 0.2)]
    again = again.assign(value=again["value"] + 0.1 * rng.standard_normal(len(again)))
    log = pd.concat([log, again], ignore_index=True)
    return log.sort_values(["time", "node"], kind="stable").reset_index(drop=True)


def test_kinds_std_duplicates_and_calibrated_anchors_give_the_batch_run():
    """Rows resolved to slots as arrays: duplicates averaged, per-row std, a kind with a
    reference anchor, angles (an anchor's yaw, the start window's reflections left out), the
    anchors' bias_m and option range_bias_m, as the batch run."""
    log = mixed_log()
    anchors = ANCHORS.assign(bias_m=[0.05, 0.1, 0.0, 0.15, 0.0], bias_std_m=0.01,
                             yaw=[0.0, YAW_B, 0.0, 0.0, 0.0])
    options = {"init_s": "1.5", "range_bias_m": "0.2", "tdoa_std_m": "0.2",
               "aoa_std_rad": "0.05", "tune": "0"}
    corrected = subtract_anchor_bias(log, anchors)           # as `locate` reads the log
    expected = method_run("ekf-track", LocateRequest(corrected, anchors, options=dict(options)))
    tracker = Tracker("ekf-track", anchors, options)
    parts = [tracker.update({c: log[c].to_numpy()[i:i + 37] for c in log.columns},
                            as_frame=False) for i in range(0, len(log), 37)]
    parts.append(tracker.close(as_frame=False))
    got = pd.concat([pd.DataFrame(p) for p in parts if p], ignore_index=True)
    assert_same(got.sort_values(["time", "node"], kind="stable").reset_index(drop=True),
                expected)
    with pytest.raises(InputError, match="row 0, column 'value': range 0.01 m to anchor 'D'"):
        tracker.update([{"time": 99.0, "node": "t2", "peer": "D", "kind": "range",
                         "value": 0.01}])


def test_a_moving_anchor_gives_the_batch_run():
    """An anchor with a track (rows at several times): its position at each step
    interpolated, as the batch run does, over chunks of rows."""
    rng = np.random.default_rng(6)
    tt = np.arange(0.0, 41.0)
    anchors = pd.concat([ANCHORS.iloc[:3].assign(time=np.nan),
                         pd.DataFrame({"id": "M", "x": 0.5 * tt, "y": 15.0 - 0.1 * tt,
                                       "time": tt})], ignore_index=True)
    t = np.round(np.cumsum(rng.uniform(0.05, 0.1, 400)), 4)
    xy = np.stack([10 + 5 * np.cos(t / 4), 7 + 3 * np.sin(t / 4)], -1)
    where = {a: np.broadcast_to(ANCHORS.set_index("id").loc[a, ["x", "y"]].to_numpy(float),
                                xy.shape) for a in "ABC"}
    where["M"] = np.stack([0.5 * t, 15 - 0.1 * t], -1)
    log = pd.concat([pd.DataFrame({"time": t, "node": "t1", "peer": a, "kind": "range",
                                   "value": np.linalg.norm(xy - p, axis=-1)
                                   + 0.1 * rng.standard_normal(t.size)})
                     for a, p in where.items()])
    log = log.sort_values(["time", "peer"], kind="stable").reset_index(drop=True)
    options = {"init_s": "1.5", "tune": "0"}
    expected = method_run("ekf-track", LocateRequest(log, anchors, options=dict(options)))
    tracker = Tracker("ekf-track", anchors, options)
    assert_same(streamed(tracker, [log.iloc[i:i + 53] for i in range(0, len(log), 53)]),
                expected)


def test_batch_run_gives_a_track_its_own_numbers_whatever_the_other_kinds():
    """The batch run's tracks are one batch of the filter: a track's estimates are those of
    its own run, also when a track before it lacks some of its kinds (its kinds are updated
    in the same order either way), which the stream, batching other tracks, relies on."""
    log = mixed_log().replace({"node": {"t2": "a2"}})        # ranges alone, first by name
    options = {"init_s": "1.5", "range_bias_m": "0.25", "tdoa_std_m": "0.2",
               "aoa_std_rad": "0.05"}
    anchors = ANCHORS.assign(yaw=[0.0, YAW_B, 0.0, 0.0, 0.0])

    def run(rows):
        out = run_method("ekf-track", LocateRequest(rows.reset_index(drop=True), anchors,
                                                    options=dict(options)))
        return out[out["node"] == "t1"].reset_index(drop=True)
    assert_same(run(log), run(log[log["node"] == "t1"]))


def test_flush_estimates_the_latest_step_at_once(log, expected):
    """With the reorder window 0, each time stamp given whole then flushed is estimated by
    that flush (once its track has started), and the numbers are the batch run's; a row of
    a flushed time that comes after is late."""
    tracker = Tracker("ekf-track", ANCHORS, OPTIONS, reorder_s=0.0)
    parts, waited = [], 0
    for t, rows in log.groupby("time", sort=True):
        parts.append(tracker.update(rows))
        flushed = tracker.flush()
        parts.append(flushed)
        started = expected[expected["time"] == t]
        if len(flushed) == 0:
            waited += 1                       # held for a start window
        else:
            assert flushed["time"].max() == t and set(started["node"]) <= set(flushed["node"])
    parts.append(tracker.close())
    assert waited < 0.1 * log["time"].nunique()
    got = pd.concat([p for p in parts if len(p)], ignore_index=True)
    assert_same(got.sort_values(["time", "node"], kind="stable").reset_index(drop=True),
                expected)
    before = tracker.summary()["rows_late"]
    tracker.update(log.iloc[-1:])
    assert tracker.summary()["rows_late"] == before + 1


def radioloc(*args: str) -> list[str]:
    return [sys.executable, "-m", "radioloc.cli", *args]


@pytest.fixture(scope="module")
def files(tmp_path_factory, log):
    folder = tmp_path_factory.mktemp("follow")
    log.to_csv(folder / "log.csv", index=False)
    ANCHORS.to_csv(folder / "anchors.csv", index=False)
    subprocess.run(radioloc("locate", str(folder / "log.csv"), "--anchors",
                            str(folder / "anchors.csv"), "--method", "ekf-track", "-o", "q=0.5",
                            "-o", "init_s=1.5", "-o", "tune=0", "--out", str(folder / "batch.csv")),
                   check=True, timeout=120, capture_output=True)
    return folder


def follow_args(folder, source: str, *more: str) -> list[str]:
    return radioloc("locate", source, "--anchors", str(folder / "anchors.csv"), "--method",
                    "ekf-track", "--follow", "-o", "q=0.5", "-o", "init_s=1.5", *more)


def interrupted_after(proc, out, lines: int) -> None:
    """Wait (60 s at most) for ``lines`` lines in ``out``, then Ctrl-C ``proc``, which ends
    cleanly."""
    deadline = time.monotonic() + 60
    while not out.exists() or len(out.read_text().splitlines()) < lines:
        assert time.monotonic() < deadline and proc.poll() is None
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=60) == 0, proc.stderr.read()


def read_sorted(out) -> pd.DataFrame:
    return pd.read_csv(out).sort_values(["time", "node"], kind="stable").reset_index(drop=True)


@pytest.mark.slow   # a subprocess (and a signal)
def test_follow_on_standard_input_writes_the_batch_rows(files, log):
    text = (files / "log.csv").read_text().splitlines(keepends=True)
    proc = subprocess.Popen(follow_args(files, "-"), stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    rng = np.random.default_rng(4)
    at = 0
    try:
        while at < len(text):
            n = int(rng.integers(1, 200))
            proc.stdin.write("".join(text[at:at + n]))     # lines cut anywhere in chunks
            proc.stdin.flush()
            at += n
        proc.stdin.close()
        out, err = proc.stdout.read(), proc.stderr.read()
        assert proc.wait(timeout=120) == 0, err
    finally:
        proc.kill()
    from io import StringIO

    got = pd.read_csv(StringIO(out)).sort_values(["time", "node"], kind="stable")
    assert_same(got.reset_index(drop=True), pd.read_csv(files / "batch.csv"))
    summary = json.loads(err.strip().splitlines()[-1])
    assert summary["end"] == "end of input" and summary["rows_in"] == len(log)


@pytest.mark.slow   # a subprocess (and a signal)
def test_follow_a_growing_json_lines_file_until_interrupted(files, log, tmp_path):
    source = tmp_path / "live.jsonl"
    half = len(log) // 2
    lines = [json.dumps(r) + "\n" for r in log.to_dict("records")]
    source.write_text("".join(lines[:half]))
    out = tmp_path / "est.csv"
    proc = subprocess.Popen(follow_args(files, str(source), "--out", str(out)),
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not (out.exists() and out.stat().st_size > 0):   # estimates before the end
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.1)
        with open(source, "a") as f:
            f.write("".join(lines[half:]))
        interrupted_after(proc, out, len(pd.read_csv(files / "batch.csv")) - 40)
    finally:
        proc.kill()
    assert_same(read_sorted(out), pd.read_csv(files / "batch.csv"))
    summary = json.loads((tmp_path / "est.summary.json").read_text())
    assert summary["end"] == "interrupted" and summary["rows_late"] == 0


@pytest.mark.slow   # a subprocess (and a signal)
def test_follow_names_the_line_of_a_bad_row(files):
    text = "time,node,peer,kind,value\n0.1,t,A,range,3\n0.2,t,A,range,oops\n"
    run = subprocess.run(follow_args(files, "-"), input=text, capture_output=True, text=True,
                         timeout=60)
    assert run.returncode != 0 and "line 3" in run.stderr and "Traceback" not in run.stderr


@pytest.mark.slow   # a subprocess (and a signal)
def test_follow_udp_datagrams_flushed_when_idle(files, log, tmp_path):
    """Rows sent as UDP datagrams (whole time stamps, the header on top of each) to
    ``udp://127.0.0.1:0``: with ``--idle-s`` every estimate is written before the run is
    interrupted, and they are the batch run's."""
    import socket

    out = tmp_path / "est.csv"
    proc = subprocess.Popen(follow_args(files, "udp://127.0.0.1:0", "--out", str(out),
                                        "--reorder-s", "0", "--idle-s", "0.002"),
                            stderr=subprocess.PIPE, text=True)
    expected = pd.read_csv(files / "batch.csv")
    try:
        listening = proc.stderr.readline()
        assert listening.startswith("listening on udp://127.0.0.1:"), listening
        port = int(listening.strip().rsplit(":", 1)[1])
        header = "time,node,peer,kind,value\n"
        sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        stamps = [rows for _, rows in log.groupby("time", sort=True)]
        for i in range(0, len(stamps), 5):
            text = pd.concat(stamps[i:i + 5]).to_csv(index=False, header=False)
            sender.sendto((header + text).encode(), ("127.0.0.1", port))
        sender.close()
        interrupted_after(proc, out, len(expected) + 1)       # every row before Ctrl-C
    finally:
        proc.kill()
    assert_same(read_sorted(out), expected)
    summary = json.loads((tmp_path / "est.summary.json").read_text())
    assert summary["end"] == "interrupted" and summary["rows_in"] == len(log)
    assert summary["rows_late"] == 0 and summary["measurements"].startswith("udp://")


def test_lines_are_read_as_csv_or_json_lines():
    from radioloc.locate.follow import RowParser

    parser = RowParser()
    columns = parser.rows([b"time,node,peer,kind,value", b"", b'0.5,"tag,1",A,range,3.5',
                           b"0.6,tag2,A,range,4"])
    assert columns["node"] == ["tag,1", "tag2"] and columns["value"] == ["3.5", "4"]
    assert columns["line"] == [3, 4]
    again = parser.rows([b"time,node,peer,kind,value", b"0.7,tag2,B,range,5"])
    assert again["time"] == ["0.7"] and again["line"] == [6]    # the header again: skipped
    with pytest.raises(InputError, match="line 7: 4 cells, the header has 5"):
        parser.rows([b"0.8,tag2,B,range"])
    lines = RowParser().rows([b'{"time": 1, "node": "t", "peer": "A", "kind": "range", '
                              b'"value": 2}'])
    assert lines == {"time": [1], "node": ["t"], "peer": ["A"], "kind": ["range"],
                     "value": [2], "line": [1]}


def test_udp_source_is_an_address_to_listen_on():
    from radioloc.locate.follow import udp_socket

    assert udp_socket("-") is None and udp_socket("udp.csv") is None
    sock = udp_socket("udp:/127.0.0.1:0")          # a path argument folds udp:// so
    try:
        assert sock.getsockname()[0] == "127.0.0.1" and sock.getsockname()[1] > 0
    finally:
        sock.close()
    with pytest.raises(InputError, match="udp://127.0.0.1:99999: cannot listen"):
        udp_socket("udp://127.0.0.1:99999")
