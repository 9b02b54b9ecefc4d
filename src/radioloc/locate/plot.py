"""``radioloc locate --plot FILE.png|html``: anchors, tracks and their uncertainty.

Left panel: the anchors (triangles), each node's track with its 95 % uncertainty ellipses at
about twenty steps (where the method gives a covariance), rows with a gated range (crosses)
or an NLOS probability above one half (circles), and the reference trajectory (dashed) with
``--reference``. Right panel, with ``--reference``: each node's error against time.
Drawn with matplotlib's Agg backend (no display needed); PNG, SVG and PDF by the suffix, or
an HTML page (:mod:`radioloc.locate.plot_html`: the figure as inline SVG beside the run
summary, the reference errors and a section per node). In an SVG each node's track is the
element ``id="track-K"`` (K: the node's place in the table).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from radioloc.core.errors import ConfigError
from radioloc.core.results import Track
from radioloc.locate.table import covariance_of

#: Formats ``--plot`` writes (by suffix).
PLOT_SUFFIXES = (".png", ".svg", ".pdf", ".html")


def check_plot_path(path: Path) -> None:
    """Refuse a ``--plot`` target whose format is not drawn, before any work is done.

    Raises
    ------
    ConfigError
        The suffix is not one of :data:`PLOT_SUFFIXES`.
    """
    if Path(path).suffix.lower() not in PLOT_SUFFIXES:
        raise ConfigError(f"--plot {path}: the figure is written as "
                          f"{', '.join(s.lstrip('.').upper() for s in PLOT_SUFFIXES)} (by the "
                          "suffix)")


def node_tracks(frame: pd.DataFrame) -> dict[str, Track]:
    """One :class:`Track` per node of a ``locate`` output table (positions, covariance).

    Parameters
    ----------
    frame : DataFrame

    Returns
    -------
    dict of str to Track
    """
    dims = ["x", "y"] + (["z"] if "z" in frame else [])
    cov = covariance_of(frame)
    out = {}
    for node, idx in frame.groupby("node", sort=False).indices.items():
        out[str(node)] = Track(frame[dims].to_numpy(float)[idx],
                               None if cov is None else cov[idx],
                               frame["time"].to_numpy(float)[idx])
    return out


def locate_figure(frame: pd.DataFrame, *, anchors: pd.DataFrame | None = None,
                  reference: pd.DataFrame | None = None, errors: pd.DataFrame | None = None,
                  title: str = ""):
    """The figure of a ``locate`` output (see the module docstring).

    Parameters
    ----------
    frame : DataFrame
        A ``locate`` output table.
    anchors : DataFrame, optional
    reference : DataFrame, optional
        From :func:`radioloc.io.read_reference`.
    errors : DataFrame, optional
        From :func:`radioloc.locate.scoring.reference_errors`.
    title : str

    Returns
    -------
    matplotlib.figure.Figure
        With an Agg canvas, not registered with pyplot.
    """
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    panels = 2 if errors is not None else 1
    fig = Figure(figsize=(6.5 * panels, 5.5), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, panels, squeeze=False)[0]
    ax = axes[0]
    colors = matplotlib.colormaps["tab10"].colors
    tracks = node_tracks(frame)
    for k, (node, track) in enumerate(tracks.items()):
        c = colors[k % len(colors)]
        track.plot(ax, every=max(1, track.steps // 20), color=c, label=node, lw=1.2,
                   gid=f"track-{k}")
        rows = frame[frame["node"] == node]
        if "gated" in rows and (rows["gated"] > 0).any():
            g = rows[rows["gated"] > 0]
            ax.scatter(g["x"], g["y"], marker="x", color=c, s=30, zorder=3,
                       label=f"{node}: gated range ({len(g)})")
        if "p_nlos" in rows and (rows["p_nlos"] > 0.5).any():
            g = rows[rows["p_nlos"] > 0.5]
            ax.scatter(g["x"], g["y"], marker="o", facecolors="none", edgecolors=c, s=40,
                       zorder=3, label=f"{node}: NLOS probability > 0.5 ({len(g)})")
        if reference is not None:
            ref = reference if "node" not in reference else reference[reference["node"] == node]
            if not ref.empty and (k == 0 or "node" in reference):
                ax.plot(ref["x"], ref["y"], ls="--", lw=0.8, color="0.3" if "node" not in
                        reference else c, label="reference" if "node" not in reference
                        else f"{node}: reference")
    if anchors is not None:
        ax.scatter(anchors["x"], anchors["y"], marker="^", s=70, color="k", zorder=4,
                   label="anchors")
        for aid, x, y in zip(anchors["id"], anchors["x"], anchors["y"]):
            ax.annotate(str(aid), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8)
    ax.set_aspect("equal", adjustable="datalim")
    has_cov = covariance_of(frame) is not None
    ax.set_title(title + (" (ellipses: 95 %)" if has_cov else ""), fontsize=10)
    ax.legend(fontsize=7, loc="best")
    ax.grid(alpha=0.3)
    if errors is not None:
        ex = axes[1]
        for k, (node, g) in enumerate(errors.groupby("node", sort=False)):
            ex.plot(g["time"], g["error_m"], color=colors[k % len(colors)], lw=1.0,
                    label=str(node))
        ex.set_xlabel("time (s)")
        ex.set_ylabel("position error (m)")
        ex.set_title("error against the reference", fontsize=10)
        ex.set_ylim(bottom=0)
        ex.grid(alpha=0.3)
        ex.legend(fontsize=7)
    return fig


def plot_locate(frame: pd.DataFrame, path: Path, *, anchors: pd.DataFrame | None = None,
                reference: pd.DataFrame | None = None, errors: pd.DataFrame | None = None,
                title: str = "", summary: dict | None = None) -> Path:
    """Draw a ``locate`` output (see the module docstring) to ``path``.

    Parameters
    ----------
    frame : DataFrame
        A ``locate`` output table.
    path : Path
        Figure file (suffix in :data:`PLOT_SUFFIXES`).
    anchors, reference, errors, title
        As :func:`locate_figure`.
    summary : dict, optional
        The run summary (``summary.json``) shown by an ``.html`` page; default: the
        method's summary in ``frame.attrs["summary"]``.

    Returns
    -------
    Path
    """
    check_plot_path(path)
    from radioloc.core.atomic import atomic_write_text, atomic_write_with

    fig = locate_figure(frame, anchors=anchors, reference=reference, errors=errors,
                        title=title)
    fmt = Path(path).suffix.lower().lstrip(".")
    if fmt == "html":
        from radioloc.locate.plot_html import locate_page

        return atomic_write_text(path, locate_page(frame, fig, summary=summary, errors=errors,
                                                   title=title))
    atomic_write_with(path, lambda f: fig.savefig(f, format=fmt, dpi=120), binary=True)
    return Path(path)
