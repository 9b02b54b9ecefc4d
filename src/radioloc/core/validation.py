"""Validation helpers used at the boundary of every public function.

They turn array arguments into float64 arrays of the expected shape and raise
:class:`~radioloc.core.errors.InputError` naming the argument (and the offending index)
instead of letting a NaN or a shape mismatch travel into the numerics.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from radioloc.core.errors import ConfigError, InputError


def _first_bad_index(mask: np.ndarray) -> tuple[int, ...]:
    return tuple(int(i) for i in np.argwhere(mask)[0])


def as_float_array(
    value: object,
    name: str,
    *,
    ndim: int | None = None,
    min_ndim: int | None = None,
    last_dim: int | Sequence[int] | None = None,
    allow_nan: bool = False,
    nonnegative: bool = False,
) -> np.ndarray:
    """Convert ``value`` to a float64 array and check it.

    Parameters
    ----------
    value : array_like
        The argument as the user passed it.
    name : str
        Argument name used in error messages.
    ndim, min_ndim : int, optional
        Exact or minimum number of dimensions.
    last_dim : int or sequence of int, optional
        Allowed size(s) of the last axis (2 or 3 for positions).
    allow_nan : bool
        Whether NaN entries are allowed (e.g. a mask of missing measurements).
    nonnegative : bool
        Whether every finite entry must be >= 0 (ranges, variances).

    Raises
    ------
    InputError
        Naming ``name`` and, for bad entries, the first offending index.
    """
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: expected numbers, got {type(value).__name__} ({exc})") from None
    if ndim is not None and arr.ndim != ndim:
        raise InputError(f"{name}: expected {ndim} dimensions, got shape {arr.shape}")
    if min_ndim is not None and arr.ndim < min_ndim:
        raise InputError(f"{name}: expected at least {min_ndim} dimensions, got shape {arr.shape}")
    if last_dim is not None:
        allowed = (last_dim,) if isinstance(last_dim, int) else tuple(last_dim)
        if arr.ndim == 0 or arr.shape[-1] not in allowed:
            raise InputError(
                f"{name}: last axis must have size {' or '.join(map(str, allowed))}, "
                f"got shape {arr.shape}"
            )
    if arr.size == 0:
        raise InputError(f"{name}: is empty")
    if not allow_nan and not np.all(np.isfinite(arr)):
        idx = _first_bad_index(~np.isfinite(arr))
        raise InputError(f"{name}: non-finite value {arr[idx]} at index {idx}")
    if nonnegative and np.any(arr < 0):
        idx = _first_bad_index(arr < 0)
        raise InputError(f"{name}: negative value {arr[idx]} at index {idx}")
    return arr


def as_positions(value: object, name: str, *, dims: Sequence[int] = (2, 3)) -> np.ndarray:
    """Positions ``(..., 2)`` or ``(..., 3)`` as a finite float64 array."""
    return as_float_array(value, name, min_ndim=1, last_dim=tuple(dims))


def check_positive(value: float, name: str, *, allow_zero: bool = False) -> float:
    """A scalar parameter that must be positive (or non-negative)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}: expected a number, got {value!r}") from None
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ConfigError(f"{name}: must be finite and {bound}, got {value!r}")
    return v


def check_probability(value: float, name: str) -> float:
    """A scalar in [0, 1]."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}: expected a number, got {value!r}") from None
    if not (0.0 <= v <= 1.0):
        raise ConfigError(f"{name}: must lie in [0, 1], got {value!r}")
    return v


def check_finite_output(arr: np.ndarray, name: str) -> np.ndarray:
    """Guard an estimator's output: raise instead of returning a silent NaN."""
    if not np.all(np.isfinite(arr)):
        idx = _first_bad_index(~np.isfinite(arr))
        raise InputError(
            f"{name}: the estimate became non-finite at index {idx}; "
            "check the inputs for degenerate geometry or zero noise variances"
        )
    return arr
