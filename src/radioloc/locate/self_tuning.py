"""Settings learned from the user's own log: the noise of each kind, each anchor's range bias
and how its error wanders, the outlier (NLOS) mixture, and the process noise.

``ekf-track`` and ``smoother`` learn them by default (``-o tune=0``: the fixed defaults of
before); an option given with ``-o`` is used as given and not learned. Everything is learned
per node, from that node's rows only (the nodes' filter runs share one batch,
:func:`learn_nodes`, and do not interact), in three steps:

Each node's first :data:`LEARN_STEPS` steps are read, over its tracks in time order (step 3:
:data:`EVIDENCE_STEPS`).

1. **Scale and process noise by evidence.** The node's tracks are filtered (extended Kalman
   filter, with a constant range bias per anchor in the state when the log has ranges) with
   every sigma at its kind's default times each factor of :data:`SCALES` (all factors in one
   batch) at the default process noise ``q``; the factor with the largest evidence wins, and
   then, at that factor, the ``q`` of :data:`Q_FACTORS` times the default with the largest
   evidence (not in step 3: there the Gauss-Markov wander and the motion explain the same
   residuals, and the evidence chose stiff tracks that follow a turning walker late, e.g. on
   the Hanyang UWB runs). The evidence is the log predictive density of every row,
   ``sum -1/2 (log 2 pi S + min(nu^2 / S, gate))``: a row the gate refuses counts at the
   gate, so a filter that loses the track and refuses its rows scores low.
2. **Noise from residuals (one EM step).** At the Rauch-Tung-Striebel smoothed states of
   that run, the residual of every row. Ranges, per anchor: the static bias (the smoothed
   bias state plus the residuals' median), and the error about it split, from the
   residuals' autocovariance ``C(k)``, into a white part ``sigma_w`` and a first-order
   Gauss-Markov part of stationary deviation ``sigma_g`` and time constant ``tau``
   (``C(k) = sigma_g^2 exp(-k dt / tau)`` for ``k >= 1``, fitted in log over the lags where
   it is clearly positive): range errors from multipath stay correlated over seconds while
   the node walks, and a filter that takes them as white claims far too little uncertainty.
   Residuals at a fitted track are smaller than the errors (the track absorbs part of them):
   each row's expected squared residual is ``sigma^2 (1 - h)``, ``h = H P H' / sigma^2`` its
   leverage under the smoothed covariance ``P``, so the (co)variances are divided by the
   mean of ``1 - h`` over the anchor's rows. The LOS/NLOS mixture (LOS spread, NLOS mean excess, LOS fraction) is fitted
   by EM to the bias-free range residuals (:func:`radioloc.locate.pf.fit_residuals`); the
   other kinds get a robust standard deviation (1.4826 MAD) of their residuals.
3. **Correlation by evidence.** The filter runs again with what step 2 found (each
   anchor's bias a constant about its learned offset, with the offsets' covariance, plus a
   Gauss-Markov part), for each factor of :data:`CORRELATION_SCALES` on ``sigma_g``, over
   the node's first :data:`EVIDENCE_STEPS` steps; the largest evidence wins.

Each learned value is reported in ``summary.json`` (``learned``, by node) with a 95 %
interval: a standard deviation ``s`` from ``n_eff`` effectively independent rows has
``s (1 +- 1.96 / sqrt(2 n_eff))``; an offset ``b +- 1.96 sqrt(sigma_g^2 2 tau / span +
sigma_w^2 / n)``; ``tau`` and ``sigma_g`` the span of their estimates on the whole log and
on its two halves; ``q`` the evidence's choice among its factors (the interval: the
neighbouring factors whose evidence is within 2 nats).

Nothing is learned from a log too short for it or whose every row states its ``std``
(:func:`not_learnable`): the fixed defaults run, and ``summary.json``'s ``tune`` says why. A
row's stated ``std`` is always kept.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from radioloc.core.errors import GeometryError, InputError
from radioloc.core.kinds import model_kinds

__all__ = ["CORRELATION_SCALES", "Q_FACTORS", "SCALES", "Learned", "learn_nodes",
           "learned_noise", "not_learnable", "offsets_taken_off", "tuned_observations"]

#: Factors on every kind's default sigma tried in step 1.
SCALES = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
#: Factors on the default process noise ``q`` tried in step 1.
Q_FACTORS = (0.1, 1.0, 10.0)
#: Factors on each anchor's learned Gauss-Markov deviation tried in step 3.
CORRELATION_SCALES = (1.0, 1.5, 2.0)
#: Fewest rows of an anchor for its own noise; fewer take the node's median over anchors.
MIN_ANCHOR_ROWS = 30
#: Autocovariance lags (steps of that anchor's rows) fitted in step 2.
LAGS = 10
#: Longest time constant learned, s (longer: a random walk would do as well).
MAX_TAU_S = 60.0
#: Steps of each node (its first, over its tracks) from which the noise is learned (steps 1
#: and 2: the smoothed run keeps every step's covariance for each of :data:`SCALES`, so its
#: memory grows with them).
LEARN_STEPS = 5000
#: Steps of each node (its first) whose evidence chooses the correlation scale (step 3).
EVIDENCE_STEPS = 2000
#: Most track-steps (tracks times their steps) in one filter run that only weighs evidence
#: (steps 1 and 3; more run in parts): every step keeps its state covariance, so this bounds
#: the memory of learning (about 0.2-0.5 GB) however many nodes the log holds.
MAX_ITEM_STEPS = 200_000


@dataclass
class Learned:
    """What :func:`learn_nodes` found for one node (arrays by row of the anchor table).

    Attributes
    ----------
    scale : float
        Step 1's factor on the default sigmas.
    sigma : dict of str to float
        Each non-range kind's sigma (its option name to the value).
    offset_m, white_m, correlated_m, tau_s : ndarray, shape (A,) or None
        Ranges: each anchor's static bias, white noise, Gauss-Markov deviation and time
        constant (None: the log has no ranges).
    offset_cov : ndarray, shape (A, A) or None
        Covariance of the offsets (module docstring).
    q : float
        Process noise of the motion model.
    correlation_scale : float
        Step 3's factor on ``correlated_m``.
    given : tuple of str
        The sigma options the user gave (their kinds keep them).
    report : dict
        JSON-ready values with intervals, for ``summary.json``.
    """

    scale: float
    sigma: dict = field(default_factory=dict)
    offset_m: np.ndarray | None = None
    offset_cov: np.ndarray | None = None
    white_m: np.ndarray | None = None
    correlated_m: np.ndarray | None = None
    tau_s: np.ndarray | None = None
    q: float = 1.0
    correlation_scale: float = 1.0
    given: tuple = ()
    report: dict = field(default_factory=dict)

    def bias_settings(self, scale: float | np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The filter's two bias states per anchor (a constant about the learned offset, and
        a Gauss-Markov part): driving-noise intensity ``(..., 2A)`` (0, then
        ``s sigma_g sqrt(2 / tau)``), time constants ``(..., 2A)`` (inf, then ``tau``) and
        prior covariance ``(..., 2A, 2A)`` (the offsets' covariance, then ``(s sigma_g)^2``
        on the diagonal), ``s`` the correlation scale (default the learned one; an array
        ``(K, 1)`` gives one row per scale)."""
        s = self.correlation_scale if scale is None else np.asarray(scale, dtype=float)
        g = s * self.correlated_m
        zero = np.zeros(np.shape(g))
        A = self.offset_cov.shape[-1]
        q = np.concatenate([zero, g * np.sqrt(2.0 / self.tau_s)], axis=-1)
        tau = np.concatenate([zero + np.inf, zero + self.tau_s], axis=-1)
        cov = np.zeros(np.shape(g)[:-1] + (2 * A, 2 * A))
        cov[..., :A, :A] = self.offset_cov
        cov[..., np.arange(A, 2 * A), np.arange(A, 2 * A)] = g ** 2
        return q, tau, cov


