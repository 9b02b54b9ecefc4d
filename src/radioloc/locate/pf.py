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
used. A gap longer than ``max_gap_s`` starts a new segment (a new start, flag ``restart``).

Batch: the segments of every node run as one batch of filters (one
:class:`P2PParticleFilter` over a leading axis of segments; :func:`batches`), aligned by
step index as ``ekf-track`` stacks its tracks
(:func:`radioloc.locate.ekf_track.stack_tracks`): each segment keeps its own time stamps,
and a segment shorter than the longest is padded at its end with steps of zero length and
no range, which do not touch its outputs. Each segment draws from its own generator
(:class:`~radioloc.estimators.particle_filter.RunGenerators`, seeded by
:func:`segment_seed`), so a node's track is the same whether the log holds other nodes or
not, and whatever the batch (tested: a two-node log gives each node exactly the rows of a
log of that node alone). The inputs are checked once for the log, not at every step
(``step(..., check=False)``). The filter tracks 2-D positions: with 3-D anchors give the node height
(``-o tag_height_m=H``); each range is then projected to the horizontal plane,
``sqrt(max(r^2 - (H - z_a)^2, 0))``, after removing the range bias.

LOS/NLOS parameters: those given as options are used. When any of ``los_std_m``,
``nlos_mean_m``, ``alpha`` is missing, by default (``-o tune=1``) each node's settings are
learned from its own ranges as ``ekf-track`` learns them (:mod:`radioloc.locate.self_tuning`,
:func:`learned_ranges`): each anchor's range offset is taken off its ranges, the missing
parameters are the mixture fitted to the ranges' residuals at the learned track, and the
process noise ``q`` (unless given) is the one learned; ``summary.json`` reports them
(``learned``), and the health check judges the track against them. Not learned (``-o
tune=0``, ``range_bias_m`` given, odometry rows, a log too short to learn from): the missing
parameters and one range bias per node (unless ``range_bias_m`` is given) are fitted by EM
(:func:`radioloc.estimators.los_nlos_em.fit_los_nlos`, :func:`node_models`) on the user's
own log. EM needs range
errors, and a user has no true distances: the errors are the residuals of the ranges
against a first pass of ``ekf-track`` with the RTS smoother (same motion options). These
residuals are smaller than the true errors where the smoother bends towards the ranges, so
the fitted spread is a lower estimate.

Outliers: a range whose squared innovation (its residual to the range predicted from the
filter's predicted mean, less the mixture's mean) exceeds ``gate`` times its variance
``S`` (see "Reported covariance" below) is skipped, causally; after 10 steps with every range
skipped the next is taken. Ranges much too short (metres) occur in real logs and have no
component in the LOS/NLOS mixture.

The EKF passes (the residuals for EM, the start states) run every segment of the log as
one batch too (:func:`ekf_tracks`).

The start (:func:`start_states`): the particles are drawn from the state, position and
velocity, of the RTS-smoothed ``ekf-track`` over the first ``init_s`` seconds (at least
``START_STEPS`` steps; its own start is the grid search of ``ekf-track`` with spread
``prior_std_m``) at the first step, covariance inflated by ``START_INFLATION``. A start
velocity drawn from a prior of metres per second would leave a few particles near the ranges
of the next step (four ranges of 0.15 m against a spread of metres), and the filter would
jump.

Seed: ``seed`` 0 unless given, so that the same log and options always give the same
output; a segment's draws come from ``SeedSequence([seed, crc32(node), segment index])``
(:func:`segment_seed`), the backward smoother's from its first child.

Reported covariance. The weighted covariance of the particles (paper 001, Algorithm 2,
line 14) is what the filter believes, and it can be far too small: with few particles the
sample covariance of a few distinct particles underestimates the spread, and when the
stated range error is much smaller than the ranges' (``-o los_std_m=0.001`` on ranges of
0.1 m) one particle takes all the weight at every step and the covariance collapses while
the track is decimetres to metres off. The reported position covariance is that weighted
covariance plus two terms:

