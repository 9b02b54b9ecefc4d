"""Smoke test of the p000-urban experiment at a tiny size (own ray-tracing cache)."""

import numpy as np

from radioloc.experiments.p000_urban import UrbanConfig, UrbanRadiolocation, simulate


def test_urban_experiment_smoke(tmp_path):
    cfg = UrbanConfig(runs=4, block_size=4, rounds=3, cache_dir=str(tmp_path / "cache"))
    exp = UrbanRadiolocation()
    scene, pos, r = simulate(cfg)
    assert pos.shape == (6, 2) and not scene.inside(pos).any()
    assert (r.n_paths[np.triu_indices(6, 1)] > 0).all()            # placement guarantees a path
    np.testing.assert_allclose(r.true_m, np.linalg.norm(pos[:, None] - pos[None], axis=-1))
    assert np.all(r.first_path_m[~np.eye(6, dtype=bool)] >= r.true_m[~np.eye(6, dtype=bool)] - 1e-6)
    df = exp.run_block(cfg, np.arange(4), np.random.default_rng(0))
    assert set(df["estimator"]) == {"rls", "ekf"} and df["step"].max() == cfg.rounds
    assert np.isfinite(df["error_m"]).all()
    summary = exp.summarize(cfg, df, tmp_path)
    names = {m.name for m in summary.metrics}
    assert {"rls_final_error_unassisted_m", "ekf_final_error_unassisted_m", "range_error_median_los_m",
            "range_error_median_nlos_m", "gsic_range_rmse_m", "matched_filter_range_rmse_m"} <= names
    for f in ("fig3_map.png", "fig4_error_vs_packet.png", "range_error_hist.png"):
        assert (tmp_path / f).stat().st_size > 0
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 2        # placement + network traces
