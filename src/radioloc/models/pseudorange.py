"""Pseudorange: a range measured with the receiver's unsynchronised clock.

A receiver timestamps the arrival of a signal sent at a known time from a known point ``s``
(a satellite, a synchronised anchor) with its own clock, which is ahead by ``clock_offset``
metres (offset times the speed of light); every row of an epoch carries the same offset:

    h(x) = |x - s| + clock_offset [+ clock_bias_g] [+ (omega_E / c) (s_x x_y - s_y x_x)]

- **A clock per group.** Rows of one group (a constellation: GPS, GLONASS) share a clock;
  group ``g > 0`` is ahead of group 0 by its inter-system bias ``clock_bias[g - 1]`` (the
  ``clock_bias`` state component, metres), the row's group in ``Context.group``.
- **Earth rotation.** With ``earth_rotation`` the satellite positions are those of the
  emission time in the Earth-fixed frame of the emission; during the signal's flight the
  Earth turns by ``omega_E |x - s| / c``, which lengthens the range by the Sagnac term
  ``(omega_E / c) (s_x x_y - s_y x_x)`` in Earth-centred, Earth-fixed (ECEF) coordinates
  (IS-GPS-200, 20.3.3.4.3.3.2; Kaplan and Hegarty, *Understanding GPS/GNSS*, 3rd ed.).
  A state in another frame gives its affine map to ECEF (``to_ecef``).

The model reads the ``clock_offset`` state component (and ``clock_bias`` with groups); a
filter evolves the offset (and its drift) with :class:`~radioloc.models.clock.ClockModel`.
A snapshot fit needs one more row than position coordinates, and one more per group.

Per-row weights (``Context.std``) come from the receiver's variance, or from a model of the
elevation (:func:`elevation_std_m`) or of the carrier-to-noise density (:func:`cn0_std_m`).

**LOS/NLOS.** A signal that reaches the receiver only by a reflection arrives late: its
error is the row's Gaussian noise plus a positive excess. With ``nlos_mean_m`` the model
has two modes per row (:meth:`PseudorangeModel.mode_logpdf`, the max-mixture of the batch
smoother): LOS ``N(0, std^2)`` with prior ``los_fraction``, and NLOS, an exponential excess
of mean ``nlos_mean_m`` plus the same Gaussian (paper 001's range model,
:class:`~radioloc.models.los_nlos.LosNlosRange`, with each row's own ``std`` as its LOS
spread).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from radioloc.core.constants import EARTH_ROTATION_RAD_PER_S, SPEED_OF_LIGHT_M_PER_S
from radioloc.core.errors import InputError
from radioloc.core.gnss import cn0_std_m, elevation_std_m
from radioloc.core.kinds import Kind, unit_slips
from radioloc.core.plausibility import check_pseudoranges
from radioloc.core.validation import check_positive, check_probability
from radioloc.models.los_nlos import LosNlosRange, emg_logpdf, gaussian_logpdf
from radioloc.models.measurement import Context, MeasurementModel
from radioloc.models.ranging import range_geometry

__all__ = ["PseudorangeModel", "EARTH_ROTATION_RAD_S", "SPEED_OF_LIGHT_M_S",
           "elevation_std_m", "cn0_std_m", "fit_nlos"]

#: WGS84 Earth rotation rate (rad/s) and the speed of light (m/s), as GPS defines them.
EARTH_ROTATION_RAD_S = EARTH_ROTATION_RAD_PER_S
SPEED_OF_LIGHT_M_S = SPEED_OF_LIGHT_M_PER_S


def fit_nlos(residual, std, los_fraction: float = 0.5, nlos_mean_m: float = 20.0,
             iterations: int = 100, tol: float = 1e-6) -> tuple[float, float]:
    """The LOS fraction and mean NLOS excess of pseudorange residuals, by EM.

    Each residual ``e_i`` is LOS, ``N(0, s_i^2)``, with probability ``alpha``, or NLOS,
    ``Exp(mean mu) + N(0, s_i^2)`` (the modes of :meth:`PseudorangeModel.mode_logpdf`), with
    its own known ``s_i``. E-step: the NLOS responsibility ``w_i``; M-step: ``alpha = 1 -
    mean(w)`` and ``mu = sum w_i E[X_i | e_i] / sum w_i``, where the excess ``X_i`` given an
    NLOS ``e_i`` is ``N(m_i, s_i^2)`` truncated to ``X > 0`` with ``m_i = e_i - s_i^2 / mu``,
    so ``E[X_i | e_i] = m_i + s_i phi(m_i / s_i) / Phi(m_i / s_i)``.

    Parameters
    ----------
    residual, std : array_like
        Residuals ``z - h(x)`` of a fit (NaN: left out) and their standard deviations, m.
    los_fraction, nlos_mean_m : float
        The start.
    iterations : int
    tol : float
        Stop when ``mu`` changes by less than ``tol`` times itself.

    Returns
    -------
    los_fraction, nlos_mean_m : float
        ``alpha`` within ``[0.01, 0.99]``; ``mu`` at least the smallest ``s_i`` (the NLOS
        mode stays distinct from the LOS one).

    Raises
    ------
    InputError
        Fewer than 10 finite residuals.
    """
    from scipy.special import log_ndtr

    e = np.asarray(residual, dtype=float)
    s = np.broadcast_to(np.asarray(std, dtype=float), e.shape)
    ok = np.isfinite(e) & np.isfinite(s)
    e, s = e[ok], s[ok]
    if e.size < 10:
        raise InputError(f"residual: {e.size} finite residuals, at least 10 are needed to fit "
                         "the LOS/NLOS mixture")
    alpha, mu = float(los_fraction), float(nlos_mean_m)
    for _ in range(int(iterations)):
        lp_nlos = np.log1p(-alpha) + emg_logpdf(e, s, mu)
        lp_los = np.log(alpha) + gaussian_logpdf(e, s)
        w = np.exp(lp_nlos - np.logaddexp(lp_nlos, lp_los))
        m = e - s * s / mu
        excess = m + s * np.exp(-0.5 * (m / s) ** 2 - 0.5 * np.log(2 * np.pi)
                                - log_ndtr(m / s))
        alpha = float(np.clip(1.0 - w.mean(), 0.01, 0.99))
        new = max(float(np.sum(w * excess) / max(np.sum(w), 1e-12)), float(s.min()))
        done = abs(new - mu) < tol * mu
        mu = new
        if done:
            break
    return alpha, mu


@dataclass(frozen=True)
class PseudorangeModel(MeasurementModel):
    """Range to a known point plus the receiver's clock offset, metres.

    Parameters
    ----------
    std_m : float
        Standard deviation of a pseudorange error, metres (> 0).
    groups : int
        Receiver clocks (one per constellation): rows of group ``g > 0`` add the state's
        ``clock_bias[g - 1]`` (their group in ``Context.group``; none: group 0).
    earth_rotation : bool
        Add the Sagnac term (module docstring); needs 3-D positions.
    to_ecef : tuple (rotation (3, 3), origin (3,)), optional
        ECEF coordinates of a point ``p`` of the state's frame: ``rotation @ p + origin``
        (None: the state is in ECEF).
    nlos_mean_m : float, optional
        Mean NLOS excess delay, metres: the rows get a LOS and an NLOS mode (module
        docstring). None: Gaussian rows.
    los_fraction : float
        Prior probability of the LOS mode (with ``nlos_mean_m``).

    Examples
    --------
    >>> import numpy as np
    >>> model = PseudorangeModel(std_m=1.0)
    >>> ctx = Context(points=np.array([[0.0, 0.0], [10.0, 0.0]]))
    >>> model.predict({"position": np.array([3.0, 4.0]), "clock_offset": np.array(2.0)},
    ...               ctx).round(3).tolist()
    [7.0, 10.062]
    """

    std_m: float
    groups: int = 1
    earth_rotation: bool = False
    to_ecef: tuple | None = None
    nlos_mean_m: float | None = None
    los_fraction: float = 0.5

    kind: ClassVar[str] = "pseudorange"

    def __post_init__(self) -> None:
        check_positive(self.std_m, "std_m")
        if self.nlos_mean_m is not None:
            check_positive(self.nlos_mean_m, "nlos_mean_m")
            check_probability(self.los_fraction, "los_fraction")
        if int(self.groups) != self.groups or self.groups < 1:
            raise InputError(f"groups: must be a whole number >= 1, got {self.groups!r}")
        if self.to_ecef is not None:
            rot, org = (np.asarray(v, dtype=float) for v in self.to_ecef)
            if rot.shape != (3, 3) or org.shape != (3,) or not (
                    np.isfinite(rot).all() and np.isfinite(org).all()):
                raise InputError("to_ecef: expected (rotation (3, 3), origin (3,)), finite")
            object.__setattr__(self, "to_ecef", (tuple(map(tuple, rot)), tuple(org)))

    @property
    def reads(self) -> tuple[str, ...]:  # type: ignore[override]
        return ("position", "clock_offset") + (("clock_bias",) if self.groups > 1 else ())

    @property
    def clock_groups(self) -> int:
        """Receiver clocks the state holds for this model (``StateLayout.with_model``)."""
        return int(self.groups)

    def _group(self, context: Context) -> np.ndarray:
        g = np.zeros(context.rows, dtype=int) if context.group is None else context.group
        if g.size and (g.min() < 0 or g.max() >= self.groups):
            raise InputError(f"context.group: groups must be in 0..{self.groups - 1} for a model "
                             f"of {self.groups} clock(s), got {int(g.min())}..{int(g.max())}")
        return g

    def _sagnac(self, position: np.ndarray, context: Context
                ) -> tuple[np.ndarray, np.ndarray]:
        """The Sagnac term ``(..., m)`` and its gradient over the position ``(..., m, D)``."""
        x = np.asarray(position, dtype=float)
        pts = context.points
        if x.shape[-1] != 3 or pts.shape[-1] != 3:
            raise InputError("earth_rotation: needs 3-D positions and points (ECEF or a local "
                             "frame with to_ecef)")
        rot, org = (np.eye(3), np.zeros(3)) if self.to_ecef is None else (
            np.asarray(v, dtype=float) for v in self.to_ecef)
        r = x @ rot.T + org                                   # receiver, ECEF
        s = pts @ rot.T + org                                 # satellites, ECEF
        k = EARTH_ROTATION_RAD_S / SPEED_OF_LIGHT_M_S
        term = k * (s[..., 0] * r[..., None, 1] - s[..., 1] * r[..., None, 0])
        grad_ecef = k * np.stack([-s[..., 1], s[..., 0], np.zeros_like(s[..., 0])], axis=-1)
        return term, grad_ecef @ rot

    def predict(self, state, context: Context) -> np.ndarray:
        return self.predict_with_jacobian(state, context)[0]

    def jacobian(self, state, context: Context) -> dict[str, np.ndarray]:
        return self.predict_with_jacobian(state, context)[1]

    def predict_with_jacobian(self, state, context: Context):
        d, u = range_geometry(state["position"], context.points, context.height_m)
        z = d + np.asarray(state["clock_offset"], dtype=float)[..., None]
        out = {"position": u, "clock_offset": np.ones(u.shape[:-1] + (1,))}
        if self.groups > 1:
            g = self._group(context)
            bias = np.asarray(state["clock_bias"], dtype=float)
            full = np.concatenate([np.zeros(bias.shape[:-1] + (1,)), bias], axis=-1)
            z = z + np.take(full, g, axis=-1)
            onehot = (g[:, None] == np.arange(1, self.groups)[None, :]).astype(float)
            out["clock_bias"] = np.broadcast_to(onehot, u.shape[:-1] + (self.groups - 1,))
        if self.earth_rotation:
            if context.height_m is not None:
                raise InputError("earth_rotation: needs 3-D positions (no height_m)")
            term, grad = self._sagnac(state["position"], context)
            z = z + term
            out["position"] = u + grad
        return z, out

    def std(self, context: Context) -> np.ndarray:
        return self.row_std(self.std_m, context)

    @property
    def noise(self) -> LosNlosRange | None:
        """The LOS/NLOS mixture of the rows (its ``los_std_m``, ``std_m``, stands for the
        rows' own std), or None."""
        if self.nlos_mean_m is None:
            return None
        return LosNlosRange(self.std_m, self.nlos_mean_m, self.los_fraction)

    def mode_logpdf(self, z, state, context: Context) -> np.ndarray:
        """Per-row log-density under NLOS (index 0) and LOS (index 1), ``(..., m, 2)``.

        Parameters
        ----------
        z : ndarray, shape (..., m)
            Measured pseudoranges (NaN: missing; 0 returned).
        state : dict
        context : Context

        Returns
        -------
        ndarray, shape (..., m, 2)
        """
        if self.nlos_mean_m is None:
            return self.logpdf(z, state, context)[..., None]
        e = np.asarray(z, dtype=float) - self.predict(state, context)
        s = np.broadcast_to(self.std(context), e.shape)
        lp = np.stack([emg_logpdf(e, s, self.nlos_mean_m), gaussian_logpdf(e, s)], axis=-1)
        return np.where(np.isnan(lp), 0.0, lp)


#: The log-schema kind this module explains (:mod:`radioloc.core.kinds`).
KINDS = (Kind("pseudorange", "m", "range to `peer` plus the receiver's clock offset (times c)",
              model=lambda sigma: PseudorangeModel(std_m=sigma),
              sigma_option="pseudorange_std_m", sigma_default=5.0,
              sigma_help="pseudorange error standard deviation, m", limit=1e8,
              check="pseudorange_units",
              check_values=lambda z, points, reference, **kw: check_pseudoranges(z, points, **kw),
              slips=tuple(unit_slips("pseudorange", "m", ns=True, what="pseudoranges")[i] for i in (1, 2, 0))),)
