"""The health check of a ``radioloc locate`` run: is the result what its data say?

One check for every method, run on its output table (:func:`check_run`), knowing nothing of
the method but the noise it states: the log's rows (ranges, time differences, angles) are
set against the positions written, through the same measurement models the generic
estimators use (:func:`radioloc.locate.adapter.node_observations`).

In windows of consecutive steps (a step alone when its rows fix the position with three to
spare, else at least :data:`WINDOW_ROWS` rows), the rows are fitted
once more about the written track: a constant correction ``d`` of the window's positions by
robust Gauss-Newton (Huber, then Tukey's biweight, with the scale re-estimated at each step) (:func:`window_fit`). What is left tells the noise, what ``d``
is tells the track:

- **off its data**: ``d`` outside the claimed covariance ``P`` (``d' (P + C)^-1 d`` above its
  :data:`CHI2_PROB` chi-square point, ``C`` the correction's own covariance, and ``|d|``
  above :data:`OFF_SIGMAS` claimed standard deviations) in more than :data:`OFF_FRACTION` of
  the windows;
- **misfit**: the residuals after the correction, normalised by the stated noise, have a
  robust scale (1.4826 times their median absolute value) above :data:`SCALE_LIMIT`;
- **one anchor misfits**: its rows' scale above :data:`SCALE_LIMIT` and four times the
  others', which fit;
- **outside the anchors' region**: positions farther outside the anchors' box than its
  diagonal and :data:`OFF_SIGMAS` claimed standard deviations.

A log with pseudoranges (a receiver clock at each epoch) or moving anchors is checked
against fixes of each epoch on its own instead (:func:`_snapshot_node`): off its data and
misfit as above. Every node is searched for **errors that persist** from epoch to epoch
(:func:`_persistence`: the residuals' lag-one products at fixes of each epoch), which a
track cannot average away: its covariance gains the fixes' covariance under them. Where the
method does not model each anchor's range offset (it learned none), the offsets left in
the ranges are estimated from those fixes and the covariance gains the shift they make
(:func:`_anchor_offsets`). Network methods (priors) are not judged.

A failing node gets one finding: its node, time span, figures and the most likely cause
the data tell apart (:func:`likely_cause`): a sign, unit or convention slip of one kind
(its values mapped back by :func:`radioloc.locate.slips.slips` fit), an anchor with x and y
swapped or a wrong anchor (its rows alone misfit at the track, or, where the track followed
it, fixes from the others fit step by step while its rows misfit them:
:func:`_held_out_anchor`), NLOS (ranges longer than the fit, not shorter), a stated noise
too small (residuals symmetric, every anchor alike), errors that persist (each epoch fits,
the errors wander slowly), weak geometry (a track far outside the anchors whose rows fit
it: its errors there are not seen in the residuals), or a diverged track (the rows fit well
a position away from the track, or it left the anchors' region and its rows misfit).
Findings are warned and recorded in the summary (``health``).

The claimed covariance is inflated by the fitted residual scale where it exceeds
:data:`INFLATE_ABOVE`, or by the larger factor the corrections ask of it
(:func:`_coverage_factor`: their median Mahalanobis distance brought to its chi-square
median), never shrunk; a method that writes none gets the covariance of the
window fits at that scale. Each node's factor is reported.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Collection
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from radioloc.core.errors import RadiolocError
from radioloc.core.kinds import model_kinds
from radioloc.estimators.fault_exclusion import chi2_quantile
from radioloc.locate.adapter import (
    default_models,
    frame_settings,
    moving_anchors,
    node_observations,
)
from radioloc.locate.self_tuning import learned_noise
from radioloc.locate.slips import slip_scale, slips
from radioloc.locate.table import add_covariance, covariance_of

__all__ = ["Finding", "HealthReport", "check_run", "divergence", "window_fit", "CHECKED_KINDS"]

#: The kinds the window check reads (RSS would need a path-loss model).
CHECKED_KINDS = ("range", "tdoa", "aoa", "aoa_elevation")
#: Kinds whose fix needs more than the position (a receiver clock at each epoch): a log
#: with them, or with moving anchors, is checked against fixes of each epoch on its own.
SNAPSHOT_KINDS = ("pseudorange",)
#: Errors that persist put the fixes this many times the claimed standard deviation off
#: (median over rows) before the check reports them (:func:`_persistence`).
PERSISTENT_RATIO = 2.0
#: Fewest epochs of a node searched for errors that persist (fewer give too few lag-one
#: products to tell them from white noise; :func:`_persistence`).
PERSISTENCE_EPOCHS = 50
#: Gauss-Newton steps of the fixes started at the written track (:func:`_persistence`).
TRACK_START_STEPS = 8
#: Rounds of offsets estimated and epochs fixed again in :func:`_anchor_offsets`.
OFFSET_ROUNDS = 5
#: An anchor's median residual at the fixes is an offset beyond this many standard errors
#: (:func:`_anchor_offsets`; white noise on a clean log passes 3 now and then).
OFFSET_SIGMAS = 5.0
#: Fewest rows in a window of the refit.
WINDOW_ROWS = 24
#: Huber threshold of the refit, in robust standard deviations.
HUBER = 3.0
#: Tukey threshold of the refit's second half, in robust standard deviations.
TUKEY = 4.685
#: Iterations of the refit (Huber for the first half).
ITERATIONS = 30
#: Probability of the chi-square point a correction must pass to count as off.
CHI2_PROB = 0.9999
#: A correction counts as off only when longer than this many claimed standard deviations.
OFF_SIGMAS = 5.0
#: Share of windows off that makes a finding.
OFF_FRACTION = 0.05
#: Robust scale of the normalised residuals above which the node misfits.
SCALE_LIMIT = 3.0
#: Scale above which the covariance is inflated by it.
INFLATE_ABOVE = 1.2
#: A mapped log (slip) or a refit without one anchor fits when its scale is below this.
FITS_BELOW = 2.0
#: NLOS: share of ranges at least 3 sigma longer than the fit, and its ratio to the shorter.
NLOS_SHARE, NLOS_RATIO = 0.03, 3.0


#: Innovation check (:func:`divergence`): steps per window, factor on the 99.9 % bound of the
#: windowed NIS per measurement, fraction of windows beyond it that flags a track.
NIS_WINDOW = 50
NIS_FACTOR = 2.0
NIS_FRACTION = 0.3
#: Fraction of gated measurements that, with a track outside the anchors' box, flags it.
GATED_FRACTION = 0.05
#: Fewest steps of a track that the innovation check judges.
NIS_MIN_STEPS = 10


@dataclass
class Finding:
    """One node's failed check, with the likely cause."""

    node: str
    start: float
    end: float
    checks: list[str]
    cause: str
    message: str
    figures: dict = field(default_factory=dict)


@dataclass
class HealthReport:
    """Findings, and the factor by which each node's covariance was inflated."""

    findings: list[Finding]
    inflation: dict[str, float]
    scale: dict[str, float]

    def summary(self) -> dict:
        return {"findings": [vars(f) for f in self.findings],
                "covariance_inflation": self.inflation, "residual_scale": self.scale}



