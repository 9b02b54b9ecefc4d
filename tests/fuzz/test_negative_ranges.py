"""One rule for negative ranges (``radioloc.core.validation.check_ranges``), applied by every
library estimator that takes ranges and by ``radioloc locate``: a range below
``bias - 6 sigma`` of its noise is refused naming the argument and the index of the first
bad value (the row, for a log); a slightly negative one (noise on a short range) is taken."""

from __future__ import annotations

import numpy as np
import pytest
from library_harness import CASES, Case

from fuzz_harness import HEAD, render, run
from radioloc.core.errors import InputError
from radioloc.core.validation import NEGATIVE_RANGE_SIGMAS, check_ranges, range_floor_m
from radioloc.estimators import ESTIMATORS, GENERIC_ESTIMATORS, NetworkRLS

#: cases without a range argument (RSS, angles, time differences, which may be negative) or
#: whose ranges are rows of indices and values (calibrate_anchors: any negative one refused)
NO_RANGES = {"GridFilter", "MixtureLocalizer", "MixtureTracker", "LeastSquares/aoa",
             "LeastSquares/tdoa", "calibrate_anchors"}
#: cases configured without a range noise level: every negative range is refused
NO_NOISE_LEVEL = {"NetworkRLS", "NewtonTracker"}
RANGE_CASES = sorted(set(CASES) - NO_RANGES)


def test_the_rule():
    r = np.array([[1.0, -0.29, np.nan], [-0.31, 2.0, -5.0]])
    floor = -NEGATIVE_RANGE_SIGMAS * 0.05
    assert np.array_equal(range_floor_m(0.05), np.float64(floor))
    with pytest.raises(InputError, match=r"^ranges: range -0\.31 at index \(1, 0\) is below"):
        check_ranges(r, "ranges", 0.05)
    # unused entries, NaN and values at the floor pass; per-entry noise; a known bias
    assert check_ranges(r, "ranges", 0.05, used=np.array([False, True, False])) is not None
    check_ranges(np.array([floor, 0.0]), "r", 0.05)
    check_ranges(r, "r", np.array([0.06, 0.06, 1.0]))
    with pytest.raises(InputError, match=r"index \(1,\)"):
        check_ranges(np.array([1.0, 0.9]), "r", 0.01, bias_m=1.0)
    with pytest.raises(InputError, match=r"negative range -1e-09 at index \(0,\)"):
        check_ranges(np.array([-1e-9]), "r")                  # no noise level: none negative
    with pytest.raises(InputError, match="do not broadcast"):
        check_ranges(np.zeros(3), "r", np.ones(2))


def _range_field(case: Case) -> str:
    return "ranges" if "ranges" in case.args else "z"


def _first_used(case: Case, field: str) -> tuple[int, ...]:
    arr = np.asarray(case.args[field], dtype=float)
    return tuple(int(i) for i in np.argwhere(np.isfinite(arr))[0])


def _with(case: Case, field: str, index, value) -> dict:
    args = dict(case.args)
    arr = np.array(args[field], dtype=float, copy=True)
    arr[index] = value
    args[field] = arr
    return args


def test_every_range_estimator_is_covered():
    names = {c.__name__ for c in ESTIMATORS} | {c.__name__ for c in GENERIC_ESTIMATORS}
    assert names - {"GridFilter", "MixtureLocalizer", "MixtureTracker"} \
        <= {k.split("/")[0] for k in RANGE_CASES}


@pytest.mark.parametrize("name", RANGE_CASES)
def test_a_negative_range_is_refused_naming_argument_and_index(name):
    case = CASES[name]()
    field = _range_field(case)
    idx = _first_used(case, field)
    with pytest.raises(InputError) as info:
        case.solve(dict(case.settings), _with(case, field, idx, -1000.0))
    msg = str(info.value)
    assert msg.startswith(f"{field}: ") and "range -1000 at index" in msg, msg
    assert "\n" not in msg


