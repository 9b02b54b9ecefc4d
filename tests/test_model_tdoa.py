"""TDoA measurement model: geometry, correlated noise of differencing, clock drift, CRB."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from estimation_helpers import gauss_newton, rmse_over_bound
from radioloc.bounds.fisher import crb
from radioloc.core.errors import ConfigError, InputError
from radioloc.models.measurement import Context, Observation, StateLayout, numerical_jacobian
from radioloc.models.tdoa import TdoaModel
from radioloc.models.clock import ClockModel
from radioloc.sim.measurements import clock_trajectory, simulate_tdoa

ANCHORS_2D = np.array([[0.0, 0.0], [20.0, 0.0], [0.0, 20.0], [20.0, 20.0], [10.0, -5.0],
                       [-5.0, 10.0]])
ANCHORS_3D = np.array([[0.0, 0.0, 0.0], [20.0, 0.0, 3.0], [0.0, 20.0, 1.0], [20.0, 20.0, 4.0],
                       [10.0, -5.0, 0.5]])
SLOTS_S = 1e-3 * np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])  # transmission slot of each anchor


def ctx_for(anchors, reference=0):
    others = [k for k in range(len(anchors)) if k != reference]
    m = len(others)
    return Context(points=anchors[others], index=np.array(others),
                   reference=np.broadcast_to(anchors[reference], (m, anchors.shape[1])),
                   reference_index=np.full(m, reference))


@pytest.mark.parametrize("anchors", [ANCHORS_2D, ANCHORS_3D], ids=["2d", "3d"])
@pytest.mark.parametrize("drift", [False, True])
def test_jacobian_equals_finite_differences(anchors, drift):
    ctx = ctx_for(anchors)
    model = TdoaModel(std_m=0.1, slot_s=SLOTS_S[:len(anchors)] if drift else None)
    dim = anchors.shape[1]
    layout = StateLayout(dim=dim, order=1).with_model(model)
    rng = np.random.default_rng(3)
    x = layout.join({"position": rng.uniform(2, 18, (7, dim)), "velocity": rng.normal(size=(7, dim)),
                     "clock_offset": rng.normal(size=7), "clock_drift": 300 * rng.normal(size=7)})
    _, H = layout.measure(model, x, ctx)
    numeric = numerical_jacobian(model, layout.split(x), ctx)
    assert set(numeric) == set(model.reads)
    for name, block in numeric.items():
        np.testing.assert_allclose(H[..., layout.slices[name]], block, atol=1e-6, rtol=1e-6)
    unread = [sl for name, sl in layout.slices.items() if name not in model.reads]
    assert all(np.all(H[..., sl] == 0.0) for sl in unread)


def test_jacobian_with_known_height():
    anchors = ANCHORS_3D
    ctx = Context(points=anchors[1:], reference=np.broadcast_to(anchors[0], (4, 3)), height_m=1.5)
    model = TdoaModel(std_m=0.1)
    state = {"position": np.array([[4.0, 7.0], [12.0, 3.0]])}
    H = model.jacobian(state, ctx)["position"]
    np.testing.assert_allclose(H, numerical_jacobian(model, state, ctx)["position"], atol=1e-7)


def test_noise_cov_is_that_of_differenced_arrival_times():
    ctx = ctx_for(ANCHORS_2D)
    R = TdoaModel(std_m=0.3).noise_cov(ctx)
    np.testing.assert_allclose(R, 0.09 * (np.eye(5) + np.ones((5, 5))))
    # two references: rows share the error of their own reference only
    two = Context(points=ANCHORS_2D[[1, 2, 4, 5]], reference=ANCHORS_2D[[0, 0, 3, 3]])
    R2 = TdoaModel(std_m=0.3).noise_cov(two)
    np.testing.assert_allclose(R2, 0.09 * (np.eye(4) + np.kron(np.eye(2), np.ones((2, 2)))))
    # a per-row sigma is the std of that difference; the rows keep correlation 1/2
    sigma = np.array([0.2, np.nan, 0.5, np.nan])
    R3 = TdoaModel(std_m=0.3).noise_cov(replace(two, std=sigma))
    s = np.where(np.isnan(sigma), 0.3 * np.sqrt(2), sigma)
    np.testing.assert_allclose(np.sqrt(np.diag(R3)), s)
    np.testing.assert_allclose(R3[0, 1], 0.5 * s[0] * s[1])
    assert R3[0, 2] == R3[1, 3] == 0.0 and R3[2, 3] == pytest.approx(0.5 * s[2] * s[3])
    assert np.all(np.linalg.eigvalsh(R3) > 0)


def test_simulated_differences_have_the_model_covariance():
    rng = np.random.default_rng(11)
    n = 20000
    pos = np.array([6.0, 9.0])
    obs = simulate_tdoa(np.broadcast_to(pos, (n, 2)), ANCHORS_2D, rng, std_m=0.2, reference=2)
    r = obs.z - obs.model.predict({"position": pos}, obs.context)
    S = np.cov(r, rowvar=False)
    R = obs.model.noise_cov(obs.context)
    # standard error of a sample covariance entry: sqrt((R_ii R_jj + R_ij^2) / n)
    se = np.sqrt((np.outer(np.diag(R), np.diag(R)) + R**2) / n)
    assert np.all(np.abs(S - R) < 4 * se)
    assert np.all(np.abs(r.mean(axis=0)) < 4 * np.sqrt(np.diag(R) / n))
    # the model's own sampler draws the same correlated noise
    z = obs.model.sample({"position": np.broadcast_to(pos, (n, 2))}, obs.context, rng)
    S2 = np.cov(z - obs.model.predict({"position": pos}, obs.context), rowvar=False)
    assert np.all(np.abs(S2 - R) < 4 * se)


def test_logpdf_rows_sum_to_the_joint_density_and_skip_missing_rows():
    ctx = ctx_for(ANCHORS_2D)
    model = TdoaModel(std_m=0.2)
    state = {"position": np.array([[5.0, 5.0], [12.0, 3.0]])}
    rng = np.random.default_rng(2)
    z = model.sample(state, ctx, rng)
    R = model.noise_cov(ctx)
    lp = model.logpdf(z, state, ctx)
    z_hat = model.predict(state, ctx)
    for b in range(2):
        assert lp[b].sum() == pytest.approx(multivariate_normal(z_hat[b], R).logpdf(z[b]), rel=1e-10)
    z_missing = z.copy()
    z_missing[:, 1] = np.nan
    lp = model.logpdf(z_missing, state, ctx)
    keep = [0, 2, 3, 4]
    assert np.all(lp[:, 1] == 0.0)
    for b in range(2):
        marginal = multivariate_normal(z_hat[b, keep], R[np.ix_(keep, keep)])
        assert lp[b].sum() == pytest.approx(marginal.logpdf(z[b, keep]), rel=1e-10)


def test_zero_noise_drift_data_is_fitted_exactly():
    rng = np.random.default_rng(5)
    truth = np.array([7.0, 4.0])
    obs = simulate_tdoa(truth[None], ANCHORS_2D, rng, std_m=1e-12, slot_s=SLOTS_S,
                        drift_m_per_s=np.array([250.0]))
    layout = StateLayout(dim=2).with_model(obs.model)
    x0 = layout.join({"position": truth[None] + 0.5, "clock_drift": np.zeros(1)})
    fit = layout.split(gauss_newton([obs], layout, x0))
    np.testing.assert_allclose(fit["position"], truth[None], atol=1e-4)
    assert fit["clock_drift"][0] == pytest.approx(250.0, abs=0.1)


def test_ml_estimate_with_clock_drift_reaches_the_crb():
    rng = np.random.default_rng(7)
    runs, std = 500, 0.01
    truth = np.array([7.0, 4.0])
    drift = 300.0 + 50.0 * rng.standard_normal(runs)
    obs = simulate_tdoa(np.broadcast_to(truth, (runs, 2)), ANCHORS_2D, rng, std_m=std,
                        slot_s=SLOTS_S, drift_m_per_s=drift)
    layout = StateLayout(dim=2).with_model(obs.model)
    x_true = layout.join({"position": np.broadcast_to(truth, (runs, 2)), "clock_drift": drift})
    x0 = x_true + np.where(np.arange(layout.size) < 2, 0.3, 0.0) * rng.standard_normal(x_true.shape)
    fit = gauss_newton([obs], layout, x0)
    bound = crb(obs.model, x_true[0], obs.context, layout)
    assert bound.components == ("position", "clock_drift")
    ratio = rmse_over_bound(fit, x_true, bound.rmse_m, 2)
    print(f"TDoA with clock drift: RMSE / sqrt(trace CRB) = {ratio:.3f}")
    assert 0.85 < ratio < 1.15, ratio
    drift_err = fit[..., layout.slices["clock_drift"]][:, 0] - drift
    assert np.sqrt(np.mean(drift_err**2)) == pytest.approx(np.sqrt(bound.covariance[2, 2]), rel=0.15)


def test_moving_or_rotating_the_scene_keeps_the_differences():
    ctx = ctx_for(ANCHORS_3D)
    model = TdoaModel(std_m=0.1)
    x = np.array([5.0, 8.0, 1.0])
    base = model.predict({"position": x}, ctx)
    c, s = np.cos(0.7), np.sin(0.7)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    shift = np.array([100.0, -40.0, 2.0])
    moved = ctx_for(ANCHORS_3D @ rot.T + shift)
    np.testing.assert_allclose(model.predict({"position": rot @ x + shift}, moved), base, atol=1e-10)
    # the scene moved but not the tag: the differences change
    assert np.max(np.abs(model.predict({"position": x}, moved) - base)) > 1.0


def test_bad_input_names_the_argument():
    with pytest.raises(ConfigError, match="std_m"):
        TdoaModel(std_m=0.0)
    with pytest.raises(InputError, match="reference"):
        TdoaModel(std_m=0.1).predict({"position": np.zeros(2)}, Context(points=ANCHORS_2D))
    with pytest.raises(InputError, match="context.index"):
        TdoaModel(std_m=0.1, slot_s=np.ones(2)).predict(
            {"position": np.zeros(2), "clock_drift": np.zeros(())}, ctx_for(ANCHORS_2D))
    rng = np.random.default_rng(0)
    with pytest.raises(InputError, match="reference"):
        simulate_tdoa(np.zeros(2), ANCHORS_2D, rng, std_m=0.1, reference=6)
    with pytest.raises(InputError, match="context.reference_index"):
        TdoaModel(std_m=0.1, slot_s=SLOTS_S).predict(
            {"position": np.zeros(2), "clock_drift": np.zeros(())},
            Context(points=ANCHORS_2D[1:], index=np.arange(1, 6), reference=ANCHORS_2D[[0] * 5]))
    with pytest.raises(InputError, match="slot_s"):
        simulate_tdoa(np.zeros(2), ANCHORS_2D, rng, std_m=0.1, slot_s=SLOTS_S[:3])
    with pytest.raises(InputError, match="slot_s"):
        simulate_tdoa(np.zeros(2), ANCHORS_2D, rng, std_m=0.1, drift_m_per_s=np.ones(1))
    with pytest.raises(InputError, match="clock_drift"):
        StateLayout(dim=2).measure(TdoaModel(std_m=0.1, slot_s=SLOTS_S), np.zeros(2),
                                   ctx_for(ANCHORS_2D))
    with pytest.raises(InputError, match="model"):
        Observation(model="tdoa", z=np.zeros(5), context=ctx_for(ANCHORS_2D))


def test_model_explains_a_track_with_a_drifting_clock():
    rng = np.random.default_rng(12)
    steps, dt = 40, 0.1
    t = dt * np.arange(steps)
    track = np.stack([5 + 8 * np.cos(0.3 * t), 6 + 8 * np.sin(0.3 * t)], axis=-1)
    clock = clock_trajectory(ClockModel(offset_std_m=0.5, drift_std_m_per_s=30.0), steps, dt, rng,
                             initial=np.broadcast_to([0.0, 3000.0], (3, 2)))
    obs = simulate_tdoa(np.broadcast_to(track, (3, steps, 2)), ANCHORS_2D, rng, std_m=1e-12,
                        slot_s=SLOTS_S, drift_m_per_s=clock[..., 1])
    assert obs.z.shape == (3, steps, 5)
    layout = StateLayout(dim=2).with_model(obs.model)
    x = layout.join({"position": np.broadcast_to(track, (3, steps, 2)),
                     "clock_offset": clock[..., 0], "clock_drift": clock[..., 1]})
    z_hat, _ = layout.measure(obs.model, x, obs.context)
    # only the scale error of the range difference, (drift / c)(d_i - d_ref), is left out
    assert np.max(np.abs(obs.z - z_hat)) < 1e-3
    without_drift = TdoaModel(std_m=0.1).predict({"position": x[..., :2]}, obs.context)
    assert np.max(np.abs(obs.z - without_drift)) > 1.0
    z_t, ctx_t = obs.at(7)
    np.testing.assert_allclose(z_t, obs.z[:, 7])
    # a subset of rows (what an estimator keeps of a step with missing rows) keeps its
    # intervals, and its noise covariance is the sub-matrix
    rows = np.array([0, 2, 3])
    sub = obs.context.take(rows)
    np.testing.assert_allclose(layout.measure(obs.model, x, sub)[0], z_hat[..., rows])
    np.testing.assert_allclose(obs.model.noise_cov(sub),
                               obs.model.noise_cov(obs.context)[np.ix_(rows, rows)])
