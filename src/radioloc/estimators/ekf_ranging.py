"""Gaussian-noise EKF baseline for peer-to-peer ranging (the approach paper 001 argues against).

Each vehicle keeps a 2-D position and covariance; prediction adds the INS reading and
``s_INS^2 I``; the update uses every range in reach at once, treating the range error as
Gaussian with the mixture's mean ``(1 - alpha) s_NLOS`` and variance
``s_LOS^2 + (1 - alpha^2) s_NLOS^2`` (moment-matched), and neighbours at their previous EKF
estimates (the same messages as the particle filter). Batched over ``(runs, vehicles)``.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.validation import as_float_array
from radioloc.estimators.p2p_particle import compact_links
from radioloc.models.los_nlos import LosNlosRange


def moment_matched(model: LosNlosRange) -> tuple[float, float]:
    """Mean and variance of the mixture range error."""
    a, mu, s = model.alpha, model.nlos_mean_m, model.los_std_m
    return (1 - a) * mu, s * s + (1 - a * a) * mu * mu


def ekf_track(initial: np.ndarray, ins: np.ndarray, ranges: np.ndarray, in_range: np.ndarray,
              anchors: np.ndarray, model: LosNlosRange, ins_std_m: float,
              init_std_m: float) -> np.ndarray:
    """Estimates ``(..., T, N, 2)``; arguments as :func:`radioloc.estimators.p2p_particle.track`."""
    x = as_float_array(initial, "initial", min_ndim=2, last_dim=2).copy()
    u = as_float_array(ins, "ins", min_ndim=3, last_dim=2)
    a = as_float_array(anchors, "anchors", ndim=2, last_dim=2)
    batch = x.shape[:-1]
    eye = np.eye(2)
    p = np.broadcast_to(init_std_m**2 * eye, batch + (2, 2)).copy()
    bias, var = moment_matched(model)
    anchors_b = np.broadcast_to(a, x.shape[:-2] + a.shape)
    out = []
    for t in range(u.shape[-3]):
        msgs = x.copy()
        x = x + u[..., t, :, :]
        p = p + ins_std_m**2 * eye
        mask = in_range[..., t, :, :]
        links, valid = compact_links(mask)
        nodes = np.concatenate([msgs, anchors_b], axis=-2)
        nodes = np.broadcast_to(nodes[..., None, :, :], mask.shape + (2,))
        c = np.take_along_axis(nodes, links[..., None], axis=-2)               # (..., N, L, 2)
        th = np.take_along_axis(np.where(mask, ranges[..., t, :, :], 0.0), links, axis=-1)
        diff = x[..., None, :] - c
        d = np.maximum(np.linalg.norm(diff, axis=-1), 1e-6)
        h = diff / d[..., None]                                                 # (..., N, L, 2)
        w = valid / var
        info = np.linalg.inv(p) + np.einsum("...li,...l,...lj->...ij", h, w, h)
        p = np.linalg.inv(info)
        innov = np.where(valid, th - bias - d, 0.0)
        x = x + np.einsum("...ij,...lj,...l->...i", p, h, w * innov)
        out.append(x)
    return np.stack(out, axis=-3)
