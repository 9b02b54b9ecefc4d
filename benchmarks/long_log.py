"""A synthetic long log for the ``radioloc locate`` budgets.

``tags`` tags walk smooth random paths inside a rectangle of ``anchors`` anchors (4 to 8, on
its corners and edge midpoints); each tag ranges to every anchor in an epoch every
``period_s`` seconds (its own phase, so tags never share a time stamp), the ranges of one
epoch sharing its time stamp; ``missing`` of the rows are dropped and ranges carry Gaussian
noise of ``std_m``. One range per row (``time, node, peer, kind, value``).

Run: ``PYTHONPATH=src python benchmarks/long_log.py ROWS OUT_DIR`` writes
``OUT_DIR/measurements.csv`` and ``OUT_DIR/anchors.csv``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

#: Anchor positions (m): corners of a 40 m x 25 m room, then edge midpoints.
ANCHORS = np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 25.0], [0.0, 25.0],
                    [20.0, 0.0], [20.0, 25.0], [0.0, 12.5], [40.0, 12.5]])


def long_log(rows: int, *, tags: int = 10, anchors: int = 6, period_s: float = 0.1,
             missing: float = 0.05, std_m: float = 0.1, seed: int = 0
             ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """A range log of about ``rows`` rows and its anchors table.

    Parameters
    ----------
    rows : int
        Rows wanted (the log has ``rows`` rows, give or take one epoch per tag).
    tags : int
    anchors : int
        4 to 8.
    period_s : float
        Seconds between a tag's epochs.
    missing : float
        Fraction of rows dropped at random.
    std_m : float
        Range noise standard deviation, m.
    seed : int

    Returns
    -------
    measurements : DataFrame
        ``time, node, peer, kind, value``, sorted by time.
    anchors : DataFrame
        ``id, x, y``.
    """
    rng = np.random.default_rng(seed)
    a = ANCHORS[:anchors]
    ids = np.array([f"A{i + 1}" for i in range(anchors)])
    epochs = int(np.ceil(1.02 * rows / (tags * anchors * (1.0 - missing)))) + 1
    # tag positions: a random walk of the velocity, reflected into the room
    t = np.arange(epochs) * period_s + rng.uniform(0, period_s, size=(tags, 1))
    v = np.cumsum(rng.normal(0.0, 0.3 * np.sqrt(period_s), size=(tags, epochs, 2)), axis=1)
    v = 1.2 * np.tanh(v)                                   # walking speeds, m/s
    p = np.cumsum(v * period_s, axis=1) + rng.uniform([5, 5], [35, 20], size=(tags, 1, 2))
    size = np.array([40.0, 25.0])
    p = size - np.abs(size - np.mod(p, 2 * size))         # reflect into [0, size]
    r = np.linalg.norm(p[:, :, None, :] - a, axis=-1) + rng.normal(0, std_m, (tags, epochs, anchors))
    r = np.maximum(r, 0.0)
    keep = rng.random(r.shape) >= missing
    ti, ei, ai = np.nonzero(keep)
    frame = pd.DataFrame({"time": np.round(t[ti, ei], 6), "node": np.array(
        [f"tag{i + 1}" for i in range(tags)])[ti], "peer": ids[ai], "kind": "range",
        "value": np.round(r[ti, ei, ai], 4)})
    frame = frame.sort_values("time", kind="stable").head(rows).reset_index(drop=True)
    return frame, pd.DataFrame({"id": ids, "x": a[:, 0], "y": a[:, 1]})


def write_long_log(rows: int, out: Path, **kwargs) -> tuple[Path, Path]:
    """Write :func:`long_log` to ``out/measurements.csv`` and ``out/anchors.csv``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meas, anchors = long_log(rows, **kwargs)
    meas.to_csv(out / "measurements.csv", index=False)
    anchors.to_csv(out / "anchors.csv", index=False)
    return out / "measurements.csv", out / "anchors.csv"


if __name__ == "__main__":
    print(write_long_log(int(float(sys.argv[1])), Path(sys.argv[2])))
