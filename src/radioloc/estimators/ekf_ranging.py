"""Gaussian-noise EKF baseline for peer-to-peer ranging (the approach paper 001 argues against).

Every vehicle runs the toolkit's one range EKF,
:class:`radioloc.estimators.ekf_tracker.RangeEKF`, typically with
``motion=InputDriven(s_INS)`` (prediction: add the INS reading and ``s_INS^2 I``) and
``measurement=LosNlosRange(...)``, whose range error the EKF uses through its first two
moments (``LosNlosRange.moments()``: mean ``(1 - alpha) s_NLOS``, variance
``s_LOS^2 + (1 - alpha^2) s_NLOS^2``). The points ranged to at each step are the
neighbours' previous EKF estimates (the same messages as the particle filter) and the
anchors; the links present are packed with :func:`radioloc.core.links.pack_mask` and passed
to ``RangeEKF.update`` as that step's anchors. Batched over ``(runs, vehicles)``.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.links import gather_packed, pack_mask
from radioloc.core.results import Track, track_from_steps
from radioloc.core.validation import as_float_array, check_positive, check_ranges, range_noise_std
from radioloc.estimators.ekf_tracker import RangeEKF

__all__ = ["run_peer_ekf"]


def run_peer_ekf(ekf: RangeEKF, ranges, initial, *, init_std_m: float, anchors=None,
                 controls=None, time=None) -> Track:
    """Track every vehicle with ``ekf``, neighbours placed at their previous estimates.

    Parameters
    ----------
    ekf : RangeEKF
        The filter (its motion and measurement models); its own anchors are not used.
    ranges : array_like, shape (..., N, T, J)
        Ranges from vehicle ``k`` at step ``t`` to node ``j``, ``J = N + M`` (the N
        vehicles first, a vehicle's range to itself NaN, then the M anchors); NaN = no
        link (skipped). A slightly negative range (noise on two nodes a few cm apart;
        :func:`~radioloc.core.validation.check_ranges`) is used as 0.
    initial : array_like, shape (..., N, n)
        Prior mean (position first; n = ``ekf.motion.state_dim``).
    init_std_m : float
        Prior standard deviation of every state component (prior covariance
        ``init_std_m^2 I``).
    anchors : array_like, shape (M, 2) or (..., M, 2), optional
        Known anchor positions.
    controls : array_like, shape (..., N, T, 2), optional
        Displacement readings (INS) for an input-driven motion model.
    time : array_like, shape (T,), optional
        Step times in seconds; the prior is at ``time[0]`` (default ``0..T-1``).

    Returns
    -------
    Track
        ``position`` (..., N, T, 2), ``covariance`` (..., N, T, 2, 2); per-step diagnostics
        ``state``, ``state_covariance``, ``nis`` and ``measurements_used``.
    """
    if not isinstance(ekf, RangeEKF):
        raise InputError(f"ekf: expected a RangeEKF, got {type(ekf).__name__}")
    check_positive(init_std_m, "init_std_m")
    r = as_float_array(ranges, "ranges", min_ndim=3, allow_nan=True)
    if np.any(np.isinf(r)):
        raise InputError("ranges: infinite value (NaN marks an absent link)")
    check_ranges(r, "ranges", range_noise_std(ekf.measurement), bias_m=ekf.range_bias_m,
                 bias_name="range_bias_m")
    n_veh, T, J = r.shape[-3:]
    a = np.zeros((0, 2)) if anchors is None else as_float_array(anchors, "anchors", min_ndim=2,
                                                                  last_dim=2)
    if J != n_veh + a.shape[-2]:
        raise InputError(f"ranges: {J} nodes per row, expected N + M = {n_veh} + {a.shape[-2]}")
    t = np.arange(T, dtype=float) if time is None else as_float_array(time, "time", ndim=1)
    if t.shape != (T,):
        raise InputError(f"time: expected {T} steps, got shape {t.shape}")
    dts = np.diff(t, prepend=t[0])
    u = None if controls is None else as_float_array(controls, "controls", min_ndim=3, last_dim=2)
    n = ekf.motion.state_dim
    state = ekf.init(initial, init_std_m**2 * np.eye(n), t[0])
    batch = state.mean.shape[:-2]
    if state.mean.shape[-2] != n_veh:
        raise InputError(f"initial: {state.mean.shape[-2]} vehicles, ranges have {n_veh}")
    anchors_b = np.broadcast_to(a, batch + a.shape[-2:])
    D = ekf.motion.dim
    estimates, nis, used = [], [], []
    for k in range(T):
        msgs = state.mean[..., :D]                                       # previous estimates
        state = ekf.predict(state, dts[k], None if u is None else u[..., k, :])
        rk = r[..., k, :]
        index, valid = pack_mask(np.isfinite(rk))                         # (..., N, L)
        if index.shape[-1]:
            nodes = np.concatenate([msgs, anchors_b], axis=-2)            # (..., J, 2)
            nodes = np.broadcast_to(nodes[..., None, :, :], rk.shape + (2,))
            points = gather_packed(nodes, index, axis=-2)
            # RangeEKF takes ranges >= 0: a simulated range pushed below zero by the noise
            # (two vehicles within a few cm) is read as 0, as a receiver would report it
            rows = np.where(valid, np.maximum(gather_packed(rk, index), 0.0), np.nan)
            state, info = ekf.update(state, rows, anchors=points)
            nis.append(info["nis"])
            used.append(info["measurements_used"])
        else:
            nis.append(np.zeros(state.mean.shape[:-1]))
            used.append(np.zeros(state.mean.shape[:-1], dtype=np.int64))
        estimates.append(ekf.estimate(state))
    track = track_from_steps(estimates, t)
    nb = len(track.batch_shape)
    diag = dict(track.diagnostics)
    diag["nis"] = np.stack(nis, axis=nb)
    diag["measurements_used"] = np.stack(used, axis=nb)
    return Track(track.position, track.covariance, track.time, diag)
