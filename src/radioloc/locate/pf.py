"""``radioloc locate --method pf``: track each node from its ranges to anchors with the
LOS/NLOS particle filter of paper 001 (:class:`radioloc.estimators.p2p_particle.P2PParticleFilter`).
Without odometry rows the motion is a constant velocity (white acceleration) or a random
walk. With odometry rows (``odometry_dx``, ``odometry_dy``) it is paper 001's input-driven
model: each particle moves by the odometry's displacement over the step (the control) plus
a random walk of diffusion ``odometry_std_m^2`` (:mod:`radioloc.locate.odometry`); the
state is the position, the start its part of the start state below, and the smoother
``fixed-lag`` (the default then; backward simulation does not take the control).

Ranges are processed as they arrive (rows of one node with the same time stamp are one
step, see :mod:`radioloc.locate.ekf_track`); ranges to peers that are not anchors are not
used. The filter tracks 2-D positions: with 3-D anchors give the node height
(``-o tag_height_m=H``); each range is then projected to the horizontal plane,
``sqrt(max(r^2 - (H - z_a)^2, 0))``, after removing the range bias.

LOS/NLOS parameters: those given as options are used; when any of ``los_std_m``,
``nlos_mean_m``, ``alpha`` is missing, all of them and the range bias are fitted by EM
(:func:`radioloc.estimators.los_nlos_em.fit_los_nlos`) on the user's own log. EM needs range
errors, and a user has no true distances: the errors are the residuals of the ranges
against a first pass of ``ekf-track`` with the RTS smoother (same motion options). These
residuals are smaller than the true errors where the smoother bends towards the ranges, so
the fitted spread is a lower estimate.

Outliers: a range whose squared residual to the range predicted from the filter's
predicted mean exceeds ``gate`` times its variance (the particle spread along the line of
sight plus the mixture's variance) is skipped, causally; after 10 steps with every range
skipped the next is taken. Ranges much too short (metres) occur in real logs and have no
component in the LOS/NLOS mixture.

The start (:func:`start_state`): the particles are drawn from the state, position and
velocity, of the RTS-smoothed ``ekf-track`` over the first ``init_s`` seconds (at least
``START_STEPS`` steps; its own start is the grid search of ``ekf-track`` with spread
``prior_std_m``) at the first step, covariance inflated by ``START_INFLATION``. A start
velocity drawn from a prior of metres per second would leave a few particles near the ranges
of the next step (four ranges of 0.15 m against a spread of metres), and the filter would
jump. A gap longer than ``max_gap_s`` starts a new track (and a new EM fit), as in
``ekf-track``.

Seed: the particle draws come from ``numpy.random.default_rng(seed)``, ``seed`` 0 unless
given, so that the same log and options always give the same output.

Smoother (``-o smooth=1``): backward simulation over the whole segment by default
(:func:`radioloc.estimators.pf_smoother.backward_simulation`, ``trajectories`` draws).
``-o smoother=fixed-lag``: the estimate at step ``k`` is the mean, over the particles of step
``k + lag``, of their ancestors at step ``k`` (followed back through the resampling
indices); the lag of a step is shortened where resampling has left fewer than
``MIN_ANCESTORS`` distinct ancestors (see :func:`fixed_lag`), otherwise the smoothed set
collapses onto one particle and claims a covariance of zero.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.core.results import Track
from radioloc.estimators.los_nlos_em import MIN_SAMPLES, fit_los_nlos
from radioloc.estimators.p2p_particle import P2PParticleFilter
from radioloc.estimators.pf_smoother import backward_simulation
from radioloc.locate.base import LocateRequest, Option, locate_method
from radioloc.locate.progress import progress
from radioloc.locate.ekf_track import (
    OPTIONS as EKF_OPTIONS,
    _predicted,
    range_rows,
    run_ekf,
    segments,
    start_position,
    track_summary,
    track_table,
    tracker_motion,
    tracker_settings,
)
from radioloc.locate.odometry import MOTION_KINDS, ODOMETRY_OPTIONS, has_odometry, odometry_controls
from radioloc.models.los_nlos import LosNlosRange

#: Residuals further than this many robust standard deviations from their median are left
#: out of the EM fit.
TRIM = 20.0
#: Fewest steps of the start window of :func:`start_state`.
START_STEPS = 3
#: Factor on the covariance of the start state.
START_INFLATION = 4.0
#: Reset rule of the filter: fewer distinct particles than this fraction after resampling
#: (paper 001's 0.05 resets a well-placed filter whenever four ranges of 0.15 m meet a
#: prediction spread of half a metre).
RESET_FRACTION = 0.01
#: Distinct ancestors the fixed-lag smoother keeps at each step (see :func:`fixed_lag`).
MIN_ANCESTORS = 20
#: Steps whose every range was gated after which the next step is taken ungated.
GATE_PATIENCE = 10

OPTIONS = {k: EKF_OPTIONS[k] for k in ("motion", "q", "range_bias_m", "tag_height_m",
                                       "prior_std_m", "init_s", "gate", "max_gap_s")}
OPTIONS.update({
    "los_std_m": Option("s_LOS, standard deviation of every range's Gaussian error, m "
                        "(default: EM on the log)", float, min=0, min_exclusive=True, max=1e6),
    "nlos_mean_m": Option("s_NLOS, mean NLOS excess range, m (default: EM on the log)", float,
                          min=0, min_exclusive=True, max=1e6),
    "alpha": Option("LOS fraction (default: EM on the log)", float, min=0, max=1),
    "particles": Option("particles per node (default 900)", int, min=1, max=10**6),
    "smooth": Option("1: smoothed track (offline; see `smoother`)", bool),
    "smoother": Option("with smooth=1: 'backward' (default; backward simulation over the "
                       "whole log) or 'fixed-lag' (ancestors over `lag` later steps)", str,
                       choices=("fixed-lag", "backward")),
    "lag": Option("steps of the fixed-lag smoother (default 20)", int, min=1, max=10**6),
    "trajectories": Option("backward trajectories of smoother=backward (default 100)", int,
                           min=1, max=10**5),
    "min_los_std_m": Option("floor of the EM-fitted s_LOS, m (default 0.15; see the module "
                            "docstring)", float, min=0, min_exclusive=True, max=1e6),
    "seed": Option("seed of the particle draws (default 0: the same output every run)", int,
                   min=0,
                   max=2**63 - 1),
    **ODOMETRY_OPTIONS,
})


def start_state(times, R, anchors, s: dict, model: LosNlosRange, bias: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of the particles' start state (position and velocity).

    The smoothed :func:`run_ekf` track over the start window (the first ``init_s`` seconds,
    at least ``START_STEPS`` steps) at its first step, with range error ``s_LOS``: the same
    ranges that fix the grid-search start position, now also fixing the start velocity.
    Its covariance is inflated by ``START_INFLATION`` (the EKF ignores NLOS excess).

    Parameters
    ----------
    times : ndarray, shape (T,)
    R : ndarray, shape (T, M)
    anchors : ndarray, shape (M, 2|3)
    s : dict
        From :func:`radioloc.locate.ekf_track.tracker_settings`.
    model : LosNlosRange
    bias : float
        Range bias, m.

    Returns
    -------
    mean : ndarray, shape (n,)
    covariance : ndarray, shape (n, n)
    """
    n = max(int(np.searchsorted(times, times[0] + s["init_s"], side="right")),
            min(START_STEPS, times.size))
    track = run_ekf(times[:n], R[:n], anchors, dict(s, bias=bias), model.los_std_m, 16.0,
                    smooth=True)
    cov = START_INFLATION * track.diagnostics["state_covariance"][0]
    return track.diagnostics["state"][0], 0.5 * (cov + cov.T)


