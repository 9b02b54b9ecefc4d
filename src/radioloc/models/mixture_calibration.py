"""Calibration of per-base-station signal-strength models ``D^(k)(x, y, m)`` (paper 004, Sect. 3.1).

Two constructions:

- :func:`progressive_calibration`: the samples are inserted one at a time. Sample ``i`` of a
  base station becomes an axis-aligned kernel component (mean = the sample, per-axis
  variance = ``bandwidth**2``) with weight ``1/n`` while the existing components are scaled
  by ``(n-1)/n``, so the model is always the running average of the inserted kernels; as
  soon as the model holds more than ``max_components`` components it is re-approximated by
  :func:`radioloc.models.mixture.reduce` (moment-preserving West/Runnalls merge, or with
  ``reduction="progressive"`` the Progressive Bayes ISD homotopy; ``insert_batch`` samples
  may be inserted between two re-approximations). This is a
  data-space counterpart of the paper's sample-by-sample Progressive Bayes update, which the
  paper performs in a parameter space it does not specify; the bounded component count and
  the re-approximation after each insertion are as in the paper. All base stations (and all
  Monte Carlo runs) are updated at once: the loop is over samples only.
- :func:`em_calibration`: batch EM (scikit-learn ``GaussianMixture``,
  ``covariance_type='diag'``), the reference.

In both, a base station missing from a calibration row (NaN) does not use that row.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.validation import as_float_array
from radioloc.models.mixture import DiagMixture, check_reduction, reduce


def _check_samples(positions, rss):
    pos = as_float_array(positions, "positions", min_ndim=2)
    m = as_float_array(rss, "rss", min_ndim=2, allow_nan=True)
    if m.shape[:-1] != pos.shape[:-1]:
        raise InputError(f"rss: shape {m.shape} does not match positions {pos.shape}")
    return pos, m


def progressive_calibration(positions, rss, bandwidth, max_components: int = 16,
                            order=None, reduction: str = "runnalls",
                            insert_batch: int = 1) -> DiagMixture:
    """Sample-by-sample calibration with a bounded number of components.

    Parameters
    ----------
    positions : array (..., N, P)
        Calibration positions (``P`` = 1 or 2 coordinates), leading batch axes allowed.
    rss : array (..., N, S)
        Signal strength of each of ``S`` base stations per sample, NaN = not received.
    bandwidth : array (P + 1,)
        Kernel standard deviations of the inserted components for (position..., m).
    max_components : int
        Bound on the components of each model.
    order : array (N,) of int, optional
        Insertion order (default: the given order).
    reduction : str
        Re-approximation after each insertion: ``"runnalls"`` (West/Runnalls merging) or
        ``"progressive"`` (the Progressive Bayes ISD homotopy of the paper's reference [3]).
    insert_batch : int
        Samples inserted before each re-approximation (1: one at a time, as in Fig. 3; more
        trades the sample-by-sample order for fewer, larger re-approximations).

    Returns
    -------
    DiagMixture
        Batch shape ``(..., S)``, dimension ``P + 1`` (position coordinates then ``m``).
    """
    pos, m = _check_samples(positions, rss)
    h = as_float_array(bandwidth, "bandwidth", ndim=1, last_dim=pos.shape[-1] + 1)
    check_reduction(reduction)
    if isinstance(insert_batch, bool) or int(insert_batch) != insert_batch or insert_batch < 1:
        raise InputError(f"insert_batch: must be an integer >= 1, got {insert_batch!r}")
    if np.any(h <= 0):
        raise InputError("bandwidth: must be > 0")
    n, s, p = pos.shape[-2], m.shape[-1], pos.shape[-1]
    batch = pos.shape[:-2] + (s,)
    if order is None:
        order = np.arange(n)
    w = np.zeros(batch + (0,))
    mu = np.zeros(batch + (0, p + 1))
    var = np.zeros(batch + (0, p + 1))
    count = np.zeros(batch)
    order = np.asarray(order)
    for step, i in enumerate(order):
        got = np.isfinite(m[..., i, :])                                    # (..., S)
        count = count + got
        scale = np.where(got, (count - 1) / np.maximum(count, 1), 1.0)
        new_mu = np.concatenate([np.broadcast_to(pos[..., i, None, :], batch[:-1] + (s, p)),
                                 np.where(got, m[..., i, :], 0.0)[..., None]], axis=-1)
        w = np.concatenate([w * scale[..., None], np.where(got, 1 / np.maximum(count, 1), 0.0)
                            [..., None]], axis=-1)
        mu = np.concatenate([mu, new_mu[..., None, :]], axis=-2)
        var = np.concatenate([var, np.broadcast_to(h**2, batch + (1, p + 1))], axis=-2)
        last = step == order.size - 1
        if w.shape[-1] > max_components and (last or w.shape[-1] >= max_components
                                             + int(insert_batch)):
            red = reduce(DiagMixture(w, mu, var), max_components, reduction)
            w, mu, var = red.weights, red.means, red.variances
    if np.any(count == 0):
        raise InputError("rss: a base station has no calibration sample")
    return DiagMixture(w / w.sum(-1, keepdims=True), mu, var)


def em_calibration(positions, rss, n_components: int = 16, *, rng: np.random.Generator,
                   reg_covar: float = 1e-3) -> DiagMixture:
    """Batch EM fit of one axis-aligned mixture per base station (scikit-learn).

    Parameters
    ----------
    positions : array_like, shape (N, P)
        Calibration positions.
    rss : array_like, shape (N, S)
        Signal strengths, NaN = not received (the row is not used for that station).
    n_components : int
        Components per station (>= 1); a station with fewer samples gets as many
        components as samples, padded with zero weights.
    rng : numpy.random.Generator
        Source of the k-means++ initialisation (one ``random_state`` per station is drawn
        from it).
    reg_covar : float
        Variance added to the diagonal of every component (scikit-learn).

    Returns
    -------
    DiagMixture
        Batch shape ``(S,)``, dimension ``P + 1``.
    """
    from sklearn.mixture import GaussianMixture

    pos, m = _check_samples(positions, rss)
    if pos.ndim != 2:
        raise InputError("positions: em_calibration takes one calibration set (N, P)")
    if isinstance(n_components, bool) or int(n_components) != n_components or n_components < 1:
        raise InputError(f"n_components: must be an integer >= 1, got {n_components!r}")
    n_components = int(n_components)
    if not isinstance(rng, np.random.Generator):
        raise InputError(f"rng: expected a numpy Generator, got {type(rng).__name__}")
    p = pos.shape[1]
    states = rng.integers(0, 2**31 - 1, size=m.shape[1])
    ws, mus, vs = [], [], []
    for k in range(m.shape[1]):      # one sklearn fit per base station
        ok = np.isfinite(m[:, k])
        if ok.sum() < 2:
            raise InputError(f"rss: base station column {k} has fewer than 2 calibration samples")
        data = np.c_[pos[ok], m[ok, k]]
        kk = min(n_components, int(ok.sum()))
        gm = GaussianMixture(kk, covariance_type="diag", random_state=int(states[k]),
                             init_params="k-means++",
                             reg_covar=reg_covar).fit(data)
        pad = n_components - kk
        ws.append(np.r_[gm.weights_, np.zeros(pad)])
        mus.append(np.r_[gm.means_, np.zeros((pad, p + 1))])
        vs.append(np.r_[gm.covariances_, np.ones((pad, p + 1))])
    return DiagMixture(np.array(ws), np.array(mus), np.array(vs))