def divergence(track, anchors: np.ndarray, gate: float | None) -> dict | None:
    """Signs that a tracker's track has diverged, from its innovations.

    The normalised innovation squared per measurement over windows of :data:`NIS_WINDOW`
    steps (a gated row counted at the gate) above :data:`NIS_FACTOR` times its 99.9 %
    chi-square bound in more than :data:`NIS_FRACTION` of the windows; or a track that leaves
    the anchors' box by more than their span while refusing more than
    :data:`GATED_FRACTION` of its measurements or with some window beyond the band (a tag
    far from a compact anchor cluster, with consistent innovations, is not flagged).

    Parameters
    ----------
    track : Track
        From :func:`run_tracker`, with diagnostics ``nis``, ``measurements_used`` and
        ``gated`` per step.
    anchors : ndarray, shape (M, 2|3)
    gate : float or None
        The innovation gate (a gated row counts as this NIS; 16 without a gate).

    Returns
    -------
    dict or None
        ``windows_out`` (fraction of windows beyond the band), ``gated`` (fraction of the
        measurements refused) and ``outside_m`` (largest distance outside the anchors' box),
        when the track diverged; None otherwise.
    """
    d = track.diagnostics
    nis = np.nan_to_num(np.asarray(d.get("nis", []), dtype=float))
    used = np.asarray(d.get("measurements_used", np.zeros(nis.size)), dtype=float)
    refused = np.asarray(d.get("gated", np.zeros(nis.size)), dtype=float)
    if nis.size < NIS_MIN_STEPS:
        return None
    w = np.ones(min(NIS_WINDOW, nis.size))
    total = np.convolve(nis + (gate or 16.0) * refused, w, "valid")
    n = np.convolve(used + refused, w, "valid")
    ok = n > 0
    counts, where = np.unique(np.maximum(n, 1), return_inverse=True)   # few distinct counts
    band = NIS_FACTOR * chi2_quantile(0.999, counts)[where]      # chi-square 99.9 % point
    windows_out = float(np.mean(total[ok] > band[ok])) if ok.any() else 0.0
    xy, box = np.asarray(track.position)[:, :2], np.asarray(anchors)[:, :2]
    lo, hi = box.min(axis=0), box.max(axis=0)
    outside = np.linalg.norm(np.maximum(lo - xy, 0) + np.maximum(xy - hi, 0), axis=1)
    span = float(np.linalg.norm(hi - lo))
    outside_m = float(outside.max()) if outside.size else 0.0
    gated = float(refused.sum() / max(refused.sum() + used.sum(), 1))
    away = span > 0 and outside_m > span and (windows_out > 0 or gated > GATED_FRACTION)
    if windows_out > NIS_FRACTION or away:
        return {"windows_out": windows_out, "outside_m": outside_m, "gated": gated}
    return None


def _robust_scale(e: np.ndarray) -> float:
    e = e[np.isfinite(e)]
    return float(1.4826 * np.median(np.abs(e))) if e.size else math.nan


def stated_sigmas(request, summary: dict) -> dict[str, tuple[float, str, bool]]:
    """The noise in force for each kind: the option given, else the one the method reports
    in its summary, else the kind's default (:attr:`radioloc.core.kinds.Kind.sigma_default`);
    with its option name and whether it was stated (given or reported)."""
    out = {}
    for kind, declared in model_kinds().items():
        name = declared.sigma_option
        value = request.option(name)
        if value is None and kind == "range":
            value = request.option("std_m")
        if value is None:
            value = summary.get(name)
        if value is None and kind == "range":
            value = summary.get("std_m")
        stated = isinstance(value, (int, float)) and value > 0
        out[kind] = (float(value) if stated else declared.sigma_default, name, stated)
    return out


@dataclass
class _Rows:
    """One node's observations against its written track."""

    observations: list
    times: np.ndarray            # (T,) the node's steps
    positions: np.ndarray        # (T, D) written track at the observations' steps
    window: np.ndarray           # (T,) window of each step
    sigma: list                  # per observation (T, S) standard deviations
    anchor_ids: list             # the anchors table's ids (``context.index`` into it)


def window_fit(rows: _Rows, observations=None, start: np.ndarray | None = None):
    """The robust correction of each window's positions (module docstring).

    Parameters
    ----------
    rows : _Rows
    observations : list of Observation, optional
        Instead of ``rows.observations`` (a log with one kind's values mapped).
    start : ndarray, shape (W, D), optional
        Start of the corrections (default zero).

    Returns
    -------
    d : ndarray, shape (W, D)
        Corrections.
    cov : ndarray, shape (W, D, D)
        Their covariance at the fitted scale (NaN where the window does not fix them).
    e : list of ndarray, shape (T, S)
        Normalised residuals after the correction, per observation.
    scale : float
        Their robust scale, corrected for the corrections fitted (times
        ``sqrt(n / (n - windows * D))``).
    """
    obs = rows.observations if observations is None else observations
    n_w = int(rows.window.max()) + 1
    dim = rows.positions.shape[1]
    d = np.zeros((n_w, dim)) if start is None else start.copy()
    scale = 1.0
    for it in range(ITERATIONS + 1):
        info = np.zeros((n_w, dim, dim))
        grad = np.zeros((n_w, dim))
        es, jacs = [], []
        pos = rows.positions + d[rows.window]
        for o, sig in zip(obs, rows.sigma):
            with np.errstate(all="ignore"):
                zhat, jac = o.model.predict_with_jacobian({"position": pos}, o.context)
            e = o.model.residual(o.z, zhat) / sig
            es.append(e)
            jacs.append(jac["position"])
        pooled = np.concatenate([e[np.isfinite(e)] for e in es])
        dof = pooled.size / max(pooled.size - n_w * dim, 1)      # the fit took n_w * dim
        scale = max(_robust_scale(pooled) * math.sqrt(dof), 1e-9) if pooled.size else 1.0
        if it == ITERATIONS:
            break
        for sig, e, jac in zip(rows.sigma, es, jacs):
            J = jac / sig[..., None]                                   # (T, S, D)
            ok = np.isfinite(e) & np.all(np.isfinite(J), -1)
            u = np.abs(e) / scale
            if it < ITERATIONS // 2:             # Huber from the track, then Tukey's biweight
                w = np.minimum(1.0, HUBER / np.maximum(u, 1e-300))
            else:
                w = np.where(u < TUKEY, (1 - (u / TUKEY) ** 2) ** 2, 0.0)
            w = np.where(ok, w, 0.0)
            Jw = np.where(ok[..., None], J, 0.0) * w[..., None]
            ez = np.where(ok, e, 0.0)
            np.add.at(info, rows.window, np.einsum("tsi,tsj->tij", Jw, np.where(ok[..., None], J, 0.0)))
            np.add.at(grad, rows.window, np.einsum("tsi,ts->ti", Jw, ez))
        lam = np.linalg.eigvalsh(info)          # symmetric: cond < 1e10, a third of the time
        good = lam[:, 0] > 1e-10 * lam[:, -1]
        safe = np.where(good[:, None, None], info, np.eye(dim))
        step = np.where(good[:, None], np.linalg.solve(safe, grad[..., None])[..., 0], 0.0)
        norm = np.linalg.norm(step, axis=1, keepdims=True)
        d = d + step * np.minimum(1.0, 50.0 / np.maximum(norm, 1e-300))   # bounded steps
    with np.errstate(all="ignore"):
        cov = np.where(good[:, None, None], np.linalg.inv(safe), np.nan) * max(scale, 1.0) ** 2
    return d, cov, es, scale


