import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import integrate, stats

from radioloc.core.errors import ConfigError, InputError
from radioloc.models.los_nlos import LosNlosRange, StickyLinkChain, emg_logpdf


@settings(max_examples=20, deadline=None)
@given(alpha=st.floats(0.0, 1.0), s_los=st.floats(0.02, 1.0), s_nlos=st.floats(0.5, 10.0))
def test_mixture_density_integrates_to_one(alpha, s_los, s_nlos):
    m = LosNlosRange(s_los, s_nlos, alpha)
    f = lambda x: np.exp(m.logpdf(x, 0.0))
    pts = [-8 * s_los, 0.0, 8 * s_los]
    total = integrate.quad(f, -40 * s_los, 0, points=pts[:2], limit=200)[0] \
        + integrate.quad(f, 0, 8 * s_los, limit=200)[0] \
        + integrate.quad(f, 8 * s_los, 60 * s_nlos + 40 * s_los, limit=200)[0]
    assert total == pytest.approx(1.0, abs=1e-5)


def test_emg_matches_scipy_exponnorm_and_is_finite_in_tails():
    s, mu = 0.05, 5.0
    x = np.linspace(-0.3, 30, 400)
    ref = stats.exponnorm.logpdf(x, mu / s, loc=0.0, scale=s)
    np.testing.assert_allclose(emg_logpdf(x, s, mu), ref, rtol=1e-9, atol=1e-9)
    far = emg_logpdf(np.array([-50.0, -5.0, 1e4]), s, mu)
    assert np.all(np.isfinite(far))
    # far left tail is dominated by the Gaussian: roughly -x^2 / (2 s^2)
    assert far[0] == pytest.approx(-0.5 * (50 / s) ** 2, rel=1e-3)


def test_sampling_matches_density():
    rng = np.random.default_rng(1)
    m = LosNlosRange(0.3, 2.0, 0.4)
    n = 100_000
    los = rng.random(n) < m.alpha
    e = m.sample(np.zeros(n), los, rng)
    hist, edges = np.histogram(e, bins=60, range=(-1.5, 12))
    centres = 0.5 * (edges[1:] + edges[:-1])
    expected = np.exp(m.logpdf(centres, 0.0)) * (edges[1] - edges[0]) * n
    ok = expected > 50
    chi = np.sum((hist[ok] - expected[ok]) ** 2 / expected[ok])
    assert chi / ok.sum() < 3.0


@settings(max_examples=30, deadline=None)
@given(alpha=st.floats(0.01, 0.99))
def test_chain_stationary_distribution(alpha):
    c = StickyLinkChain(alpha)
    P = c.transition
    np.testing.assert_allclose(P.sum(1), 1.0)
    assert P[0, 1] == pytest.approx(alpha / 2)
    np.testing.assert_allclose(c.stationary @ P, c.stationary, atol=1e-12)
    np.testing.assert_allclose(c.stationary, [1 - alpha, alpha])


def test_chain_sample_frequency():
    z = StickyLinkChain(0.3).sample(400, (500,), np.random.default_rng(2))
    assert z.mean() == pytest.approx(0.3, abs=0.02)
    # one-step LOS->NLOS switching frequency
    prev, nxt = z[:-1], z[1:]
    assert (prev & ~nxt).sum() / prev.sum() == pytest.approx(0.35, abs=0.03)


def test_bad_input():
    with pytest.raises(ConfigError, match="alpha"):
        LosNlosRange(alpha=1.5)
    with pytest.raises(ConfigError, match="los_std_m"):
        LosNlosRange(los_std_m=0.0)
    with pytest.raises(InputError, match="los"):
        LosNlosRange().sample(np.zeros(3), np.zeros(2, bool), np.random.default_rng(0))


@pytest.mark.parametrize("alpha", [0.0, 1e-308, 1e-300, 0.3, 1.0 - 1e-16, 1.0])
def test_compiled_mixture_logpdf_equals_the_scipy_form(alpha):
    m = LosNlosRange(0.05, 5.0, alpha)
    e = np.concatenate([np.linspace(-60, 80, 2001), [-1e3, 1e4]])
    lp = m.logpdf_by_state(e, 0.0)
    with np.errstate(divide="ignore"):
        ref = np.logaddexp(lp[..., 0] + np.log1p(-alpha), lp[..., 1] + np.log(alpha))
    np.testing.assert_allclose(m.logpdf(e, 0.0), ref, rtol=1e-10, atol=1e-10)
    # broadcasting of measured against true ranges
    np.testing.assert_allclose(m.logpdf(e[:5, None] + 3.0, np.full((1, 4), 3.0)),
                               np.broadcast_to(ref[:5, None], (5, 4)), rtol=1e-10, atol=1e-10)
