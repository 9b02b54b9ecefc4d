"""The generic extended Kalman filter: any measurement model through ``Observation``s.

Known answers (zero noise gives the truth), invariants (batch equals one by one, step by
step equals run, moving the scene moves the estimate), statistical consistency (NEES and
NIS of a simulated constant-velocity track), the iterated update and the RTS smoother
against the plain filter, per-anchor range biases estimated online (WiFi RTT ranges are
biased long by 1-7 m per access point), a clock offset, a bearing model written here with
only ``predict`` and ``std`` (numerical Jacobian, wrapped residuals), several kinds in one
step, and bad input naming the argument.
"""

from dataclasses import replace
from typing import ClassVar

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators.extended_kalman import ExtendedKalmanFilter, FilterState
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.measurement import Context, MeasurementModel, Observation, StateLayout
from radioloc.models.motion import ConstantVelocity, RandomWalk
from radioloc.models.ranging import RangeModel

from model_cases import MinimalBearing

ANCHORS = np.array([[0.0, 0.0], [30.0, 0.0], [30.0, 20.0], [0.0, 20.0]])
DT = 0.2



class Pseudorange(MeasurementModel):
    """Range plus the receiver clock offset (metres): ``|x - a| + c dt`` (test-local)."""

    kind: ClassVar[str] = "pseudorange"
    reads: ClassVar[tuple[str, ...]] = ("position", "clock_offset")

    def __init__(self, std_m: float) -> None:
        self.std_m = std_m

    def predict(self, state, context):
        d = np.linalg.norm(state["position"][..., None, :] - context.points, axis=-1)
        return d + state["clock_offset"][..., None]

    def std(self, context):
        return self.row_std(self.std_m, context)


def cv_track(runs, steps, rng, accel_var=0.05, start=(8.0, 6.0, 1.0, 0.5)):
    """Constant-velocity states ``(runs, steps, 4)`` drawn from the filter's own model."""
    x0 = np.asarray(start) + np.array([1.0, 1.0, 0.2, 0.2]) * rng.standard_normal((runs, 4))
    return ConstantVelocity(accel_var).simulate(x0, steps, DT, rng)


def ranges(truth, model, rng, anchors=ANCHORS, index=None):
    ctx = Context(points=anchors, index=index)
    return Observation(model, model.sample({"position": truth[..., :2]}, ctx, rng), ctx)


def prior(truth, rng, std=(1.0, 1.0, 0.3, 0.3)):
    """A prior drawn around the true first state, with its covariance."""
    std = np.asarray(std)
    return truth[..., 0, :] + std * rng.standard_normal(truth[..., 0, :].shape), np.diag(std**2)


def rmse(position, truth, burn=0):
    return float(np.sqrt(np.mean(np.sum((position[..., burn:, :] - truth[..., burn:, :2]) ** 2, -1))))


def test_zero_noise_converges_to_the_truth():
    rng = np.random.default_rng(0)
    truth = cv_track(3, 60, rng, accel_var=1e-12)
    ctx = Context(points=ANCHORS)
    z = np.linalg.norm(truth[..., None, :2] - ANCHORS, axis=-1)
    mean, cov = prior(truth, rng)
    tr = ExtendedKalmanFilter(ConstantVelocity(1e-6)).run(
        Observation(RangeModel(std_m=0.01), z, ctx), np.arange(60) * DT, prior_mean=mean,
        prior_cov=cov)
    err = np.linalg.norm(tr.position[:, -1] - truth[:, -1, :2], axis=-1)
    assert np.all(err < 1e-3), err
    assert np.all(np.linalg.norm(tr.diagnostics["state"][:, -1, 2:] - truth[:, -1, 2:], axis=-1) < 1e-3)


def test_batch_equals_one_by_one_and_step_equals_run():
    rng = np.random.default_rng(1)
    truth = cv_track(3, 25, rng)
    obs = ranges(truth, RangeModel(std_m=0.2), rng)
    obs.z[0, 3, 1] = np.nan
    obs.z[2, 7, 2] += 15.0                                  # an outlier for the gate
    mean, cov = prior(truth, rng)
    ekf = ExtendedKalmanFilter(ConstantVelocity(0.05), iterations=2)
    t = np.arange(25) * DT
    batch = ekf.run(obs, t, prior_mean=mean, prior_cov=cov)
    assert batch.diagnostics["gated"][2, 7] == 1
    for r in range(3):
        one = ekf.run(Observation(obs.model, obs.z[r], obs.context), t, prior_mean=mean[r],
                      prior_cov=cov)
        np.testing.assert_allclose(one.position, batch.position[r], rtol=0, atol=1e-10)
        np.testing.assert_allclose(one.covariance, batch.covariance[r], rtol=0, atol=1e-12)
    state = ekf.init(mean, cov, t[0])
    for k in range(25):
        state = ekf.step(state, Observation(obs.model, obs.z[:, k], obs.context),
                         dt=t[k] - t[k - 1] if k else 0.0)
        np.testing.assert_allclose(ekf.estimate(state).position, batch.position[:, k], atol=1e-10)


