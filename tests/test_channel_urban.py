"""Smoke test of the p000-urban experiment at a tiny size (own ray-tracing cache)."""

import numpy as np

from radioloc.core.rng import block_generator
from radioloc.experiments.p000_urban import UrbanConfig, UrbanRadiolocation, simulate
from radioloc.sim.urban import ack_set_ranges


def test_urban_experiment_smoke(tmp_path):
    cfg = UrbanConfig(runs=4, block_size=4, rounds=3, scenarios=2, cache_dir=str(tmp_path / "cache"))
    exp = UrbanRadiolocation()
    net = simulate(cfg, 0)
    scene, pos, r = net.scene, net.positions, net.ranges
    assert pos.shape == (6, 2) and not scene.inside(pos).any()
    np.testing.assert_allclose(r.true_m, np.linalg.norm(pos[:, None] - pos[None], axis=-1))
    off = ~np.eye(6, dtype=bool)
    heard = r.n_paths[off] > 0                                         # no placement requirement
    assert np.all(r.first_path_m[off][heard] >= r.true_m[off][heard] - 1e-6)
    assert np.isnan(r.first_path_m[off][~heard]).all() and np.isnan(r.sic_m[:, off][:, ~heard]).all()
    df = exp.run_block(cfg, np.arange(4), block_generator(0, 0))
    runs = df[df["table"] == "runs"]
    # the paper's estimators, and the same two on the controls' ranges (unbiased, first path)
    assert {"rls", "ekf"} <= set(runs["estimator"]) and runs["step"].max() == cfg.rounds
    assert set(runs["estimator"]) <= {f"{e}{c}" for e in ("rls", "ekf")
                                      for c in ("", "_unbiased", "_first_path")}
    assert np.isfinite(runs[runs["estimator"] == "ekf"]["error_m"]).all()
    assert set(runs["scenario"]) == {0, 1}                           # run r uses placement r % 2
    final = df[df["table"] == "final"]
    ests = set(runs["estimator"])
    assert len(final) == len(ests) * 4 * 6 and np.isfinite(final[final["estimator"] == "ekf"]["error_m"]).all()
    # the scenario rows are the simulated network's
    nodes = df[(df["table"] == "nodes") & (df["scenario"] == 0)].sort_values("node")
    np.testing.assert_allclose(nodes[["x", "y"]].to_numpy(float), pos)
    assert (df["table"] == "ranges").sum() == 2 * cfg.rounds * 30 * cfg.scenarios
    summary = exp.summarize(cfg, df, tmp_path)
    names = {m.name for m in summary.metrics}
    assert {"rls_final_error_unassisted_m", "ekf_final_error_unassisted_m", "range_error_median_los_m",
            "range_error_median_nlos_m", "sic_range_rmse_m", "matched_filter_range_rmse_m",
            "nlos_link_share", "first_path_excess_median_nlos_m", "rts_detection_rate",
            "rls_unassisted_error_vs_nlos_share_spearman"} <= names
    for f in ("fig3_map.png", "fig4_error_vs_packet.png", "range_error_hist.png", "error_vs_nlos.png"):
        assert (tmp_path / f).stat().st_size > 0
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 2        # one network trace per placement
    # another block of the same experiment sees the same scenario; another seed another one
    assert simulate(cfg, 0) is net
    assert not np.allclose(simulate(cfg, 0, 1).positions, pos)
    assert not np.allclose(simulate(UrbanConfig(cache_dir=cfg.cache_dir, rounds=3), 1).positions, pos)


def test_ack_set_ranges_drop_masters_with_too_few_ranges():
    S, K = 2, 4
    ranges = np.arange(S * K * K, dtype=float).reshape(S, K, K) + 1.0
    ranges[1, 2, [0, 1]] = np.nan                      # master 2 hears only node 3 in set 1
    order = np.array([[[1, 0], [0, 1], [1, 0], [0, 1]]])
    out = ack_set_ranges(ranges, order, min_ranges=2)
    assert out.shape == (1, S, K, K)
    assert np.isnan(out[0, :, np.arange(K), np.arange(K)]).all()
    np.testing.assert_array_equal(out[0, 0, 0, 1:], ranges[1, 0, 1:])     # master 0: set 1 first
    np.testing.assert_array_equal(out[0, 1, 1, [0, 2, 3]], ranges[1, 1, [0, 2, 3]])
    assert np.isnan(out[0, 0, 2]).all()                # master 2's set 1 has one range: no packet
    np.testing.assert_array_equal(out[0, 1, 2, [0, 1, 3]], ranges[0, 2, [0, 1, 3]])


def test_urban_config_selects_the_channel_provider():
    from radioloc.channel.raytrace import TraceConfig
    from radioloc.channel.sionna_rt import SionnaConfig
    from radioloc.core.errors import ConfigError
    import pytest

    assert isinstance(UrbanConfig().channel, TraceConfig)
    assert isinstance(UrbanConfig(provider="sionna").channel, SionnaConfig)
    with pytest.raises(ConfigError, match="provider"):
        UrbanConfig(provider="wireless-insite")
    with pytest.raises(ConfigError, match="scenarios"):
        UrbanConfig(scenarios=0)


def test_a_run_whose_estimator_fails_gets_nan_and_the_others_keep_their_numbers():
    from types import SimpleNamespace

    from radioloc.core.errors import GeometryError
    from radioloc.experiments.p000_urban import positions_or_nan

    class Fails:                                       # fails on any batch holding run 2
        def run(self, rho, prior, prior_var):
            bad = np.flatnonzero(rho[:, 0, 0, 0] == 2.0)
            if bad.size:
                raise GeometryError("singular", index=(int(bad[0]),))
            return SimpleNamespace(position=np.repeat(prior[:, :, None], rho.shape[1], axis=2) + 1.0)

    R, S, K = 5, 3, 4
    rho = np.broadcast_to(np.arange(R, dtype=float)[:, None, None, None], (R, S, K, K)).copy()
    prior = np.random.default_rng(0).normal(size=(R, K, 2))
    out = positions_or_nan(Fails(), rho, prior, np.ones((R, K, 2)))
    assert np.isnan(out[2]).all()
    keep = np.arange(R) != 2
    np.testing.assert_array_equal(out[keep], np.repeat(prior[keep][:, :, None], S, axis=2) + 1.0)
