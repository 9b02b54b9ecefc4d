"""Gold codes, ACK synthesis, OMP-SIC vs matched filter (compiled kernels against the NumPy
reference), network ranging with a missing link."""

import numpy as np
import pytest
from shapely.geometry import box

from radioloc.channel.cdma import CDMAConfig, gold_codes, received_acks
from radioloc.channel.gsic import GSICConfig, OMPSICConfig, gsic_toa, matched_filter_toa, omp_sic_toa
from radioloc.channel.ranging import network_ranges
from radioloc.channel.raytrace import C_LIGHT, TraceConfig
from radioloc.channel.scene import Scene
from radioloc.core.errors import ConfigError, InputError

CFG = CDMAConfig(turnaround_jitter_s=0.0)
CODES = gold_codes(CFG.code_degree)


@pytest.mark.parametrize("degree", [5, 7])
def test_gold_codes_three_valued_cross_correlation(degree):
    g = gold_codes(degree)
    n = 2**degree - 1
    assert g.shape == (n + 2, n)
    F = np.fft.fft(g[:8], axis=1)
    cc = np.round(np.fft.ifft(F[:, None] * np.conj(F[None]), axis=2).real).astype(int)
    t = 1 + 2 ** ((degree + 2) // 2)
    off = cc[~np.eye(8, dtype=bool)]
    assert set(np.unique(off)) <= {-1, -t, t - 2}
    assert np.all(cc[np.arange(8), np.arange(8), 0] == n)


def _users(rng, B, U, amp):
    d = rng.uniform(0.5e-6, 12e-6, (B, U, 1))
    g = amp[None, :, None] * np.exp(2j * np.pi * rng.random((B, U, 1)))
    ci = np.tile(np.arange(U), (B, 1))
    return d, g, ci


def test_gsic_recovers_five_users_within_quarter_chip_at_high_snr():
    rng = np.random.default_rng(1)
    amp = np.full(5, 10 * np.sqrt(CFG.noise_var / CFG.tx_power_w))      # +20 dB per sample
    d, g, ci = _users(rng, 20, 5, amp)
    y = received_acks(d, g, ci, CFG, rng, CODES)
    r = gsic_toa(y, ci, CODES, CFG)
    assert r.detected.all()
    np.testing.assert_array_less(np.abs(r.toa_s - d[..., 0]), 0.25 * CFG.chip_s)


def test_near_far_cancellation_beats_matched_filter():
    rng = np.random.default_rng(2)
    s = np.sqrt(CFG.noise_var / CFG.tx_power_w)
    amp = np.array([3000.0, 0.5, 0.5, 0.5, 0.5]) * s                  # one user 75 dB above the rest
    d, g, ci = _users(rng, 40, 5, amp)
    y = received_acks(d, g, ci, CFG, rng, CODES)
    gs = gsic_toa(y, ci, CODES, CFG)
    mf = matched_filter_toa(y, ci, CODES, CFG)
    ok_g = np.abs(gs.toa_s - d[..., 0])[:, 1:] < 0.25 * CFG.chip_s
    ok_m = np.abs(mf.toa_s - d[..., 0])[:, 1:] < 0.25 * CFG.chip_s
    assert ok_g.mean() > 0.8
    assert ok_g.mean() > ok_m.mean() + 0.5
    # the strong user is found by both
    assert np.all(np.abs(gs.toa_s[:, 0] - d[:, 0, 0]) < 0.25 * CFG.chip_s)


def test_first_arrival_not_strongest_path():
    rng = np.random.default_rng(3)
    s = np.sqrt(CFG.noise_var / CFG.tx_power_w)
    B = 10
    d = np.tile([[[2.0e-6, 2.6e-6]]], (B, 1, 1))                        # weak early, strong late
    g = np.tile([[[1.0 * s, 20.0 * s]]], (B, 1, 1)).astype(complex)
    ci = np.zeros((B, 1), int)
    y = received_acks(d, g, ci, CFG, rng, CODES)
    r = gsic_toa(y, ci, CODES, CFG)
    np.testing.assert_array_less(np.abs(r.toa_s[:, 0] - 2.0e-6), 0.25 * CFG.chip_s)


def test_noise_only_rarely_detects():
    rng = np.random.default_rng(4)
    B, U = 40, 3
    d = np.full((B, U, 1), np.nan)
    g = np.zeros((B, U, 1), complex)
    ci = np.tile(np.arange(U), (B, 1))
    y = received_acks(d, g, ci, CFG, rng, CODES)
    assert gsic_toa(y, ci, CODES, CFG).detected.mean() < 0.1
    assert np.isnan(matched_filter_toa(y, ci, CODES, CFG).toa_s).mean() > 0.9


def test_bad_input():
    rng = np.random.default_rng(0)
    with pytest.raises(InputError, match="y"):
        gsic_toa(np.zeros((2, 10)), np.zeros((2, 1), int), CODES, CFG)
    with pytest.raises(InputError, match="code_idx"):
        received_acks(np.zeros((1, 2, 1)), np.zeros((1, 2, 1)), np.zeros((1, 3), int), CFG, rng)
    with pytest.raises(InputError, match="delays"):
        received_acks(-np.ones((1, 1, 1)), np.ones((1, 1, 1)), np.zeros((1, 1), int), CFG, rng)
    with pytest.raises(ConfigError, match="code_degree"):
        gold_codes(8)
    with pytest.raises(ConfigError, match="samples_per_chip"):
        CDMAConfig(samples_per_chip=0)
    with pytest.raises(ConfigError, match="false_alarm"):
        GSICConfig(false_alarm=2.0)


def test_network_ranges_reports_unreachable_pair(tmp_path):
    # node 2 sits in a closed courtyard: no path to anyone; nodes 0 and 1 see each other
    walls = [box(-60, -60, 60, -50), box(-60, 50, 60, 60), box(-60, -50, -50, 50), box(50, -50, 60, 50)]
    scene = Scene.from_polygons(walls)
    pos = np.array([[-150.0, 100.0], [150.0, 100.0], [0.0, 0.0]])
    rng = np.random.default_rng(5)
    r = network_ranges(scene, pos, 4, rng, trace=TraceConfig(max_order=2), cdma=CFG,
                       cache_dir=tmp_path)
    assert r.n_paths[0, 2] == 0 and r.n_paths[1, 2] == 0 and r.los[0, 1]
    assert r.sic_m.shape == (4, 3, 3)
    assert np.isnan(r.sic_m[:, :, 2]).mean() > 0.8 and np.isnan(r.sic_m[:, 2, :]).mean() > 0.8
    np.testing.assert_array_less(np.abs(r.sic_m[:, 0, 1] - 300.0), 0.25 * CFG.chip_s * C_LIGHT / 2 + 1.0)


from hypothesis import given, settings, strategies as st  # noqa: E402


@settings(max_examples=20, deadline=None)
@given(st.floats(0.1e-6, 14e-6), st.integers(0, 20))
def test_single_user_high_snr_delay_within_half_cell(tau, code):
    rng = np.random.default_rng(code)
    s = np.sqrt(CFG.noise_var / CFG.tx_power_w)
    y = received_acks(np.full((1, 1, 1), tau), np.full((1, 1, 1), 30 * s + 0j),
                      np.array([[code]]), CFG, rng, CODES)
    for est in (gsic_toa, matched_filter_toa):
        r = est(y, np.array([[code]]), CODES, CFG)
        assert r.detected[0, 0]
        assert abs(r.toa_s[0, 0] - tau) <= 0.5 * CFG.sample_s + 1e-12


@pytest.mark.parametrize("cfg, noise_var", [
    (OMPSICConfig(), None),
    (OMPSICConfig(), "true"),
    (OMPSICConfig(joint_refit=False, iterations=2), None),
    (OMPSICConfig(iterations=1, max_taps=4), None),
    (OMPSICConfig(early_relative=0.05, first_sweep_taps=2), None),
])
def test_compiled_kernels_equal_numpy_reference_on_random_ack_sets(cfg, noise_var):
    rng = np.random.default_rng(11)
    B, U, P = 24, 5, 3
    s = np.sqrt(CFG.noise_var / CFG.tx_power_w)
    d = rng.uniform(0.2e-6, 14e-6, (B, U, P))
    g = s * 10 ** rng.uniform(-0.5, 3, (B, U, P)) * np.exp(2j * np.pi * rng.random((B, U, P)))
    g[rng.random((B, U, P)) < 0.2] = 0.0                              # some absent paths
    ci = np.stack([rng.choice(40, U, replace=False) for _ in range(B)])
    y = received_acks(d, g, ci, CFG, rng, CODES)
    nv = CFG.noise_var if noise_var == "true" else None
    for fast, ref in ((omp_sic_toa(y, ci, CODES, CFG, cfg, nv),
                       omp_sic_toa(y, ci, CODES, CFG, cfg, nv, backend="numpy")),
                      (matched_filter_toa(y, ci, CODES, CFG, cfg),
                       matched_filter_toa(y, ci, CODES, CFG, cfg, backend="numpy"))):
        np.testing.assert_array_equal(fast.taps != 0, ref.taps != 0)      # same detections
        np.testing.assert_allclose(fast.taps, ref.taps, rtol=1e-8, atol=1e-9 * np.abs(ref.taps).max())
        np.testing.assert_array_equal(fast.toa_s, ref.toa_s)
        assert ref.detected.mean() > 0.5


def test_old_names_are_aliases_and_backend_checked():
    assert gsic_toa is omp_sic_toa and GSICConfig is OMPSICConfig
    y = np.zeros((1, CFG.n_samples), complex)
    with pytest.raises(ConfigError, match="backend"):
        omp_sic_toa(y, np.zeros((1, 1), int), CODES, CFG, backend="fortran")


def test_responders_detect_the_rts_with_the_same_detector(tmp_path):
    # LOS pair at high SNR: the detected RTS is within half a delay cell of the first path;
    # the ideal variant has no RTS error
    scene = Scene.from_polygons([box(-60, 50, 60, 60)])
    pos = np.array([[-150.0, 0.0], [150.0, 0.0]])
    common = dict(trace=TraceConfig(max_order=1), cache_dir=tmp_path)
    det = network_ranges(scene, pos, 6, np.random.default_rng(2), cdma=CFG, **common)
    ideal = network_ranges(scene, pos, 6, np.random.default_rng(2),
                           cdma=CDMAConfig(turnaround_jitter_s=0.0, rts_sync="ideal"), **common)
    off = ~np.eye(2, dtype=bool)
    assert np.all(np.abs(det.rts_error_m[:, off]) <= 0.5 * CFG.sample_s * C_LIGHT + 1e-6)
    assert np.any(det.rts_error_m[:, off] != 0)
    assert np.all(ideal.rts_error_m[:, off] == 0)
    for r in (det, ideal):
        np.testing.assert_array_less(np.abs(r.sic_m[:, off] - 300.0), 0.5 * CFG.sample_s * C_LIGHT + 1.0)
    with pytest.raises(ConfigError, match="rts_sync"):
        CDMAConfig(rts_sync="perfect")


def test_received_acks_numba_equals_numpy_definition():
    rng = np.random.default_rng(5)
    B, U, P = 4, 3, 5
    d = rng.uniform(0, 0.6 * CFG.window_s, (B, U, P))
    d[0, 1, 2] = np.nan                                           # an absent path
    d[1, 0, 0] = 7 * CFG.sample_s                                 # exactly on a sample
    g = rng.normal(size=(B, U, P)) + 1j * rng.normal(size=(B, U, P))
    ci = rng.integers(0, len(CODES), (B, U))
    fast = received_acks(d, g, ci, CFG, np.random.default_rng(1), CODES)
    ref = received_acks(d, g, ci, CFG, np.random.default_rng(1), CODES, backend="numpy")
    np.testing.assert_allclose(fast, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
