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
        for key in ("pf_mean_error_m_alpha", "ml_mean_error_m_alpha", "ml_local_mean_error_m_alpha",
                    "pd_alpha"):
            assert np.isfinite(names[f"{key}{a}"].value)
    for m, n in ((26, 20), (26, 24), (26, 30), (30, 20), (36, 20)):
        assert np.isfinite(names[f"pf_mean_error_m_M{m}_N{n}"].value)
    assert "ransac_mean_error_m_alpha30" in names
    assert np.isfinite(names["pf_mean_error_m_alpha30_layout_centre"].value)
    assert set(res.layout) == {"staggered", "centre"}
    assert res.x_true.between(0.0, 150.0).all()
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
    cfg = dataclasses.replace(exp.config(full=False), max_time_s=55.0, particles=50,
                              ins_particles=50, static_samples=300)
    res = exp.run_block(cfg, np.array([0]), block_generator(0, 0))
    summary = exp.summarize(cfg, res, tmp_path)
    names = {m.name for m in summary.metrics}
    run = res.name.iloc[0]
    for meth in ("pf", "ekf-track", "pf-ins", "ml", "ransac", "ls", "eskf"):
        assert f"{meth}_rmse2d_{run}" in names
    assert res[["x_est", "y_est", "x_ref", "y_ref"]].notna().all().all()


# ---------------------------------------------------------------- layout, road, local ML
import pytest  # noqa: E402

from radioloc.core.errors import InputError  # noqa: E402
from radioloc.estimators.snapshot_baselines import LocalML  # noqa: E402
from radioloc.models.los_nlos import LosNlosRange  # noqa: E402
from radioloc.sim.highway import HighwayScenario, anchor_coverage, anchor_layout, reflect, trajectories  # noqa: E402


@pytest.mark.parametrize("m", [26, 27, 28, 30, 33, 36])
def test_staggered_layout_covers_every_lane_along_the_whole_road(m):
    sc = HighwayScenario(anchors=m)
    a = anchor_layout("staggered", m, sc.length_m, sc.width_m)
    assert a.shape == (m, 2)
    # every point a vehicle can occupy: y0 in [A + 1, W - A - 1], curve +-A
    lo, hi = 1.0, sc.width_m - 1.0
    x, y = np.meshgrid(np.linspace(0, sc.length_m, 601), np.linspace(lo, hi, 113))
    p = np.stack([x.ravel(), y.ravel()], axis=-1)
    d = np.linalg.norm(p[:, None] - a[None], axis=-1).min(axis=1)
    assert d.max() < sc.radius_m


def test_staggered_layout_rows_9_8_9_for_26_anchors_and_staggered():
    a = anchor_layout("staggered", 26, 150.0, 30.0)
    ys, counts = np.unique(a[:, 1], return_counts=True)
    np.testing.assert_allclose(ys, [5.0, 15.0, 25.0])
    assert counts.tolist() == [9, 8, 9]
    assert np.all((a[:, 0] > 0) & (a[:, 0] < 150.0))
    # the middle row does not sit at the same x as the outer rows
    outer, middle = a[a[:, 1] == 5.0, 0], a[a[:, 1] == 15.0, 0]
    assert np.abs(middle[:, None] - outer[None]).min() > 1.0


def test_default_layout_every_vehicle_step_hears_an_anchor_centre_line_does_not():
    sc = HighwayScenario(start_width_m=20.0)
    cov = anchor_coverage(sc, 5, np.random.default_rng(3))
    assert cov["fraction_no_anchor"] == 0.0 and cov["fraction_vehicles_never_anchored"] == 0.0
    centre = HighwayScenario(start_width_m=20.0, layout="centre")
    assert anchor_coverage(centre, 5, np.random.default_rng(3))["fraction_no_anchor"] > 0.05


def test_vehicles_stay_on_the_road_and_keep_their_speed():
    sc = HighwayScenario(start_width_m=20.0, steps=900)       # long enough to reach the end
    tr = trajectories(sc, 4, np.random.default_rng(5))
    assert np.all((tr[..., 0] >= 0.0) & (tr[..., 0] <= sc.length_m))
    assert np.any(tr[..., -1, 0] < tr[..., -2, 0])            # some have turned round
    dx = np.abs(np.diff(tr[..., 0], axis=-1))
    # |dx| = speed except on the step that hits the end (folded there)
    assert np.mean(np.isclose(dx, sc.speed_m)) > 0.99
    np.testing.assert_allclose(reflect(np.array([-1.0, 10.0, 155.0, 310.0]), 150.0), [1.0, 10.0, 145.0, 10.0])


def test_local_ml_search_finds_the_global_optimum_near_its_centre_and_validates():
    rng = np.random.default_rng(2)
    model = LosNlosRange(0.05, 5.0, 0.9)
    anchors = np.array([[0.0, 0.0], [8.0, 0.0], [0.0, 8.0], [8.0, 8.0], [4.0, -3.0]])
    x = rng.uniform(1, 7, (6, 2))
    d = np.linalg.norm(x[:, None] - anchors[None], axis=-1) + 0.01 * rng.standard_normal((6, 5))
    glob = LocalML(model, 10.0).locate(d, anchors)
    loc = LocalML(model, 10.0, search_radius_m=1.0).locate(d, anchors, search_centre=x + 0.3)
    np.testing.assert_allclose(loc.position, glob.position, atol=0.03)
    np.testing.assert_allclose(loc.position, x, atol=0.1)
    # a centre far away: the local search cannot reach the optimum
    far = LocalML(model, 10.0, search_radius_m=1.0).locate(d, anchors, search_centre=x + 5.0)
    assert np.all(np.linalg.norm(far.position - x, axis=-1) > 2.0)
    with pytest.raises(InputError, match="search_centre"):
        LocalML(model, 10.0, search_radius_m=1.0).locate(d, anchors)
    with pytest.raises(InputError, match="search_centre"):
        LocalML(model, 10.0).locate(d, anchors, search_centre=x)
