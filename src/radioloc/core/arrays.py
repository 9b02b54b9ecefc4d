"""Arrays handed to compiled kernels.

numba compiles one machine-code specialisation per argument type, and an array's type
includes its layout and its read-only flag: a read-only view (``np.broadcast_to``, a
``pandas`` column, a memory-mapped file) or a strided slice given where the kernel usually
sees a fresh C array costs a second compile of the whole kernel (tens of seconds for the
larger ones) and a second cache entry. The call sites of the larger kernels (the network
EKF's packets, the P2P link kernel, the BLUE, the mixture product and reduction) pass their
arrays through :func:`kernel_array`, so each of them has one specialisation per dtype.
"""

from __future__ import annotations

import numpy as np


def kernel_array(x, dtype=np.float64) -> np.ndarray:
    """``x`` as a C-contiguous, writeable array of ``dtype`` (a copy only when it is not).

    Parameters
    ----------
    x : array_like
        The values.
    dtype : numpy dtype, optional
        The kernel's element type (float64 unless given).

    Returns
    -------
    numpy.ndarray
        ``x`` itself when it already is C-contiguous, writeable and of ``dtype``; else a
        copy that is.
    """
    if (type(x) is np.ndarray and x.dtype == dtype and x.flags.c_contiguous
            and x.flags.writeable):
        return x  # the no-copy case decided by the flags: np.require takes microseconds
    return np.require(x, dtype, ("C", "W"))