def _node_rows(request, out_node: pd.DataFrame, node: str, sigmas: dict,
               learned: dict | None = None) -> _Rows | None:
    """The node's checked observations and its track at their steps (None: nothing to check).
    With what the method learned of the node's noise (``learned``, its ``summary.json``
    entry: :mod:`radioloc.locate.self_tuning`), each anchor's ranges less its learned offset,
    against their learned spread, and the other kinds against their learned sigma."""
    from radioloc.io.measurements import Measurements

    meas = request.measurements
    kinds = [k for k in CHECKED_KINDS if k in set(meas["kind"].unique())]
    if not kinds or request.anchors is None:
        return None
    options = {name: value for value, name, _ in sigmas.values()}
    if learned:
        options.update({name: learned[name] for _, name, _ in sigmas.values() if name in learned})
    models = default_models(kinds, options)
    own = meas[(meas["node"] == node) & meas["kind"].isin(kinds)]
    height = request.option("tag_height_m")
    try:
        times, obs = node_observations(Measurements(own), request.anchors, node, models,
                                       height_m=height, checked=True)
    except RadiolocError:
        return None
    if not obs or times.size == 0:
        return None
    dim = obs[0].context.position_dim
    cols = ["x", "y", "z"][:dim]
    if any(c not in out_node for c in cols):
        return None
    t_out = out_node["time"].to_numpy(dtype=float)
    xyz = out_node[cols].to_numpy(dtype=float)
    pos = np.column_stack([np.interp(times, t_out, xyz[:, k]) for k in range(dim)])
    ids = list(dict.fromkeys(request.anchors["id"]))
    obs = _unbiased(request, obs, pos) if not learned else learned_noise(obs, learned, ids)
    sigma = []
    for o in obs:
        base = np.broadcast_to(o.model.std(o.context), o.z.shape)
        sigma.append(np.where(np.isfinite(o.std), o.std, base) if o.std is not None else base)
    n_rows = np.sum([np.isfinite(o.z).sum(axis=1) for o in obs], axis=0)
    window = np.zeros(times.size, dtype=int)
    count, w, window_alone = 0, 0, False
    for t, n in enumerate(n_rows):
        alone = n >= dim + 3                 # a step that fixes the position with 3 rows to spare
        if t and (count >= WINDOW_ROWS or alone or window_alone):
            w, count = w + 1, 0
        window[t], window_alone = w, alone
        count += n
    if count < WINDOW_ROWS // 2 and w > 0 and not window_alone:   # a short last window
        window[window == w] = w - 1
    return _Rows(obs, times, pos, window, sigma, ids)


def _unbiased(request, obs: list, pos: np.ndarray) -> list:
    """The range observations less the biases the method was told of: ``range_bias_m``, and
    with ``anchor_bias`` each anchor's median range residual at the written track."""
    obs = _less_declared_bias(request, obs)
    if not request.option("anchor_bias", False, bool):
        return obs
    out = []
    for o in obs:
        if o.model.kind == "range":
            with np.errstate(all="ignore"):
                zhat = o.model.predict({"position": pos}, o.context)
            offset = np.nanmedian(np.where(np.isfinite(o.z), o.z - zhat, np.nan), axis=0)
            o = replace(o, z=o.z - np.nan_to_num(offset))
        out.append(o)
    return out


def _less_declared_bias(request, obs: list) -> list:
    """The range observations less the bias the user declared (``-o range_bias_m``)."""
    bias = request.option("range_bias_m", 0.0) or 0.0
    return [replace(o, z=o.z - bias) if o.model.kind == "range" and bias else o for o in obs]


def _claimed(out_node: pd.DataFrame, rows_times: np.ndarray, dim: int) -> np.ndarray | None:
    cov = covariance_of(out_node)
    if cov is None or cov.shape[-1] < dim:
        return None
    t_out = out_node["time"].to_numpy(dtype=float)
    idx = np.clip(np.searchsorted(t_out, rows_times), 0, len(t_out) - 1)
    return cov[idx][:, :dim, :dim]


def check_run(method_name: str, request, out: pd.DataFrame, rerun=None,
              options: Collection[str] = ()) -> tuple[pd.DataFrame, HealthReport]:
    """Check a method's output against its log; warn of each finding.

    Parameters
    ----------
    method_name : str
    request : LocateRequest
        The log, anchors and options the method ran on.
    out : DataFrame
        Its output (``time, node, x, y[, z][, cov_*]``).
    rerun : callable, optional
        ``rerun(request) -> DataFrame``: the method again. With it, a noise found too small
        is tried at the value the residuals say (when ``options`` declares it), and the
        warning tells whether the log then passes.
    options : collection of str
        The method's options.

    Returns
    -------
    out : DataFrame
        With the covariance inflated where the residuals show a misspecified noise (or
        written from the window fits where the method gives none).
    report : HealthReport
    """
    attrs, summary = out.attrs, out.attrs.get("summary", {})
    out = out.copy(deep=False)
    out.attrs = {}          # not deep-copied by pandas into every frame made from it below
    findings, inflation, scales = [], {}, {}
    if request.priors is None:
        # network methods (nodes fixed by priors and each other) are not judged here
        sigmas = stated_sigmas(request, summary)
        snapshot = moving_anchors(request.anchors) or bool(
            request.measurements["kind"].isin(SNAPSHOT_KINDS).any())
        parts = []
        for node, idx in out.groupby("node", sort=False).indices.items():
            own = out.iloc[idx].sort_values("time", kind="stable")
            if snapshot:
                checked = _snapshot_node(method_name, request, own, node, sigmas)
            else:
                rows = _node_rows(request, own, node, sigmas,
                                  summary.get("learned", {}).get(str(node)))
                checked = None if rows is None else _check_node(method_name, request, own,
                                                                node, rows, sigmas)
                if checked is not None:
                    modelled = bool(summary.get("learned", {}).get(str(node))
                                    or summary.get("anchor_bias"))
                    checked = _with_persistence(request, node, sigmas, checked,
                                                offsets=not modelled)
            if checked is None:
                parts.append(own)
                continue
            found, factor, scale, filled = checked
            findings += found
            inflation[node], scales[node] = factor, scale
            parts.append(filled)
        if parts:
            out = pd.concat(parts).loc[out.index]
        if rerun is not None:
            _try_noise(method_name, request, findings, sigmas, scales, rerun, options)
    findings = _with_innovations(findings, summary.get("innovations", []), out)
    for f in findings:
        warnings.warn(f"method {method_name}: {f.message}", stacklevel=3)
    out.attrs = attrs
    return out, HealthReport(findings, inflation, scales)


def _try_noise(method_name, request, findings, sigmas, scales, rerun, options) -> None:
    """Run the method again with the noise the residuals say (where a finding blames the
    stated noise and the method takes its option), and say in the finding whether it fits."""
    blamed = [f for f in findings if f.cause == "noise" and f.node in scales]
    if not blamed:
        return
    largest = max(blamed, key=lambda f: scales[f.node])
    scale = scales[largest.node]
    kinds = set(request.measurements["kind"].unique())
    tried = {name: float(f"{value * scale:.2g}") for kind, (value, name, stated) in sigmas.items()
             if kind in kinds and stated and name in options}
    if not tried:
        return
    again = replace(request, options={**request.options, **{k: repr(v) for k, v in tried.items()}},
                    parsed={**request.parsed, **tried})
    text = " ".join(f"-o {k}={v:g}" for k, v in tried.items())
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = rerun(again)
            left = check_run(method_name, again, out)[1].findings
    except (RadiolocError, ArithmeticError) as exc:
        verdict = f"it fails ({exc})"
    else:
        verdict = "the log then passes" if not left else f"still failing ({left[0].cause})"
    for f in blamed:
        whose = (f" (node {largest.node!r} asks it, the most; one run takes one value)"
                 if scales[f.node] < scale / 1.5 else "")
        f.message += f"; tried {text}{whose}: {verdict}"
        f.figures["tried"] = {"options": tried, "passes": verdict.endswith("passes")}


