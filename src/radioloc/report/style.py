"""One figure style for every experiment.

Use :func:`figure` to make a figure and :func:`save` to write it, so that all reports look
alike and stay legible at page width. Figures are :class:`matplotlib.figure.Figure` objects
made without pyplot and written with the Agg canvas: importing this module does not touch
the matplotlib backend (a notebook's backend stays as it is), and no figure is registered
with pyplot, so none needs closing.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

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
    """A new figure and axes in the house style: ``fig, ax = figure()``.

    Parameters
    ----------
    nrows, ncols : int
        Grid of axes, as :meth:`matplotlib.figure.Figure.subplots`.
    width, height : float
        Figure size in inches.
    **kw
        Passed to :meth:`matplotlib.figure.Figure.subplots` (``squeeze``,
        ``gridspec_kw``, ``sharex``, ...).

    Returns
    -------
    fig : matplotlib.figure.Figure
        A figure with an Agg canvas, not registered with pyplot.
    ax : Axes or array of Axes
    """
    matplotlib.rcParams.update(_RC)
    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    ax = fig.subplots(nrows, ncols, **kw)
    return fig, ax


def save(fig, path: Path | str) -> Path:
    """Write ``fig`` as a PNG (tight layout).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : path

    Returns
    -------
    Path
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path)
    return path
