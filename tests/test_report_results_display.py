"""Estimate and Track in notebooks: short repr, HTML repr, plot with uncertainty ellipses."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.collections import EllipseCollection
from matplotlib.figure import Figure

from radioloc.core.errors import InputError
from radioloc.core.results import Estimate, Track


def _track(runs=3, steps=40):
    t = np.arange(steps) * 0.5
    pos = np.stack([np.broadcast_to(t, (runs, steps)) + np.arange(runs)[:, None],
                    np.broadcast_to(np.sin(t), (runs, steps))], -1)
    cov = np.broadcast_to(np.diag([0.04, 0.01]), (runs, steps, 2, 2)).copy()
    return Track(pos, cov, t, {"nis": np.ones((runs, steps))})


def test_repr_is_one_short_line():
    e = Estimate(np.array([1.0, 2.0]), np.eye(2) * 0.02, 3.0,
                 {"converged": np.array(True), "iterations": np.array(4)})
    text = repr(e)
    assert "\n" not in text and len(text) < 160
    assert text.startswith("Estimate(2-D;") and "x=1, y=2 m" in text and "converged 1 of 1" in text
    t = repr(_track())
    assert t.startswith("Track(2-D; batch 3; steps 40") and "nis" in t and len(t) < 200


def test_repr_html_is_a_table():
    html = _track()._repr_html_()
    assert html.startswith("<div><b>Track</b>") and "<table>" in html and "steps" in html
    assert "none (no covariance)" in Estimate(np.zeros((4, 2)))._repr_html_()


def test_track_plot_draws_every_run_and_ellipses():
    fig = Figure()
    ax = fig.subplots()
    out = _track().plot(ax, every=10, label="ekf")
    assert out is ax
    assert len(ax.lines) == 3
    (coll,) = [c for c in ax.collections if isinstance(c, EllipseCollection)]
    assert len(coll.get_offsets()) == 3 * 4                   # steps 0, 10, 20, 30 of 3 runs
    # 95 % ellipse of std (0.2, 0.1): full axes 2 * 2.448 * std
    np.testing.assert_allclose(coll._widths * 2, 2 * 2.4477 * 0.2, rtol=1e-3)
    np.testing.assert_allclose(coll._heights * 2, 2 * 2.4477 * 0.1, rtol=1e-3)
    assert ax.get_legend_handles_labels()[1] == ["ekf"]


def test_estimate_plot_without_covariance_draws_points_only():
    fig = Figure()
    ax = fig.subplots()
    Estimate(np.random.default_rng(1).normal(size=(5, 2))).plot(ax)
    assert len(ax.collections) == 1 and not isinstance(ax.collections[0], EllipseCollection)


def test_plot_rejects_bad_confidence():
    with pytest.raises(InputError, match="confidence"):
        _track().plot(Figure().subplots(), confidence=1.5)