@pytest.mark.parametrize("name", RANGE_CASES)
def test_a_slightly_negative_range_follows_the_noise_level(name):
    case = CASES[name]()
    field = _range_field(case)
    args = _with(case, field, _first_used(case, field), -1e-6)
    if name in NO_NOISE_LEVEL:
        with pytest.raises(InputError, match="no noise level"):
            case.solve(dict(case.settings), args)
    else:
        result = case.solve(dict(case.settings), args)
        assert np.all(np.isfinite(np.asarray(result.position)))


def test_a_noise_level_lets_network_rls_take_a_noisy_range():
    case = CASES["NetworkRLS"]()
    idx = _first_used(case, "ranges")
    args = _with(case, "ranges", idx, -0.5)
    track = NetworkRLS(forgetting=0.7, std_m=0.1).run(**args)
    assert np.all(np.isfinite(track.position))
    with pytest.raises(InputError, match=r"range -0\.7 at index"):
        NetworkRLS(forgetting=0.7, std_m=0.1).run(**_with(case, "ranges", idx, -0.7))


def _range_methods() -> list[str]:
    from radioloc.locate.base import methods

    return sorted(n for n, m in methods().items() if m.kinds is None or "range" in m.kinds)


@pytest.mark.parametrize("method", _range_methods() + ["gn3"])
def test_locate_refuses_a_negative_range_naming_its_line(scenarios, workdir, method):
    """Every locate method that reads ranges (the network ones with their priors, the
    others with the anchors of gn's scenario)."""
    sc = scenarios[method if method in scenarios else "gn"]
    sc = type(sc)(**{**sc.__dict__, "method": sc.method if method == "gn3" else method,
                     "options": {}})
    rows = [list(r) for r in sc.rows]
    rows[3][4] = "-4.5"
    meas = workdir / f"neg-{method}.csv"
    meas.write_text(render(rows))
    res = run(sc.args(meas))
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert res.exit_code == 2 and len(lines) == 1, res.output
    assert "line 4, column 'value': negative range -4.5" in lines[0], lines[0]


@pytest.mark.parametrize("method", ["gn", "ekf-track", "pf"])
def test_locate_takes_a_noisy_negative_range_with_its_std(scenarios, workdir, method):
    """A row with ``std`` 0.1 m may be down to -0.6 m; below that it is refused."""
    sc = scenarios[method]
    body = [r + ["0.1"] for r in sc.rows[1:]]
    for value, ok in (("-0.05", True), ("-0.7", False)):
        rows = [HEAD + ["std"]] + [list(r) for r in body]
        rows[2][4] = value
        meas = workdir / f"neg-std-{method}.csv"
        meas.write_text(render(rows))
        res = run(sc.args(meas))
        if ok:
            assert res.exit_code == 0, res.output
        else:
            assert res.exit_code == 2 and "line 3, column 'value': negative range -0.7" \
                in res.output, res.output


def test_range_model_density_applies_the_rule():
    """RangeModel.logpdf (and mode_logpdf of the LOS/NLOS noise): a range below -6 sigma of
    its noise (the row's std, else the model's LOS one) is refused naming z and the index."""
    from radioloc.models import LosNlosRange, RangeModel
    from radioloc.models.measurement import Context

    state = {"position": np.array([[1.0, 2.0]])}
    ctx = Context(points=np.array([[0.0, 0.0], [10.0, 0.0]]))
    for model in (RangeModel(std_m=0.1), RangeModel(noise=LosNlosRange(0.1, 2.0, 0.9))):
        assert np.all(np.isfinite(model.logpdf(np.array([[-0.5, 9.0]]), state, ctx)))
        with pytest.raises(InputError, match=r"^z: range -0\.7 at index \(0, 0\)"):
            model.mode_logpdf(np.array([[-0.7, 9.0]]), state, ctx)
    with_std = Context(points=ctx.points, std=np.array([1.0, 0.1]))
    assert np.isfinite(RangeModel(std_m=0.1).logpdf(np.array([[-5.0, 9.0]]), state,
                                                     with_std)).all()
