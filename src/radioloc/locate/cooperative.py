"""Cooperative tag-to-tag ranges for ``ekf-track`` (``-o cooperative=1``): each peer's
estimate acts as a moving anchor.

Paper 001 (Ekambaram and Ramchandran, Sect. IV, Fig. 3) approximates the coupled model of
many vehicles by one filter per vehicle in which the neighbours' estimated locations stand
for their true ones. Here each tag keeps its own extended Kalman filter (no joint state;
the tags run as one batch, :meth:`~radioloc.estimators.ExtendedKalmanFilter.run` with a
``coupling``): a range ``r`` between tags ``i`` and ``j`` at time ``t`` updates tag ``i``'s
filter as a range to an anchor at ``x_j``, tag ``j``'s latest estimate (after its own rows
of time ``t``), with the noise variance

    ``std_m^2 + u' P_j u``,   ``u = (x_i - x_j) / |x_i - x_j|``,

where ``P_j`` is the covariance of ``x_j``: to first order the range moves by ``u' dx_j``
when the peer's position is off by ``dx_j``, so the peer's uncertainty along the line of
sight is added to the range's. (The paper takes the neighbours' estimates as exact; the
inflation is this module's.) Tag ``j``'s filter uses the same row the other way round.
The cross-covariance the two filters build up is ignored.

So that a peer's latest estimate exists at every row's time, the tracks of tags linked by
tag-to-tag rows step on one grid: the union of their times (a track before its first or
after its last time stays put: a step of zero length with no rows). Each track's output is
taken at its own times, where it equals the track of the plain run when no tag-to-tag row
reaches it (the motion models are continuous-time, so splitting an interval changes
nothing). A row is used when both tags have a track running at its time.

Tag-to-tag ranges logged on a clock of their own can be put on the tags' clock by
:func:`align_peer_ranges` (no truth: the two tags' tracks without them).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.core.errors import InputError
from radioloc.models.measurement import Context, Observation
from radioloc.models.ranging import RangeModel

__all__ = ["peer_ranges", "CooperativeBatch", "cooperative_batch", "align_peer_ranges"]


def peer_ranges(measurements: pd.DataFrame, anchor_ids) -> pd.DataFrame:
    """The tag-to-tag ranges of a log: rows of kind ``range`` whose peer is not an anchor.

    Parameters
    ----------
    measurements : DataFrame
        ``time, node, peer, kind, value`` (and ``std``), as read by
        :func:`radioloc.io.logs.read_measurements`.
    anchor_ids : iterable of str

    Returns
    -------
    DataFrame
        ``time, node, peer, value, std`` (``std`` NaN where the row gives none).
    """
    m = measurements
    rows = m[(m["kind"] == "range") & ~m["peer"].isin(set(anchor_ids)) & (m["peer"] != m["node"])]
    std = rows["std"] if "std" in rows else pd.Series(np.nan, index=rows.index)
    return pd.DataFrame({"time": rows["time"].to_numpy(float), "node": rows["node"].astype(str),
                         "peer": rows["peer"].astype(str), "value": rows["value"].to_numpy(float),
                         "std": std.to_numpy(float)})


class CooperativeBatch:
    """Tracks of many tags on shared time grids, with their tag-to-tag ranges.

    Built by :func:`cooperative_batch`. :attr:`time` and :attr:`observations` go to
    :meth:`~radioloc.estimators.ExtendedKalmanFilter.run`, with :meth:`coupling` as its
    ``coupling``; :attr:`own_steps` picks each track's own times out of the result.

    Attributes
    ----------
    time : ndarray, shape (B, T)
    observations : list of Observation
        The tracks' own rows on the grid, ``z`` of shape ``(B, T, S)``.
    own_steps : list of ndarray of int
        Per track, the grid steps of its own times (in order).
    peer : ndarray of int, shape (B, T, N)
        Batch index of the peer's running track for each tag slot (-1: none).
    z : ndarray, shape (B, T, N)
        Tag-to-tag ranges (NaN: none); ``std`` likewise (NaN: the model's).
    model : RangeModel
        The range model of the tag-to-tag rows (no anchor bias).
    dim : int
        Position coordinates of the state.
    """

    def __init__(self, time, observations, own_steps, peer, z, std, model, dim):
        self.time, self.observations, self.own_steps = time, observations, own_steps
        self.peer, self.z, self.std, self.model, self.dim = peer, z, std, model, dim
        self.std_m = float(model.std(Context(points=np.zeros((1, dim))))[0])

    def coupling(self, k: int, state) -> list[Observation]:
        """Step ``k``'s tag-to-tag rows: ranges to the peers' current means, with the
        peers' position variance along the line of sight added to the noise variance.

        Parameters
        ----------
        k : int
            Grid step.
        state : FilterState
            The batch's state after the step's own rows, mean ``(B, n)``.

        Returns
        -------
        list of Observation
            One observation, ``z`` of shape ``(B, N)``, points ``(B, N, D)``.
        """
        D = self.dim
        p = self.peer[:, k]                                  # (B, N)
        q = np.maximum(p, 0)
        x = state.mean[..., :D]                              # (B, D)
        points = x[q]                                        # (B, N, D)
        P = state.covariance[..., :D, :D][q]                 # (B, N, D, D)
        diff = x[:, None, :] - points
        dist = np.linalg.norm(diff, axis=-1, keepdims=True)
        u = diff / np.maximum(dist, 1e-9)
        extra = np.einsum("...i,...ij,...j->...", u, P, u)   # u' P_peer u
        own = np.where(np.isfinite(self.std[:, k]), self.std[:, k], self.std_m)
        z = np.where(p >= 0, self.z[:, k], np.nan)
        return [Observation(self.model, z, Context(points=points),
                            std=np.sqrt(own ** 2 + extra))]

    def track_of(self, track, b: int):
        """Track ``b`` of a run over the batch, at its own times."""
        return track[b, self.own_steps[b]]


def _components(nodes: list[str], pairs) -> dict[str, int]:
    """Connected components of the tags linked by ``pairs``: a label per node."""
    parent = {n: n for n in nodes}

    def root(n):
        while parent[n] != n:
            n = parent[n]
        return n

    for a, b in pairs:
        parent[root(a)] = root(b)
    return {n: nodes.index(root(n)) for n in nodes}


def cooperative_batch(tracks: list, peers: pd.DataFrame, model: RangeModel, dim: int
                      ) -> CooperativeBatch:
    """Put tracks on shared time grids and attach their tag-to-tag ranges.

    Parameters
    ----------
    tracks : list of (node, times (T_b,), list of Observation)
        The tracks (a node's log split at its gaps), ``z`` of shape ``(T_b, S)``; the same
        model for a kind in every track.
    peers : DataFrame
        From :func:`peer_ranges`.
    model : RangeModel
        Model of the tag-to-tag rows (its ``std`` where a row gives none).
    dim : int
        Position coordinates of the state.

    Returns
    -------
    CooperativeBatch
    """
    from radioloc.locate.ekf_track import stack_tracks

    nodes = list(dict.fromkeys(tr[0] for tr in tracks))
    slot = {n: i for i, n in enumerate(nodes)}
    peers = peers[peers["node"].isin(slot) & peers["peer"].isin(slot)]
    comp = _components(nodes, zip(peers["node"], peers["peer"]))
    grids: dict[int, np.ndarray] = {}
    for node, times, _ in tracks:
        grids[comp[node]] = np.union1d(grids.get(comp[node], np.empty(0)), times)
    for c, t in peers.groupby(peers["node"].map(comp))["time"]:
        grids[c] = np.union1d(grids[c], t.to_numpy(float))
    B, T, N = len(tracks), max(g.size for g in grids.values()), len(nodes)
    time = np.empty((B, T))
    own_steps, grid_obs = [], []
    for b, (node, times, obs) in enumerate(tracks):
        g = grids[comp[node]]
        time[b, :g.size] = np.clip(g, times[0], times[-1])
        time[b, g.size:] = times[-1]
        steps = np.searchsorted(g, times)
        own_steps.append(steps)
        grid_obs.append([_on_grid(o, steps, g.size) for o in obs])
    _, observations = stack_tracks([np.arange(T, dtype=float)] * B, grid_obs)
    peer = np.full((B, T, N), -1)
    z = np.full((B, T, N), np.nan)
    std = np.full((B, T, N), np.nan)
    span = np.array([(tr[1][0], tr[1][-1]) for tr in tracks])
    owner = np.array([slot[tr[0]] for tr in tracks])
    for direction in (("node", "peer"), ("peer", "node")):
        me, other = (peers[c].map(slot).to_numpy() for c in direction)
        t = peers["time"].to_numpy(float)
        for b, (node, _, _) in enumerate(tracks):
            g = grids[comp[node]]
            mine = (me == slot[node]) & (t >= span[b, 0]) & (t <= span[b, 1])
            for j in np.unique(other[mine]):
                rows = mine & (other == j)
                live = np.flatnonzero(owner == j)
                for c in live:                 # the peer's track running at each row's time
                    on = rows & (t >= span[c, 0]) & (t <= span[c, 1])
                    k = np.searchsorted(g, t[on])
                    peer[b, k, j] = c
                    z[b, k, j] = peers["value"].to_numpy(float)[on]
                    std[b, k, j] = peers["std"].to_numpy(float)[on]
    return CooperativeBatch(time, observations, own_steps, peer, z, std, model, dim)


def _on_grid(obs: Observation, steps: np.ndarray, size: int) -> Observation:
    """``obs`` (``z`` of shape ``(T_b, S)``) spread over a grid of ``size`` steps."""
    z = np.full((size,) + obs.z.shape[1:], np.nan)
    z[steps] = obs.z
    std = None
    if obs.std is not None:
        std = np.full_like(z, np.nan)
        std[steps] = obs.std
    return Observation(obs.model, z, obs.context, std)


def align_peer_ranges(time_s: np.ndarray, range_m: np.ndarray, track: pd.DataFrame,
                      node: str, peer: str, max_offset_s: float = 300.0, step_s: float = 0.5
                      ) -> dict:
    """Clock offset and bias of tag-to-tag ranges logged on a clock of their own.

    The offset ``tau`` maximises the correlation between the ranges and the distance between
    the two tags' tracks (computed without these ranges) at ``time_s + tau``, over offsets
    in ``[-max_offset_s, max_offset_s]`` at which at least half of the rows fall within both
    tracks; the bias is the median of ``range - distance`` there. Nothing else is read.
    A distance that changes little, or repeats (tags walking one loop), leaves ``tau``
    poorly determined: ``correlation`` and ``runner_up`` (the best correlation at least
    20 s away) say how well.

    Parameters
    ----------
    time_s : ndarray, shape (K,)
        Times of the ranges on their own clock, seconds.
    range_m : ndarray, shape (K,)
    track : DataFrame
        ``time, node, x, y`` of both tags (a ``locate`` output).
    node, peer : str
        The two tags.
    max_offset_s, step_s : float
        Offsets searched, seconds.

    Returns
    -------
    dict
        ``offset_s`` (add it to ``time_s``), ``bias_m`` (subtract it from the ranges),
        ``correlation``, ``runner_up``.

    Raises
    ------
    InputError
        A tag without a track, or no offset placing half of the rows within the tracks.
    """
    t = np.asarray(time_s, dtype=float)
    r = np.asarray(range_m, dtype=float)
    ends = []
    for name in (node, peer):
        one = track[track["node"] == name].sort_values("time")
        if one.empty:
            raise InputError(f"track: no row of node {name!r}")
        ends.append(one)
    lo = max(e["time"].iloc[0] for e in ends)
    hi = min(e["time"].iloc[-1] for e in ends)

    def distance(times):
        xy = [np.stack([np.interp(times, e["time"], e[c]) for c in ("x", "y")], -1) for e in ends]
        return np.linalg.norm(xy[0] - xy[1], axis=-1)

    offsets = np.arange(-max_offset_s, max_offset_s + step_s / 2, step_s)
    rho = np.full(offsets.size, -np.inf)
    for i, tau in enumerate(offsets):
        inside = (t + tau >= lo) & (t + tau <= hi)
        if inside.sum() >= max(3, t.size / 2):
            d = distance(t[inside] + tau)
            if np.std(d) > 0 and np.std(r[inside]) > 0:
                rho[i] = np.corrcoef(r[inside], d)[0, 1]
    if not np.isfinite(rho).any():
        raise InputError(f"time_s: no offset within {max_offset_s:g} s puts half of the "
                         "ranges within both tracks")
    k = int(np.argmax(rho))
    far = np.abs(offsets - offsets[k]) >= 20.0
    inside = (t + offsets[k] >= lo) & (t + offsets[k] <= hi)
    bias = float(np.median(r[inside] - distance(t[inside] + offsets[k])))
    return {"offset_s": float(offsets[k]), "bias_m": bias, "correlation": float(rho[k]),
            "runner_up": float(rho[far].max()) if far.any() else float("nan")}