def _with_innovations(findings: list[Finding], signs: list[dict], out: pd.DataFrame
                      ) -> list[Finding]:
    """The findings with a tracker's innovation signs (:func:`divergence`, recorded by the
    method in its summary's ``innovations``) added to its node's finding, or as its own."""
    by_node = {f.node: f for f in findings}
    for sign in sorted(signs, key=lambda d: (-d["windows_out"], -d["outside_m"])):
        node = sign["node"]
        outside = (f", up to {sign['outside_m']:.3g} m outside the anchors' box"
                   if sign["outside_m"] > 0 else "")
        text = (f"its innovations look diverged (above {NIS_FACTOR:g} times their 99.9 % band "
                f"in {100 * sign['windows_out']:.0f} % of {NIS_WINDOW}-step windows, "
                f"{100 * sign['gated']:.0f} % of the measurements gated{outside})")
        figures = {k: round(float(sign[k]), 3) for k in ("windows_out", "gated", "outside_m")}
        if node in by_node:
            f = by_node[node]
            if "innovations" not in f.checks:
                f.checks.append("innovations")
                f.figures.update(figures)
                head, _, tail = f.message.partition("; likely cause: ")
                f.message = f"{head}; {text}; likely cause: {tail}"
            continue
        end = float(out.loc[out["node"] == node, "time"].max())
        f = Finding(node, float(sign["start"]), end, ["innovations"], "noise",
                    f"node {node!r}, time {float(sign['start']):g} to {end:g}: {text}; likely "
                    f"cause: {sign.get('cause') or sign['noise'] + ' too small for this log?'}",
                    figures)
        by_node[node] = f
        findings.append(f)
    return findings


def _snapshot_node(method_name, request, own, node, sigmas):
    """The check of a node whose fixes need more than its position (a receiver clock with
    pseudoranges) or whose anchors move (module docstring), against fixes of each epoch on
    its own (:class:`~radioloc.estimators.least_squares.LeastSquares`, Huber loss).

    - **Off its data / misfit**, as the window check: the fixes ``d`` from the track beyond
      the claimed covariance plus the fixes' own (at their robust residual scale).
    - **Errors that persist over epochs** (:func:`_persistence`). Each row's standardised
      residual at its plain least-squares fix, times the same row's at the next epoch,
      averaged over rows (clipped at :data:`HUBER` robust standard deviations): white errors
      give zero, errors that wander slowly (multipath, NLOS) give their variance ``g^2``
      (in stated-noise units; divided by the share of a fix's rows left to its residuals,
      ``1 - unknowns / rows``), counted when 3 standard errors above zero. A track can
      average white errors, not these: the fix's covariance under them,
      ``g^2 (J' W J)^-1``, is added to the claimed one; a finding when its standard
      deviation is more than :data:`PERSISTENT_RATIO` times the claimed one (median).

    Returns ``(findings, factor, scale, filled)`` as :func:`_check_node`, or None (nothing to
    fix)."""
    claimed_out = covariance_of(own)
    options = {name: value for value, name, _ in sigmas.values()}
    fixed = _epoch_fits(request, request.measurements, node, options, "huber")
    if fixed is None or claimed_out is None:
        return None
    times, _, fit, u, own_rows = fixed
    dim = min(fit.position.shape[-1], claimed_out.shape[-1])
    cols = ["x", "y", "z"][:dim]
    unknowns = fit.diagnostics["state"].shape[-1]
    ok = ~np.asarray(fit.diagnostics["degenerate"]) & np.all(np.isfinite(fit.position), -1)
    used = np.isfinite(u) & ok[:, None]
    n = int(used.sum())
    if ok.sum() < 5 or n <= ok.sum() * unknowns:
        return None
    scale = _robust_scale(u[used]) * math.sqrt(n / (n - ok.sum() * unknowns))
    g2, persistent, ratio = _persistence(own, _track_fits(request, own, node, options),
                                         claimed_out[:, :dim, :dim])
    t_out = own["time"].to_numpy(dtype=float)
    xyz = own[cols].to_numpy(dtype=float)
    track = np.column_stack([np.interp(times, t_out, xyz[:, k]) for k in range(dim)])
    fix_cov = fit.covariance[..., :dim, :dim]
    P_fix = _claimed(own, times, dim)
    d = (fit.position[..., :dim] - track)[ok]
    C = fix_cov[ok] * max(scale, 1.0) ** 2 + g2 * fix_cov[ok]
    P = P_fix[ok]
    with np.errstate(all="ignore"):
        m2 = np.einsum("ti,tij,tj->t", d, np.linalg.pinv(P + C), d)
        far = np.linalg.norm(d, axis=1) > OFF_SIGMAS * np.sqrt(np.trace(P, axis1=1, axis2=2))
    off = (m2 > chi2_quantile(CHI2_PROB, dim)) & far
    coverage = _coverage_factor(d, P, C)
    # a residual scale from errors that persist is not white noise the track mis-weighs
    factor = max(max(1.0, scale) if scale > INFLATE_ABOVE and g2 == 0.0 else 1.0, coverage)
    total = claimed_out * factor ** 2
    total[:, :dim, :dim] += persistent
    filled = own if factor == 1.0 and g2 == 0.0 else add_covariance(own, total)
    checks = []
    figures = {"residual_scale": round(scale, 3), "coverage_factor": round(coverage, 3)}
    what = []
    if off.mean() > OFF_FRACTION:
        checks.append("off_its_data")
        figures["windows_off"] = round(float(off.mean()), 3)
        figures["correction_m"] = round(float(np.median(np.linalg.norm(d[off], axis=1))), 3)
        what.append(f"fixes of each epoch on its own lie {figures['correction_m']:.3g} m from "
                    f"the track, beyond its claimed uncertainty, at {100 * off.mean():.0f} % of "
                    "its epochs")
    if scale > SCALE_LIMIT:
        checks.append("misfit")
        what.append(f"their residuals {scale:.3g} times the stated noise")
    if ratio > PERSISTENT_RATIO:
        checks.append("persistent")
        text, more = _persistent_finding(g2, ratio)
        what.append(text)
        figures.update(more)
    if not checks:
        return [], factor, scale, filled
    v = u[used] / (scale if 0 < scale < SCALE_LIMIT else 1.0)     # 0: rows fitted exactly
    longer, shorter = float(np.mean(v > 3)), float(np.mean(v < -3))
    if longer > NLOS_SHARE and longer > NLOS_RATIO * shorter:
        cause = ("nlos", (f"NLOS: {100 * longer:.0f} % of the rows lie 3 sigma or more "
                          f"longer than the fixes and {100 * shorter:.0f} % shorter (a LOS/NLOS "
                          "model: --method smoother -o loss=max-mixture)"))
    elif scale > SCALE_LIMIT:
        cause = ("noise", f"{noise_in_force(own_rows, options)} too small for this log?")
    else:
        cause = ("persistent", (f"errors that persist over epochs (multipath, NLOS): each "
                                f"epoch's rows fit (residuals {scale:.2g} times the stated "
                                "noise), but the track averages their errors as if "
                                "independent and claims too little"))
    figures["inflation"] = round(factor, 3)
    start, end = float(times[ok].min()), float(times[ok].max())
    grown = ("covariance inflated" + (f" x{factor:.3g}" if factor > 1 else "")
             + (" plus the persistent part" if g2 > 0 else ""))
    message = (f"node {node!r}, time {start:g} to {end:g}: {'; '.join(what)}; likely cause: "
               f"{cause[1]} ({grown})")
    return [Finding(node, start, end, checks, cause[0], message, figures)], factor, scale, filled


