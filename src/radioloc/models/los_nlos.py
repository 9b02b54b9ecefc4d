"""LOS/NLOS range model of paper 001 and the sticky Markov chain over the link state.

A range between nodes at distance ``d`` is

* LOS (``z = 1``): ``theta = d + n``,            ``n ~ N(0, s_LOS^2)``;
* NLOS (``z = 0``): ``theta = d + eps + n``,     ``eps ~ Exp(mean s_NLOS)``;

(Sect. V of the paper). The NLOS error ``eps + n`` is an exponentially modified Gaussian
whose log-density is evaluated through ``scipy.special.log_ndtr`` so that it stays finite
far in both tails. The LOS fraction is ``alpha``; the link state follows a two-state
Markov chain with ``p(z_t = 1 | z_{t-1} = 0) = alpha / 2`` and stationary distribution
``(alpha, 1 - alpha)`` over (LOS, NLOS). A Kalman filter uses the mixture through its
first two moments (:meth:`LosNlosRange.moments`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.validation import (
    LENGTH_LIMIT_M,
    check_positive,
    check_probability,
    paired_arrays,
)

_LOG_2PI = float(np.log(2.0 * np.pi))


def gaussian_logpdf(x: np.ndarray, std: float) -> np.ndarray:
    """Log-density of ``N(0, std^2)`` at ``x``.

    Parameters
    ----------
    x : array_like
        Points (range errors), metres.
    std : float
        Standard deviation, metres.

    Returns
    -------
    ndarray
        ``log N(x; 0, std^2)``, same shape as ``x``.
    """
    z = np.asarray(x, dtype=float) / std
    return -0.5 * z * z - np.log(std) - 0.5 * _LOG_2PI


def emg_logpdf(x: np.ndarray, std: float, mean_exp: float) -> np.ndarray:
    """Log-density of ``Exp(mean mean_exp) + N(0, std^2)`` at ``x`` (stable in both tails).

    ``log f(x) = log lam + lam^2 std^2 / 2 - lam x + log Phi((x - lam std^2) / std)`` with
    ``lam = 1 / mean_exp``; ``log Phi`` is ``log_ndtr``, exact for large negative arguments.

    Parameters
    ----------
    x : array_like
        Points (range errors), metres.
    std : float
        Standard deviation of the Gaussian part, metres.
    mean_exp : float
        Mean of the exponential part, metres.

    Returns
    -------
    ndarray
        The log-density, same shape as ``x``.
    """
    from scipy.special import log_ndtr               # here: scipy costs start-up time

    lam = 1.0 / mean_exp
    x = np.asarray(x, dtype=float)
    return (np.log(lam) + 0.5 * (lam * std) ** 2 - lam * x
            + log_ndtr((x - lam * std * std) / std))


@dataclass(frozen=True)
class LosNlosRange:
    """Mixture range model of paper 001 (Sect. II, V).

    Parameters
    ----------
    los_std_m : float
        ``s_LOS``: standard deviation of the Gaussian error present on every link.
    nlos_mean_m : float
        ``s_NLOS``: mean of the exponential excess delay of NLOS links.
    alpha : float
        LOS fraction, in [0, 1].
    """

    los_std_m: float = 0.05
    nlos_mean_m: float = 5.0
    alpha: float = 0.3

    def __post_init__(self) -> None:
        check_positive(self.los_std_m, "los_std_m", maximum=LENGTH_LIMIT_M)
        check_positive(self.nlos_mean_m, "nlos_mean_m", maximum=LENGTH_LIMIT_M)
        check_probability(self.alpha, "alpha")

    @property
    def chain(self) -> "StickyLinkChain":
        """The sticky link-state chain of this model's LOS fraction.

        Returns
        -------
        StickyLinkChain
            ``StickyLinkChain(alpha)``.
        """
        return StickyLinkChain(self.alpha)

    def moments(self) -> tuple[float, float]:
        """Mean and variance of the mixture range error (what a Kalman filter uses).

        Returns
        -------
        mean_m : float
            ``(1 - alpha) s_NLOS``.
        variance_m2 : float
            ``s_LOS^2 + (1 - alpha^2) s_NLOS^2``.
        """
        a, mu, s = self.alpha, self.nlos_mean_m, self.los_std_m
        return (1 - a) * mu, s * s + (1 - a * a) * mu * mu

    def logpdf_by_state(self, measured: np.ndarray, true_ranges: np.ndarray) -> np.ndarray:
        """``log p(theta | d, z)`` for ``z = 0`` (NLOS) and ``z = 1`` (LOS).

        Parameters
        ----------
        measured : array_like
            Measured ranges ``theta``, metres.
        true_ranges : array_like
            Distances ``d`` (broadcast against ``measured``).

        Returns
        -------
        ndarray, shape (..., 2)
            Log-densities under NLOS (index 0) and LOS (index 1).
        """
        m, d = paired_arrays("measured", measured, "true_ranges", true_ranges)
        e = m - d
        return np.stack([emg_logpdf(e, self.los_std_m, self.nlos_mean_m),
                         gaussian_logpdf(e, self.los_std_m)], axis=-1)

    def logpdf(self, measured: np.ndarray, true_ranges: np.ndarray) -> np.ndarray:
        """Mixture log-density ``log(alpha p_LOS + (1 - alpha) p_NLOS)``.

        The log-sum of :meth:`logpdf_by_state` weighted by ``(1 - alpha, alpha)``.

        Parameters
        ----------
        measured : array_like
            Measured ranges, metres.
        true_ranges : array_like
            Distances (broadcast against ``measured``).

        Returns
        -------
        ndarray
            The log-density, broadcast shape.
        """
        with np.errstate(divide="ignore"):
            logw = np.log([1.0 - self.alpha, self.alpha])
        lp = self.logpdf_by_state(measured, true_ranges) + logw
        return np.logaddexp(lp[..., 0], lp[..., 1])

    def mixture_constants(self) -> tuple[float, float, float, float, float, float]:
        """Constants of the compiled mixture log-density of
        :mod:`radioloc.estimators.pf_compiled` (``mixture_logpdf_scalar``).

        Returns
        -------
        tuple of float
            ``(1 / s, lam, lam s, c_los, c_nlos, k_tail)`` with ``lam = 1 / s_NLOS``,
            ``c_los = log alpha - log s - log(2 pi) / 2``, ``c_nlos = log(1 - alpha) +
            log lam + (lam s)^2 / 2`` and ``k_tail = exp(c_nlos - c_los - (lam s)^2 / 2 -
            log(2 pi) / 2)`` (0 where it overflows, which selects the plain log-sum).
        """
        with np.errstate(divide="ignore"):
            logw = np.log([1.0 - self.alpha, self.alpha])
        s, lam = self.los_std_m, 1.0 / self.nlos_mean_m
        c_los = logw[1] - np.log(s) - 0.5 * _LOG_2PI
        c_nlos = logw[0] + np.log(lam) + 0.5 * (lam * s) ** 2
        with np.errstate(invalid="ignore", over="ignore"):
            k_tail = float(np.exp(c_nlos - c_los - 0.5 * (lam * s) ** 2 - 0.5 * _LOG_2PI))
        # k_tail = 0 (overflow, alpha tiny) selects the plain log-sum inside
        return (1.0 / s, lam, lam * s, float(c_los), float(c_nlos),
                k_tail if np.isfinite(k_tail) else 0.0)

    def sample(self, true_ranges: np.ndarray, los: np.ndarray,
               rng: np.random.Generator) -> np.ndarray:
        """Ranges for the given distances and link states.

        Parameters
        ----------
        true_ranges : array_like
            Distances, metres.
        los : array_like of bool
            Link states (True = LOS), same shape as ``true_ranges``.
        rng : numpy.random.Generator
            Source of the exponential excess and the Gaussian noise.

        Returns
        -------
        ndarray
            Measured ranges, same shape as ``true_ranges``.
        """
        d = np.asarray(true_ranges, dtype=float)
        los = np.asarray(los, dtype=bool)
        if los.shape != d.shape:
            raise InputError(f"los: shape {los.shape} differs from true_ranges {d.shape}")
        excess = rng.exponential(self.nlos_mean_m, d.shape)
        return d + np.where(los, 0.0, excess) + self.los_std_m * rng.standard_normal(d.shape)


def sticky_transition(alpha) -> np.ndarray:
    """Transition matrices of the sticky link chain, ``P[..., z_prev, z]``.

    ``p(z_t = 1 | z_{t-1} = 0) = alpha / 2`` and, from stationarity ``alpha p(0|1) = (1 -
    alpha) p(1|0)``, ``p(z_t = 0 | z_{t-1} = 1) = (1 - alpha) / 2`` (0 = NLOS, 1 = LOS).

    Parameters
    ----------
    alpha : float or array_like
        LOS fractions in [0, 1].

    Returns
    -------
    ndarray, shape (..., 2, 2)
    """
    a = np.asarray(alpha, dtype=float)
    return np.stack([np.stack([1.0 - a / 2.0, a / 2.0], axis=-1),
                     np.stack([(1.0 - a) / 2.0, (1.0 + a) / 2.0], axis=-1)], axis=-2)


@dataclass(frozen=True)
class StickyLinkChain:
    """Two-state Markov chain over ``z`` (0 = NLOS, 1 = LOS) with ``p(1|0) = alpha/2``.

    ``p(0|1)`` follows from stationarity ``alpha p(0|1) = (1 - alpha) p(1|0)``, i.e.
    ``p(0|1) = (1 - alpha) / 2``.

    Parameters
    ----------
    alpha : float
        LOS fraction in [0, 1] (the stationary probability of ``z = 1``).
    """

    alpha: float

    def __post_init__(self) -> None:
        check_probability(self.alpha, "alpha")

    @property
    def transition(self) -> np.ndarray:
        """Transition matrix.

        Returns
        -------
        ndarray, shape (2, 2)
            ``P[z_prev, z]`` (0 = NLOS, 1 = LOS).
        """
        return sticky_transition(self.alpha)

    @property
    def stationary(self) -> np.ndarray:
        """Stationary distribution.

        Returns
        -------
        ndarray, shape (2,)
            ``(p(z=0), p(z=1)) = (1 - alpha, alpha)``.
        """
        return np.array([1.0 - self.alpha, self.alpha])

    @property
    def log_transition(self) -> np.ndarray:
        """Log of :attr:`transition`.

        Returns
        -------
        ndarray, shape (2, 2)
        """
        with np.errstate(divide="ignore"):
            return np.log(self.transition)

    @property
    def log_stationary(self) -> np.ndarray:
        """Log of :attr:`stationary`.

        Returns
        -------
        ndarray, shape (2,)
        """
        with np.errstate(divide="ignore"):
            return np.log(self.stationary)

    def sample(self, steps: int, shape: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
        """Boolean LOS paths started from the stationary distribution.

        Parameters
        ----------
        steps : int
            Number of time steps.
        shape : tuple of int
            Shape of the batch of independent links.
        rng : numpy.random.Generator
            Source of the uniforms.

        Returns
        -------
        ndarray of bool, shape (steps, *shape)
        """
        if steps < 1:
            raise InputError(f"steps: must be >= 1, got {steps}")
        u = rng.random((steps, *shape))
        z = np.empty((steps, *shape), dtype=bool)
        z[0] = u[0] < self.alpha
        p_los = self.transition[:, 1]
        for t in range(1, steps):
            z[t] = u[t] < p_los[z[t - 1].astype(int)]
        return z