def evidence(track, observations: list, gate: float | None) -> np.ndarray:
    """Log predictive density of every heard row of a filtered run, per batch member
    (module docstring: a refused row counts at the gate)."""
    nu = track.diagnostics["innovation"]
    S = np.diagonal(track.diagnostics["innovation_covariance"], axis1=-2, axis2=-1)
    heard = np.concatenate([np.isfinite(o.z) for o in observations], axis=-1)
    g = np.inf if gate is None else gate
    with np.errstate(invalid="ignore", divide="ignore"):
        r2 = np.where(np.isfinite(nu), np.minimum(nu ** 2 / S, g), g)
        lp = -0.5 * (np.log(2 * np.pi * S) + r2)
    lp = np.where(heard & np.isfinite(lp), lp, 0.0)
    return lp.sum(axis=(-2, -1))


def not_learnable(meas, given=()) -> str | None:
    """Why the settings are not learned from this log (None: they are).

    Every node needs an anchor it ranges to :data:`MIN_ANCHOR_ROWS` times or more (a node
    without ranges: that many rows of one kind); a log whose every row states its ``std``,
    or whose every kind has its sigma option given, has its noise already. Otherwise the
    fixed defaults (and the stated stds) run.

    Parameters
    ----------
    meas : DataFrame
        The measurements (``node``, ``peer``, ``kind`` columns, ``std`` optional).
    given : collection of str
        The sigma options given.
    """
    if "std" in meas.columns and bool(np.isfinite(meas["std"].to_numpy(float)).all()):
        return "every row states its std: they ran as stated, with the fixed defaults (tune=0)"
    kinds = model_kinds()
    options = {kinds[k].sigma_option for k in meas["kind"].unique()
               if k in kinds and kinds[k].sigma_option}
    if options and options <= set(given):
        return (f"every kind's sigma is given ({', '.join(sorted(options))}): the fixed "
                "defaults (tune=0) ran")
    for node, rows in meas.groupby("node", sort=False):
        ranges = rows[rows["kind"] == "range"]
        most = int((ranges.groupby("peer").size() if len(ranges)
                    else rows.groupby("kind").size()).max())
        if most < MIN_ANCHOR_ROWS:
            what = "ranges to its best-heard anchor" if len(ranges) else "rows of one kind"
            return (f"node {node!r} has {most} {what}, fewer than the {MIN_ANCHOR_ROWS} "
                    "needed to learn its noise: the fixed defaults (tune=0) ran")
    return None


