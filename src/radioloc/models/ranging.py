"""Range measurement models: ``sample(true_ranges, rng)`` and ``logpdf(measured, true_ranges)``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.validation import check_positive

_LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True)
class GaussianRange:
    """Range with additive zero-mean Gaussian error: ``r = d + N(0, std_m^2)``.

    Parameters
    ----------
    std_m : float
        Standard deviation of the range error in metres (> 0).
    """

    std_m: float

    def __post_init__(self) -> None:
        check_positive(self.std_m, "std_m")

    @property
    def variance(self) -> float:
        return self.std_m**2

    def sample(self, true_ranges: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy ranges of the same shape as ``true_ranges``."""
        d = np.asarray(true_ranges, dtype=float)
        return d + self.std_m * rng.standard_normal(d.shape)

    def logpdf(self, measured: np.ndarray, true_ranges: np.ndarray) -> np.ndarray:
        """Elementwise log-density of ``measured`` given ``true_ranges``."""
        z = (np.asarray(measured, dtype=float) - np.asarray(true_ranges, dtype=float)) / self.std_m
        return -0.5 * z**2 - np.log(self.std_m) - 0.5 * _LOG_2PI
