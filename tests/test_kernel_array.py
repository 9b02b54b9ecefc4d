"""core.arrays.kernel_array: what reaches a compiled kernel is C-contiguous, writeable and of
the kernel's dtype, copied only when it is not; read-only and strided inputs then compile
no second specialisation."""

import numpy as np
from numba import njit

from radioloc.core.arrays import kernel_array


@njit
def _total(x):
    s = 0.0
    for v in x.ravel():
        s += v
    return s


def test_a_fresh_c_array_of_the_dtype_is_passed_through_uncopied():
    x = np.arange(12.0).reshape(3, 4)
    assert kernel_array(x) is x
    i = np.arange(5)
    assert kernel_array(i, np.int64) is i


def test_read_only_strided_and_other_dtypes_are_copied_into_a_c_writeable_array():
    base = np.arange(24.0).reshape(4, 6)
    for x in (np.broadcast_to(base[0], (4, 6)), base[:, ::2], base.T,
              np.arange(24, dtype=np.int32).reshape(4, 6)):
        y = kernel_array(x)
        assert y.flags.c_contiguous and y.flags.writeable and y.dtype == np.float64
        np.testing.assert_array_equal(y, x)
        assert not np.shares_memory(y, base)


def test_one_compiled_specialisation_whatever_the_flags_of_the_input():
    base = np.arange(24.0).reshape(4, 6)
    ro = base.copy()
    ro.flags.writeable = False
    inputs = [base, ro, np.broadcast_to(base[0], (4, 6)), base[:, ::2], base.T]
    sums = [_total(kernel_array(x)) for x in inputs]
    assert len(_total.signatures) == 1
    assert sums == [float(np.sum(x)) for x in inputs]
