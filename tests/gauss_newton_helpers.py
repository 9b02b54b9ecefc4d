"""A tiny batched Gauss-Newton fit for the measurement-model tests (the maximum-likelihood
estimate of a snapshot under Gaussian noise with a full covariance)."""

import numpy as np


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


def rmse_over_bound(estimate, truth, bound_rmse_m, dim):
    """Position RMSE over the runs divided by the bound's ``sqrt(trace)``."""
    err = estimate[..., :dim] - truth[..., :dim]
    return float(np.sqrt(np.mean(np.sum(err**2, axis=-1))) / np.mean(bound_rmse_m))