def fit_model(times, R, anchors, s: dict, parts: list[slice] | None = None
              ) -> tuple[LosNlosRange, float, dict]:
    """LOS/NLOS model and range bias fitted by EM on residuals to a smoothed EKF track.

    Parameters
    ----------
    times : ndarray, shape (T,)
    R : ndarray, shape (T, M)
    anchors : ndarray, shape (M, 2|3)
    s : dict
        From :func:`radioloc.locate.ekf_track.tracker_settings`.
    parts : list of slice, optional
        Segments tracked separately (default: one).

    Residuals more than ``TRIM`` robust standard deviations (1.4826 MAD) from their median
    are left out: the mixture has no component for ranges much too short, and one such
    range would inflate ``s_LOS``; the causal gate of the filter handles them.

    Returns
    -------
    model : LosNlosRange
    bias_m : float
    info : dict
        ``samples`` used.
    """
    errors = []
    for seg in parts or [slice(None)]:
        track = run_ekf(times[seg], R[seg], anchors, dict(s, bias=0.0), 0.15, 16.0, smooth=True)
        pred = _predicted(track.position[:, :2], anchors, s["height"])
        errors.append((R[seg] - pred)[np.isfinite(R[seg])])
    e = np.concatenate(errors)
    med = float(np.median(e))
    mad = max(1.4826 * float(np.median(np.abs(e - med))), 1e-3)
    keep = np.abs(e - med) <= TRIM * mad          # gross outliers: the gate's job, not EM's
    if keep.sum() < MIN_SAMPLES:
        outliers = f" ({int((~keep).sum())} of them gross outliers)" if (~keep).any() else ""
        raise InputError(f"method pf: the log holds {e.size} range(s) to anchors{outliers}; "
                         f"fitting its LOS/NLOS model by EM needs at least {MIN_SAMPLES}: give a "
                         "longer log, or use --method ekf-track")
    fit = fit_los_nlos(e[keep], fit_bias=True, alpha0=0.9, los_std0=mad,
                       nlos_mean0=max(5 * mad, 0.1))
    return fit.model, fit.bias_m, {"samples": int(keep.sum()), "trimmed": int((~keep).sum())}


