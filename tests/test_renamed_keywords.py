"""Range noise is ``std_m`` everywhere; the old keywords still work for one release.

Each old keyword (and an old positional variance) raises a ``FutureWarning`` naming the new
keyword and gives the result of the new call with ``std_m = sqrt(variance)``.
"""

import numpy as np
import pytest

from radioloc.bounds.anchors import range_crb, range_fisher_information
from radioloc.bounds.cooperative import (
    network_crb,
    network_crb_node_traces,
    network_range_information,
)
from radioloc.bounds.single_sensor import differenced_crb, raw_range_crb
from radioloc.core.errors import ConfigError, InputError
from radioloc.core.renamed import Renamed, renamed_keywords
from radioloc.estimators.closed_form import ClosedFormTracker
from radioloc.estimators.ekf import NetworkEKF
from radioloc.estimators.multilateration import Multilateration
from radioloc.estimators.rls import NetworkRLS, transformed_noise_var
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.ranging import GaussianRange
from radioloc.models.single_sensor import SquaredRangeModel
from radioloc.sim.network import iteration_ranges
from radioloc.sim.single_sensor import circular_sensor_path, noisy_ranges

SQUARE = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 20.0], [0.0, 20.0]])
TRUTH = np.array([[3.0, 4.0], [12.0, 15.0]])
T = 0.1


def _network(seed=0, K=4, N=3):
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0, 30, (2, K, 2))
    prior = truth + rng.normal(0, 1.0, truth.shape)
    ranges = iteration_ranges(truth, N, std_m=0.5, rng=rng)
    return ranges, prior, np.full(prior.shape, 1.0)


def _sensor_scene(n=12):
    rng = np.random.default_rng(3)
    sensor = circular_sensor_path(n, 5.0, 1.3)
    t = (np.arange(n) - (n - 1))[:, None] * T
    truth = np.array([1.0, 0.5]) + t * [0.8, -0.2]
    r = np.linalg.norm(truth - sensor, axis=-1) + rng.normal(0, 0.1, n)
    return r, sensor


def _same(old, new):
    """Run ``old`` expecting one FutureWarning naming std_m; compare with ``new``."""
    with pytest.warns(FutureWarning, match=r"is renamed std_m=") as record:
        got = old()
    assert len(record) == 1
    np.testing.assert_allclose(got, new(), rtol=1e-12, atol=1e-12)


def _network_run(est):
    ranges, prior, var = _network()
    return est.run(ranges, prior, var).position


def _sensor_run(est):
    r, sensor = _sensor_scene()
    return est.locate(r, sensor, T).diagnostics["state"]


@pytest.mark.parametrize("old, new", [
    (lambda: Multilateration(range_std_m=0.5), lambda: Multilateration(std_m=0.5)),
    (lambda: Multilateration("gauss-newton", 0.5), lambda: Multilateration(std_m=0.5)),
])
def test_multilateration_old_keyword_warns_and_fits_the_same(old, new):
    r = np.linalg.norm(TRUTH[:, None] - SQUARE, axis=-1) + [0.1, -0.2, 0.05, 0.0]

    def fit(make):
        est = make().locate(r, SQUARE)
        return np.concatenate([est.position.ravel(), est.covariance.ravel()])
    _same(lambda: fit(old), lambda: fit(new))


@pytest.mark.parametrize("old", [lambda: NetworkEKF(range_var_m2=4.0),
                                 lambda: NetworkEKF(4.0, "numba")])
def test_network_ekf_old_variance_is_std_m_squared(old):
    _same(lambda: _network_run(old()),
          lambda: _network_run(NetworkEKF(std_m=2.0)))


def test_network_rls_old_variance_is_std_m_squared():
    _same(lambda: _network_run(NetworkRLS(0.8, "transformed-noise", range_var_m2=4.0)),
          lambda: _network_run(NetworkRLS(0.8, "transformed-noise", std_m=2.0)))


def test_closed_form_old_keyword_and_position_are_the_variance():
    new = lambda: _sensor_run(ClosedFormTracker(0.15, std_m=0.3))
    _same(lambda: _sensor_run(ClosedFormTracker(0.15, range_var=0.09)), new)
    _same(lambda: _sensor_run(ClosedFormTracker(0.15, 0.09)), new)


def test_squared_range_model_old_keyword_and_position_are_the_variance():
    state = np.array([1.0, 0.5, 0.8, -0.2])
    _, sensor = _sensor_scene()
    n = len(sensor)

    def cov(model):
        return np.concatenate([model.noise_covariance(state, sensor).ravel(), model.noise_mean()])
    new = lambda: cov(SquaredRangeModel(n, n - 1, T, 0.15, std_m=0.3, range_excess_kurtosis=-1.2,
                                        printed_eq14=True))
    _same(lambda: cov(SquaredRangeModel(n, n - 1, T, 0.15, range_var=0.09,
                                        range_excess_kurtosis=-1.2, printed_eq14=True)), new)
    _same(lambda: cov(SquaredRangeModel(n, n - 1, T, 0.15, 0.09, 0.0, -1.2, True)), new)
    # the channel noise enters: std_m = 0 is another covariance
    assert not np.allclose(cov(SquaredRangeModel(n, n - 1, T, 0.15)), new())
    with pytest.raises(ConfigError, match="std_m.*range_var"):
        SquaredRangeModel(n, n - 1, T, 0.15, range_var=0.09, std_m=0.3)
    with pytest.warns(FutureWarning), pytest.raises(InputError, match="std_m"):
        SquaredRangeModel(n, n - 1, T, 0.15, range_var=-0.1)