def test_a_run_goes_on_from_the_last_state_and_gate_streak_of_another():
    """Split in two, the second part going on from the first's last state and its gate
    streak (``state=``, ``streak=``), a run gives the whole run's numbers, also where a
    long spell of outliers spans the split and the gate's patience lets rows through."""
    rng = np.random.default_rng(2)
    truth = cv_track(2, 40, rng)
    obs = ranges(truth, RangeModel(std_m=0.2), rng)
    obs.z[1, 8:20] += 15.0                                 # 12 steps of outliers
    mean, cov = prior(truth, rng)
    ekf = ExtendedKalmanFilter(ConstantVelocity(0.05))
    t = np.arange(40) * DT
    whole = ekf.run(obs, t, prior_mean=mean, prior_cov=cov)
    assert list(whole.diagnostics["gated"][1, 8:19]) == [4] * 10 + [0]      # patience 10

    def part(steps):
        return Observation(obs.model, obs.z[:, steps], obs.context)
    first = ekf.run(part(slice(0, 11)), t[:11], prior_mean=mean, prior_cov=cov)
    d = first.diagnostics
    assert list(d["gate_streak"]) == [0, 3]
    state = FilterState(d["state"][:, -1], d["state_covariance"][:, -1], t[10],
                        ekf.state_layout(obs))
    rest = ekf.run(part(slice(11, None)), t[11:], state=state, streak=d["gate_streak"])
    np.testing.assert_allclose(rest.position, whole.position[:, 11:], rtol=0, atol=1e-10)
    np.testing.assert_allclose(rest.covariance, whole.covariance[:, 11:], rtol=0, atol=1e-12)
    assert (rest.diagnostics["gated"] == whole.diagnostics["gated"][:, 11:]).all()
    forgetful = ekf.run(part(slice(11, None)), t[11:], state=state)          # streak 0
    assert (forgetful.diagnostics["gated"][1] != rest.diagnostics["gated"][1]).any()
    with pytest.raises(InputError, match="state: its time"):
        ekf.run(part(slice(11, None)), t[11:], state=replace(state, time=t[12]))


def test_moving_the_scene_moves_the_estimate():
    rng = np.random.default_rng(2)
    truth = cv_track(2, 30, rng)
    obs = ranges(truth, RangeModel(std_m=0.2), rng)
    mean, cov = prior(truth, rng)
    ekf = ExtendedKalmanFilter(ConstantVelocity(0.05))
    tr = ekf.run(obs, prior_mean=mean, prior_cov=cov)
    shift = np.array([12.5, -7.0])
    moved = ekf.run(Observation(obs.model, obs.z, Context(points=ANCHORS + shift)),
                    prior_mean=mean + np.r_[shift, 0, 0], prior_cov=cov)
    np.testing.assert_allclose(moved.position, tr.position + shift, atol=1e-9)
    np.testing.assert_allclose(moved.covariance, tr.covariance, atol=1e-9)


@pytest.mark.parametrize("noise", ["gaussian", "los_nlos"])
def test_nees_and_nis_of_a_simulated_track_are_in_band(noise):
    """The claimed covariance matches the error: mean NEES of the 4-D state near 4, mean
    NIS per range near 1 (200 runs x 40 steps, steps 10.. scored)."""
    rng = np.random.default_rng(3)
    runs, steps = 200, 40
    truth = cv_track(runs, steps, rng)
    model = RangeModel(std_m=0.15) if noise == "gaussian" else \
        RangeModel(noise=LosNlosRange(los_std_m=0.15, nlos_mean_m=0.3, alpha=0.7))
    obs = ranges(truth, model, rng)
    mean, cov = prior(truth, rng)
    tr = ExtendedKalmanFilter(ConstantVelocity(0.05), gate=None).run(
        obs, np.arange(steps) * DT, prior_mean=mean, prior_cov=cov)
    e = tr.diagnostics["state"] - truth
    nees = np.einsum("...i,...i->...", e, np.linalg.solve(tr.diagnostics["state_covariance"],
                                                          e[..., None])[..., 0])
    nis = tr.diagnostics["nis"] / tr.diagnostics["measurements_used"]
    mean_nees, mean_nis = nees[:, 10:].mean(), nis[:, 10:].mean()
    if noise == "gaussian":
        assert 3.6 < mean_nees < 4.4, mean_nees
        assert 0.9 < mean_nis < 1.1, mean_nis
    else:   # the skewed mixture matched by its two moments: consistent on average
        assert 3.0 < mean_nees < 5.0, mean_nees
        assert 0.8 < mean_nis < 1.2, mean_nis


