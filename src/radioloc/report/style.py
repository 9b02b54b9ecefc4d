"""One figure style for every experiment.

Use :func:`figure` to make a figure and :func:`save` to write it; both set the Agg backend
and the house style so that all reports look alike and stay legible at page width.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

#: Colours by role, used consistently across experiments.
COLORS = {
    "ours": "#1f77b4",
    "baseline": "#d62728",
    "bound": "#444444",
    "truth": "#2ca02c",
    "alt": "#ff7f0e",
    "alt2": "#9467bd",
    "alt3": "#8c564b",
}

#: Line styles named in the papers' figures (RLS dashed, EKF solid, bounds dotted).
LINESTYLES = {"rls": "--", "ekf": "-", "bound": ":"}

_RC = {
    "figure.dpi": 110,
    "savefig.dpi": 130,
    "font.size": 10,
    "axes.titlesize": 11,
    "axes.labelsize": 10,
    "legend.fontsize": 9,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "lines.linewidth": 1.6,
}


def figure(nrows: int = 1, ncols: int = 1, *, width: float = 6.4, height: float = 4.0, **kw):
    """A new figure and axes in the house style: ``fig, ax = figure()``."""
    plt.rcParams.update(_RC)
    fig, ax = plt.subplots(nrows, ncols, figsize=(width, height), **kw)
    return fig, ax


def save(fig, path: Path | str) -> Path:
    """Write ``fig`` as a PNG (tight layout) and close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
