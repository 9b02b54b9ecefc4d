"""Invalid inputs refused with the toolkit's own error naming the place, and a valid one
accepted: grid-rssi's anchors (collinear, coincident, in degrees, with heights), rls's
anchor heights, a reference cell on a row that is not tdoa, a tiny row std, ranges between
nodes that a snapshot method does not use, library settings and arrays of the wrong type,
and the pseudorange start fit that ran out of iterations."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.validation import check_ranges
from radioloc.estimators.anchor_calibration import calibrate_anchors
from radioloc.estimators.extended_kalman import ExtendedKalmanFilter
from radioloc.estimators.least_squares import LeastSquares
from radioloc.estimators.particle_filter import ParticleFilter
from radioloc.models.measurement import Context, Observation
from radioloc.models.motion import WhiteAccelerationCV
from radioloc.models.ranging import GaussianRange
from radioloc.models.tdoa import TdoaModel
from radioloc.models.rssi_trapezoid import fit_trapezoid_model
from reliability_helpers import assert_one_line_error, invoke

HEAD = "time,node,peer,kind,value"
SQUARE = {"A1": (0.0, 0.0), "A2": (20.0, 0.0), "A3": (20.0, 20.0), "A4": (0.0, 20.0)}


def write_anchors(path, anchors: dict, z: bool = False):
    cols = "id,x,y,z" if z else "id,x,y"
    path.write_text(cols + "\n" + "".join(
        f"{k},{x!r},{y!r}" + (",1.5" if z else "") + "\n" for k, (x, y) in anchors.items()))
    return path


def range_log(path, anchors: dict, nodes: dict):
    """Exact ranges of every node to every anchor at times 0 and 1."""
    path.write_text(HEAD + "\n" + "".join(
        f"{t!r},{n},{a},range,{math.dist(p, q)!r}\n"
        for t in (0.0, 1.0) for n, p in nodes.items() for a, q in anchors.items()))
    return path


@pytest.fixture(scope="module")
def trapezoid(tmp_path_factory):
    """A trapezoid RSSI/distance model (RSSI 70 - 2 d) for grid-rssi."""
    rng = np.random.default_rng(3)
    d = rng.uniform(0, 30, 4000)
    model = fit_trapezoid_model(np.clip(np.rint(70 - 2.0 * d + rng.normal(0, 0.3, d.size)), 0, 100),
                                d, tau_min=0.2, sigma_min=0.2, window=0)
    path = tmp_path_factory.mktemp("model") / "model.json"
    model.save(path)
    return path


def rss_log(path, anchors: dict, node=(7.0, 12.0)):
    path.write_text(HEAD + "\n" + "".join(
        f"{t!r},n1,{a},rss,{70 - 2.0 * math.dist(node, q) - 110!r}\n"
        for t in (0.0, 1.0) for a, q in anchors.items()))
    return path


# ---- grid-rssi and rls: anchors that cannot fix a position, heights ignored -------------

@pytest.mark.parametrize("shape, words", [
    ("collinear", "are collinear"), ("coincident", "coincide"), ("degrees", "degrees?")])
def test_grid_rssi_refuses_anchors_that_cannot_fix_a_position(tmp_path, trapezoid, shape,
                                                               words):
    anchors = {"collinear": {"A1": (0.0, 0.0), "A2": (10.0, 5.0), "A3": (20.0, 10.0)},
               "coincident": {"A1": (5.0, 5.0), "A2": (5.0, 5.0), "A3": (5.0, 5.0)},
               "degrees": {"A1": (2.35, 48.85), "A2": (2.3502, 48.85), "A3": (2.35, 48.8502)},
               }[shape]
    res = invoke(["locate", rss_log(tmp_path / "m.csv", anchors), "--method", "grid-rssi",
                  "--anchors", write_anchors(tmp_path / "a.csv", anchors),
                  "--calibration", trapezoid])
    line = assert_one_line_error(res)
    assert words in line and "no_check=" in line


def test_grid_rssi_still_locates_from_a_good_geometry(tmp_path, trapezoid):
    res = invoke(["locate", rss_log(tmp_path / "m.csv", SQUARE), "--method", "grid-rssi",
                  "--anchors", write_anchors(tmp_path / "a.csv", SQUARE),
                  "--calibration", trapezoid, "-o", "cell_m=1"])
    assert res.exit_code == 0, res.output
    est = pd.read_csv(pd.io.common.StringIO(res.stdout))
    assert np.all(np.hypot(est["x"] - 7.0, est["y"] - 12.0) < 3.0)


def test_grid_rssi_refuses_anchors_with_heights(tmp_path, trapezoid):
    res = invoke(["locate", rss_log(tmp_path / "m.csv", SQUARE), "--method", "grid-rssi",
                  "--anchors", write_anchors(tmp_path / "a.csv", SQUARE, z=True),
                  "--calibration", trapezoid])
    assert "method grid-rssi: locates in the plane" in assert_one_line_error(res)


@pytest.mark.parametrize("method", ["rls", "ekf"])
def test_network_methods_refuse_anchors_with_heights(tmp_path, method):
    nodes = {"N1": (10.0, 10.0), "N2": (4.0, 15.0)}
    (tmp_path / "p.csv").write_text("node,x,y,var_x,var_y\n" + "".join(
        f"{k},{x + 1},{y},100,100\n" for k, (x, y) in nodes.items()))
    meas = range_log(tmp_path / "m.csv", SQUARE, nodes)
    res = invoke(["locate", meas, "--method", method, "--priors", tmp_path / "p.csv",
                  "--anchors", write_anchors(tmp_path / "a.csv", SQUARE, z=True)])
    assert f"method {method}: locates in the plane" in assert_one_line_error(res)


# ---- the measurements file: a reference on another kind, a tiny std --------------------

@pytest.mark.parametrize("method", ["ekf-track", "lsq", "pf", "smoother", "gn"])
def test_reference_cell_on_a_range_row_is_refused_naming_the_line(tmp_path, method):
    meas = tmp_path / "m.csv"
    rows = [f"{t!r},tag,{a},range,{math.dist((7.0, 12.0), q)!r}," for t in (0.0, 1.0)
            for a, q in SQUARE.items()]
    rows[2] = rows[2] + "A1"
    meas.write_text(HEAD + ",reference\n" + "\n".join(rows) + "\n")
    res = invoke(["locate", meas, "--method", method, "--anchors",
                  write_anchors(tmp_path / "a.csv", SQUARE)])
    line = assert_one_line_error(res)
    assert f"{meas}: line 4, column 'reference': 'A1' on a range row" in line


@pytest.mark.parametrize("method", ["gn", "ekf-track"])
@pytest.mark.parametrize("std", ["1e-40", "0", "-1"])
def test_tiny_row_std_is_refused_naming_file_line_and_column(tmp_path, method, std):
    meas = tmp_path / "m.csv"
    rows = [f"{t!r},tag,{a},range,{math.dist((7.0, 12.0), q)!r},0.1" for t in (0.0, 1.0)
            for a, q in SQUARE.items()]
    rows[5] = rows[5].rsplit(",", 1)[0] + "," + std
    meas.write_text(HEAD + ",std\n" + "\n".join(rows) + "\n")
    res = invoke(["locate", meas, "--method", method, "--anchors",
                  write_anchors(tmp_path / "a.csv", SQUARE)])
    assert f"{meas}: line 7, column 'std': {std} must be >= 1e-30" in assert_one_line_error(res)


def test_gn_says_how_many_ranges_between_nodes_it_leaves_out(tmp_path):
    nodes = {"t1": (7.0, 12.0), "t2": (15.0, 3.0)}
    anchors = write_anchors(tmp_path / "a.csv", SQUARE)
    plain = range_log(tmp_path / "m.csv", SQUARE, nodes)
    both = tmp_path / "both.csv"
    both.write_text(plain.read_text() + "0.0,t1,t2,range,12.0\n1.0,t2,t1,range,12.1\n")
    ref = invoke(["locate", plain, "--anchors", anchors, "--method", "gn"])
    res = invoke(["locate", both, "--anchors", anchors, "--method", "gn"])
    assert res.exit_code == 0 and ref.exit_code == 0, res.output
    assert res.stdout == ref.stdout
    assert ("warning: method gn: 2 range row(s) between nodes not used (first: line 18, 't1' "
            "to 't2')") in res.stderr


# ---- the library ---------------------------------------------------------------------

def test_least_squares_refuses_an_infinite_tdoa_reference():
    pts = np.array([[20.0, 0.0], [20.0, 20.0], [0.0, 20.0]])
    for bad in (np.inf, np.nan, 1e300):
        ref = np.array([[bad, 0.0]] * 3)
        with pytest.raises(InputError, match="reference"):
            LeastSquares().locate(Observation(TdoaModel(std_m=0.1), np.ones(3),
                                              Context(points=pts, reference=ref)))


@pytest.mark.parametrize("make", [
    lambda: ExtendedKalmanFilter(WhiteAccelerationCV(0.05, 2), iterations=math.nan),
    lambda: ExtendedKalmanFilter(WhiteAccelerationCV(0.05, 2), gate_patience=math.inf),
    lambda: ParticleFilter(WhiteAccelerationCV(0.05, 2), seed=math.inf),
    lambda: ParticleFilter(WhiteAccelerationCV(0.05, 2), seed=[1, math.nan]),
    lambda: ParticleFilter(WhiteAccelerationCV(0.05, 2), seed="abc")],
    ids=["ekf-iterations-nan", "ekf-patience-inf", "pf-seed-inf", "pf-seeds-nan", "pf-seed-text"])
def test_non_integer_settings_are_config_errors(make):
    with pytest.raises(ConfigError, match="iterations|gate_patience|seed"):
        make()


CAL_PRIOR = np.array([[0.0, 0.0], [20.0, 0.0], [0.0, 20.0], [20.0, 20.5]])


@pytest.mark.parametrize("ranges", [
    [[0, 1, 20.0], [0, 2, "abc"]],
    np.array([[0, 1, 20.0], [0, 2, "abc"]], dtype=object),
    np.array([[0, 1, 20.0], [0, 3, 28.3]]) + 0j], ids=["list-text", "object-text", "complex"])
def test_calibrate_anchors_refuses_text_and_complex_ranges(ranges):
    with pytest.raises(InputError, match="anchor_ranges: expected real numbers"):
        calibrate_anchors(CAL_PRIOR, np.array([0, 0, 0, 1.0]), anchor_ranges=ranges)


def test_complex_ranges_are_refused_not_cast():
    r = np.array([3.0, 4.0]) + 1j
    with pytest.raises(InputError, match="ranges: expected real numbers"):
        check_ranges(r, "ranges")
    with pytest.raises(InputError, match="true_ranges: expected real numbers"):
        GaussianRange(0.1).sample(r, np.random.default_rng(0))


# ---- a valid input that was refused ----------------------------------------------------

def test_pseudorange_tracks_start_whatever_the_noise_draw(tmp_path):
    """The start fit of a pseudorange log (clock offset 150 m) had needed up to 146
    iterations of its limit of 50 for some noise draws (this one: seed 122)."""
    ids = [f"A{k}" for k in range(6)]
    anchors = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0], [10.0, -3.0],
                        [23.0, 7.0]])
    write_anchors(tmp_path / "a.csv", dict(zip(ids, anchors.tolist())))
    t = 0.2 * np.arange(150)
    xy = np.stack([10 + 6 * np.cos(t / 6), 7 + 4 * np.sin(t / 6)], axis=-1)
    d = np.linalg.norm(xy[:, None, :] - anchors, axis=-1)
    pr = d + (150.0 + 2.0 * t)[:, None] + 0.3 * np.random.default_rng(122).standard_normal(d.shape)
    pd.DataFrame([(t[k], "tag", ids[a], "pseudorange", pr[k, a]) for k in range(len(t))
                  for a in range(6)], columns=HEAD.split(",")).to_csv(tmp_path / "m.csv",
                                                                       index=False)
    for method in ("ekf-track", "smoother"):
        res = invoke(["locate", tmp_path / "m.csv", "--anchors", tmp_path / "a.csv", "--method",
                      method, "-o", "pseudorange_std_m=0.3", "-q"])
        assert res.exit_code == 0, res.output
        est = pd.read_csv(pd.io.common.StringIO(res.stdout))
        rmse = np.sqrt(np.mean(np.sum((est[["x", "y"]].to_numpy() - xy) ** 2, axis=1)))
        assert rmse < 0.5, (method, rmse)


@pytest.mark.parametrize("row, words", [
    ([0, 1.7976931348623157e308, 20.0], "anchor index out of range"),
    ([0, 1, 1.7976931348623157e308], r"range 1.79769e\+308 is not a finite number from 0 to 1e\+09 m")],
    ids=["huge-index", "huge-range"])
def test_calibrate_anchors_refuses_huge_numbers_without_a_foreign_error(row, words):
    ranges = np.array([[0, 1, 20.0], [0, 2, 20.0], [1, 3, 20.5], row])
    with pytest.raises(InputError, match=words):
        calibrate_anchors(CAL_PRIOR, np.array([0, 0, 0, 1.0]), anchor_ranges=ranges)


def test_tdoa_reference_with_batch_axes_the_points_lack_is_refused():
    pts = np.array([[20.0, 0.0], [20.0, 20.0], [0.0, 20.0]])
    with pytest.raises(InputError, match="reference: shape"):
        Context(points=pts, reference=np.zeros((3, 3, 2)))
    Context(points=np.broadcast_to(pts, (2, 3, 2)), reference=np.zeros((3, 2)))