def test_los_nlos_noise_mean_is_taken_off_the_ranges():
    """Ranges biased by the NLOS excess: a filter that knows the model's mean has
    zero-mean innovations and tracks better than one that assumes zero-mean noise of the
    same variance."""
    rng = np.random.default_rng(4)
    truth = cv_track(50, 40, rng)
    noise = LosNlosRange(los_std_m=0.1, nlos_mean_m=2.0, alpha=0.5)
    obs = ranges(truth, RangeModel(noise=noise), rng)
    mean, cov = prior(truth, rng)
    ekf = ExtendedKalmanFilter(ConstantVelocity(0.05), gate=None)
    aware = ekf.run(obs, prior_mean=mean, prior_cov=cov)
    naive = ekf.run(Observation(RangeModel(std_m=float(np.sqrt(noise.moments()[1]))), obs.z,
                                obs.context), prior_mean=mean, prior_cov=cov)
    assert abs(np.mean(aware.diagnostics["innovation"][:, 10:])) < 0.15
    assert np.mean(naive.diagnostics["innovation"][:, 10:]) > 0.5 * noise.moments()[0]
    assert rmse(aware.position, truth, 10) < rmse(naive.position, truth, 10)


def test_iterated_update_beats_the_ekf_from_a_far_prior():
    """Accurate ranges, a prior 4 m off with a matching spread: the first updates are
    strongly nonlinear, and Gauss-Newton iterations land nearer the truth."""
    rng = np.random.default_rng(5)
    runs = 200
    truth = np.broadcast_to(np.array([5.0, 4.0]), (runs, 5, 2))
    anchors = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    obs = ranges(truth, RangeModel(std_m=0.02), rng, anchors=anchors)
    start = truth[:, 0] + 4.0 * rng.standard_normal((runs, 2))
    err = {}
    for it in (1, 5):
        tr = ExtendedKalmanFilter(RandomWalk(1e-4), gate=None, iterations=it).run(
            obs, prior_mean=start, prior_cov=16.0 * np.eye(2))
        err[it] = np.linalg.norm(tr.position - truth, axis=-1)
    # after the first update the iterated filter is already near the truth
    assert np.median(err[5][:, 0]) < 0.1 < np.median(err[1][:, 0])
    assert np.mean(err[5][:, -1]) <= np.mean(err[1][:, -1])


def test_rts_smoother_lowers_the_error():
    rng = np.random.default_rng(6)
    truth = cv_track(20, 50, rng)
    obs = ranges(truth, RangeModel(std_m=0.3), rng)
    mean, cov = prior(truth, rng)
    ekf = ExtendedKalmanFilter(ConstantVelocity(0.05))
    filt = ekf.run(obs, np.arange(50) * DT, prior_mean=mean, prior_cov=cov)
    smooth = ekf.run(obs, np.arange(50) * DT, prior_mean=mean, prior_cov=cov, smooth=True)
    assert rmse(smooth.position, truth) < 0.8 * rmse(filt.position, truth)
    np.testing.assert_allclose(smooth.position[:, -1], filt.position[:, -1], atol=1e-12)
    assert np.all(np.trace(smooth.covariance, axis1=-2, axis2=-1)
                  <= np.trace(filt.covariance, axis1=-2, axis2=-1) + 1e-12)


def circle(runs, steps, rng, centre=(25.0, 15.0), radius_m=10.0, speed_m_per_s=1.5):
    """Laps of a circle from random starting angles: states ``(runs, steps, 4)``."""
    w = speed_m_per_s / radius_m
    a = rng.uniform(0.0, 2.0 * np.pi, (runs, 1)) + w * np.arange(steps) * DT
    return np.stack([centre[0] + radius_m * np.cos(a), centre[1] + radius_m * np.sin(a),
                     -speed_m_per_s * np.sin(a), speed_m_per_s * np.cos(a)], -1)


