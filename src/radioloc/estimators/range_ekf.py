"""Extended Kalman filter for ranges to one moving sensor (paper 002 baseline).

State ``[x, y, vx, vy]`` with the constant-acceleration transition of eq. (1),
``F = [[I, T I], [0, I]]`` and process noise ``delta_g^2 [[T^4/4 I, T^3/2 I], [T^3/2 I, T^2 I]]``;
measurement ``rhat_n = |p_n - s_n| + omega_n`` with variance ``xi``. Batched over runs, loop
over samples.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.validation import as_float_array, check_finite_output, check_positive


def range_ekf(ranges, sensor, initial_state, initial_covariance, *, sample_period_s: float,
              accel_var: float, range_var: float) -> np.ndarray:
    """Filtered states ``[x, y, vx, vy]`` at every sample, shape (..., n, 4).

    Parameters
    ----------
    ranges : (..., n)
    sensor : (n, 2) or (..., n, 2)
    initial_state : (..., 4)  prior mean at sample 0, ``[x, y, vx, vy]``.
    initial_covariance : (4, 4) or (..., 4, 4)
    sample_period_s, accel_var, range_var : float
        T, ``delta_g^2`` and ``xi`` (must be > 0).
    """
    r = as_float_array(ranges, "ranges", min_ndim=1, nonnegative=True)
    s = as_float_array(sensor, "sensor", min_ndim=2, last_dim=2)
    x = as_float_array(initial_state, "initial_state", min_ndim=1, last_dim=4)
    P = as_float_array(initial_covariance, "initial_covariance", min_ndim=2, last_dim=4)
    T = check_positive(sample_period_s, "sample_period_s")
    q = check_positive(accel_var, "accel_var", allow_zero=True)
    xi = check_positive(range_var, "range_var")
    n = r.shape[-1]
    batch = np.broadcast_shapes(r.shape[:-1], s.shape[:-2], x.shape[:-1], P.shape[:-2])
    x = np.broadcast_to(x, batch + (4,)).copy()
    P = np.broadcast_to(P, batch + (4, 4)).copy()
    s = np.broadcast_to(s, batch + (n, 2))
    I2 = np.eye(2)
    F = np.block([[I2, T * I2], [0 * I2, I2]])
    Q = q * np.block([[T**4 / 4 * I2, T**3 / 2 * I2], [T**3 / 2 * I2, T**2 * I2]])
    out = np.empty(batch + (n, 4))
    for i in range(n):
        if i > 0:
            x = x @ F.T
            P = F @ P @ F.T + Q
        d = x[..., :2] - s[..., i, :]
        h = np.maximum(np.linalg.norm(d, axis=-1), 1e-9)
        H = np.concatenate([d / h[..., None], np.zeros(batch + (2,))], axis=-1)   # (..., 4)
        PH = (P @ H[..., None])[..., 0]
        innov_var = np.einsum("...i,...i->...", H, PH) + xi
        K = PH / innov_var[..., None]
        x = x + K * (r[..., i] - h)[..., None]
        P = P - K[..., :, None] * PH[..., None, :]
        out[..., i, :] = x
    return check_finite_output(out, "range_ekf states")
