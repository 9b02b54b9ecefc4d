"""``radioloc calibrate``: anchors' positions and range biases from a log's own ranges.

Input: the anchors CSV with an optional ``std_m`` column (the prior standard deviation of a
roughly known anchor's position per axis, metres; empty or 0: surveyed, held fixed) and a
measurements CSV of ``range`` rows: anchor-to-anchor ranges (``node`` and ``peer`` both
anchors) and/or a tag's ranges as it moves (``node`` a tag, ``peer`` an anchor; every
``(node, time)`` is one unknown tag position). With several tags, they share one range bias.

Output: the anchors table with the estimated ``x, y[, z]``, the posterior covariance
(``cov_xx, cov_xy, cov_yy[, cov_xz, cov_yz, cov_zz]``), the Cramer-Rao bound beside it
(``crb_std_m``, the square root of its trace), and, with ``bias=True``, each anchor's
``bias_m`` and ``bias_std_m``. ``radioloc locate`` reads that file as an anchors file and
subtracts ``bias_m`` from every range to that anchor.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.core.errors import InputError
from radioloc.estimators.anchor_calibration import AnchorCalibration, calibrate_anchors

__all__ = ["calibrate_log", "calibration_table", "MISFIT_RATIO"]

#: With the linear loss, a solution whose range residual rms exceeds this many ``std_m`` is
#: refused: Gaussian ranges of that standard deviation give an rms near ``std_m`` (above
#: 3 ``std_m`` with a negligible probability), while a unit slip, biased ranges calibrated
#: without a bias, or a wrong anchor give a fit that is confidently wrong.
MISFIT_RATIO = 3.0


def _prior_std(anchors: pd.DataFrame) -> np.ndarray:
    if "std_m" not in anchors.columns:
        raise InputError("anchors: calibration needs a 'std_m' column (prior standard deviation "
                         "of each rough anchor, m; empty or 0 for a surveyed one)")
    std = np.nan_to_num(anchors["std_m"].to_numpy(dtype=float), nan=0.0)
    if not (std > 0).any():
        raise InputError("anchors: every anchor is surveyed (std_m empty or 0): nothing to "
                         "calibrate")
    return std


def calibrate_log(measurements: pd.DataFrame, anchors: pd.DataFrame, *, std_m: float = 0.1,
                  bias: bool = False, bias_prior_std_m: float = 1.0,
                  loss: str = "linear") -> tuple[AnchorCalibration, dict]:
    """Calibrate the anchors of a log.

    Parameters
    ----------
    measurements : DataFrame
        As read by :func:`radioloc.io.logs.read_measurements` (without the anchors check).
    anchors : DataFrame
        As read by :func:`radioloc.io.logs.read_anchors`, with the raw ``std_m`` column.
    std_m, bias, bias_prior_std_m, loss
        See :func:`radioloc.estimators.anchor_calibration.calibrate_anchors`.

    Returns
    -------
    AnchorCalibration
    dict
        Counts: ``anchor_ranges``, ``tag_ranges``, ``tag_epochs``, ``rough_anchors``.
    """
    dims = ["x", "y"] + (["z"] if "z" in anchors.columns else [])
    ids = anchors["id"].tolist()
    index = {a: i for i, a in enumerate(ids)}
    rows = measurements[measurements["kind"] == "range"]
    other = measurements[measurements["kind"] != "range"]
    if len(other):
        raise InputError(f"calibrate: uses only 'range' rows; the measurements hold {len(other)} "
                         f"{other['kind'].iloc[0]!r} row(s) (first at line {int(other['line'].iloc[0])})")
    peer_ok = rows["peer"].isin(index)
    if not peer_ok.all():
        i = int(np.flatnonzero(~peer_ok.to_numpy())[0])
        raise InputError(f"calibrate: line {int(rows['line'].iloc[i])}: peer "
                         f"{rows['peer'].iloc[i]!r} is not an anchor")
    between = rows["node"].isin(index).to_numpy()
    aa = rows[between]
    tag = rows[~between]
    anchor_ranges = np.column_stack([aa["node"].map(index), aa["peer"].map(index), aa["value"]]) \
        if len(aa) else None
    tag_ranges = None
    epochs = 0
    if len(tag):
        key = pd.MultiIndex.from_frame(tag[["node", "time"]])
        codes, uniq = pd.factorize(key)
        epochs = len(uniq)
        tag_ranges = np.column_stack([codes, tag["peer"].map(index), tag["value"]])
    prior_std = _prior_std(anchors)
    result = calibrate_anchors(anchors[dims].to_numpy(dtype=float), prior_std,
                               anchor_ranges=anchor_ranges, tag_ranges=tag_ranges, std_m=std_m,
                               estimate_bias=bias, bias_prior_std_m=bias_prior_std_m, loss=loss)
    if loss == "linear" and result.residual_rms_m > MISFIT_RATIO * std_m:
        raise InputError(
            f"calibrate: the ranges do not fit the anchors: the range residual rms at the "
            f"solution is {result.residual_rms_m:.3g} m, {result.residual_rms_m / std_m:.3g} "
            f"times --std-m ({std_m:g} m); ranges or anchors in another unit, biased ranges "
            "without --bias, outliers (give a robust --loss) or a --std-m too small")
    return result, {"anchor_ranges": int(len(aa)), "tag_ranges": int(len(tag)),
                    "tag_epochs": int(epochs), "rough_anchors": int((prior_std > 0).sum())}


def calibration_table(anchors: pd.DataFrame, result: AnchorCalibration) -> pd.DataFrame:
    """The calibrated anchors file (see the module docstring)."""
    dims = ["x", "y"] + (["z"] if "z" in anchors.columns else [])
    out = pd.DataFrame({"id": anchors["id"].to_numpy()})
    for k, d in enumerate(dims):
        out[d] = result.position[:, k]
    for a in range(len(dims)):
        for b in range(a, len(dims)):
            out[f"cov_{dims[a]}{dims[b]}"] = result.covariance[:, a, b]
    out["crb_std_m"] = np.sqrt(np.trace(result.crb, axis1=1, axis2=2))
    if result.bias_m is not None:
        out["bias_m"] = result.bias_m
        out["bias_std_m"] = result.bias_std_m
    return out