def test_per_anchor_biases_are_estimated_online():
    """WiFi RTT: 6 access points whose ranges are biased long by 1-7 m, a tag walking laps
    among them, bias prior N(0, 5^2) per AP: the biases are learnt from the ranges alone."""
    rng = np.random.default_rng(7)
    anchors = np.array([[0.0, 0.0], [25.0, 0.0], [50.0, 0.0], [0.0, 30.0], [25.0, 30.0],
                        [50.0, 30.0]])
    bias = np.array([1.0, 2.2, 3.4, 4.6, 5.8, 7.0])
    truth = circle(10, 300, rng)
    model = RangeModel(std_m=0.3, anchor_bias=True)
    ctx = Context(points=anchors, index=np.arange(6))
    obs = Observation(model, model.sample({"position": truth[..., :2], "anchor_bias": bias},
                                          ctx, rng), ctx)
    mean, cov = prior(truth, rng)
    t = np.arange(truth.shape[1]) * DT
    ekf = ExtendedKalmanFilter(ConstantVelocity(0.2), gate=None, bias_prior_std_m=5.0)
    assert ekf.state_layout(obs) == StateLayout(dim=2, order=1, n_bias=6)
    tr = ekf.run(obs, t, prior_mean=mean, prior_cov=cov)
    est = tr.diagnostics["state"][:, -1, 4:]
    assert np.all(np.abs(est - bias) < 0.3), est - bias
    # the position is nearly as good as with the biases known and removed
    known = ExtendedKalmanFilter(ConstantVelocity(0.2), gate=None).run(
        Observation(RangeModel(std_m=0.3), obs.z - bias, Context(points=anchors)), t,
        prior_mean=mean, prior_cov=cov)
    burn = 100
    assert rmse(tr.position, truth, burn) < 1.2 * rmse(known.position, truth, burn)
    # ignoring the biases is far worse
    blind = ExtendedKalmanFilter(ConstantVelocity(0.2), gate=None).run(
        Observation(RangeModel(std_m=0.3), obs.z, Context(points=anchors)), t,
        prior_mean=mean, prior_cov=cov)
    assert rmse(blind.position, truth, burn) > 10 * rmse(tr.position, truth, burn)


def test_clock_offset_is_estimated():
    rng = np.random.default_rng(8)
    truth = cv_track(5, 40, rng)
    ctx = Context(points=ANCHORS)
    offset = 37.0
    model = Pseudorange(0.1)
    z = model.sample({"position": truth[..., :2], "clock_offset": np.full(truth.shape[:2], offset)},
                     ctx, rng)
    mean, cov = prior(truth, rng)
    ekf = ExtendedKalmanFilter(ConstantVelocity(0.05), clock_offset_prior_std_m=100.0)
    tr = ekf.run(Observation(model, z, ctx), np.arange(40) * DT, prior_mean=mean, prior_cov=cov)
    # the clock's drift is in the state by default (a constant offset: a drift near 0)
    assert ekf.state_layout(Observation(model, z, ctx)).clock == 2
    assert np.all(np.abs(tr.diagnostics["state"][:, -1, 4] - offset) < 0.5)
    assert np.all(np.abs(tr.diagnostics["state"][:, -1, 5]) < 0.1)
    assert rmse(tr.position, truth, 10) < 0.5


def test_transition_of_the_clock_and_the_biases():
    """Block-diagonal prediction: the motion model's block, the two-state clock
    (offset += drift dt; white frequency noise and a drift random walk) and random-walk
    biases, over a batch of intervals."""
    motion = ConstantVelocity(0.3)
    ekf = ExtendedKalmanFilter(motion, clock_offset_std_m_per_sqrt_s=2.0,
                               clock_drift_std_m_per_s_per_sqrt_s=0.5, bias_std_m_per_sqrt_s=0.1)
    layout = StateLayout(dim=2, order=1, clock=2, n_bias=3)
    dt = np.array([0.1, 2.0])
    F, Q = ekf.transition(layout, dt)
    assert F.shape == Q.shape == (2, 9, 9)
    np.testing.assert_array_equal(F[:, :4, :4], motion.F(dt))
    np.testing.assert_array_equal(Q[:, :4, :4], motion.Q(dt))
    qo, qd = 4.0, 0.25
    for j, d in enumerate(dt):
        np.testing.assert_allclose(F[j, 4:6, 4:6], [[1.0, d], [0.0, 1.0]])
        np.testing.assert_allclose(Q[j, 4:6, 4:6], [[qo * d + qd * d**3 / 3, qd * d**2 / 2],
                                                    [qd * d**2 / 2, qd * d]])
        np.testing.assert_allclose(F[j, 6:, 6:], np.eye(3))
        np.testing.assert_allclose(Q[j, 6:, 6:], 0.01 * d * np.eye(3))
    assert not np.any(F[:, :4, 4:]) and not np.any(Q[:, :4, 4:]) and not np.any(Q[:, 4:6, 6:])


