"""Calibration of per-base-station signal-strength models ``D^(k)(x, y, m)`` (paper 004, Sect. 3.1).

Three constructions:

- :func:`parameter_calibration`: our reading of the paper's Progressive Bayes calibration in
  the parameter space (Fig. 3). The paper re-approximates the parameter density by a
  Gaussian mixture after each sample; ours keeps one Gaussian over the parameters, updated
  in two linearised steps per sample (Titterington's recursive EM with a Gaussian prior).
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
from scipy.special import softmax

from radioloc.core.errors import InputError
from radioloc.core.validation import as_float_array
from radioloc.models.mixture import DiagMixture, check_reduction, reduce

_LOG2PI = float(np.log(2.0 * np.pi))


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


def _halton(n: int, dim: int) -> np.ndarray:
    """The first ``n`` points of the Halton sequence in ``[0, 1)^dim`` (bases 2, 3, 5, ...),
    offset by one point (the first Halton point, 0, is a corner of the box)."""
    primes = [2, 3, 5, 7, 11, 13, 17, 19, 23, 29][:dim]
    out = np.zeros((n, dim))
    for d, b in enumerate(primes):
        for i in range(n):
            f, r, k = 1.0, 0.0, i + 1
            while k > 0:
                f /= b
                r += f * (k % b)
                k //= b
            out[i, d] = r
    return out


def parameter_calibration(positions, rss, bounds, std_bounds, n_components: int = 16,
                          steps: int = 2, order=None) -> DiagMixture:
    """Calibration in the parameter space: our reading of paper 004's Progressive Bayes
    calibration (Sect. 3.1, Fig. 3), not the paper's method itself.

    The paper re-approximates the parameter density by a Gaussian mixture, progressively,
    after each sample; here the parameter density is one Gaussian, updated in linearised
    progression steps (below).

    Per base station, the density of the parameter vector ``eta`` of eq. (1) (per component
    the weight, the means and the standard deviations) starts from a uniform prior and is
    multiplied by the likelihood of each calibration sample in turn,
    ``f~(eta_i) = f^p(eta_i) f^L(eta_i | C_i)``, and re-approximated after each sample
    (Fig. 3). Our reading, where the paper is silent:

    - **Parameters.** ``eta`` holds per component the softmax logit of its weight, its
      means and the logarithms of its per-axis standard deviations.
    - **Parameter-space likelihood.** ``f^L(eta | c_i) = D(c_i; eta)``, the density of
      eq. (1) at the sample ``c_i = (position, m)``, as a function of ``eta``.
    - **Approximating density.** One Gaussian ``N(eta; eta_hat, Lambda^-1)`` (a mixture of
      one component). The uniform prior is replaced by the Gaussian of its variances:
      ``(hi - lo)^2 / 12`` for the means and log-stds, ``pi^2 / 6`` for the logits (the
      variance of the logarithm of an exponential variable: a flat Dirichlet prior on the
      weights); its centre places the component means on a Halton sequence over the box
      ``bounds`` (the uniform prior's own mean, every component at the centre of the box,
      is a fixed point of the label symmetry: equal components get equal updates).
    - **Progression** ([3]). Sample ``i`` enters as ``f^p(eta) f^L(eta | c_i)^gamma``,
      ``gamma`` from 0 to 1 in ``steps`` Euler steps. For a Gaussian approximation the
      moments follow ``d Lambda / d gamma = H(eta_hat)`` and
      ``d eta_hat / d gamma = Lambda^-1 g(eta_hat)``, with ``g = d log f^L / d eta`` and
      ``H`` the information of one sample; the gradient and ``H`` are re-evaluated at every
      step (the linearisation follows the progression). ``H`` is the complete-data
      information weighted by the responsibilities ``r_j`` (positive semi-definite, unlike
      the Hessian of the log-likelihood): ``r_j / sigma_jd^2`` for a mean, ``2 r_j`` for a
      log-std, ``diag(w) - w w^T`` for the logits. With a flat prior this is the recursive
      (stochastic-approximation) EM of Titterington (1984).
    - The log-stds are clipped to ``std_bounds``.

    The returned model is the mode of the parameter density after the last sample
    ("the parameter model will form a more distinct maximum"). Every base station and every
    leading batch axis (Monte Carlo run) is updated at once; the loops are over samples and
    progression steps.

    Parameters
    ----------
    positions : array (..., N, P)
        Calibration positions (P = 1 or 2 coordinates), leading batch axes allowed.
    rss : array (..., N, S)
        Signal strength of each of S base stations per sample, NaN = not received (the
        sample does not update that station).
    bounds : array (P + 1, 2)
        Lower and upper end of the uniform prior of the component means per axis
        (position coordinates, then ``m``).
    std_bounds : array (P + 1, 2)
        Lower and upper end of the uniform prior of the component standard deviations per
        axis (> 0).
    n_components : int
        Components of each model, ``N^(k)`` of eq. (1).
    steps : int
        Euler steps of the progression per sample (>= 1).
    order : array (N,) of int, optional
        Insertion order (default: the given order).

    Returns
    -------
    DiagMixture
        Batch shape ``(..., S)``, dimension ``P + 1`` (position coordinates then ``m``).
    """
    pos, m = _check_samples(positions, rss)
    dim = pos.shape[-1] + 1
    box = as_float_array(bounds, "bounds", ndim=2, last_dim=2)
    sbox = as_float_array(std_bounds, "std_bounds", ndim=2, last_dim=2)
    for name, b in (("bounds", box), ("std_bounds", sbox)):
        if b.shape[0] != dim:
            raise InputError(f"{name}: expected {dim} rows (position coordinates, then m), "
                             f"got {b.shape[0]}")
        if np.any(b[:, 1] <= b[:, 0]):
            raise InputError(f"{name}: every upper end must exceed its lower end")
    if np.any(sbox <= 0):
        raise InputError("std_bounds: must be > 0")
    for name, val in (("n_components", n_components), ("steps", steps)):
        if isinstance(val, bool) or int(val) != val or int(val) < 1:
            raise InputError(f"{name}: must be an integer >= 1, got {val!r}")
    k, n, s = int(n_components), pos.shape[-2], m.shape[-1]
    batch = pos.shape[:-2] + (s,)
    if np.any(np.sum(np.isfinite(m), axis=-2) == 0):
        raise InputError("rss: a base station has no calibration sample")
    lo_s, hi_s = np.log(sbox[:, 0]), np.log(sbox[:, 1])
    # the Gaussian stand-in of the uniform prior
    mu = np.broadcast_to(box[:, 0] + _halton(k, dim) * (box[:, 1] - box[:, 0]),
                         batch + (k, dim)).copy()
    ls = np.broadcast_to(0.5 * (lo_s + hi_s), batch + (k, dim)).copy()
    alpha = np.zeros(batch + (k,))
    lam_mu = np.broadcast_to(12.0 / (box[:, 1] - box[:, 0]) ** 2, batch + (k, dim)).copy()
    lam_ls = np.broadcast_to(12.0 / (hi_s - lo_s) ** 2, batch + (k, dim)).copy()
    lam_a = np.broadcast_to(np.eye(k) * 6.0 / np.pi**2, batch + (k, k)).copy()
    order = np.arange(n) if order is None else np.asarray(order)
    dg = 1.0 / int(steps)
    for i in order:
        got = np.isfinite(m[..., i, :])                                    # (..., S)
        c = np.concatenate([np.broadcast_to(pos[..., i, None, :], batch[:-1] + (s, dim - 1)),
                            np.where(got, m[..., i, :], 0.0)[..., None]], axis=-1)
        gate = np.where(got, dg, 0.0)
        for _ in range(int(steps)):
            w = softmax(alpha, axis=-1)
            inv_var = np.exp(-2.0 * ls)
            z2 = (c[..., None, :] - mu) ** 2 * inv_var                      # (..., S, K, D)
            logn = -np.sum(ls + 0.5 * z2, axis=-1) - 0.5 * dim * _LOG2PI
            r = softmax(np.log(w) + logn, axis=-1)                         # responsibilities
            # information of this sample (Euler step of d Lambda / d gamma)
            lam_mu += gate[..., None, None] * r[..., None] * inv_var
            lam_ls += gate[..., None, None] * 2.0 * r[..., None]
            lam_a += gate[..., None, None] * (w[..., :, None] * np.eye(k)
                                              - w[..., :, None] * w[..., None, :])
            # gradient of log f^L and the mean step Lambda^-1 g
            mu = mu + gate[..., None, None] * r[..., None] * (c[..., None, :] - mu) \
                * inv_var / lam_mu
            ls = np.clip(ls + gate[..., None, None] * r[..., None] * (z2 - 1.0) / lam_ls,
                         lo_s, hi_s)
            alpha = alpha + gate[..., None] * np.linalg.solve(lam_a, (r - w)[..., None])[..., 0]
    return DiagMixture(softmax(alpha, axis=-1), mu, np.exp(2.0 * ls))
