"""The compiled objectives of the snapshot baselines (LocalML, Ransac) against the array
expressions of the same maths: equal bit for bit on random scenes, for every LOS fraction
regime of the mixture and both search readings."""

import numpy as np
import pytest

from radioloc.core.errors import ConfigError
from radioloc.estimators.snapshot_baselines import LocalML, Ransac, _numpy_sum
from radioloc.models.los_nlos import LosNlosRange


def _scene(rng, batch=(3, 7), nodes=13):
    truth = rng.uniform(0, 30, batch + (2,))
    cen = rng.uniform(0, 30, batch + (nodes, 2))
    d = np.linalg.norm(truth[..., None, :] - cen, axis=-1)
    r = d + rng.normal(0, 0.05, d.shape) + (rng.random(d.shape) < 0.5) * rng.exponential(5, d.shape)
    r[rng.random(r.shape) < 0.3] = np.nan
    return truth, cen, r


@pytest.mark.parametrize("alpha", [0.0, 1e-9, 0.3, 1.0])
@pytest.mark.parametrize("local", [False, True])
def test_local_ml_kernel_equals_array_form(alpha, local):
    rng = np.random.default_rng(int(alpha * 1000) + local)
    truth, cen, r = _scene(rng)
    model = LosNlosRange(0.05, 5.0, alpha)
    kw = {"search_radius_m": 2.0} if local else {}
    centre = truth + rng.normal(0, 1, truth.shape) if local else None
    fast = LocalML(model, 10.0, **kw).locate(r, cen, centre)
    ref = LocalML(model, 10.0, kernel="numpy", **kw).locate(r, cen, centre)
    np.testing.assert_array_equal(fast.position, ref.position)
    np.testing.assert_allclose(fast.diagnostics["log_likelihood"], ref.diagnostics["log_likelihood"],
                               rtol=1e-10)


def test_ransac_kernel_equals_array_form():
    rng = np.random.default_rng(5)
    _, cen, r = _scene(rng, batch=(11,))
    fast = Ransac(0.15, 10.0).locate(r, cen)
    ref = Ransac(0.15, 10.0, kernel="numpy").locate(r, cen)
    np.testing.assert_array_equal(fast.position, ref.position)
    np.testing.assert_array_equal(fast.diagnostics["inliers"], ref.diagnostics["inliers"])


def test_single_snapshot_without_batch_axes():
    rng = np.random.default_rng(6)
    _, cen, r = _scene(rng, batch=())
    model = LosNlosRange(0.05, 5.0, 0.3)
    np.testing.assert_array_equal(LocalML(model, 10.0).locate(r, cen).position,
                                  LocalML(model, 10.0, kernel="numpy").locate(r, cen).position)


@pytest.mark.parametrize("n", [1, 5, 7, 8, 9, 16, 23, 40])
def test_compiled_sum_follows_numpy_order(n):
    a = np.random.default_rng(n).standard_normal((50, n)) * 10.0 ** np.arange(n)
    np.testing.assert_array_equal([_numpy_sum(row, n) for row in a], a.sum(axis=-1))


def test_bad_kernel_name_raises():
    with pytest.raises(ConfigError, match="kernel"):
        LocalML(LosNlosRange(), 10.0, kernel="fortran")
    with pytest.raises(ConfigError, match="kernel"):
        Ransac(0.15, 10.0, kernel="fortran")