def test_a_bearing_model_with_a_numerical_jacobian_tracks_across_the_wrap():
    """Sensors at the east side see the target pass behind them, where the bearing jumps
    from +pi to -pi: wrapped residuals keep the filter on track."""
    rng = np.random.default_rng(9)
    sensors = np.array([[40.0, 4.0], [40.0, 10.0], [20.0, -10.0]])
    truth = cv_track(20, 60, rng, start=(8.0, 0.0, 0.0, 0.5))
    model = MinimalBearing(0.01)
    obs = ranges(truth, model, rng, anchors=sensors)
    assert np.any(np.abs(np.diff(obs.z[..., 0], axis=-1)) > np.pi)   # the wrap is crossed
    mean, cov = prior(truth, rng)
    tr = ExtendedKalmanFilter(ConstantVelocity(0.05)).run(obs, np.arange(60) * DT,
                                                          prior_mean=mean, prior_cov=cov)
    assert np.all(np.abs(tr.diagnostics["innovation"]) <= np.pi)
    assert tr.diagnostics["gated"].sum() < 0.02 * obs.z.size
    assert rmse(tr.position, truth, 10) < 0.3


def test_several_kinds_in_one_step():
    rng = np.random.default_rng(10)
    truth = cv_track(20, 40, rng)
    rng_obs = ranges(truth, RangeModel(std_m=0.3), rng, anchors=ANCHORS[:2])
    aoa = ranges(truth, MinimalBearing(0.02), rng, anchors=ANCHORS[2:3])
    mean, cov = prior(truth, rng)
    ekf = ExtendedKalmanFilter(ConstantVelocity(0.05))
    both = ekf.run([rng_obs, aoa], np.arange(40) * DT, prior_mean=mean, prior_cov=cov)
    assert both.diagnostics["innovation"].shape == (20, 40, 3)
    assert both.diagnostics["innovation_covariance"].shape == (20, 40, 3, 3)
    assert np.all(both.diagnostics["measurements_used"][:, 1:] == 3)
    only = ekf.run(rng_obs, np.arange(40) * DT, prior_mean=mean, prior_cov=cov)
    assert rmse(both.position, truth, 10) < rmse(only.position, truth, 10)


def test_bad_input_names_the_argument():
    rng = np.random.default_rng(11)
    truth = cv_track(1, 5, rng)[0]
    obs = ranges(truth, RangeModel(std_m=0.1), rng)
    ekf = ExtendedKalmanFilter(ConstantVelocity(0.05))
    good = {"prior_mean": truth[0], "prior_cov": np.eye(4)}
    with pytest.raises(InputError, match=r"observations\[1\]"):
        ekf.run([obs, obs.z], **good)
    bad = obs.z.copy()
    bad[2, 1] = np.inf
    with pytest.raises(InputError, match=r"observations\[0\]\.z"):
        ekf.run(Observation(obs.model, bad, obs.context), **good)
    with pytest.raises(InputError, match="prior_mean"):
        ekf.run(obs, prior_mean=truth[0, :3], prior_cov=np.eye(3))
    with pytest.raises(InputError, match="prior_cov"):
        ekf.run(obs, prior_mean=truth[0], prior_cov=-np.eye(4))
    with pytest.raises(InputError, match="time"):
        ekf.run(obs, np.arange(4.0), **good)
    with pytest.raises(InputError, match="context.index"):
        ekf.run(Observation(RangeModel(std_m=0.1, anchor_bias=True), obs.z, obs.context), **good)
    with pytest.raises(InputError, match="anchor_bias"):   # a layout without the biases
        ekf.update(ekf.init(truth[0], np.eye(4)),
                   Observation(RangeModel(std_m=0.1, anchor_bias=True), obs.z[0],
                               Context(points=ANCHORS, index=np.arange(4))))
    with pytest.raises(ConfigError, match="gate"):
        ExtendedKalmanFilter(ConstantVelocity(0.05), gate=-1.0)
    with pytest.raises(ConfigError, match="iterations"):
        ExtendedKalmanFilter(ConstantVelocity(0.05), iterations=0)
    with pytest.raises(ConfigError, match="motion"):
        ExtendedKalmanFilter(object())
    with pytest.raises(ConfigError, match="layout"):
        ExtendedKalmanFilter(ConstantVelocity(0.05), layout=StateLayout(dim=3, order=1))