* the kernel of the particle set: ``h^2 P_pred`` with ``P_pred`` the predicted particle
  covariance of the step (``F P F^T + Q``, which does not collapse) and Silverman's
  bandwidth for K particles in two dimensions, ``h^2 = K^(-1/3)`` (the regularised
  particle filter's kernel; 0.46 for 10 particles, 0.10 for 900);
* the misfit (:class:`Misfit`): when the innovations (each range minus the range from the
  predicted mean and the mixture's mean) are larger than their predicted variance ``S``
  (the predicted covariance along the line of sight plus this floor, plus the mixture's
  variance), the excess ``eps^2`` (mean of ``min(nu^2, MISFIT_CLIP S) - S`` over the last
  ``MISFIT_STEPS`` steps, exponentially weighted; 0 if negative) is position error or
  understated noise; either way the track is about as wrong as a fix from those ranges
  with that error, ``eps^2 (A / n)^-1`` (``A``: the ranges' sum of ``u u^T``, ``u`` the
  unit vector to the anchor, per step with ranges).

Both are causal; the smoothers add the same terms to their covariances. The gate uses the
predicted covariance and the mixture's variance, not the misfit term: under NLOS the misfit
grows, and a gate widened by it lets the NLOS ranges in (real UWB log, Hanyang NLOS/A/1,
seed 1: 2-D RMSE 0.92 m, largest error 6.8 m with the misfit in the gate; 0.78 m and 2.7 m
without it, with 70-71 % of errors inside the 95 % ellipse either way). Measured (tests/test_pf_honesty.py: a simulated
log of two tags, four anchors, ranges of 0.1 m, three seeds; rows after the first 2 s):
for particles in {10, 20, 900} and ``los_std_m`` 0.001 or fitted, at least 90 % of each
run's rows have an error within three times ``uncertainty_m`` (93-100 %; before these
terms, 0-20 % with ``los_std_m=0.001`` and 56-86 % with 10 particles), and with the
defaults the claim is cautious, not useless (median error over ``uncertainty_m`` about
0.4-0.5).

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
import warnings
import zlib

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.kinds import model_kinds
from radioloc.core.results import Track
from radioloc.estimators.los_nlos_em import MIN_SAMPLES, fit_los_nlos
from radioloc.estimators.particle_filter import ParticleFilter, RunGenerators
from radioloc.estimators.pf_smoother import backward_simulation
from radioloc.io.measurements import Measurements
from radioloc.locate.adapter import (anchor_positions, anchor_ranges, given_sigmas,
                                    log_observations, sigma_options)
from radioloc.locate.base import LocateRequest, Option, locate_method
from radioloc.locate.progress import progress
from radioloc.locate.self_tuning import not_learnable
from radioloc.locate.ekf_track import (
    OPTIONS as EKF_OPTIONS,
    _predicted,
    learn_tracks,
    log_models,
    track_window,
    reads_clock,
    segment_tracks,
    segments,
    stack_tracks,
    track_prior,
    track_priors,
    track_summary,
    track_table,
    tracker_filter,
    tracker_motion,
    tracker_settings,
)
from radioloc.locate.odometry import MOTION_KINDS, ODOMETRY_OPTIONS, has_odometry, odometry_controls
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.measurement import Context, Observation
from radioloc.models.ranging import RangeModel

#: Residuals further than this many robust standard deviations from their median are left
#: out of the EM fit.
TRIM = 20.0
#: Residuals fitted by EM at most (see :func:`fit_residuals`).
EM_SAMPLES = 2500
#: Fewest steps of the start window of :func:`start_states`.
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

OPTIONS = {k: EKF_OPTIONS[k] for k in ("motion", "q", "range_bias_m", "tune", "tag_height_m",
                                       "prior_std_m", "init_s", "gate", "max_gap_s")}
OPTIONS.update({
    "los_std_m": Option("s_LOS, standard deviation of every range's Gaussian error, m "
                        "(default: learned from the log; see tune)", float, min=0, min_exclusive=True,
                        max=1e6),
    "nlos_mean_m": Option("s_NLOS, mean NLOS excess range, m (default: learned from the log)", float,
                          min=0, min_exclusive=True, max=1e6),
    "alpha": Option("LOS fraction (default: learned from the log)", float, min=0, max=1),
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
    **{k: v for k, v in sigma_options().items() if k != "range_std_m"},   # the other kinds'
})


def ekf_tracks(items: list[tuple[np.ndarray, np.ndarray]], anchors, s: dict,
               range_std: list[float], gate: float | None, smooth: bool,
               labels: list[str] | None = None) -> list[Track]:
    """Range-only EKF tracks of several segments in one batch (:func:`run_ekf` of each).

    The segments are stacked as ``ekf-track`` stacks its tracks
    (:func:`radioloc.locate.ekf_track.stack_tracks`): each keeps its own times, start and
    range error, and its track equals its own :func:`run_ekf`.

    Parameters
    ----------
    items : list of (times (T_b,), ranges (T_b, M))
        Ranges with the bias removed.
    anchors : ndarray, shape (M, 2|3)
    s : dict
        From :func:`radioloc.locate.ekf_track.tracker_settings`.
    range_std : list of float
        Range standard deviation of each segment, m.
    gate : float or None
    smooth : bool
        RTS-smoothed tracks.
    labels : list of str, optional
        Each segment's name in the message of a start that fails.

    Returns
    -------
    list of Track

    Raises
    ------
    GeometryError
        The ranges of a segment's start window do not fix a start position.
    """
    s0 = dict(s, bias=0.0, odometry_std=None)
    ekf = tracker_filter(anchors, s0, gate)
    ctx = Context(points=anchors, index=np.arange(len(anchors)), height_m=s["height"])
    obs = [[Observation(RangeModel(std_m=std), R, ctx, np.full(R.shape, std))]
           for (_, R), std in zip(items, range_std)]
    prior_mean, prior_cov = track_priors(
        ekf, [(None if labels is None else labels[b], times, o)
              for b, ((times, _), o) in enumerate(zip(items, obs))], anchors, s0)
    t, batch = stack_tracks([times for times, _ in items], obs)
    track = ekf.run(batch, t, prior_mean=prior_mean, prior_cov=prior_cov, smooth=smooth)
    return [track[b, :times.size] for b, (times, _) in enumerate(items)]


def start_states(items: list[tuple[np.ndarray, np.ndarray]], anchors, s: dict,
                 range_std: list[float], labels: list[str] | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of the particles' start state (position and velocity) of each
    segment.

    The smoothed EKF track (:func:`ekf_tracks`) over the start window (the first
    ``init_s`` seconds, at least ``START_STEPS`` steps) at its first step, with range
    error ``s_LOS``: the same ranges that fix the grid-search start position, now also
    fixing the start velocity. Its covariance is inflated by ``START_INFLATION`` (the EKF
    ignores NLOS excess).

    Parameters
    ----------
    items : list of (times (T_b,), ranges (T_b, M))
        Ranges with the bias removed.
    anchors : ndarray, shape (M, 2|3)
    s : dict
        From :func:`radioloc.locate.ekf_track.tracker_settings`.
    range_std : list of float
        ``s_LOS`` of each segment, m.
    labels : list of str, optional
        As for :func:`ekf_tracks`.

    Returns
    -------
    mean : ndarray, shape (B, n)
    covariance : ndarray, shape (B, n, n)
    """
    windows = []
    for times, R in items:
        n = max(int(np.searchsorted(times, times[0] + s["init_s"], side="right")),
                min(START_STEPS, times.size))
        windows.append((times[:n], R[:n]))
    tracks = ekf_tracks(windows, anchors, s, range_std, 16.0, smooth=True, labels=labels)
    mean = np.stack([tr.diagnostics["state"][0] for tr in tracks])
    cov = START_INFLATION * np.stack([tr.diagnostics["state_covariance"][0] for tr in tracks])
    return mean, 0.5 * (cov + np.swapaxes(cov, -1, -2))


def range_residuals(items: list[tuple[np.ndarray, np.ndarray]], anchors, s: dict,
                    labels: list[str] | None = None) -> list[np.ndarray]:
    """Each segment's finite ranges minus the ranges predicted from its RTS-smoothed EKF
    track (range error 0.15 m, gate 16; one batch, :func:`ekf_tracks`).

    Parameters
    ----------
    items : list of (times (T_b,), ranges (T_b, M))
    anchors : ndarray, shape (M, 2|3)
    s : dict
        From :func:`radioloc.locate.ekf_track.tracker_settings`.
    labels : list of str, optional
        As for :func:`ekf_tracks`.

    Returns
    -------
    list of ndarray, shape (n_b,)
    """
    tracks = ekf_tracks(items, anchors, s, [0.15] * len(items), 16.0, smooth=True,
                        labels=labels)
    return [(R - _predicted(tr.position[:, :2], anchors, s["height"]))[np.isfinite(R)]
            for (_, R), tr in zip(items, tracks)]


def node_residuals(per_node: list, anchors, s: dict, method: str) -> dict[str, np.ndarray]:
    """Each node's range residuals to its smoothed EKF tracks (:func:`range_residuals`),
    every segment of every node in one batch.

    Parameters
    ----------
    per_node : list of (node, times (T,), ranges (T, M))
        Ranges with the bias removed.
    anchors : ndarray, shape (M, 2|3)
    s : dict
        From :func:`radioloc.locate.ekf_track.tracker_settings` (``max_gap_s`` splits a
        node's times into segments).
    method : str
        For the message when a segment has no start.

    Returns
    -------
    dict of node to ndarray
    """
    items, owners = [], []
    for node, times, R in per_node:
        for seg in segments(times, s["max_gap_s"]):
            items.append((times[seg], R[seg]))
            owners.append(node)
    res = range_residuals(items, anchors, s, [f"method {method}: node {o!r}" for o in owners])
    out: dict[str, list] = {}
    for o, e in zip(owners, res):
        out.setdefault(o, []).append(e)
    return {o: np.concatenate(e) for o, e in out.items()}


def fit_residuals(e: np.ndarray) -> tuple[LosNlosRange, float, dict]:
    """LOS/NLOS model and range bias fitted by EM on range residuals (those of
    :func:`node_residuals`).

    Residuals more than ``TRIM`` robust standard deviations (1.4826 MAD) from their median
    are left out: the mixture has no component for ranges much too short, and one such
    range would inflate ``s_LOS``; the causal gate of the filter handles them. Of more than
    ``EM_SAMPLES`` residuals, ``EM_SAMPLES`` evenly spaced in log order are fitted (the
    parameters' sampling error is then a few per cent; the fit's cost grows with them).

    Parameters
    ----------
    e : ndarray, shape (n,)
        Range residuals, m.

    Returns
    -------
    model : LosNlosRange
    bias_m : float
    info : dict
        ``samples`` used, ``trimmed``.
    """
    med = float(np.median(e))
    mad = max(1.4826 * float(np.median(np.abs(e - med))), 1e-3)
    keep = np.abs(e - med) <= TRIM * mad          # gross outliers: the gate's job, not EM's
    if keep.sum() < MIN_SAMPLES:
        outliers = f" ({int((~keep).sum())} of them gross outliers)" if (~keep).any() else ""
        raise InputError(f"method pf: the log holds {e.size} range(s) to anchors{outliers}; "
                         f"fitting its LOS/NLOS model by EM needs at least {MIN_SAMPLES}: give a "
                         "longer log, or use --method ekf-track")
    kept = e[keep]
    if kept.size > EM_SAMPLES:
        kept = kept[np.linspace(0, kept.size - 1, EM_SAMPLES).round().astype(np.int64)]
    with threadpool_limits(limits=1, user_api="blas"):   # L-BFGS-B's tiny BLAS calls
        fit = fit_los_nlos(kept, fit_bias=True, alpha0=0.9, los_std0=mad,
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
                     "them (each anchor's range offset, the LOS/NLOS parameters and the "
                     "process noise learned from the log unless given; fixed-lag or "
                     "backward-simulation smoother with -o smooth=1); with other kinds, the "
                     "generic particle filter over every kind's model, the ranges' noise "
                     "LOS/NLOS",
               options=OPTIONS, kinds=tuple(model_kinds()) + ("rss",) + MOTION_KINDS,
               inputs=("anchors",))
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
    if set(request.measurements["kind"].unique()) - {"range", *MOTION_KINDS}:
        return generic_tracks(request, want)
    return pf_tracks(request, (want,))[want]


def generic_tracks(request: LocateRequest, want: str = "filtered") -> pd.DataFrame:
    """``--method pf`` on a log with kinds besides ranges and odometry: the generic
    :class:`~radioloc.estimators.particle_filter.ParticleFilter` over every kind's model
    (:func:`radioloc.locate.ekf_track.log_models`, the sigma options of ``ekf-track``), the
    ranges with the LOS/NLOS model of :func:`node_models` as their noise (given, or fitted
    by EM on the node's ranges, its range bias removed), each segment started from the
    ``ekf-track`` start (:func:`radioloc.locate.ekf_track.track_prior`) on the trackers'
    state layout, its draws seeded by :func:`segment_seed`; ``smooth=1``: the
    backward-simulation smoother. Components other than the motion's follow the
    state's transition without noise (a receiver clock's offset integrates its drift).

    Parameters
    ----------
    request : LocateRequest
    want : {"filtered", "backward"}

    Returns
    -------
    DataFrame
        As :func:`locate_pf`, without ``gated`` and ``p_nlos``.

    Raises
    ------
    ConfigError
        Options of paper 001's filter alone (``gate``, ``lag``, ``smoother=fixed-lag``),
        odometry rows.
    """
    table = request.require_anchors("pf")
    anchors = anchor_positions(table)
    s = tracker_settings(request, anchors)
    only = [k for k in ("gate", "lag") if request.option(k) is not None] + \
        (["smoother=fixed-lag"] if want == "fixed-lag" else []) + \
        (["odometry rows"] if s["odometry_std"] is not None else [])
    if only:
        raise ConfigError(f"method pf: {', '.join(only)} belong to paper 001's filter of ranges "
                          "(and odometry); with other kinds pf runs the generic particle filter")
    if s["bias"]:
        raise ConfigError("method pf: range_bias_m with kinds besides ranges: the bias is fitted "
                          "with the LOS/NLOS model (give los_std_m, nlos_mean_m, alpha to fix it)")
    log, _, models = log_models(request, request.measurements, table, s)
    noise, fitted, learned = {}, [], {}
    if "range" in models:
        ranges = Measurements(request.measurements[request.measurements["kind"] == "range"])
        noise, fitted, learned = node_models(request, anchors,
                                             anchor_ranges(ranges, table, "pf"), s)
    seed, particles = request.option("seed", 0, int), request.option("particles", 900, int)
    tables, counts = [], {}
    for node, times, obs in log_observations(log, table, models, "pf", s["height"]):
        q = s["q"]
        if node in noise:
            los_nlos, bias, q = noise[node]
            obs = [dataclasses.replace(o, model=RangeModel(noise=los_nlos),
                                       z=o.z - bias[o.context.index])
                   if o.model.kind == "range" else o for o in obs]
        for o in obs:
            counts[o.model.kind] = counts.get(o.model.kind, 0) + int(np.isfinite(o.z).sum())
        ekf = tracker_filter(anchors, dict(s, bias=0.0, q=q), None, clock=reads_clock(obs))
        for n, seg in enumerate(segments(times, s["max_gap_s"])):
            t, ob = times[seg], track_window(times, obs, seg, s["init_s"])
            mean, var = track_prior(ekf, t, ob, anchors, dict(s, bias=0.0, q=q))
            pf = ParticleFilter(tracker_motion(dict(s, q=q)), n_particles=particles,
                                seed=[segment_seed(seed, node, n)],
                                layout=ekf.state_layout(ob))
            track = pf.run(ob, t, prior_mean=mean[None], prior_cov=np.diag(var)[None],
                           smooth=want == "backward")
            tables.append(track_table(node, t, track[0], restart=n > 0))
    out = pd.concat(tables, ignore_index=True)
    out.attrs["summary"] = {"nodes": int(out["node"].nunique()), "steps": len(out),
                            "ranges": counts.get("range", 0), "measurements": counts,
                            "restarts": int(out["restart"].sum()), "seed": seed,
                            "particles": particles, "filter": "generic",
                            "smoother": None if want == "filtered" else want, "model": fitted,
                            **({"learned": learned} if learned else {})}
    return out


def pf_tracks(request: LocateRequest, outputs=("filtered",)) -> dict[str, pd.DataFrame]:
    """The filtered and smoothed tracks of ``--method pf`` from one filter pass.

    Parameters
    ----------
    request : LocateRequest
        As for ``locate --method pf`` (its ``smooth`` and ``smoother`` options are ignored:
        ``outputs`` says what to return).
    outputs : tuple of {"filtered", "fixed-lag", "backward"}
        Tracks to return: the causal filter's, the fixed-lag smoother's, the backward
        simulation smoother's (drawn after the filter from a second stream of each
        segment's seed).

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
    table = request.require_anchors("pf")
    anchors = anchor_positions(table)
    per_node = anchor_ranges(Measurements(request.measurements), table, "pf")
    s = tracker_settings(request, anchors)
    if s["odometry_std"] is not None and "backward" in outputs:
        raise ConfigError("option smoother: backward simulation does not take the odometry "
                          "input; with odometry rows use smoother=fixed-lag")
    if s["dim"] != 2:
        raise InputError("method pf: tracks 2-D positions; with 3-D anchors give the node "
                         "height (-o tag_height_m=H)")
    seed = request.option("seed", 0, int)
    particles = request.option("particles", 900, int)
    opts = {"particles": particles, "lag": request.option("lag", 20, int),
            "trajectories": request.option("trajectories", 100, int),
            "gate": request.option("gate", 16.0) or None}
    models, fitted, learned = node_models(request, anchors, per_node, s)
    segs = []
    for node, times, R in per_node:
        for n, seg in enumerate(segments(times, s["max_gap_s"])):
            controls = (None if s["odometry_std"] is None else
                        odometry_controls(request.measurements, node, times[seg], 2))
            model, bias, q = models[node]
            segs.append(Segment(node, times[seg], R[seg], n > 0, model, bias, q, controls,
                                segment_seed(seed, node, n)))
    keep = "fixed-lag" in outputs or "backward" in outputs
    state_dim = tracker_motion(dict(s, dim=2)).state_dim
    groups = []
    for q in dict.fromkeys(sg.q for sg in segs):           # a batch shares its motion model
        mine = [i for i, sg in enumerate(segs) if sg.q == q]
        groups += [[mine[j] for j in g]
                   for g in batches([segs[i] for i in mine], particles, state_dim, keep)]
    tracks: dict[int, dict[str, Track]] = {}
    resets = 0
    with progress(sum(int(np.isfinite(sg.ranges).sum()) for sg in segs), "pf") as bar:
        for g in groups:
            out, r = _filter([segs[i] for i in g], anchors, dict(s, q=segs[g[0]].q), outputs,
                             opts, bar)
            tracks.update(zip(g, out))
            resets += r
    warn_misfit([(sg.node, float(sg.times[0]), tracks[i]["misfit"]) for i, sg in enumerate(segs)],
                models)
    result = {}
    for k in outputs:
        tables = [track_table(sg.node, sg.times, tracks[i][k], restart=sg.restart)
                  for i, sg in enumerate(segs)]
        result[k] = pd.concat(tables, ignore_index=True)
        result[k].attrs["summary"] = track_summary(
            tables, per_node, seed=seed, particles=particles, filter_resets=resets,
            smoother=None if k == "filtered" else k, model=fitted,
            **({"learned": learned} if learned else {}))
    return result


#: Fraction of a segment's steps with the misfit term above the particles' covariance
#: beyond which :func:`warn_misfit` warns.
MISFIT_WARN = 0.5


def warn_misfit(shares: list[tuple[str, float, float]], models: dict) -> None:
    """One warning for the segments whose innovations exceed the LOS/NLOS model's spread at
    more than ``MISFIT_WARN`` of their steps (the reported uncertainty is then mostly the
    misfit term of the module docstring).

    Parameters
    ----------
    shares : list of (node, start time, fraction of steps)
    models : dict of node to (LosNlosRange, bias_m)
    """
    bad = [x for x in shares if x[2] > MISFIT_WARN]
    if not bad:
        return
    node, t0, share = max(bad, key=lambda x: x[2])
    m = models[node][0]
    warnings.warn(
        f"method pf: {len(bad)} of {len(shares)} track(s) meet ranges farther from their "
        f"prediction than the LOS/NLOS model allows (worst: node {node!r} from time {t0!r}, "
        f"at {100 * share:.0f} % of its steps); the reported uncertainty includes that "
        f"misfit; los_std_m={m.los_std_m:g}, nlos_mean_m={m.nlos_mean_m:g} too small for "
        "this log?", stacklevel=2)


@dataclasses.dataclass(frozen=True)
class Segment:
    """One node's ranges between two gaps longer than ``max_gap_s``: one particle filter.

    Attributes
    ----------
    node : str
    times : ndarray, shape (T,)
    ranges : ndarray, shape (T, M)
        Ranges to the anchors as measured (NaN: none).
    restart : bool
        Not the node's first segment.
    model : LosNlosRange
        The node's LOS/NLOS model.
    bias : ndarray, shape (M,)
        The range bias of each anchor's ranges, m.
    q : float
        Process noise of the node's motion.
    controls : ndarray, shape (T, 2) or None
        Odometry displacement over each step.
    seed : numpy.random.SeedSequence
        Of the segment's draws (:func:`segment_seed`).
    """

    node: str
    times: np.ndarray
    ranges: np.ndarray
    restart: bool
    model: LosNlosRange
    bias: np.ndarray
    q: float
    controls: np.ndarray | None
    seed: np.random.SeedSequence


def segment_seed(seed: int, node: str, index: int) -> np.random.SeedSequence:
    """Seed of a segment's draws: from the ``seed`` option, the node's name and the
    segment's index within the node, so that a node's track does not depend on the other
    nodes of the log, nor on which segments share a batch.

    Parameters
    ----------
    seed : int
    node : str
    index : int

    Returns
    -------
    numpy.random.SeedSequence
    """
    return np.random.SeedSequence([int(seed), zlib.crc32(str(node).encode("utf-8")), int(index)])


def learned_ranges(request: LocateRequest, s: dict) -> dict:
    """Each node's settings learned from its range rows as ``ekf-track`` learns them
    (:func:`radioloc.locate.ekf_track.learn_tracks`): by node, the
    :class:`~radioloc.locate.self_tuning.Learned` of the nodes whose anchor offsets and
    LOS/NLOS mixture were learned; empty with ``-o tune=0``, a given ``range_bias_m``,
    odometry rows, or a log too short to learn from.

    Parameters
    ----------
    request : LocateRequest
    s : dict
        From :func:`radioloc.locate.ekf_track.tracker_settings`.

    Returns
    -------
    dict of node to Learned
    """
    if not request.option("tune", True, bool) or s["odometry_std"] is not None or s["bias"]:
        return {}
    given = given_sigmas(request)
    meas = request.measurements[request.measurements["kind"] == "range"]
    if not_learnable(meas, given) is not None:
        return {}
    table = request.require_anchors("pf")
    log, _, models = log_models(request, meas, table, s, anchor_bias=True)
    tracks = segment_tracks(log_observations(log, table, models, "pf", s["height"]), s)
    learned = learn_tracks(request, tracks, table, s, 16.0, given)
    return {node: lr for node, lr in learned.items()
            if lr.offset_m is not None and lr.report.get("range_mixture")}


def node_models(request: LocateRequest, anchors, per_node: list, s: dict
                ) -> tuple[dict, list[dict], dict]:
    """Each node's LOS/NLOS model, range bias by anchor and process noise (see the module
    docstring).

    The given ``los_std_m``, ``nlos_mean_m``, ``alpha`` are used; when any is missing, the
    missing ones come from what was learned of the node (:func:`learned_ranges`: its
    anchors' offsets as the bias, the learned ``q``) or, where nothing was learned, they
    and one range bias (unless ``range_bias_m`` is given) are fitted by EM on the node's
    residuals (:func:`fit_residuals`) to its smoothed EKF track, the tracks of every node
    in one batch (:func:`range_residuals`); ``min_los_std_m`` floors a fitted ``s_LOS``.

    Parameters
    ----------
    request : LocateRequest
    anchors : ndarray, shape (M, 2|3)
    per_node : list of (node, times, ranges)
        From :func:`radioloc.locate.adapter.anchor_ranges`.
    s : dict
        From :func:`radioloc.locate.ekf_track.tracker_settings`.

    Returns
    -------
    models : dict of node to (LosNlosRange, bias (M,), q)
        The bias of each anchor's ranges, m (one value for all but where learned).
    fitted : list of dict
        Per node: ``node``, the three parameters, ``range_bias_m`` (by anchor id where
        learned), ``q``, ``fitted`` (``"learned"``, ``"em"`` or ``"given"``).
    learned : dict of node to dict
        What was learned of each node (its ``summary.json`` entry).
    """
    names = ("los_std_m", "nlos_mean_m", "alpha")
    given = [request.option(k) for k in names]
    fit = any(g is None for g in given)
    learned = learned_ranges(request, s) if fit else {}
    rest = [p for p in per_node if p[0] not in learned]
    residuals = node_residuals(rest, anchors, s, "pf") if fit and rest else {}
    floor = request.option("min_los_std_m", 0.15)
    ids = [str(a) for a in request.anchors["id"]] if learned else []
    models, fitted = {}, []
    for node, _, _ in per_node:
        bias, q, values = np.full(len(anchors), float(s["bias"])), s["q"], list(given)
        if node in learned:
            lr = learned[node]
            mix = lr.report["range_mixture"]
            auto = [max(mix["los_std_m"], floor), mix["nlos_mean_m"], mix["los_fraction"]]
            bias, q = np.asarray(lr.offset_m, dtype=float), lr.q
        elif fit:
            model, fit_bias, _ = fit_residuals(residuals[node])
            auto = [max(model.los_std_m, floor), model.nlos_mean_m, model.alpha]
            if "range_bias_m" not in request.parsed:
                bias = np.full(len(anchors), float(fit_bias))
        values = [a if g is None else g for g, a in zip(given, auto)] if fit else values
        models[node] = (LosNlosRange(*values), bias, float(q))
        fitted.append({"node": node, **dict(zip(names, map(float, values))),
                       "range_bias_m": (dict(zip(ids, map(float, bias))) if node in learned
                                        else float(bias[0])), "q": float(q),
                       "fitted": "learned" if node in learned else "em" if fit else "given"})
    return models, fitted, {str(n): lr.report for n, lr in learned.items()}


#: Bytes of stored particle sets (for a smoother) per batch of segments.
HISTORY_BYTES = 1 << 28


def batches(segs: list[Segment], particles: int, state_dim: int, keep: bool) -> list[list[int]]:
    """Segments run as one batch of filters: all of them, longest first; with a smoother
    (``keep``), as many as keep the stored particle sets within ``HISTORY_BYTES``.

    Parameters
    ----------
    segs : list of Segment
    particles : int
    state_dim : int
    keep : bool

    Returns
    -------
    list of list of int
        Indices into ``segs``.
    """
    order = sorted(range(len(segs)), key=lambda i: -segs[i].times.size)
    if not keep:
        return [order]
    out: list[list[int]] = []
    for i in order:
        per = segs[i].times.size * particles * (state_dim + 1) * 8
        if out and (len(out[-1]) + 1) * max(segs[out[-1][0]].times.size * particles *
                                            (state_dim + 1) * 8, per) <= HISTORY_BYTES:
            out[-1].append(i)
        else:
            out.append([i])
    return out


#: Steps over which :class:`Misfit` averages (the weight of older steps decays by
#: ``1 - 1 / MISFIT_STEPS`` per step).
MISFIT_STEPS = 5
#: A range's squared innovation counts at most this many times its predicted variance in
#: :class:`Misfit` (one gross outlier then moves the floor little).
MISFIT_CLIP = 16.0


class Misfit:
    """Position covariance implied by innovations larger than the filter predicts (see the
    module docstring), for a batch of ``B`` filters.

    Parameters
    ----------
    B : int
    clip : float
        A range's squared innovation counts at most ``clip`` times its predicted variance.

    Attributes
    ----------
    covariance : ndarray, shape (B, 2, 2)
        ``eps^2 (A / n)^-1`` after the last :meth:`update`.
    """

    def __init__(self, B: int, clip: float) -> None:
        self.clip = float(clip)
        self.excess = np.zeros(B)         # decayed sum of min(nu^2, clip S) - S
        self.count = np.zeros(B)          # decayed number of ranges
        self.steps = np.zeros(B)          # decayed number of steps with a range
        self.info = np.zeros((B, 2, 2))   # decayed sum of u u^T
        self.covariance = np.zeros((B, 2, 2))

    def update(self, nu: np.ndarray, S: np.ndarray, u: np.ndarray, finite: np.ndarray) -> None:
        """Take one step's innovations.

        Parameters
        ----------
        nu, S : ndarray, shape (B, M)
            Innovations (NaN where ``finite`` is False) and their predicted variances.
        u : ndarray, shape (B, M, 2)
            Unit vectors from the anchors to the predicted position.
        finite : ndarray of bool, shape (B, M)
        """
        keep = 1.0 - 1.0 / MISFIT_STEPS
        with np.errstate(invalid="ignore"):
            c = np.where(finite, np.minimum(nu * nu, self.clip * S) - S, 0.0)
        self.excess = keep * self.excess + c.sum(axis=-1)
        self.count = keep * self.count + finite.sum(axis=-1)
        self.steps = keep * self.steps + finite.any(axis=-1)
        w = finite[..., None] * u
        self.info = keep * self.info + np.einsum("bmi,bmj->bij", w, u)
        eps2 = np.maximum(self.excess, 0.0) / np.maximum(self.count, 1e-12)
        per_step = self.info / np.maximum(self.steps, 1e-12)[:, None, None] + 1e-6 * np.eye(2)
        self.covariance = eps2[:, None, None] * np.linalg.inv(per_step)


def horizontal(r: np.ndarray, anchors: np.ndarray, height: float | None) -> np.ndarray:
    """Ranges (..., M) projected to the horizontal plane at the node height (3-D anchors)."""
    if anchors.shape[1] != 3:
        return r
    dz = height - anchors[:, 2]
    return np.where(np.isfinite(r), np.sqrt(np.maximum(r * r - dz * dz, 0.0)), np.nan)


def _filter(group: list[Segment], anchors, s, outputs, opts, bar) -> tuple[list[dict], int]:
    """The particle-filter tracks of a batch of segments (see the module docstring), each
    with ``"misfit"``, the fraction of its steps whose :class:`Misfit` covariance exceeds
    the particles' (trace), and the number of resets."""
    from radioloc.estimators.p2p_particle import P2PParticleFilter   # numba: when pf runs

    B, T, M = len(group), max(g.times.size for g in group), anchors.shape[0]
    K = opts["particles"]
    motion = tracker_motion(dict(s, dim=2))
    n = motion.state_dim
    t = np.empty((B, T))
    r = np.full((B, T, M), np.nan)
    controls = None if s["odometry_std"] is None else np.zeros((B, T, 2))
    for b, g in enumerate(group):          # padded: steps of zero length with no range
        t[b, :g.times.size], t[b, g.times.size:] = g.times, g.times[-1]
        r[b, :g.times.size] = horizontal(g.ranges - g.bias, anchors, s["height"])
        if controls is not None:
            controls[b, :g.times.size] = g.controls
    dts = np.diff(t, axis=1, prepend=t[:, :1])
    F, Q = motion.F(dts), motion.Q(dts)                                    # (B, T, n, n)
    mean0, cov0 = start_states([(g.times, g.ranges - g.bias) for g in group], anchors, s,
                               [g.model.los_std_m for g in group],
                               [f"method pf: node {g.node!r}" for g in group])
    mean0, cov0 = mean0[:, :n], cov0[:, :n, :n]
    pf = P2PParticleFilter(motion, group[0].model, particles=K, reset_fraction=RESET_FRACTION)
    rng = RunGenerators([g.seed for g in group], (B,))
    state = pf.init(mean0, rng, time=t[:, 0])
    draws = mean0[:, None, :] + np.einsum("bij,bkj->bki", np.linalg.cholesky(cov0),
                                          rng.standard_normal((B, K, n)))
    params = np.array([[g.model.los_std_m, g.model.nlos_mean_m, g.model.alpha] for g in group])
    state = dataclasses.replace(state, particles=draws, covariance=cov0.copy(), params=params)
    xy = anchors[:, :2]
    nodes = np.broadcast_to(xy, (B, M, 2))
    moments = np.array([g.model.moments() for g in group])        # (B, 2): mean, variance
    keep = "fixed-lag" in outputs or "backward" in outputs
    gate = opts["gate"]
    means, covs, extra = np.empty((T, B, n)), np.empty((T, B, n, n)), np.empty((T, B, 2, 2))
    dominant = np.zeros((B, T), dtype=bool)      # the misfit term exceeds the particles'
    history, ancestors = [], []
    streak = np.zeros(B, dtype=np.int64)
    gated = np.zeros((B, T), dtype=np.int64)
    p_nlos = np.zeros((B, T))
    misfit = Misfit(B, MISFIT_CLIP)
    kernel = float(K) ** (-1.0 / 3.0)        # Silverman's h^2 for K particles in 2-D
    for k in range(T):
        row = r[:, k]
        finite = np.isfinite(row)
        # innovation of each range: its residual to the range from the predicted mean, and
        # its variance (particle spread along the line of sight, misfit, mixture)
        pred = np.einsum("bij,bj->bi", F[:, k, :2], state.mean)                 # (B, 2)
        if controls is not None:
            pred = pred + controls[:, k]
        diff = pred[:, None, :] - xy                                             # (B, M, 2)
        d = np.sqrt(np.sum(diff * diff, axis=-1))
        u = diff / np.maximum(d, 1e-9)[..., None]
        P = (F[:, k] @ state.covariance @ np.swapaxes(F[:, k], -1, -2) + Q[:, k])[:, :2, :2]
        S = np.einsum("bmi,bij,bmj->bm", u, P + misfit.covariance, u) + moments[:, 1:]
        nu = row - d - moments[:, :1]
        misfit.update(nu, S, u, finite)
        if gate:   # causal gate
            active = (streak < GATE_PATIENCE) & finite.any(axis=-1)
            S_gate = np.einsum("bmi,bij,bmj->bm", u, P, u) + moments[:, 1:]   # no misfit
            out = finite & active[:, None] & (nu * nu > gate * S_gate)
            count = out.sum(axis=-1)
            streak = np.where(active & (count == finite.sum(axis=-1)), streak + 1, 0)
            gated[:, k] = count
            row = np.where(out, np.nan, row)
        state = pf.step(state, row, nodes, rng, dt=dts[:, k], check=False,
                        control=None if controls is None else controls[:, k])
        bar.advance(int(finite.sum()))                  # the rows of the step
        means[k], covs[k] = state.mean, state.covariance
        extra[k] = misfit.covariance + kernel * P
        dominant[:, k] = np.trace(misfit.covariance, axis1=-2, axis2=-1) > \
            np.trace(state.covariance[:, :2, :2], axis1=-2, axis2=-1)
        used = state.links >= 0
        if used.any():   # the largest NLOS probability among the ranges used
            los = np.einsum("bkl->bl", state.link_los) / K   # the mean over the particles
            p_nlos[:, k] = np.max(np.where(used, 1.0 - los, 0.0), axis=-1)
        if keep:
            history.append(state.particles)
            ancestors.append(state.ancestors)
    out = []
    for b, g in enumerate(group):
        size = g.times.size
        flags = {"gated": gated[b, :size], "p_nlos": p_nlos[b, :size]}
        floor = extra[:size, b]
        tracks = {}
        if "filtered" in outputs:
            tracks["filtered"] = Track(means[:size, b, :2], covs[:size, b, :2, :2] + floor,
                                       g.times, flags)
        if "fixed-lag" in outputs:
            mean, cov = fixed_lag([h[b] for h in history[:size]],
                                  [a[b] for a in ancestors[:size]], opts["lag"])
            tracks["fixed-lag"] = Track(mean[:, :2], cov[:, :2, :2] + floor, g.times, flags)
        if "backward" in outputs:
            mean, cov = backward_simulation([h[b] for h in history[:size]], g.times, motion,
                                            opts["trajectories"],
                                            np.random.default_rng(g.seed.spawn(1)[0]))
            tracks["backward"] = Track(mean[:, :2], cov[:, :2, :2] + floor, g.times, flags)
        tracks["misfit"] = float(dominant[b, :size].mean())
        out.append(tracks)
    return out, int(state.resets.sum())