def fixed_lag(history: list[np.ndarray], ancestors: list[np.ndarray], lag: int
              ) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-lag smoothed positions from particle sets and their ancestor indices.

    Parameters
    ----------
    history : list of ndarray, shape (K, n)
        Equally weighted (resampled) particles after each step.
    ancestors : list of ndarray of int, shape (K,)
        Resampling indices of each step: particle ``j`` of step ``s`` descends from particle
        ``ancestors[s][j]`` of step ``s - 1``.
    lag : int
        Later steps used at most: the lag of step ``k`` is halved until the particles of
        step ``k + lag`` descend from at least ``MIN_ANCESTORS`` distinct particles of step
        ``k`` (or as many as survive the next resampling), so that resampling does not
        collapse the smoothed set onto one ancestor (a covariance of zero).

    Returns
    -------
    mean : ndarray, shape (T, n)
        Mean over the particles of step ``k + lag_k`` of their ancestors at step ``k``.
    covariance : ndarray, shape (T, n, n)
        Their covariance.
    """
    T = len(history)
    out = np.empty((T, history[0].shape[-1]))
    cov = np.empty((T, history[0].shape[-1], history[0].shape[-1]))
    for k in range(T):
        own = np.unique(ancestors[k + 1]).size if k + 1 < T else history[k].shape[0]
        need = min(MIN_ANCESTORS, own)
        L = min(lag, T - 1 - k)
        while True:
            j = np.arange(history[k + L].shape[0])
            for s_ in range(k + L, k, -1):
                j = ancestors[s_][j]
            if L == 0 or np.unique(j).size >= need:
                break
            L //= 2
        pts = history[k][j]
        out[k] = pts.mean(axis=0)
        dev = pts - out[k]
        cov[k] = dev.T @ dev / len(j)
    return out, cov


@locate_method("pf", "LOS/NLOS particle filter (paper 001) tracking each node from its ranges "
                     "to anchors as they arrive, driven by odometry rows when the log has "
                     "them (parameters fitted by EM on the log unless given; fixed-lag or "
                     "backward-simulation smoother with -o smooth=1)",
               options=OPTIONS, kinds=("range",) + MOTION_KINDS, inputs=("anchors",))
def locate_pf(request: LocateRequest) -> pd.DataFrame:
    """Track every node with a :class:`P2PParticleFilter` over its range rows.

    Parameters
    ----------
    request : LocateRequest
        Measurements (range rows), anchors, ``-o`` options (see :data:`OPTIONS`).

    Returns
    -------
    DataFrame
        ``time, node, x, y, uncertainty_m``, the covariance columns and the flags ``gated``,
        ``restart``, ``p_nlos``: one row per time stamp at which the node has a range to an
        anchor (filtered, or smoothed with ``smooth=1``).
    """
    if not request.option("smooth", False, bool):
        want = "filtered"
    else:
        default = "fixed-lag" if has_odometry(request.measurements) else "backward"
        want = request.option("smoother", default, str)
    return pf_tracks(request, (want,))[want]


def pf_tracks(request: LocateRequest, outputs=("filtered",)) -> dict[str, pd.DataFrame]:
    """The filtered and smoothed tracks of ``--method pf`` from one filter pass.

    Parameters
    ----------
    request : LocateRequest
        As for ``locate --method pf`` (its ``smooth`` and ``smoother`` options are ignored:
        ``outputs`` says what to return).
    outputs : tuple of {"filtered", "fixed-lag", "backward"}
        Tracks to return: the causal filter's, the fixed-lag smoother's, the backward
        simulation smoother's (drawn after the filter from the same generator).

    Returns
    -------
    dict of str to DataFrame
        One table per name of ``outputs``: ``time, node, x, y, uncertainty_m``, the
        covariance columns and flags ``gated``, ``restart``, ``p_nlos``; ``attrs["summary"]``
        holds the counts, the seed and each node's LOS/NLOS parameters.
    """
    bad = set(outputs) - {"filtered", "fixed-lag", "backward"}
    if bad:
        raise InputError(f"outputs: unknown track(s) {sorted(bad)}")
    anchors, per_node = range_rows(request, "pf")
    s = tracker_settings(request, anchors)
    if s["odometry_std"] is not None and "backward" in outputs:
        raise ConfigError("option smoother: backward simulation does not take the odometry "
                          "input; with odometry rows use smoother=fixed-lag")
    if s["dim"] != 2:
        raise InputError("method pf: tracks 2-D positions; with 3-D anchors give the node "
                         "height (-o tag_height_m=H)")
    given = [request.option(k) for k in ("los_std_m", "nlos_mean_m", "alpha")]
    seed = request.option("seed", 0, int)
    rng = np.random.default_rng(seed)
    particles = request.option("particles", 900, int)
    lag = request.option("lag", 20, int)
    trajectories = request.option("trajectories", 100, int)
    gate = request.option("gate", 16.0) or None
    tables = {k: [] for k in outputs}
    fitted, resets = [], [0]
    with progress(sum(t.size for _, t, _ in per_node), "pf: steps") as bar:
        for node, times, R in per_node:
            _track_node(request, node, times, R, anchors, s, given, particles, rng, gate,
                        outputs, lag, trajectories, resets, fitted, tables, bar)
    result = {}
    for k, v in tables.items():
        result[k] = pd.concat(v, ignore_index=True)
        result[k].attrs["summary"] = track_summary(
            v, per_node, seed=seed, particles=particles, filter_resets=resets[0],
            smoother=None if k == "filtered" else k, model=fitted)
    return result


def _track_node(request, node, times, R, anchors, s, given, particles, rng, gate, outputs, lag,
                trajectories, resets, fitted, tables, bar) -> None:
    """One node's tracks, appended to ``tables``; its model to ``fitted``."""
    parts = segments(times, s["max_gap_s"])
    try:
        if any(g is None for g in given):
            model, bias, _ = fit_model(times, R, anchors, s, parts)
            floor = request.option("min_los_std_m", 0.15)
            if model.los_std_m < floor:
                model = LosNlosRange(floor, model.nlos_mean_m, model.alpha)
            if "range_bias_m" in request.parsed:
                bias = s["bias"]
        else:
            model, bias = LosNlosRange(*given), s["bias"]
        fitted.append({"node": node, "los_std_m": model.los_std_m,
                       "nlos_mean_m": model.nlos_mean_m, "alpha": model.alpha,
                       "range_bias_m": float(bias),
                       "fitted": any(g is None for g in given)})
        for n, seg in enumerate(parts):
            controls = (None if s["odometry_std"] is None else
                        odometry_controls(request.measurements, node, times[seg], 2))
            tracks = _filter(times[seg], R[seg], anchors, s, model, bias, particles, rng,
                             gate, outputs, lag, trajectories, resets, bar, controls)
            for k, track in tracks.items():
                tables[k].append(track_table(node, times[seg], track, restart=n > 0))
    except GeometryError as exc:
        raise GeometryError(f"method pf: node {node!r}: {exc}") from None