def _with_persistence(request, node, sigmas: dict, checked: tuple, offsets: bool = True
                      ) -> tuple:
    """A window-checked node (:func:`_check_node`'s result) with the errors that persist
    from epoch to epoch (:func:`_persistence`) and, where the method does not model them
    (``offsets``), the range offsets of its anchors (:func:`_anchor_offsets`): their
    covariance added to the written one, and a finding (or a check added to the node's)
    when it is more than :data:`PERSISTENT_RATIO` times the claimed standard deviation."""
    found, factor, scale, filled = checked
    claimed = covariance_of(filled)
    if claimed is None:
        return checked
    options = {name: value for value, name, _ in sigmas.values()}
    fixed = _track_fits(request, filled, node, options)       # made once for both searches
    g2, persistent, ratio = _persistence(filled, fixed, claimed)
    shifted = (_anchor_offsets(request, filled, node, options, claimed, fixed) if offsets
               else None)
    if g2 == 0.0 and shifted is None:
        return checked
    added = persistent + (0.0 if shifted is None else shifted[1])
    filled = add_covariance(filled, claimed + added)
    clauses = []
    if g2 and ratio > PERSISTENT_RATIO:
        text, figures = _persistent_finding(g2, ratio)
        clauses.append(("persistent", text + " (covariance widened by their part)", figures,
                        "errors that persist over epochs (multipath, NLOS)"))
    if shifted is not None and shifted[2] > PERSISTENT_RATIO:
        clauses.append(("anchor_offsets", *_offsets_finding(request, *shifted)))
    for check, text, figures, cause in clauses:
        if found:
            found[0].checks.append(check)
            found[0].figures.update(figures)
            found[0].message += f"; {text}"
        else:
            t = filled["time"].to_numpy(dtype=float)
            found = [Finding(node, float(t.min()), float(t.max()), [check], check,
                             f"node {node!r}, time {t.min():g} to {t.max():g}: {text}; likely "
                             f"cause: {cause}", figures)]
    return found, factor, scale, filled


