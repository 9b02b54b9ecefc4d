"""Top-M place weights, settings chosen by spatially grouped cross-validation, and tracking
over the places of the fingerprint model."""

from __future__ import annotations

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators.mixture_localization import MixtureLocalizer
from radioloc.estimators.place_tracking import track_places
from radioloc.models.fingerprint_mixture import FingerprintMixture, place_weights
from radioloc.models.fingerprint_selection import (select_knn_k, select_places_settings,
                                                   spatial_folds)


def _grid_scene(rng, noise=3.0, per=2, step=1.0):
    """Places on a 12 x 12 m grid, 6 stations, log-distance RSS with noise."""
    g = np.arange(0, 12, step)
    xy = np.array([(x, y) for x in g for y in g])
    aps = np.array([[0, 0], [12, 0], [0, 12], [12, 12], [6, -3], [6, 15]], float)
    pos = np.repeat(xy, per, axis=0)

    def rss_at(p, sd):
        d = np.linalg.norm(p[:, None] - aps[None], axis=-1)
        return -40 - 25 * np.log10(np.maximum(d, 0.5)) + rng.normal(0, sd, d.shape)
    return pos, rss_at(pos, noise), rss_at


def test_top_places_keeps_m_places_and_none_keeps_all():
    rng = np.random.default_rng(0)
    pos, rss, _ = _grid_scene(rng)
    model = FingerprintMixture.fit(pos, rss, shrink=1.0)
    ll = model.loglik(rss[:20])
    w, _ = place_weights(model, ll, 2.0, 7)
    assert np.all((w > 0).sum(1) == 7) and np.allclose(w.sum(1), 1)
    full, _ = place_weights(model, ll, 2.0, None)
    np.testing.assert_allclose(full, model.posterior(rss[:20], 2.0), rtol=1e-12)
    # the kept places are the heaviest ones, in the ratio of the full posterior
    top = np.argsort(-full, axis=1)[:, :7]
    kept = np.take_along_axis(full, top, 1)
    np.testing.assert_allclose(np.take_along_axis(w, top, 1), kept / kept.sum(1, keepdims=True))
    loc = MixtureLocalizer(model, 4, temperature=2.0, top_places=7)
    np.testing.assert_allclose(loc.locate(rss[:20]).position, w @ model.positions)
    with pytest.raises(InputError, match="top_places"):
        MixtureLocalizer(model, 4, top_places=0)


def test_spatial_folds_keep_blocks_together():
    rng = np.random.default_rng(1)
    pos = rng.uniform(0, 20, (500, 2))
    fold = spatial_folds(pos, np.zeros((500, 0), int), 4, 5.0, seed=3)
    cell = np.floor(pos / 5.0) @ [1, 100]
    for c in np.unique(cell):
        assert np.unique(fold[cell == c]).size == 1
    assert set(fold) == {0, 1, 2, 3}
    np.testing.assert_array_equal(fold, spatial_folds(pos, np.zeros((500, 0), int), 4, 5.0, 3))


def test_selection_is_the_cv_argmin_and_refuses_bad_settings():
    rng = np.random.default_rng(2)
    pos, rss, _ = _grid_scene(rng)
    s = select_places_settings(pos, rss, temperatures=(1.0, 4.0), top_places=(3, 0),
                               shrinks=(1.0,), folds=3, block_m=4.0)
    assert len(s.table) == 4
    best = s.table.loc[s.table.cv_mean_error_m.idxmin()]
    assert (s.temperature, s.top_places or 0, s.shrink) == (best.temperature, best.top_places,
                                                          best.shrink)
    assert np.all(np.isfinite(s.table.cv_mean_error_m)) and s.table.cv_mean_error_m.min() < 6
    with pytest.raises(ConfigError, match="folds"):
        select_places_settings(pos, rss, folds=1)
    with pytest.raises(ConfigError, match="block_m"):
        select_places_settings(pos, rss, block_m=100.0)
    with pytest.raises(ConfigError, match="block_m"):
        select_places_settings(pos, rss, block_m=0.0)


def test_knn_k_by_the_same_folds_is_the_cv_argmin_and_refuses_bad_settings():
    from sklearn.neighbors import KNeighborsRegressor

    rng = np.random.default_rng(3)
    pos, rss, _ = _grid_scene(rng, noise=6.0)
    k, table = select_knn_k(pos, rss, ks=(1, 5, 20), folds=3, block_m=4.0)
    assert list(table["k"]) == [1, 5, 20] and k == table["k"][table.cv_mean_error_m.idxmin()]
    # known answer of one candidate: the fold-by-fold error of scikit-learn's regressor
    fold = spatial_folds(pos, np.zeros((len(pos), 0), np.int64), 3, 4.0, 0)
    err = 0.0
    for f in range(3):
        tr, te = fold != f, fold == f
        est = KNeighborsRegressor(n_neighbors=5, weights="distance").fit(rss[tr], pos[tr])
        err += np.linalg.norm(est.predict(rss[te]) - pos[te], axis=1).sum()
    assert table.cv_mean_error_m[1] == pytest.approx(err / len(pos), rel=1e-12)
    # noisy readings: one neighbour is worse than several
    assert table.cv_mean_error_m[0] > table.cv_mean_error_m.min()
    with pytest.raises(ConfigError, match="ks"):
        select_knn_k(pos, rss, ks=(0, 3))
    with pytest.raises(ConfigError, match="folds"):
        select_knn_k(pos, rss, folds=1)
    with pytest.raises(InputError, match="rss"):
        select_knn_k(pos, rss[:-1])


def test_tracking_known_answers_and_beats_one_shot_on_a_slow_walk():
    rng = np.random.default_rng(4)
    pos, rss, rss_at = _grid_scene(rng)
    model = FingerprintMixture.fit(pos, rss, shrink=1.0)
    # a slow walk (0.3 m/s, one scan per second) through the area, noisy scans
    t = np.arange(60.0)
    walk = np.c_[2 + 0.3 * t * 0.4, 3 + 0.3 * t * 0.3]
    scans = rss_at(walk, 6.0)
    one = MixtureLocalizer(model, 4, top_places=10).locate(scans).position
    tr = track_places(model, scans, t, 0.5, 1.0, 10)
    e_one = np.linalg.norm(one - walk, axis=1).mean()
    e_tr = np.linalg.norm(tr.position - walk, axis=1).mean()
    assert e_tr < 0.8 * e_one
    # a disk wider than the area: the prediction is uniform, tracking = one-shot
    wide = track_places(model, scans, t, 100.0, 1.0, 10)
    np.testing.assert_allclose(wide.position, one, atol=1e-9)
    # moving the scene moves the track
    moved = track_places(FingerprintMixture.fit(pos + [50.0, -20.0], rss, shrink=1.0), scans, t,
                         0.5, 1.0, 10)
    np.testing.assert_allclose(moved.position, tr.position + [50.0, -20.0], atol=1e-8)
    with pytest.raises(InputError, match="time_s"):
        track_places(model, scans, t[::-1], 0.5)
    with pytest.raises(InputError, match="rss"):
        track_places(model, scans[:, :3], t, 0.5)
