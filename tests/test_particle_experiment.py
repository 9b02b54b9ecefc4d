import dataclasses

import numpy as np

from radioloc.core.rng import block_generator
from radioloc.experiments.base import get_experiment


def test_highway_experiment_smoke(tmp_path):
    exp = get_experiment("p001-highway")
    cfg = dataclasses.replace(exp.config(full=False), steps=6, particles=30, ml_every=3)
    res = exp.run_block(cfg, np.array([0]), block_generator(0, 0))
    summary = exp.summarize(cfg, res, tmp_path)
    names = {m.name: m for m in summary.metrics}
    for a in (5, 15, 30, 45):
        for key in ("pf_mean_error_m_alpha", "ml_mean_error_m_alpha", "pd_alpha"):
            assert np.isfinite(names[f"{key}{a}"].value)
    for m, n in ((26, 20), (26, 24), (26, 30), (30, 20), (36, 20)):
        assert np.isfinite(names[f"pf_mean_error_m_M{m}_N{n}"].value)
    assert "ransac_mean_error_m_alpha30" in names
    assert 0.0 <= names["pd_alpha30"].value <= 1.0
    assert (tmp_path / "fig4a_error_cdf.png").exists() and (tmp_path / "fig4b_trajectories.png").exists()
    assert res.error_m.notna().all()


def test_real_uwb_experiment_smoke(tmp_path, monkeypatch):
    import os
    from pathlib import Path

    import pytest
    root = Path(os.environ.get("RADIOLOC_DATA", "/work/shared/data"))
    if not (root / "hanyang-uwb-outdoor").is_dir():
        pytest.skip("hanyang-uwb-outdoor data set absent")
    monkeypatch.setenv("RADIOLOC_DATA", str(root))
    exp = get_experiment("real-uwb-hanyang")
    cfg = dataclasses.replace(exp.config(full=False), max_epochs=40, particles=50, static_samples=300)
    res = exp.run_block(cfg, np.array([0]), block_generator(0, 0))
    summary = exp.summarize(cfg, res, tmp_path)
    names = {m.name for m in summary.metrics}
    run = res.name.iloc[0]
    for meth in ("pf", "ml", "ransac", "ls", "eskf"):
        assert f"{meth}_rmse_m_{run}" in names
    assert res.error_m.notna().all()
