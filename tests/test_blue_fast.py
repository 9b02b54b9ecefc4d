"""The compiled BLUE iterates every track to its own stop inside one kernel
(``closed_form._blue_tracks``): its stopping decisions (iterations, ``converged``,
``stalled``) and estimates equal the plain NumPy loop of the same maths
(``tests/test_closed_form_kernels._reference``, LU solves) on random tracks, for both
stopping rules and for ``max_iter`` 0, 1 and 2; the parallel and the one-thread paths give
the same numbers bit for bit."""

import numpy as np
import pytest

from radioloc.core.errors import GeometryError
from radioloc.estimators import closed_form as cf
from radioloc.estimators.closed_form import ClosedFormTracker
from radioloc.sim.single_sensor import circular_sensor_path
from test_closed_form_kernels import T, _check, _reference, _tracks


@pytest.mark.parametrize("max_iter", [0, 1, 2])
@pytest.mark.parametrize("stopping", ["change", "criterion"])
def test_fused_iterations_match_numpy_loop(max_iter, stopping):
    rng = np.random.default_rng(10 + max_iter)
    r, s = _tracks(rng, 30, 24)
    tr = ClosedFormTracker(0.15, 0.1, max_iter=max_iter, stopping=stopping)
    got = _check(tr, r, s)
    it = got.diagnostics["iterations"]
    assert np.all(it <= max_iter)
    if max_iter == 0:                                   # the OLS start, nothing else
        np.testing.assert_array_equal(got.diagnostics["state"], got.diagnostics["ols_state"])
        np.testing.assert_array_equal(got.diagnostics["state_covariance"], 0.0)
        assert not got.diagnostics["converged"].any()


def test_converged_and_stalled_flags_match_their_rules():
    rng = np.random.default_rng(20)
    r, s = _tracks(rng, 40, 30)
    tr = ClosedFormTracker(0.15, 0.1, stopping="criterion", tol=1e-9, max_iter=15)
    got = _check(tr, r, s).diagnostics
    # the NumPy loop's stall rule: the criterion of the next step did not decrease
    beta, _, _, it = _reference(tr, r, s)
    assert got["stalled"].any()                         # tol = 1e-9: most tracks stall
    assert not np.any(got["stalled"] & got["converged"])
    assert np.all(got["iterations"][got["stalled"]] >= 1)
    np.testing.assert_array_equal(got["iterations"], it)
    loose = ClosedFormTracker(0.15, 0.1, max_iter=50).locate(r, s, T).diagnostics
    assert loose["converged"].all() and not loose["stalled"].any()


def test_parallel_and_one_thread_paths_equal_bit_for_bit():
    rng = np.random.default_rng(21)
    n = 40
    r, s = _tracks(rng, 3 * cf._PARALLEL_MIN_TRACKS + 5, n)
    r[4, 7] = np.nan
    tr = ClosedFormTracker(0.15, 0.1)
    batch = tr.locate(r, s, T).diagnostics                       # parallel kernel
    for i in (0, 4, r.shape[0] - 1):
        one = tr.locate(r[i:i + 1], s, T).diagnostics             # one-thread path
        for key in ("state", "state_covariance", "ols_state", "iterations", "converged",
                    "stalled"):
            np.testing.assert_array_equal(one[key][0], batch[key][i])


def test_singular_track_in_a_large_batch_raises():
    n = 12
    s = circular_sensor_path(n, 5.0, 1.3)
    r = np.tile(np.linalg.norm(np.array([1.0, 0.5]) - s, axis=-1), (40, 1))
    with pytest.raises(GeometryError, match="singular"):
        ClosedFormTracker(0.0, 0.0).locate(r, s, T)