def _filter(times, R, anchors, s, model, bias, particles, rng, gate, outputs, lag,
            trajectories, resets: list[int], bar, controls=None) -> dict[str, Track]:
    """One node's particle-filter tracks over one segment (see the module docstring)."""
    r = R - bias
    if anchors.shape[1] == 3:
        dz = s["height"] - anchors[:, 2]
        r = np.where(np.isfinite(r), np.sqrt(np.maximum(r * r - dz * dz, 0.0)), np.nan)
    motion = tracker_motion(dict(s, dim=2))
    mean0, cov0 = start_state(times, R, anchors, s, model, bias)
    mean0, cov0 = mean0[:motion.state_dim], cov0[:motion.state_dim, :motion.state_dim]
    pf = P2PParticleFilter(motion, model, particles=particles, reset_fraction=RESET_FRACTION,
                           init_std=np.sqrt(np.diagonal(cov0)))
    rows = np.concatenate([np.full((len(times), 1), np.nan), r], axis=1)[None]  # (1, T, 1+M)
    nodes = np.concatenate([np.zeros((1, 2)), anchors[:, :2]], axis=0)          # (1+M, 2)
    dts = np.diff(times, prepend=times[0])
    state = pf.init(mean0[None], rng, time=times[0])
    draws = mean0 + rng.standard_normal((particles, mean0.size)) @ np.linalg.cholesky(cov0).T
    state = dataclasses.replace(state, particles=draws[None], covariance=cov0[None].copy())
    means, covs, history, ancestors = [], [], [], []
    keep = "fixed-lag" in outputs or "backward" in outputs
    bias_m, var_m2 = model.moments()
    streak = 0
    gated = np.zeros(len(times), dtype=np.int64)
    p_nlos = np.zeros(len(times))
    for k in range(len(times)):
        row = rows[:, k]
        if gate and streak < GATE_PATIENCE and np.isfinite(row).any():
            # causal gate: residual to the range from the predicted mean, over its variance
            pred = motion.predict(state.mean, dts[k])[..., :2]                      # (1, 2)
            if controls is not None:
                pred = pred + controls[k]
            diff = pred[:, None, :] - nodes[None]                                   # (1, J, 2)
            d = np.sqrt(np.sum(diff ** 2, axis=-1))
            u = diff / np.maximum(d, 1e-9)[..., None]
            P = state.covariance[0, :2, :2]
            spread = np.einsum("...i,ij,...j->...", u, P, u) + var_m2
            out = np.isfinite(row) & ((row - d - bias_m) ** 2 > gate * spread)
            streak = streak + 1 if out.sum() == np.isfinite(row).sum() else 0
            gated[k] = int(out.sum())
            row = np.where(out, np.nan, row)
        else:
            streak = 0
        state = pf.step(state, row, nodes, rng, dt=dts[k],
                        control=None if controls is None else controls[k][None])
        bar.advance()
        means.append(state.mean[0])
        covs.append(state.covariance[0])
        used = state.links[0] >= 0
        if used.any():   # the largest NLOS probability among the ranges used
            p_nlos[k] = float(np.max(1.0 - state.link_los[0].mean(axis=0)[used]))
        if keep:
            history.append(state.particles[0])
            ancestors.append(state.ancestors[0])
    flags = {"gated": gated, "p_nlos": p_nlos}
    out = {}
    if "filtered" in outputs:
        mean, cov = np.stack(means), np.stack(covs)
        out["filtered"] = Track(mean[:, :2], cov[:, :2, :2], times, flags)
    if "fixed-lag" in outputs:
        mean, cov = fixed_lag(history, ancestors, lag)
        out["fixed-lag"] = Track(mean[:, :2], cov[:, :2, :2], times, flags)
    if "backward" in outputs:
        mean, cov = backward_simulation(history, times, motion, trajectories, rng)
        out["backward"] = Track(mean[:, :2], cov[:, :2, :2], times, flags)
    resets[0] += int(state.resets[0])
    return out