def _with_std(o, std) -> object:
    """``o`` with ``std`` on its measured rows, a std its log stated kept."""
    new = np.where(np.isfinite(o.z), std, np.nan)
    if o.std is not None:
        new = np.where(np.isfinite(o.std), o.std, new)
    return replace(o, std=new)


def _scaled(observations: list, factor: float | np.ndarray, given: dict) -> list:
    """Observations with each row's std its kind's default times ``factor`` (a kind whose
    sigma option was given keeps it, as does a row whose std the log states)."""
    out = []
    for o in observations:
        k = model_kinds().get(o.model.kind)
        if k is None or k.sigma_option in given:
            out.append(o)
            continue
        f = np.asarray(factor, dtype=float).reshape(np.shape(factor) + (1,) * 2)
        out.append(_with_std(o, k.sigma_default * f))
    return out


def _residuals(layout, track, observations: list, b: int, scale: float
               ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Residuals ``(T, S)`` of one track's observations at batch member ``b``'s smoothed
    states, with each row's leverage ``H P H' / sigma^2`` (``P`` the smoothed covariance,
    ``sigma`` the row's std at step 1's ``scale``): a residual's expected square is
    ``sigma^2 (1 - leverage)``, the share of its error the track did not absorb."""
    steps = observations[0].steps
    X = track.diagnostics["state"][b, :steps]
    P = track.diagnostics["state_covariance"][b, :steps]
    out = []
    for o in observations:
        if o.moving:
            parts = [layout.measure(o.model, X[t], o.at(t)[1]) for t in range(steps)]
            z_hat, H = np.stack([p[0] for p in parts]), np.stack([p[1] for p in parts])
        else:
            z_hat, H = layout.measure(o.model, X, o.context)
        k = model_kinds().get(o.model.kind)
        var = (scale * (k.sigma_default if k is not None else 1.0)) ** 2
        lev = np.clip(np.einsum("tsi,tij,tsj->ts", H, P, H) / var, 0.0, 0.95)
        out.append((o.model.residual(o.z, z_hat), lev))
    return out


def _halves(halves: list, whole: float) -> list[float]:
    """The span of an estimate on the two halves of the log and on all of it."""
    return [float(min(*halves, whole)), float(max(*halves, whole))]


def _correlation(x: np.ndarray, dt: float, dof: float) -> tuple[float, float, float]:
    """White deviation, Gauss-Markov deviation and time constant of one anchor's residuals
    (module docstring, step 2), ``x`` centred and clipped, ``dof`` the factor on their
    (co)variances (``1 / mean(1 - leverage)``)."""
    C0 = float(np.mean(x * x)) * dof
    lags = np.arange(1, min(LAGS, x.size // 3) + 1)
    C = np.array([np.mean(x[:-L] * x[L:]) for L in lags]) * dof
    good = C > 0.05 * C0
    if good.sum() >= 2:
        A = np.vstack([np.ones(good.sum()), lags[good] * dt]).T
        c, slope = np.linalg.lstsq(A, np.log(C[good]), rcond=None)[0]
        tau = float(np.clip(-1.0 / slope, dt, MAX_TAU_S)) if slope < 0 else MAX_TAU_S
        g2 = float(min(np.exp(c), 0.95 * C0))
    else:
        tau, g2 = dt, 0.05 * C0
    return float(np.sqrt(max(C0 - g2, 0.05 * C0))), float(np.sqrt(g2)), tau


def _interval(value: float, n_eff: float) -> list[float]:
    """95 % interval of a standard deviation from ``n_eff`` independent values."""
    h = 1.96 / np.sqrt(2.0 * max(n_eff, 1.0))
    return [float(value * max(1.0 - h, 0.0)), float(value * (1.0 + h))]


def _range_noise(res: list, times: list, index: np.ndarray, n_anchors: int, dim: int,
                 bias_state: np.ndarray, bias_cov: np.ndarray, row_std: float,
                 names: list) -> dict:
    """Step 2 for the ranges of one node (``res``: per segment ``(T, S)`` residuals).

    The offsets' covariance is step 1's posterior covariance of the constant biases
    (``bias_cov``, which holds how the geometry ties them to the track), rescaled per anchor
    from the white rows of std ``row_std`` step 1 assumed to the errors found: the variance
    of a mean of ``n`` such errors, ``sigma_w^2 / n + sigma_g^2 2 tau / span``, against
    ``row_std^2 / n``."""
    from radioloc.locate.pf import fit_residuals

    R = np.concatenate([r for r, _ in res])
    lev = np.concatenate([h for _, h in res])
    t = np.concatenate(times)
    heard = np.isfinite(R)
    rows = []
    for j in range(R.shape[1]):
        ok = heard[:, j]
        if ok.sum() < MIN_ANCHOR_ROWS:
            rows.append(None)
            continue
        x, tt = R[ok, j], t[ok]
        dof = 1.0 / max(float(np.mean(1.0 - lev[ok, j])), 0.05)
        med = float(np.median(x))
        mad = max(1.4826 * float(np.median(np.abs(x - med))), 1e-3)
        xc = np.clip(x - med, -3 * mad, 3 * mad)
        dt = float(np.median(np.diff(tt))) if tt.size > 1 else 1.0
        w, g, tau = _correlation(xc, max(dt, 1e-3), dof)
        span = max(float(tt[-1] - tt[0]), dt)
        n_eff = max(span / (2 * tau), 1.0)
        off = float(bias_state[index[j]]) + med
        refit = [_correlation(v - v.mean(), dt, dof) for v in np.array_split(xc, 2)]
        half_g = _halves([f[1] for f in refit], g)
        half_tau = _halves([f[2] for f in refit], tau)
        k = (g * g * 2 * tau / span + w * w / ok.sum()) * ok.sum() / row_std ** 2
        rows.append({"anchor": names[index[j]], "rows": int(ok.sum()), "offset_m": off,
                     "inflation": float(np.sqrt(max(k, 1.0))),
                     "white_m": w, "white_m_95": _interval(w, ok.sum()),
                     "correlated_m": g, "correlated_m_95": half_g,
                     "tau_s": tau, "tau_s_95": half_tau, "n_eff": n_eff})
    known = [r for r in rows if r is not None]
    if not known:
        raise GeometryError(f"no anchor has {MIN_ANCHOR_ROWS} ranges to learn its noise from")
    # the level from the evidence (row_std), the anchors' ratios and the white / correlated
    # split from the residuals (which the track absorbs in part)
    level = row_std / float(np.median([np.hypot(r["white_m"], r["correlated_m"])
                                       for r in known]))
    for r in known:
        r["white_m"], r["correlated_m"] = r["white_m"] * level, r["correlated_m"] * level
        r["white_m_95"] = _interval(r["white_m"], r["rows"])
        r["correlated_m_95"] = [v * level for v in r["correlated_m_95"]]
    pooled = {k: float(np.median([r[k] for r in known]))
              for k in ("white_m", "correlated_m", "tau_s")}
    offset = np.zeros(n_anchors)
    inflation = np.ones(n_anchors)
    white, corr, tau = (np.full(n_anchors, pooled[k]) for k in ("white_m", "correlated_m",
                                                                   "tau_s"))
    for j, r in enumerate(rows):
        if r is not None:
            a = index[j]
            offset[a], white[a], corr[a], tau[a] = (r["offset_m"], r["white_m"],
                                                    r["correlated_m"], r["tau_s"])
            inflation[a] = r["inflation"]
    free = R - np.array([np.median(R[heard[:, j], j]) if heard[:, j].any() else 0.0
                         for j in range(R.shape[1])])
    mixture = None
    try:
        los, _, _ = fit_residuals(free[heard])
        mixture = {"los_std_m": float(los.los_std_m), "nlos_mean_m": float(los.nlos_mean_m),
                   "los_fraction": float(los.alpha)}
    except InputError:
        pass
    cov = inflation[:, None] * bias_cov * inflation[None, :]
    unheard = np.ones(n_anchors, dtype=bool)
    unheard[[index[j] for j, r in enumerate(rows) if r is not None]] = False
    big = float(np.median([abs(r["offset_m"]) for r in known])) + pooled["white_m"]
    cov[unheard, :] = 0.0                   # an anchor not learned: about as large as any
    cov[:, unheard] = 0.0
    cov[unheard, unheard] = big ** 2
    for r in known:
        a = names.index(r["anchor"])
        sd = float(np.sqrt(cov[a, a]))
        r["offset_m_95"] = [r["offset_m"] - 1.96 * sd, r["offset_m"] + 1.96 * sd]
    return {"offset": offset, "offset_cov": cov, "white": white, "correlated": corr,
            "tau": tau, "anchors": known, "pooled": pooled, "mixture": mixture}


def learn_nodes(nodes: dict, make_filter, prior, gate: float | None, given: dict,
                q_default: float, anchor_names: list, dim: int, q_given: bool = False
                ) -> dict:
    """Learn each node's settings from its tracks (module docstring), the nodes' runs in one
    batch: each filter run holds every track of every node (each with its own process noise
    and anchor-bias settings), so a log of many nodes costs about as many time steps as its
    longest node. A node's result is that of its run alone: the batch members do not
    interact.

    Parameters
    ----------
    nodes : dict of str to list of (times (T,), observations)
        Each node's segments.
    make_filter : callable
        ``make_filter(q, bias_std, tau, bias_terms)`` -> ExtendedKalmanFilter (``q`` of shape
        ``(B, 1)``, one per batch member, broadcast over the time steps; ``bias_terms``
        0: no anchor bias, the node has no ranges; else its anchor
        biases as :func:`radioloc.locate.ekf_track.tracker_filter` takes them).
    prior : callable
        ``prior(ekf, times, observations, bias_cov)`` -> (mean (n,), cov (n, n)); with
        ``bias_cov`` (2A, 2A) the anchor biases start at 0 with this covariance (the learned
        offsets are then in the range model), else about a common offset. It may not depend
        on the rows' ``std`` (the factors tried): it is asked once per track and
        ``bias_cov``.
    gate : float or None
    given : dict
        The sigma options given (kept, not learned).
    q_default : float
        The process noise's default (or the value given, with ``q_given``: then kept).
    anchor_names : list of str
        Ids of the anchor table's rows.
    dim : int
        Position coordinates.

    Returns
    -------
    dict of str to Learned
    """
    ranged = {n: any(o.model.kind == "range" for _, obs in tracks for o in obs)
              for n, tracks in nodes.items()}
    out = {}
    for has_ranges in (False, True):         # the filter holds anchor biases or not
        group = {n: tracks for n, tracks in nodes.items() if ranged[n] == has_ranges}
        if group:
            out.update(_learn_group(group, has_ranges, make_filter, prior, gate, given,
                                    q_default, anchor_names, dim, q_given))
    return {n: out[n] for n in nodes}


def _window(tracks: list, steps: int) -> list:
    """A node's first ``steps`` steps, over its tracks in time order: a run that reads the
    log in chunks learns from the same rows (:mod:`radioloc.locate.chunked`)."""
    from radioloc.locate.ekf_track import observation_window

    out = []
    for t, obs in tracks:
        if steps <= 0:
            break
        out.append((t[:steps], [observation_window(o, slice(0, steps)) for o in obs]))
        steps -= t.size
    return out


def _learn_group(nodes: dict, has_ranges: bool, make_filter, prior, gate, given, q_default,
                 anchor_names, dim, q_given) -> dict:
    """:func:`learn_nodes` for nodes that all have ranges, or none."""
    from radioloc.locate.ekf_track import stack_tracks

    asked = {}       # each track's start, the same for every factor tried

    def filtered(items, q, smooth, bias):
        ekf = make_filter(q[:, None], 0.0 if bias is None else bias[0][:, None, :],
                          None if bias is None else bias[1][:, None, :],
                          0 if not has_ranges else 1 if bias is None else 2)
        means, covs = [], []
        for b, (key, t, o) in enumerate(items):
            bias_cov = None if bias is None else bias[2][b]
            k = (key, None if bias_cov is None else bias_cov.tobytes())
            if k not in asked:
                asked[k] = prior(ekf, t, o, bias_cov)
            means.append(asked[k][0])
            covs.append(asked[k][1])
        t, stacked = stack_tracks([it[1] for it in items], [it[2] for it in items])
        track = ekf.run(stacked, t, prior_mean=np.stack(means), prior_cov=np.stack(covs),
                        smooth=smooth)
        return track, evidence(track, stacked, gate), ekf.state_layout(stacked)

    def run(items, q, smooth, bias=None):
        """The filter over ``items`` (node, times, observations); ``q``: the process noise,
        one or per item; ``bias``: per item the bias states' driving noise, time constants
        and prior covariance (step 3). Returns the track (None where the items ran in
        parts: :data:`MAX_ITEM_STEPS`), each item's evidence and the state layout."""
        q = np.broadcast_to(np.asarray(q, dtype=float), (len(items),))
        steps = max(t.size for _, t, _ in items)
        size = len(items) if smooth else max(1, MAX_ITEM_STEPS // steps)
        if size >= len(items):
            return filtered(items, q, smooth, bias)
        parts = [filtered(items[a:a + size], q[a:a + size], smooth,
                          None if bias is None else tuple(v[a:a + size] for v in bias))[1:]
                 for a in range(0, len(items), size)]          # each part's track let go
        return None, np.concatenate([p[0] for p in parts]), parts[0][1]

    def by_node(ev, items, factors: int = 1) -> dict:
        """Each node's evidence summed over its tracks, per factor tried (``items`` come
        factor by factor, each factor's the same tracks)."""
        total = {key[0]: np.zeros(factors) for key, _, _ in items}
        per = len(items) // factors
        for j, ((key, _, _), e) in enumerate(zip(items, ev)):
            total[key[0]][j // per] += e
        return total

    win = {n: _window(tracks, LEARN_STEPS) for n, tracks in nodes.items()}

    def at_scale(scale_of):
        return [((n, i), t, _scaled(o, scale_of(n), given))
                for n in nodes for i, (t, o) in enumerate(win[n])]

    # step 1: the scale of every sigma (at the default q), then q at that scale, by evidence
    items = [it for f in SCALES for it in at_scale(lambda n, f=f: f)]
    by_scale = by_node(run(items, q_default, False)[1], items, len(SCALES))
    best = {n: int(np.argmax(by_scale[n])) for n in nodes}
    by_q = {n: {q_default: float(by_scale[n][best[n]])} for n in nodes}
    q_factor = dict.fromkeys(nodes, 1.0)
    tried = () if q_given else [f for f in Q_FACTORS if f != 1.0]
    if tried:                                 # every other factor in one run
        items = [it for _ in tried for it in at_scale(lambda n: SCALES[best[n]])]
        ev = by_node(run(items, q_default * np.repeat(tried, len(items) // len(tried)),
                         False)[1], items, len(tried))
        for n, e in ev.items():
            for qf, v in zip(tried, e):
                by_q[n][q_default * qf] = float(v)
                if float(v) > by_q[n][q_default * q_factor[n]]:
                    q_factor[n] = qf
    learned, smoothed = {}, {}
    items = at_scale(lambda n: SCALES[best[n]])   # the smoothed run, at the q chosen
    track, _, layout = run(items, [q_default * q_factor[key[0]] for key, _, _ in items], True)
    for b, ((n, i), _, _) in enumerate(items):
        smoothed.setdefault(n, []).append((track, layout, b))
    for n in nodes:
        learned[n] = _step_two(n, win[n], smoothed[n], SCALES[best[n]], q_default * q_factor[n],
                               by_scale[n], by_q[n], given, has_ranges, anchor_names, dim)
    # step 3: the correlation's scale, by evidence (nodes whose range offsets were learned;
    # their offsets taken off the ranges, so that one model serves the batch)
    wander = [n for n in nodes if learned[n].offset_m is not None]
    if wander:
        settings = {n: learned[n].bias_settings(np.asarray(CORRELATION_SCALES)[:, None])
                    for n in wander}
        items, bias = [], []
        for c in range(len(CORRELATION_SCALES)):
            for n in wander:
                for i, (t, o) in enumerate(_window(nodes[n], EVIDENCE_STEPS)):
                    items.append(((n, i), t, offsets_taken_off(
                        tuned_observations(o, learned[n]))))
                    bias.append([v[c] for v in settings[n]])
        bias = tuple(np.stack([b[j] for b in bias]) for j in range(3))
        ev3 = by_node(run(items, [learned[key[0]].q for key, _, _ in items], False, bias)[1],
                      items, len(CORRELATION_SCALES))
        for n in wander:
            learned[n].correlation_scale = CORRELATION_SCALES[int(np.argmax(ev3[n]))]
            learned[n].report.update({
                "correlation_scale": learned[n].correlation_scale,
                "evidence_by_correlation_scale": dict(zip(map(str, CORRELATION_SCALES),
                                                          map(float, ev3[n])))})
    return learned


def offsets_taken_off(observations: list) -> list:
    """Ranges less each anchor's learned offset, with a model without offsets: the nodes of
    one batch share a model per kind (their offsets differ), and the innovations are the
    same."""
    out = []
    for o in observations:
        if o.model.kind == "range" and o.model.offset_m is not None:
            offset = np.asarray(o.model.offset_m)[o.context.index]
            o = replace(o, model=replace(o.model, offset_m=None), z=o.z - offset)
        out.append(o)
    return out


def _step_two(node, tracks: list, smoothed: list, scale: float, q: float, ev_scale,
              by_q: dict, given: dict, has_ranges: bool, anchor_names: list, dim: int
              ) -> Learned:
    """Step 2 for one node: its noise from the residuals at its smoothed tracks
    (``smoothed``: per track the run, its state layout and the track's batch member)."""
    learned = Learned(scale=scale, q=q, given=tuple(given))
    near = sorted(v for v, e in by_q.items() if e >= max(by_q.values()) - 2.0)
    report = {"scale": scale, "evidence_by_scale": dict(zip(map(str, SCALES),
                                                            map(float, ev_scale))),
              "q": q, "q_95": [near[0], near[-1]],
              "evidence_by_q": {f"{v:g}": e for v, e in sorted(by_q.items())}}
    per_kind: dict[str, list] = {}
    for (times, obs), (track, layout, b) in zip(tracks, smoothed):
        for o, r in zip(obs, _residuals(layout, track, obs, b, scale)):
            per_kind.setdefault(o.model.kind, []).append((times, r, o))
    for kind, items in per_kind.items():
        k = model_kinds().get(kind)
        if kind == "range" or k is None or k.sigma_option in given:
            continue
        r = np.concatenate([x[1][0][np.isfinite(x[1][0])] for x in items])
        h = np.concatenate([x[1][1][np.isfinite(x[1][0])] for x in items])
        if r.size < MIN_ANCHOR_ROWS:
            continue
        s = 1.4826 * float(np.median(np.abs(r - np.median(r)))) / np.sqrt(
            max(float(np.mean(1.0 - h)), 0.05))
        s = max(s, k.sigma_default * 1e-3)
        learned.sigma[k.sigma_option] = s
        report[k.sigma_option] = s
        report[k.sigma_option + "_95"] = _interval(s, r.size)
    if has_ranges and "range_std_m" not in given:
        items = per_kind["range"]
        index = items[0][2].context.index
        track, layout, b = smoothed[0]
        sl = layout.slices["anchor_bias"]
        bias = track.diagnostics["state"][b, 0, sl]
        bias_cov = track.diagnostics["state_covariance"][b, 0, sl, sl]
        rn = _range_noise([x[1] for x in items], [x[0] for x in items], index,
                          len(anchor_names), dim, bias, bias_cov,
                          model_kinds()["range"].sigma_default * scale, anchor_names)
        learned.offset_m, learned.white_m = rn["offset"], rn["white"]
        learned.offset_cov = rn["offset_cov"]
        learned.correlated_m, learned.tau_s = rn["correlated"], rn["tau"]
        report.update({"range_anchors": rn["anchors"], "range_pooled": rn["pooled"],
                       "range_mixture": rn["mixture"]})
    learned.report = report
    return learned


def tuned_observations(observations: list, learned: Learned) -> list:
    """A node's observations with what :func:`learn_nodes` found: ranges with each anchor's
    offset in the model and its white noise per row (the Gauss-Markov part is the filter's
    bias state), the other kinds their learned sigma per row; a row whose std the log
    states keeps it."""
    out = []
    for o in observations:
        k = model_kinds().get(o.model.kind)
        if k is not None and k.sigma_option in learned.given:
            pass
        elif o.model.kind == "range" and learned.offset_m is not None:
            std = learned.white_m[o.context.index]
            o = _with_std(replace(o, model=replace(o.model, offset_m=tuple(learned.offset_m),
                                                   anchor_bias=True, bias_terms=2)), std)
        elif k is not None and k.sigma_option in learned.sigma:
            o = _with_std(o, learned.sigma[k.sigma_option])
        elif k is not None and o.model.kind != "range":
            o = _with_std(o, k.sigma_default * learned.scale)
        out.append(o)
    return out


def learned_noise(observations: list, report: dict, anchor_ids: list) -> list:
    """Observations judged against what was learned (a node's ``learned`` entry of
    ``summary.json``): each anchor's learned offset in the range model, and a per-row std
    ``sqrt(white^2 + (scale * correlated)^2)`` (the whole spread of its error about the
    offset); anchors not learned take the node's pooled values. For the health check.

    Parameters
    ----------
    observations : list of Observation
    report : dict
        The node's ``learned`` entry.
    anchor_ids : list of str
        The anchor table's ids, by row (``context.index`` into it).

    Returns
    -------
    list of Observation
    """
    anchors = {a["anchor"]: a for a in report.get("range_anchors", [])}
    pooled = report.get("range_pooled")
    cs = report.get("correlation_scale", 1.0)
    if pooled is None:
        return observations
    rows = [anchors.get(str(a)) for a in anchor_ids]
    offset = tuple(r["offset_m"] if r else 0.0 for r in rows)
    spread = np.array([np.hypot((r or pooled)["white_m"], cs * (r or pooled)["correlated_m"])
                       for r in rows])
    out = []
    for o in observations:
        if o.model.kind == "range":
            o = replace(o, model=replace(o.model, offset_m=offset),
                        std=np.where(np.isfinite(o.z), spread[o.context.index], np.nan))
        out.append(o)
    return out
