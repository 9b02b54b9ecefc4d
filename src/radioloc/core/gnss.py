"""Signal-quality weights of GNSS pseudoranges: a standard deviation per row from the
satellite's elevation or the signal's carrier-to-noise density (the ``std`` column of a
log, which :class:`~radioloc.models.pseudorange.PseudorangeModel` reads)."""

from __future__ import annotations

import numpy as np

from radioloc.core.validation import check_positive

__all__ = ["elevation_std_m", "cn0_std_m"]


def elevation_std_m(elevation_deg, zenith_std_m: float = 3.0, floor_deg: float = 5.0
                    ) -> np.ndarray:
    """Standard deviation of a pseudorange from its satellite's elevation:
    ``zenith_std_m / sin(elevation)`` (elevation floored at ``floor_deg``).

    Parameters
    ----------
    elevation_deg : array_like
        Degrees above the horizon.
    zenith_std_m : float
        The standard deviation at the zenith, metres.
    floor_deg : float
        Elevations below are taken at this one (the weight of a satellite on the horizon
        stays finite).

    Returns
    -------
    ndarray
        Metres.
    """
    el = np.maximum(np.asarray(elevation_deg, dtype=float), check_positive(floor_deg, "floor_deg"))
    return check_positive(zenith_std_m, "zenith_std_m") / np.sin(np.radians(el))


def cn0_std_m(cn0_dbhz, std_at_ref_m: float = 5.0, ref_dbhz: float = 45.0) -> np.ndarray:
    """Standard deviation of a pseudorange from its carrier-to-noise density: the code
    tracking error scales with ``(C/N0)^(-1/2)``, so ``std_at_ref_m * 10^((ref - cn0) / 20)``.

    Parameters
    ----------
    cn0_dbhz : array_like
        dB-Hz.
    std_at_ref_m : float
        The standard deviation at ``ref_dbhz``, metres.
    ref_dbhz : float

    Returns
    -------
    ndarray
        Metres.
    """
    cn0 = np.asarray(cn0_dbhz, dtype=float)
    return check_positive(std_at_ref_m, "std_at_ref_m") * 10.0 ** ((ref_dbhz - cn0) / 20.0)
