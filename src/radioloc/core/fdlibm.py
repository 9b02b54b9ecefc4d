"""The natural logarithm of fdlibm's ``e_log.c`` in pieces that compiled loops inline.

``log(x)`` for a positive normal ``x``: write ``x = 2^k (1 + f)`` with ``1 + f`` in
``[sqrt(2) / 2, sqrt(2)]`` (exponent and mantissa from the bits: :data:`TWO52_BITS`,
:data:`MANT`, :data:`ONE_I`), then ``s = f / (2 + f)``, ``R = log_poly(s)`` and
``log(x) = log_finish(k, f, s, R)`` (within 1 ulp). Branch-free and call-free, so a loop
over them vectorises; the reduction stays with each caller, which reads the bits from a
scalar (``estimators.pf_random``) or from an int64 view of its lane rows
(``models.mixture``).
"""

from __future__ import annotations

import math

from numba import njit

# ln 2 in two parts and the coefficients of the polynomial in s^2
LN2_HI = 6.93147180369123816490e-01
LN2_LO = 1.90821492927058770002e-10
LG1 = 6.666666666666735130e-01
LG2 = 3.999999999940941908e-01
LG3 = 2.857142874366239149e-01
LG4 = 2.222219843214978396e-01
LG5 = 1.818357216161805012e-01
LG6 = 1.531383769920937332e-01
LG7 = 1.479819860511658591e-01
SQRT2 = math.sqrt(2.0)
#: 2^52, and the bits of 2^52 as a float: ``(bits >> 52) | TWO52_BITS`` read as a float,
#: minus ``TWO52 + 1023``, is the unbiased exponent
TWO52 = 4503599627370496.0
TWO52_BITS = 0x4330000000000000
#: the mantissa bits, and the exponent bits of 1.0: ``(bits & MANT) | ONE_I`` is in [1, 2)
MANT = (1 << 52) - 1
ONE_I = 1023 << 52


@njit(cache=True, inline="always", error_model="numpy")
def log_poly(s):  # pragma: no cover - compiled
    """fdlibm's ``R(z)``, ``z = s^2``, in its two halves.

    Parameters
    ----------
    s : float
        ``f / (2 + f)``.

    Returns
    -------
    float
        ``R``, summed as ``t2 + t1`` (fdlibm's order).
    """
    z = s * s
    w = z * z
    t1 = w * (LG2 + w * (LG4 + w * LG6))
    t2 = z * (LG1 + w * (LG3 + w * (LG5 + w * LG7)))
    return t2 + t1


@njit(cache=True, inline="always", error_model="numpy")
def log_finish(k, f, s, r):  # pragma: no cover - compiled
    """``log(2^k (1 + f))`` from ``s = f / (2 + f)`` and ``r = log_poly(s)``.

    Parameters
    ----------
    k : float
        The exponent.
    f, s, r : float
        The reduced argument, ``f / (2 + f)`` and the polynomial.

    Returns
    -------
    float
        The logarithm.
    """
    hfsq = 0.5 * f * f
    return k * LN2_HI - ((hfsq - (s * (hfsq + r) + k * LN2_LO)) - f)
