"""One figure style for every experiment.

Use :func:`figure` to make a figure and :func:`save` to write it with its caption, so that
all reports look alike and stay legible at page width. Figures are
:class:`matplotlib.figure.Figure` objects made without pyplot and written with the Agg
canvas: importing this module does not touch the matplotlib backend (a notebook's backend
stays as it is), and no figure is registered with pyplot, so none needs closing.
"""

from __future__ import annotations

import warnings
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


def figure(nrows: int = 1, ncols: int = 1, *, width: float = 6.4, height: float = 4.0,
           layout: str | None = None, **kw):
    """A new figure and axes in the house style: ``fig, ax = figure()``.

    Parameters
    ----------
    nrows, ncols : int
        Grid of axes, as :meth:`matplotlib.figure.Figure.subplots`.
    width, height : float
        Figure size in inches.
    layout : str, optional
        Matplotlib layout engine, e.g. ``"constrained"`` for a figure legend placed
        ``loc="outside right upper"`` (default: none, :func:`save` lays out tightly).
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
    fig = Figure(figsize=(width, height), layout=layout)
    FigureCanvasAgg(fig)
    ax = fig.subplots(nrows, ncols, **kw)
    return fig, ax


def save(fig, path: Path | str, *, caption: str) -> Path:
    """Write ``fig`` as a PNG and record its caption beside it.

    The figure is laid out tightly (unless it has a layout engine of its own, e.g.
    ``layout="constrained"``) and the PNG holds every artist: a legend placed outside the
    axes (``fig.legend(loc="outside right upper")``, ``bbox_to_anchor``) is kept whole
    rather than clipped at the figure's edge.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : path
    caption : str
        What the figure shows, recorded in ``captions.json`` in the same folder
        (:func:`radioloc.report.captions.record_caption`) and shown under the figure in the
        report.

    Returns
    -------
    Path

    Raises
    ------
    ConfigError
        The caption is empty or repeats the file name.
    """
    from radioloc.report.captions import record_caption

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    record_caption(path, caption)              # refused before any figure is written
    if fig.get_layout_engine() is None:
        with warnings.catch_warnings():     # a legend beside the axes: the crop keeps it
            warnings.filterwarnings("ignore", "Tight layout not applied")
            fig.tight_layout()
    fig.savefig(path, bbox_inches="tight", pad_inches=0.08)
    return path
