"""``radioloc locate --method rls|ekf``: cooperative network positioning from pairwise ranges.

Input: a measurements CSV of ``range`` rows between nodes (and optionally to anchors), a
priors CSV (``--priors``, format in :mod:`radioloc.io.priors`) with every node's prior mean
and variance, optionally an anchors CSV (anchors become nodes with prior variance
``anchor_var_m2``, default 1e-6 m^2, and are not reported).

The rows with the same ``(time, node)`` form one packet: ``node`` is the master and its
ranges to the peers update the estimates (missing peers are missing links). Packets are
processed in time order; after the last packet of each time stamp every node's estimate is
reported at that time (one row per time and node).

Options (``-o key=value``): ``range_std_m`` (range noise standard deviation, default 30 m;
EKF only), ``forgetting`` (RLS lambda, default 1), ``anchor_var_m2``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd

from radioloc.core.errors import InputError
from radioloc.core.validation import check_positive
from radioloc.estimators.ekf import NetworkEKF
from radioloc.estimators.rls import NetworkRLS
from radioloc.io.priors import read_node_priors
from radioloc.locate.base import LocateRequest, Option, locate_method
from radioloc.locate.progress import counted
from radioloc.locate.table import add_covariance


@dataclass
class _Network:
    ids: list[str]
    reported: np.ndarray          # (K,) bool: not an anchor
    prior_mean: np.ndarray        # (1, K, 2)
    prior_var: np.ndarray         # (1, K, 2)
    times: np.ndarray             # (P,)
    masters: np.ndarray           # (P,)
    ranges: np.ndarray            # (P, K), NaN where missing
    masks: np.ndarray             # (P, K)


#: prior variances the network filters take (m^2): below, the RLS information overflows;
#: above, the EKF update loses every digit (the library refuses them as well)
PRIOR_VAR_RANGE = (1e-24, 1e12)


def _network(request: LocateRequest, method: str) -> _Network:
    if request.priors is None:
        raise InputError(f"method {method}: needs a priors file (--priors) with columns "
                         "node, x, y, var_x, var_y")
    priors = read_node_priors(request.priors)
    ids = list(priors["node"])
    mean = priors[["x", "y"]].to_numpy()
    var = priors[["var_x", "var_y"]].to_numpy()
    out = (var < PRIOR_VAR_RANGE[0]) | (var > PRIOR_VAR_RANGE[1])
    if out.any():
        i, j = (int(k) for k in np.argwhere(out)[0])
        where = f"line {int(priors['line'].iloc[i])}, " if "line" in priors else ""
        raise InputError(f"{request.priors}: {where}column {('var_x', 'var_y')[j]}: "
                         f"{var[i, j]:g} m^2 for node {ids[i]} is outside the supported range "
                         f"[{PRIOR_VAR_RANGE[0]:g}, {PRIOR_VAR_RANGE[1]:g}] m^2")
    reported = np.ones(len(ids), bool)
    if request.anchors is not None:
        avar = check_positive(request.option("anchor_var_m2", 1e-6), "anchor_var_m2")
        if not PRIOR_VAR_RANGE[0] <= avar <= PRIOR_VAR_RANGE[1]:
            raise InputError(f"anchor_var_m2: {avar:g} m^2 is outside the supported range "
                             f"[{PRIOR_VAR_RANGE[0]:g}, {PRIOR_VAR_RANGE[1]:g}] m^2")
        anchors = request.anchors[~request.anchors["id"].isin(ids)]
        ids += list(anchors["id"])
        mean = np.vstack([mean, anchors[["x", "y"]].to_numpy()])
        var = np.vstack([var, np.full((len(anchors), 2), avar)])
        reported = np.concatenate([reported, np.zeros(len(anchors), bool)])
    index = {n: i for i, n in enumerate(ids)}
    rows = request.kind("range", method)
    for col in ("node", "peer"):
        unknown = ~rows[col].isin(index)
        if unknown.any():
            r = rows[unknown].iloc[0]
            raise InputError(f"method {method}: measurements line {int(r['line'])}, column "
                             f"'{col}': node {r[col]!r} has no row in the priors file")
    heard = set(rows["node"]) | set(rows["peer"])
    silent = [i for i, n in enumerate(ids) if reported[i] and n not in heard]
    if silent:
        reported[silent] = False
        first = int(priors["line"].iloc[silent[0]]) if "line" in priors else None
        warnings.warn(f"method {method}: {len(silent)} node(s) of the priors file with no range "
                      f"measurement not estimated (left out of the output), e.g. "
                      f"{ids[silent[0]]!r}" + (f" (priors line {first})" if first else ""),
                      stacklevel=2)
    rows = rows.groupby(["time", "node", "peer"], sort=True, as_index=False).agg(
        value=("value", "mean"), line=("line", "min"))
    packets = rows[["time", "node"]].drop_duplicates().reset_index(drop=True)
    p_idx = rows.merge(packets.reset_index(), on=["time", "node"])["index"].to_numpy()
    K = len(ids)
    ranges = np.full((len(packets), K), np.nan)
    ranges[p_idx, rows["peer"].map(index).to_numpy()] = rows["value"].to_numpy()
    return _Network(ids, reported, mean[None], var[None], packets["time"].to_numpy(),
                    packets["node"].map(index).to_numpy(), ranges, np.isfinite(ranges))


def _report(net: _Network, estimates: list[np.ndarray], covariances: list[np.ndarray] | None
            ) -> pd.DataFrame:
    """Every reported node's estimate after the last packet of each time stamp (packets of
    one time stamp from several masters give one row per node, not one per packet)."""
    K = len(net.ids)
    last = np.append(net.times[1:] != net.times[:-1], True)           # last packet of a time
    pos = np.stack(estimates)[last]                                   # (P', K, 2)
    times = net.times[last]
    keep = np.broadcast_to(net.reported, (len(times), K))
    out = pd.DataFrame({"time": np.repeat(times, K)[keep.ravel()],
                        "node": np.tile(np.array(net.ids, dtype=object), len(times))[keep.ravel()],
                        "x": pos[..., 0][keep], "y": pos[..., 1][keep]})
    if covariances is not None:
        out = add_covariance(out, np.stack(covariances)[last][keep])
    out.attrs["summary"] = {"packets": int(len(net.times)), "nodes": int(net.reported.sum()),
                            "ranges": int(net.masks.sum())}
    return out


def packets(net, what: str):
    """The packets of ``net`` (master, ranges, mask), progress counting their ranges."""
    return counted(zip(net.masters, net.ranges, net.masks), int(sum(np.sum(k) for k in net.masks)),
                   lambda packet: int(np.sum(packet[2])), what)


@locate_method("rls", "Distributed RLS network positioning from pairwise ranges and node priors "
                      "(Brown & Iltis eq. (1)-eq. (12); --priors; options: forgetting)",
               options={"forgetting": Option("forgetting factor lambda in (0, 1] (1)", float, min=0,
                                             min_exclusive=True, max=1),
                        "anchor_var_m2": Option("prior variance of anchors in the network, m^2 "
                                                "(1e-6)", float, min=0, min_exclusive=True)},
               kinds=("range",), inputs=("priors", "anchors"), planar=True)
def locate_rls(request: LocateRequest) -> pd.DataFrame:
    """Run :class:`NetworkRLS` over the packets of a measurement log.

    Each packet updates only its master's position from differenced squared ranges.
    No uncertainty is reported: the RLS pseudo-covariance is not a covariance in m^2.

    Parameters
    ----------
    request : LocateRequest
        Measurements (``range`` rows), ``--priors``, optional anchors and the option
        ``forgetting``.

    Returns
    -------
    DataFrame
        Columns ``time, node, x, y``: every node's estimate after each time stamp's packets.
    """
    net = _network(request, "rls")
    rls = NetworkRLS(forgetting=request.option("forgetting", 1.0))
    state = rls.init(net.prior_mean, net.prior_var)
    estimates = []
    for m, rho, mask in packets(net, "rls"):                         # in time order
        state = rls.step(state, np.array([m]), rho[None], mask[None])
        estimates.append(rls.estimate(state).position[0])
    return _report(net, estimates, None)


@locate_method("ekf", "Sequential EKF network positioning from pairwise ranges and node priors "
                      "(Brown & Iltis eq. (13)-eq. (25); --priors; options: range_std_m)",
               options={"range_std_m": Option("range error standard deviation, m (30)", float,
                                              min=0, min_exclusive=True, max=1e7),
                        "anchor_var_m2": Option("prior variance of anchors in the network, m^2 "
                                                "(1e-6)", float, min=0, min_exclusive=True)},
               kinds=("range",), inputs=("priors", "anchors"), planar=True)
def locate_ekf(request: LocateRequest) -> pd.DataFrame:
    """Run :class:`NetworkEKF` over the packets of a measurement log.

    Each packet's ranges update the joint estimate of all nodes; ``uncertainty_m`` is
    the square root of the trace of each node's 2x2 covariance block.

    Parameters
    ----------
    request : LocateRequest
        Measurements (``range`` rows), ``--priors``, optional anchors and the option
        ``range_std_m`` (default 30 m).

    Returns
    -------
    DataFrame
        Columns ``time, node, x, y, uncertainty_m`` and the covariance columns after each
        time stamp's packets.
    """
    net = _network(request, "ekf")
    std = check_positive(request.option("range_std_m", 30.0), "range_std_m")
    ekf = NetworkEKF(std_m=std)
    state = ekf.init(net.prior_mean, net.prior_var)
    estimates, covariances = [], []
    for m, rho, mask in packets(net, "ekf"):                         # in time order
        state = ekf.step(state, np.array([m]), rho[None], mask[None])
        est = ekf.estimate(state)
        estimates.append(est.position[0])
        covariances.append(est.covariance[0])
    return _report(net, estimates, covariances)
