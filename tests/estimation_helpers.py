"""Tiny estimators for the measurement-model tests: a batched Gauss-Newton fit (the
maximum-likelihood estimate of a snapshot under Gaussian noise with a full covariance) and an
extended Kalman filter over the Kalman core, plus a linear-Gaussian trajectory draw."""

import numpy as np

from radioloc.estimators.kalman import kalman_predict, kalman_update


def read_columns(layout, models):
    """State columns of the components any of ``models`` reads, in state order."""
    read = {c for m in models for c in m.reads}
    return np.concatenate([np.arange(sl.start, sl.stop) for c, sl in layout.slices.items()
                           if c in read])


def gauss_newton(observations, layout, x0, iters=8):
    """Weighted least squares ``min sum_k r_k^T R_k^-1 r_k`` over the columns the models
    read, from ``x0`` ``(..., n)`` (observations hold snapshot ``z`` of shape ``(..., m)``)."""
    cols = read_columns(layout, [o.model for o in observations])
    x = np.array(x0, dtype=float)
    for _ in range(iters):
        A = np.zeros(x.shape[:-1] + (cols.size, cols.size))
        b = np.zeros(x.shape[:-1] + (cols.size,))
        for obs in observations:
            z_hat, H = layout.measure(obs.model, x, obs.context)
            H = H[..., cols]
            r = obs.model.residual(obs.z, z_hat)
            W = np.linalg.inv(obs.model.noise_cov(obs.context))
            WH = np.einsum("...ij,...jk->...ik", W, H)
            A += np.einsum("...mi,...mj->...ij", H, WH)
            b += np.einsum("...mi,...m->...i", WH, r)
        x[..., cols] += np.linalg.solve(A, b[..., None])[..., 0]
    return x


def draw_track(F, Q, x0, steps, rng):
    """States ``(..., T, n)`` of ``x_k = F x_{k-1} + w``, ``w ~ N(0, Q)``, from ``x0``."""
    vals, vecs = np.linalg.eigh(Q)
    root = vecs * np.sqrt(np.maximum(vals, 0.0))
    xs = [np.asarray(x0, dtype=float)]
    for _ in range(steps - 1):
        w = np.einsum("ij,...j->...i", root, rng.standard_normal(xs[-1].shape))
        xs.append(np.einsum("ij,...j->...i", F, xs[-1]) + w)
    return np.stack(xs, axis=-2)


def ekf_track(observations, layout, F, Q, prior_mean, prior_cov):
    """Extended Kalman filter means ``(..., T, n)``: predict with ``F, Q``, then update with
    each observation in turn (full noise covariance, NaN rows skipped)."""
    mean = np.array(prior_mean, dtype=float)
    cov = np.broadcast_to(prior_cov, mean.shape + mean.shape[-1:]).copy()
    out = []
    for k in range(observations[0].steps):
        if k:
            mean, cov = kalman_predict(mean, cov, F, Q)
        for obs in observations:
            z, ctx = obs.at(k)
            z_hat, H = layout.measure(obs.model, mean, ctx)
            nu = obs.model.residual(z, z_hat)
            mean, cov, _, _ = kalman_update(mean, cov, nu, H, R=obs.model.noise_cov(ctx))
        out.append(mean)
    return np.stack(out, axis=-2)


def rmse_over_bound(estimate, truth, bound_rmse_m, dim):
    """Position RMSE over the runs (and steps) divided by the bound's RMS ``sqrt(trace)``."""
    err = estimate[..., :dim] - truth[..., :dim]
    return float(np.sqrt(np.mean(np.sum(err**2, axis=-1)) / np.mean(np.square(bound_rmse_m))))