def _anchor_offsets(request, own: pd.DataFrame, node, options: dict, claimed: np.ndarray,
                    fixed: tuple | None) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Each anchor's range offset left in the ranges, and how far it moves the fixes: from
    the fixes of each epoch on its own (started at the written track), each anchor's
    offset is the median of its residuals, taken off its ranges and the epochs fixed
    again, :data:`OFFSET_ROUNDS` times. The shift of the fixes is what offsets of that
    size do to a method that leaves them in (offsets of 1-4 m per access point in WiFi
    RTT, antenna delays in UWB): its mean square ``(D, D)`` is added to the covariance, a
    systematic error no averaging removes (where an anchor's median residual at the fixes
    is beyond :data:`OFFSET_SIGMAS` standard errors of 0: on clean ranges nothing is
    added). Offsets and positions trade off along weakly determined directions, where more
    rounds drift rather than converge (WiFi RTT Canteen 1, M2: shift 1.7, 2.8, 5.5, 10.6 m
    after 5, 10, 20, 40 rounds): the few rounds give the well-determined part, a lower
    bound. Returns ``(offsets by anchor-table row (A,), the shift's mean square at each
    output row (N, D, D), its RMS over the claimed standard deviation)``, or None (fewer
    than :data:`PERSISTENCE_EPOCHS` epochs, no ranges to three anchors, no offset).
    ``fixed``: the fixes of :func:`_track_fits` from the whole log, used where ranges are
    the only kind they read (else the ranges are fixed on their own)."""
    from radioloc.estimators.fault_exclusion import standardised_residuals
    from radioloc.estimators.least_squares import LeastSquares

    if fixed is None or [o.model.kind for o in fixed[1]] != ["range"]:
        meas = request.measurements
        ranges = meas[meas["kind"] == "range"]
        fixed = None if ranges.empty else _track_fits(request, own, node, options, ranges)
        if fixed is None:
            return None
    _, (o,), fit, _, _ = fixed
    dim = claimed.shape[-1]
    ok = ~np.asarray(fit.diagnostics["degenerate"]) & np.all(np.isfinite(fit.position), -1)
    if ok.sum() < PERSISTENCE_EPOCHS or o.context.rows < 3 or fit.position.shape[-1] < dim:
        return None
    index = o.context.index
    offset = np.zeros(len(request.anchors))
    x0 = x = np.asarray(fit.position, dtype=float)
    unit = np.where(np.isfinite(o.z), 1.0, np.nan)          # residuals in metres
    with np.errstate(all="ignore"):
        for k in range(OFFSET_ROUNDS):
            current = replace(o, z=o.z - offset[index], std=unit)
            r = standardised_residuals([current], fit)[ok]
            heard = np.isfinite(r).sum(0) >= PERSISTENCE_EPOCHS
            step = np.nanmedian(r[:, heard], axis=0)
            if k == 0:    # no anchor's median residual beyond OFFSET_SIGMAS standard errors
                se = 1.2533 * 1.4826 * np.nanmedian(np.abs(r[:, heard] - step), axis=0) \
                    / np.sqrt(np.isfinite(r[:, heard]).sum(0))
                if not np.any(np.abs(step) > OFFSET_SIGMAS * se):
                    return None
            offset[index[heard]] += step
            fit = LeastSquares(max_iterations=TRACK_START_STEPS).locate(
                [replace(o, z=o.z - offset[index])], initial=x)
            ok &= ~np.asarray(fit.diagnostics["degenerate"])
            x = np.where(ok[:, None], fit.position, x)
    d = (x - x0)[ok][:, :dim]
    if not d.size:
        return None
    shift = np.einsum("ti,tj->ij", d, d) / len(d)
    with np.errstate(all="ignore"):
        ratio = float(np.sqrt(np.trace(shift) / np.nanmedian(np.trace(claimed, axis1=1,
                                                                       axis2=2))))
    return offset, np.broadcast_to(shift, claimed.shape), ratio


def _offsets_finding(request, offset: np.ndarray, shift: np.ndarray, ratio: float
                     ) -> tuple[str, dict, str]:
    """The clause, figures and cause of a finding of anchor offsets (:func:`_anchor_offsets`)."""
    ids = [str(a) for a in request.anchors["id"]]
    rms = math.sqrt(float(np.trace(shift[0])))
    listed = ", ".join(f"{a} {b:+.2g}" for a, b in zip(ids, offset) if b)
    text = (f"each anchor's ranges carry an offset the estimate leaves in ({listed} m, "
            f"from the residuals at fixes of each epoch): taken off, the fixes move by "
            f"{rms:.3g} m (RMS), {ratio:.3g} times the claimed uncertainty (covariance "
            "widened by that shift)")
    return text, {"offsets_m": {a: round(float(b), 3) for a, b in zip(ids, offset) if b},
                  "offset_shift_m": round(rms, 3), "offset_shift_to_claimed": round(ratio, 3)}, (
        "range offsets per anchor (WiFi RTT access points, UWB antenna delays): ekf-track, "
        "smoother and pf learn them from the log by default")


def _persistent_finding(g2: float, ratio: float) -> tuple[str, dict]:
    """The clause and figures of a finding of errors that persist (:func:`_persistence`)."""
    text = (f"errors that persist from epoch to epoch ({math.sqrt(g2):.2g} times the stated "
            f"noise) put fixes of each epoch {ratio:.3g} times the claimed uncertainty off, "
            "which a track cannot average away")
    return text, {"persistent_sigmas": round(math.sqrt(g2), 3),
                  "persistent_to_claimed": round(ratio, 3)}


def _track_fits(request, own: pd.DataFrame, node, options: dict,
                meas: pd.DataFrame | None = None):
    """:func:`_epoch_fits` of the node's epochs (of ``meas``, default the whole log)
    started at its written track ``own``; None with fewer than :data:`PERSISTENCE_EPOCHS`
    epochs (too few for the searches that read them) or nothing to fix."""
    if own["time"].nunique() < PERSISTENCE_EPOCHS:
        return None
    return _epoch_fits(request, request.measurements if meas is None else meas, node,
                       options, track=own)


def _persistence(own: pd.DataFrame, fixed: tuple | None, claimed: np.ndarray
                 ) -> tuple[float, np.ndarray, float]:
    """Errors that persist from epoch to epoch (:func:`_snapshot_node`), from the fixes of
    each epoch ``fixed`` (:func:`_track_fits`): ``(g^2, the fixes' covariance under them at
    each output row (N, D, D), its median standard deviation over the claimed one)``;
    ``g^2`` 0 when the log shows none. The fixes are made from the rows as logged, at the
    noise in force: offsets a method learned count as persistent errors here (tried: less
    the learned offsets, WiFi RTT Conference Room 3 covered 76 %, not 94 %), so where a
    method learned them the part added is an upper bound."""
    dim = claimed.shape[-1]
    none = 0.0, np.zeros_like(claimed), 0.0
    if fixed is None:
        return none
    times, _, fit, u, _ = fixed
    unknowns = fit.diagnostics["state"].shape[-1]
    ok = ~np.asarray(fit.diagnostics["degenerate"]) & np.all(np.isfinite(fit.position), -1)
    kept = np.isfinite(u) & ok[:, None]
    rows_per = kept.sum(-1)
    if ok.sum() < 5 or fit.position.shape[-1] < dim:
        return none
    bound = HUBER * max(_robust_scale(u[kept]), 1.0)
    clipped = np.clip(u, -bound, bound)
    prod = (clipped[:-1] * clipped[1:])[kept[:-1] & kept[1:]]
    spare = float(np.mean(1.0 - unknowns / rows_per[ok]))
    if prod.size <= 10 or spare <= 0:
        return none
    mean, err = float(prod.mean()), float(prod.std()) * math.sqrt(2.0 / prod.size)
    if not mean > 3 * err:
        return none
    g2 = mean / spare
    ok_t = times[ok]
    t_out = own["time"].to_numpy(dtype=float)
    near = np.flatnonzero(ok)[np.clip(np.searchsorted(ok_t, t_out), 0, ok_t.size - 1)]
    persistent = g2 * fit.covariance[near][:, :dim, :dim]
    with np.errstate(all="ignore"):
        ratio = float(np.nanmedian(np.sqrt(np.trace(persistent, axis1=1, axis2=2)
                                           / np.trace(claimed, axis1=1, axis2=2))))
    return g2, persistent, ratio


def _epoch_fits(request, meas: pd.DataFrame, node, options: dict, loss: str = "linear",
                track: pd.DataFrame | None = None):
    """``(times, observations, fit, standardised residuals, rows)`` of a node's epochs each
    fixed on its own (:class:`~radioloc.estimators.least_squares.LeastSquares` with
    ``loss``, the sigmas of ``options``; ranges less the ``range_bias_m`` the user declared;
    started at the written ``track`` when given, else from scratch), or None (nothing to
    fix, or a log that fails)."""
    from radioloc.estimators.fault_exclusion import standardised_residuals
    from radioloc.estimators.least_squares import LeastSquares
    from radioloc.io.measurements import Measurements

    kinds = [k for k in (*CHECKED_KINDS, *SNAPSHOT_KINDS) if k in set(meas["kind"].unique())]
    rows = meas[(meas["node"] == node) & meas["kind"].isin(kinds)]
    if rows.empty or request.anchors is None:
        return None
    models = default_models(kinds, options, settings=frame_settings(request))
    try:
        times, obs = node_observations(Measurements(rows), request.anchors, node, models,
                                       height_m=request.option("tag_height_m"), checked=True)
        if not obs or times.size == 0:
            return None
        obs = _less_declared_bias(request, obs)
        initial, steps = None, 50
        if track is not None:       # each fix started at the written track: a few steps do
            dim = obs[0].context.position_dim
            t_out = track["time"].to_numpy(dtype=float)
            initial = np.column_stack([np.interp(times, t_out, track[c].to_numpy(dtype=float))
                                       for c in ["x", "y", "z"][:dim] if c in track])
            if initial.shape[-1] != dim or not np.isfinite(initial).all():
                initial = None
            steps = 50 if initial is None else TRACK_START_STEPS
        with np.errstate(all="ignore"):
            fit = LeastSquares(loss=loss, max_iterations=steps).locate(obs, initial=initial)
            u = standardised_residuals(obs, fit)
    except RadiolocError:
        return None
    return times, obs, fit, u, rows


def snapshot_scale(request, meas: pd.DataFrame, kinds=None) -> float:
    """The robust scale of a log's standardised residuals at fixes of each epoch on its own
    (every node, the sigmas in force; NaN when no epoch is fixed, or when none of ``kinds``
    is a kind the fixes read): for the slip search, a map of the values whose scale falls by
    no more than the map's own factor has not restored the geometry
    (:func:`radioloc.locate.slips.likely_slip`)."""
    if kinds is not None and not set(kinds) & {*CHECKED_KINDS, *SNAPSHOT_KINDS}:
        return math.nan
    options = {name: value for value, name, _ in stated_sigmas(request, {}).values()}
    pooled = []
    for node in meas["node"].unique():
        fixed = _epoch_fits(request, meas, node, options)
        if fixed is None:
            continue
        fit, u = fixed[2], fixed[3]
        ok = ~np.asarray(fit.diagnostics["degenerate"])
        pooled.append(u[np.isfinite(u) & ok[:, None]])
    return _robust_scale(np.concatenate(pooled)) if pooled else math.nan


def noise_in_force(meas: pd.DataFrame, noise: dict) -> str:
    """The noise each kind of the log ran with, as text: its sigma option's value (``noise``,
    else the kind's default), or the rows' own ``std`` where every row of the kind states one
    (its median)."""
    parts = []
    for kind in sorted(meas["kind"].unique()):
        declared = model_kinds().get(kind)
        if declared is None or not declared.sigma_option:
            continue
        std = (meas.loc[meas["kind"] == kind, "std"].to_numpy(dtype=float)
               if "std" in meas else np.array([np.nan]))
        if np.isfinite(std).all():
            parts.append(f"the {kind} rows' own std (median {np.median(std):.3g})")
        else:
            name = declared.sigma_option
            parts.append(f"{name}={noise.get(name, declared.sigma_default):g}")
    return ", ".join(parts)


def _check_node(method_name, request, own, node, rows: _Rows, sigmas):
    times = np.unique(own["time"].to_numpy(dtype=float))
    dim = rows.positions.shape[1]
    d, cov_d, es, scale = window_fit(rows)
    t_obs = rows.times
    claimed = _claimed(own, t_obs, dim)
    n_w = d.shape[0]
    # --- off its data: the correction outside the claimed covariance
    off = np.zeros(n_w, dtype=bool)
    if claimed is not None:
        P = np.zeros((n_w, dim, dim))
        np.add.at(P, rows.window, claimed)
        P /= np.bincount(rows.window, minlength=n_w)[:, None, None]
        total = P + np.nan_to_num(cov_d, nan=0.0)
        with np.errstate(all="ignore"):
            m2 = np.einsum("wi,wij,wj->w", d, np.linalg.pinv(total), d)
            far = np.linalg.norm(d, axis=1) > OFF_SIGMAS * np.sqrt(np.trace(P, axis1=1, axis2=2))
        off = (m2 > chi2_quantile(CHI2_PROB, dim)) & far & np.all(np.isfinite(cov_d), (1, 2))
        coverage = _coverage_factor(d, P, cov_d)
    else:
        coverage = 1.0
    # --- outside the anchors' region
    anchors = request.anchors
    box = anchors[["x", "y"]].to_numpy(dtype=float)
    lo, hi = box.min(0), box.max(0)
    xy = own[["x", "y"]].to_numpy(dtype=float)
    outside = np.linalg.norm(np.maximum(lo - xy, 0) + np.maximum(xy - hi, 0), axis=1)
    unc = own["uncertainty_m"].to_numpy(dtype=float) if "uncertainty_m" in own else np.zeros(len(own))
    away = outside > np.linalg.norm(hi - lo) + OFF_SIGMAS * unc
    checks, figures = [], {"residual_scale": round(scale, 3)}
    if off.mean() > OFF_FRACTION:
        checks.append("off_its_data")
        figures["windows_off"] = round(float(off.mean()), 3)
        figures["correction_m"] = round(float(np.median(np.linalg.norm(d[off], axis=1))), 3)
    if scale > SCALE_LIMIT:
        checks.append("misfit")
    if _wrong_anchor(_per_anchor_scale(rows, es)) is not None:
        checks.append("anchor_misfit")
    if away.any():
        checks.append("outside_anchors")
        figures["outside_m"] = round(float(outside.max()), 3)
    factor = max(max(1.0, scale) if scale > INFLATE_ABOVE else 1.0, coverage)
    figures["coverage_factor"] = round(coverage, 3)
    filled = _inflate(own, factor, rows, cov_d, t_obs)
    if not checks:
        return [], factor, scale, filled
    bad_t = own["time"].to_numpy(dtype=float)[away]
    if "off_its_data" in checks:
        bad_t = np.concatenate([bad_t, t_obs[np.isin(rows.window, np.flatnonzero(off))]])
    if bad_t.size == 0 or "misfit" in checks or "anchor_misfit" in checks:
        bad_t = np.concatenate([bad_t, times])     # a misfit is judged over the whole track
    start, end = float(bad_t.min()), float(bad_t.max())
    cause = likely_cause(request, rows, d, es, scale, sigmas, node, bool(away.any()),
                         fits=checks == ["outside_anchors"])
    figures["inflation"] = round(factor, 3)
    what = []
    if "off_its_data" in checks:
        what.append(f"the rows fit positions {figures['correction_m']:.3g} m from the track, "
                    f"beyond its claimed uncertainty, in {100 * figures['windows_off']:.0f} % of "
                    "its windows")
    if "misfit" in checks:
        what.append(f"residuals {scale:.3g} times the stated noise")
    if "anchor_misfit" in checks and len(checks) == 1:
        what.append("one anchor's rows misfit while the others fit")
    if "outside_anchors" in checks:
        what.append(f"positions up to {figures['outside_m']:.3g} m outside the anchors' box")
    message = (f"node {node!r}, time {start:g} to {end:g}: {'; '.join(what)}; likely cause: "
               f"{cause[1]}" + (f" (covariance inflated x{factor:.3g})" if factor > 1 else ""))
    return [Finding(node, start, end, checks, cause[0], message, figures)], factor, scale, filled


def _coverage_factor(d: np.ndarray, P: np.ndarray, cov_d: np.ndarray) -> float:
    """The smallest ``k >= 1`` for which the corrections' median ``d' (k^2 P + C)^-1 d`` is at
    most its chi-square median: the factor by which the claimed covariance ``P`` is too
    small for the data (1 when it covers them; above :data:`INFLATE_ABOVE` only counted)."""
    ok = np.all(np.isfinite(cov_d), (1, 2)) & np.all(np.isfinite(P), (1, 2))
    if ok.sum() < 5:
        return 1.0
    d, P, C = d[ok], P[ok], cov_d[ok]
    target = chi2_quantile(0.5, d.shape[1])

    def median_m2(k):
        with np.errstate(all="ignore"):
            return float(np.median(np.einsum("wi,wij,wj->w", d, np.linalg.pinv(k * k * P + C), d)))

    if median_m2(1.0) <= target:
        return 1.0
    lo, hi = 1.0, 2.0
    while median_m2(hi) > target and hi < 1e6:
        lo, hi = hi, 2 * hi
    for _ in range(30):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if median_m2(mid) > target else (lo, mid)
    return hi if hi > INFLATE_ABOVE else 1.0


def _inflate(own: pd.DataFrame, factor: float, rows: _Rows, cov_d, t_obs) -> pd.DataFrame:
    cov = covariance_of(own)
    if cov is None:       # a method without covariance: the window fits' (per window of rows)
        dim = cov_d.shape[-1]
        t_out = own["time"].to_numpy(dtype=float)
        idx = np.clip(np.searchsorted(t_obs, t_out), 0, len(t_obs) - 1)
        steps = np.bincount(rows.window)[rows.window[idx]]
        per_window = cov_d.copy()
        lost = ~np.all(np.isfinite(per_window), (1, 2))
        if lost.all():
            return own
        per_window[lost] = np.max(per_window[~lost], axis=0)   # a window that fixes nothing
        filled = per_window[rows.window[idx]] * steps[:, None, None] / max(factor, 1.0) ** 2
        cov = filled[:, :dim, :dim]
    if factor == 1.0 and covariance_of(own) is not None:
        return own
    return add_covariance(own, cov * factor ** 2)


def _centre(rows: _Rows) -> np.ndarray:
    """Corrections that move each window to the centre of the anchors (a second start)."""
    pts = np.concatenate([o.context.points.reshape(-1, o.context.points.shape[-1])
                          for o in rows.observations])
    dim = rows.positions.shape[1]
    n_w = int(rows.window.max()) + 1
    mean = np.zeros((n_w, dim))
    np.add.at(mean, rows.window, rows.positions)
    mean /= np.bincount(rows.window, minlength=n_w)[:, None]
    return pts[:, :dim].mean(0) - mean


def _refit_scale(rows: _Rows, observations, start=None) -> float:
    return window_fit(rows, observations, start)[3]


def likely_cause(request, rows: _Rows, d, es, scale, sigmas, node, diverged: bool = False,
                 fits: bool = False) -> tuple[str, str]:
    """``(code, text)`` of the likeliest cause of a node's failure (module docstring);
    ``diverged``: the track left the anchors' region (then not blamed on the noise);
    ``fits``: its rows fit it there (then weak geometry, not a lost track)."""
    obs = rows.observations
    # a slip of one kind's values: mapped back, the rows fit
    if scale > SCALE_LIMIT:
        for kinds, undo, how, question in slips():
            if not any(o.model.kind in kinds for o in obs):
                continue
            if not np.isclose(slip_scale(undo), 1.0):
                continue                     # units: the plausibility checks' domain
            mapped = [replace(o, z=undo(o.z)) if o.model.kind in kinds else o for o in obs]
            with np.errstate(all="ignore"):
                s = min(_refit_scale(rows, mapped), _refit_scale(rows, mapped, _centre(rows)))
            if s < FITS_BELOW:
                return "slip", f"{question} (the rows fit once {how})"
    # one anchor's rows misfit: alone at the track, or once fixes from the others fit
    per = _per_anchor_scale(rows, es)
    worst = _wrong_anchor(per)
    if worst is not None:
        others = np.median([v for k, v in per.items() if k != worst])
        held = (f"its rows misfit {per[worst]:.3g} times the noise, the others "
                f"{others:.3g} times")
    elif scale > SCALE_LIMIT and (found := _held_out_anchor(rows)) is not None:
        worst, fit, misfit = found
        held = (f"without it the others fit fixes step by step ({fit:.2g} times the noise), "
                f"where its rows misfit {misfit:.3g} times")
    if worst is not None:
        swapped = _swapped_fits(request, rows, worst)
        if swapped:
            return "anchor", (f"anchor {worst!r} has x and y swapped (its rows fit it at "
                              f"{swapped})")
        return "anchor", f"anchor {worst!r} is wrong ({held})"
    if diverged and fits:
        return "geometry", (f"weak geometry, not a lost track (its rows fit it: residuals "
                            f"{scale:.2g} times the stated noise): far outside the anchors, "
                            "slowly changing range errors pass into the track unseen, and its "
                            "claimed uncertainty there is not checked by the rows")
    if diverged:
        return "diverged", "a diverged track (it left the region the anchors fix)"
    # NLOS: ranges longer than the fit, rarely shorter
    for o, e in zip(obs, es):
        if o.model.kind != "range":
            continue
        v = e[np.isfinite(e)] / max(scale if scale < SCALE_LIMIT else 1.0, 1.0)
        longer, shorter = np.mean(v > 3), np.mean(v < -3)
        if longer > NLOS_SHARE and longer > NLOS_RATIO * shorter:
            return "nlos", (f"NLOS: {100 * longer:.0f} % of the ranges lie 3 sigma or more longer "
                            f"than the fit and {100 * shorter:.0f} % shorter (a LOS/NLOS model: "
                            "--method smoother or pf)")
    if scale > SCALE_LIMIT:
        kinds = sorted({o.model.kind for o in obs})
        tried = ", ".join(f"{sigmas[k][1]}={sigmas[k][0] * scale:.2g}" for k in kinds)
        if all(sigmas[k][2] for k in kinds):
            named = ", ".join(f"{sigmas[k][1]}={sigmas[k][0]:g}" for k in kinds)
            return "noise", f"{named} too small for this log? (the residuals say {tried})"
        return "noise", (f"a noise model too narrow for this log (the residuals' robust spread: "
                         f"{tried})")
    return "diverged", "a diverged track (the rows fit well positions away from it)"


def _wrong_anchor(per: dict[str, float]) -> str | None:
    """The anchor whose rows alone misfit (scale above :data:`SCALE_LIMIT` and 4 times the
    others' median, which fit), or None."""
    if len(per) < 3:
        return None
    worst = max(per, key=per.get)
    others = float(np.median([v for k, v in per.items() if k != worst]))
    if per[worst] > SCALE_LIMIT and per[worst] > 4 * max(others, 1.0) and others < SCALE_LIMIT:
        return worst
    return None


def _per_anchor_scale(rows: _Rows, es) -> dict[str, float]:
    """Robust scale of each anchor's normalised residuals (a time difference counts for its
    peer)."""
    out: dict[int, list] = {}
    for o, e in zip(rows.observations, es):
        if o.context.index is None:
            continue
        for s, a in enumerate(o.context.index):
            if a >= 0:
                out.setdefault(int(a), []).append(e[:, s])
    return {rows.anchor_ids[a]: _robust_scale(np.concatenate(v)) for a, v in out.items()}


def _step_by_step(rows: _Rows, observations) -> tuple[_Rows, list] | None:
    """``rows`` with a window for each step where ``observations`` give it more rows than
    unknowns (so each fix is tested), the other steps' rows left out (one empty window);
    with those observations. None when fewer than :data:`WINDOW_ROWS` rows are left."""
    dim = rows.positions.shape[1]
    n = np.sum([np.isfinite(o.z).sum(axis=1) for o in observations], axis=0)
    keep = n > dim
    if n[keep].sum() < WINDOW_ROWS // 2:
        return None
    window = np.where(keep, np.cumsum(keep) - 1, int(keep.sum()))
    kept = [replace(o, z=np.where(keep.reshape((-1,) + (1,) * (o.z.ndim - 1)), o.z, np.nan))
            for o in observations]
    return replace(rows, window=window), kept


def _held_out_anchor(rows: _Rows) -> tuple[str, float, float] | None:
    """The one anchor without whose rows the others fit fixes made step by step, while its
    own rows misfit those fixes: ``(id, fit, misfit)``.

    Each anchor is left out in turn. The others' rows fix each step (:func:`window_fit`, a
    window per step); their residuals are studentised by ``sqrt(1 - h)`` and the left-out
    anchor's by ``sqrt(1 + h)`` (``h`` the row's leverage at the fix: a fix with one row to
    spare leaves small residuals where the geometry gives them little room), so both robust
    scales estimate the same noise when the anchor is right. Named when only that anchor's
    leaving out gives a fit below :data:`FITS_BELOW`, and its rows misfit above
    :data:`SCALE_LIMIT` and four times the fit."""
    anchors = sorted({int(a) for o in rows.observations if o.context.index is not None
                      for a in np.ravel(o.context.index) if a >= 0})
    if len(anchors) < 3:
        return None
    fits = {}
    for a in anchors:
        without = [o if o.context.index is None else
                   replace(o, z=np.where(o.context.index == a, np.nan, o.z))
                   for o in rows.observations]
        steps = _step_by_step(rows, without)
        if steps is None:
            continue
        step_rows, kept = steps
        n_w, dim = int(step_rows.window.max()) + 1, step_rows.positions.shape[1]
        with np.errstate(all="ignore"):
            d = window_fit(step_rows, kept)[0]
            pos = step_rows.positions + d[step_rows.window]
            parts = []
            info = np.zeros((n_w, dim, dim))
            for o, k, sig in zip(step_rows.observations, kept, step_rows.sigma):
                zhat, jac = o.model.predict_with_jacobian({"position": pos}, o.context)
                J = np.nan_to_num(jac["position"] / sig[..., None])
                e = o.model.residual(o.z, zhat) / sig
                used = np.isfinite(k.z)
                np.add.at(info, step_rows.window,
                          np.einsum("tsi,tsj->tij", J * used[..., None], J))
                parts.append((o, J, e, used))
            cov = np.linalg.pinv(info)[step_rows.window]
            fit, held = [], []
            for o, J, e, used in parts:
                h = np.einsum("tsi,tij,tsj->ts", J, cov, J)
                fit.append(np.where(used, e / np.sqrt(np.maximum(1 - h, 1e-3)), np.nan).ravel())
                if o.context.index is not None:
                    out = (np.ravel(o.context.index) == a)[None, :] & np.isfinite(o.z)
                    held.append(np.where(out, e / np.sqrt(1 + h), np.nan).ravel())
        fits[a] = (_robust_scale(np.concatenate(fit)),
                   _robust_scale(np.concatenate(held)) if held else math.nan)
    good = [a for a, (fit, misfit) in fits.items() if fit < FITS_BELOW]
    if len(good) != 1:
        return None
    fit, misfit = fits[good[0]]
    if not (misfit > SCALE_LIMIT and misfit > 4 * fit):
        return None
    return rows.anchor_ids[good[0]], fit, misfit


def _swapped_fits(request, rows: _Rows, anchor: str) -> str | None:
    """Where the anchor's rows fit it with x and y swapped (text), or None."""
    table = request.anchors
    ids = list(dict.fromkeys(table["id"]))
    a = ids.index(anchor)
    mapped = []
    for o in rows.observations:
        ctx = o.context
        if ctx.index is None or ctx.points.ndim != 2 or a not in ctx.index:
            mapped.append(o)
            continue
        pts = ctx.points.copy()
        pts[ctx.index == a, :2] = pts[ctx.index == a, 1::-1]
        mapped.append(replace(o, context=replace(ctx, points=pts)))
    x, y = table.loc[table["id"] == anchor, ["x", "y"]].to_numpy(float)[0]
    if x == y:
        return None
    steps = _step_by_step(rows, mapped)
    if steps is None:
        return None
    with np.errstate(all="ignore"):
        _, _, es, _ = window_fit(*steps)
    if _per_anchor_scale(steps[0], es).get(anchor, math.inf) < FITS_BELOW:
        return f"x={y:g}, y={x:g}"
    return None