def test_bounds_and_sims_take_the_old_variance_with_a_warning():
    state = np.array([1.0, 0.5, 0.8, -0.2])
    _, sensor = _sensor_scene()
    kw = {"sample_period_s": T, "accel_var": 0.15}
    _same(lambda: differenced_crb(state, sensor, range_var=0.09, **kw),
          lambda: differenced_crb(state, sensor, std_m=0.3, **kw))
    _same(lambda: raw_range_crb(state, sensor, range_var=0.09, **kw),
          lambda: raw_range_crb(state, sensor, std_m=0.3, **kw))
    _same(lambda: range_crb(TRUTH, SQUARE, 0.09), lambda: range_crb(TRUTH, SQUARE, std_m=0.3))
    _same(lambda: range_fisher_information(TRUTH, SQUARE, range_variance=0.09),
          lambda: range_fisher_information(TRUTH, SQUARE, std_m=0.3))
    _, prior, var = _network()
    _same(lambda: network_range_information(prior, 4.0),
          lambda: network_range_information(prior, std_m=2.0))
    _same(lambda: network_crb(prior, 4.0, var, counts=3.0),
          lambda: network_crb(prior, std_m=2.0, prior_var=var, counts=3.0))
    _same(lambda: network_crb_node_traces(prior, 4.0, var, np.arange(3.0)),
          lambda: network_crb_node_traces(prior, std_m=2.0, prior_var=var, counts=np.arange(3.0)))
    _same(lambda: transformed_noise_var(prior, range_var=4.0),
          lambda: transformed_noise_var(prior, std_m=2.0))
    _same(lambda: iteration_ranges(prior, 2, 4.0, np.random.default_rng(1)),
          lambda: iteration_ranges(prior, 2, std_m=2.0, rng=np.random.default_rng(1)))
    path = np.zeros((5, 2)) + [10.0, 0.0]
    _same(lambda: noisy_ranges(np.zeros((5, 2)), path, 0.04, np.random.default_rng(1)),
          lambda: noisy_ranges(np.zeros((5, 2)), path, std_m=0.2, rng=np.random.default_rng(1)))


def test_old_and_new_keyword_together_is_a_config_error():
    with pytest.raises(ConfigError, match="std_m.*range_var_m2"):
        NetworkEKF(range_var_m2=4.0, std_m=2.0)
    with pytest.raises(ConfigError, match="std_m.*range_std_m"):
        Multilateration(range_std_m=1.0, std_m=1.0)


def test_a_bad_old_variance_is_refused_by_the_new_name():
    with pytest.warns(FutureWarning), pytest.raises(ConfigError, match="std_m"):
        NetworkEKF(range_var_m2=-1.0)
    with pytest.warns(FutureWarning), pytest.raises(InputError, match="std_m"):
        ClosedFormTracker(0.1, range_var=-0.1)


def test_the_helper_warns_once_and_converts():
    @renamed_keywords({"old_var": Renamed("new_std", variance=True)}, positional=("old_var",))
    def f(a, *, new_std=1.0):
        return a * new_std

    assert f(2.0, new_std=3.0) == 6.0
    with pytest.warns(FutureWarning, match="f: old_var= is renamed new_std="):
        assert f(2.0, 9.0) == 6.0
    with pytest.raises(TypeError, match="at most 2 positional"):
        f(1.0, 2.0, 3.0)


def test_closed_form_takes_a_gaussian_range_model_as_std_m():
    np.testing.assert_allclose(
        _sensor_run(ClosedFormTracker(0.15, measurement=GaussianRange(0.3))),
        _sensor_run(ClosedFormTracker(0.15, std_m=0.3)), rtol=1e-12, atol=1e-12)


def test_closed_form_subtracts_the_models_mean_error_and_uses_its_variance():
    model = LosNlosRange(los_std_m=0.05, nlos_mean_m=0.4, alpha=0.5)
    mean, var = model.moments()
    r, sensor = _sensor_scene()
    got = ClosedFormTracker(0.15, measurement=model).locate(r + mean, sensor, T)
    ref = ClosedFormTracker(0.15, std_m=np.sqrt(var)).locate(r, sensor, T)
    np.testing.assert_allclose(got.diagnostics["state"], ref.diagnostics["state"], rtol=1e-9)
    np.testing.assert_allclose(got.covariance, ref.covariance, rtol=1e-9)


def test_closed_form_refuses_two_noise_settings_or_a_model_without_moments():
    with pytest.raises(ConfigError, match="std_m or measurement"):
        ClosedFormTracker(0.1, std_m=0.3, measurement=GaussianRange(0.3))
    with pytest.raises(ConfigError, match="moments"):
        ClosedFormTracker(0.1, measurement=object())
