"""Validation helpers used at the boundary of every public function.

They turn array arguments into float64 arrays of the expected shape and raise
:class:`~radioloc.core.errors.InputError` naming the argument (and the offending index)
instead of letting a NaN or a shape mismatch travel into the numerics.
"""

from __future__ import annotations

import math
import warnings
from typing import Callable, Sequence

import numpy as np

from radioloc.core.errors import ConfigError, InputError

#: Largest magnitude accepted in an array argument or a scalar setting (SI units: 1e30 m is
#: 1e14 light years). Squares and products of such values stay far from float64 overflow,
#: so an overflow inside an estimator is impossible by construction, not a RuntimeWarning.
MAGNITUDE_LIMIT = 1e30
#: Largest length setting (metres) that sizes a grid, a kernel or a search: 1e9 m is beyond
#: any terrestrial scene, and a cell or blur count derived from it stays an integer.
LENGTH_LIMIT_M = 1e9
#: Smallest magnitude accepted for a positive scalar setting (a standard deviation of
#: 1e-300 would overflow its inverse square).
POSITIVE_FLOOR = 1e-30
#: Bounds of integer settings: iteration counts, particles per node, mixture components.
#: Beyond them a call would run for hours or exhaust memory; the error names the limit.
MAX_ITERATIONS = 1_000_000
MAX_PARTICLES = 10_000_000
MAX_COMPONENTS = 100_000
#: Default bound on the memory one call may allocate; the environment variable
#: ``RADIOLOC_MEMORY_LIMIT_GB`` overrides it.
MEMORY_LIMIT_GB = 4.0


#: Array kinds refused at the boundary, by numpy dtype kind: their conversion to float would
#: drop an imaginary part, read True as 1, or hide text and None inside an object array.
REFUSED_KINDS = {"c": "complex", "b": "bool", "O": "object (mixed or non-numeric)",
                 "U": "text", "S": "bytes", "M": "datetime", "m": "timedelta",
                 "V": "structured"}


def check_dtype(value: object, name: str) -> np.ndarray:
    """``value`` as an array of real numbers (int, unsigned or float dtype), not converted.

    Parameters
    ----------
    value : array_like
        The argument as the user passed it.
    name : str
        Argument name used in error messages.

    Returns
    -------
    ndarray
        ``np.asarray(value)``.

    Raises
    ------
    InputError
        A complex, bool, object, text, datetime or structured array (or a nested sequence
        that is none of these, e.g. ragged), naming ``name`` and the dtype.
    """
    if isinstance(value, (bool, np.bool_)):
        raise InputError(f"{name}: expected real numbers, got a bool ({value!r})")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            arr = np.asarray(value)
    except (TypeError, ValueError, OverflowError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"{name}: expected an array of numbers, got {type(value).__name__} "
                         f"({first})") from None
    kind = REFUSED_KINDS.get(arr.dtype.kind)
    if kind is not None:
        raise InputError(f"{name}: expected real numbers, got {kind} values (dtype {arr.dtype})")
    return arr


def check_shapes(name_a: str, shape_a: tuple[int, ...], name_b: str,
                 shape_b: tuple[int, ...]) -> tuple[int, ...]:
    """The broadcast shape of two arguments, or an error naming both.

    Parameters
    ----------
    name_a, name_b : str
        Argument names.
    shape_a, shape_b : tuple of int
        Their shapes.

    Returns
    -------
    tuple of int

    Raises
    ------
    InputError
        The shapes do not broadcast.
    """
    try:
        return tuple(np.broadcast_shapes(tuple(shape_a), tuple(shape_b)))
    except ValueError:
        raise InputError(f"{name_a} (shape {tuple(shape_a)}) and {name_b} (shape "
                         f"{tuple(shape_b)}) do not broadcast together") from None


def paired_arrays(name_a: str, a: object, name_b: str, b: object
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Two arguments of a model's density as float arrays that broadcast together.

    Parameters
    ----------
    name_a, name_b : str
        Argument names, for the messages.
    a, b : array_like
        The arguments as the user passed them.

    Returns
    -------
    tuple of ndarray
        Both as float64 (not broadcast).

    Raises
    ------
    InputError
        A complex, bool, object or text argument, or shapes that do not broadcast, naming
        the argument(s).
    """
    x, y = check_dtype(a, name_a), check_dtype(b, name_b)
    check_shapes(name_a, x.shape, name_b, y.shape)
    return x.astype(float, copy=False), y.astype(float, copy=False)


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
    max_abs: float | None = MAGNITUDE_LIMIT,
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
    max_abs : float or None
        Largest magnitude accepted (default :data:`MAGNITUDE_LIMIT`); None: no bound.

    Returns
    -------
    ndarray
        The float64 array.

    Raises
    ------
    InputError
        Naming ``name`` and, for bad entries, the first offending index; a complex, bool,
        object or text array (:func:`check_dtype`).
    """
    value = check_dtype(value, name)
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{name}: expected numbers, got {type(value).__name__} "
                         f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})"
                         ) from None
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
    if max_abs is not None:
        with np.errstate(invalid="ignore"):
            big = np.isfinite(arr) & (np.abs(arr) > max_abs)
        if np.any(big):
            idx = _first_bad_index(big)
            raise InputError(f"{name}: magnitude {arr[idx]:g} at index {idx} is beyond the "
                             f"supported limit of {max_abs:g}")
    return arr


def as_positions(value: object, name: str, *, dims: Sequence[int] = (2, 3)) -> np.ndarray:
    """Positions ``(..., 2)`` or ``(..., 3)`` as a finite float64 array."""
    return as_float_array(value, name, min_ndim=1, last_dim=tuple(dims))


def _scalar(value: object, name: str) -> float:
    if isinstance(value, (bool, np.bool_, str, bytes, complex, np.complexfloating)) \
            or value is None:
        raise ConfigError(f"{name}: expected a real number, got {value!r}")
    if isinstance(value, np.ndarray) and value.dtype.kind not in "iuf":
        raise ConfigError(f"{name}: expected a real number, got an array of dtype {value.dtype}")
    try:
        return float(value)
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(f"{name}: expected a number, got {value!r}") from None


def check_positive(value: float, name: str, *, allow_zero: bool = False,
                   maximum: float = MAGNITUDE_LIMIT) -> float:
    """A scalar parameter that must be positive (or non-negative).

    Parameters
    ----------
    value : float
        The setting.
    name : str
        Its name, for the message.
    allow_zero : bool
        Accept 0.
    maximum : float
        Largest value accepted (default :data:`MAGNITUDE_LIMIT`; :data:`LENGTH_LIMIT_M` for
        a length that sizes a grid or a kernel).

    Returns
    -------
    float
        The value; a non-zero value lies in ``[POSITIVE_FLOOR, maximum]``.

    Raises
    ------
    ConfigError
        Not a number (text, None, a bool), not finite, negative, zero when not allowed,
        or a magnitude outside the supported range.
    """
    v = _scalar(value, name)
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ConfigError(f"{name}: must be finite and {bound}, got {value!r}")
    if v != 0 and not (POSITIVE_FLOOR <= v <= maximum):
        raise ConfigError(f"{name}: {v:g} is outside the supported range "
                          f"[{POSITIVE_FLOOR:g}, {maximum:g}]")
    return v


def check_positive_values(value, name: str, *, allow_zero: bool = True,
                          allow_inf: bool = False):
    """A non-negative setting (positive without ``allow_zero``), as :func:`check_positive`:
    a scalar, or an array of them (one per anchor, say); ``allow_inf``: ``inf`` too (a time
    constant of a process that never reverts).

    Returns
    -------
    float or ndarray
    """
    arr = np.asarray(value, dtype=float) if allow_inf else value
    if allow_inf and np.ndim(arr) and np.isposinf(arr).any():
        check_positive_values(np.where(np.isposinf(arr), 1.0, arr), name,
                              allow_zero=allow_zero)
        return arr
    if np.ndim(value) == 0:
        if allow_inf and np.isposinf(arr):
            return math.inf
        return check_positive(value, name, allow_zero=allow_zero)
    arr = as_float_array(value, name)
    for v in arr.ravel():
        check_positive(float(v), name, allow_zero=allow_zero)
    return arr


def check_real(value: float, name: str) -> float:
    """A finite scalar parameter of either sign, within :data:`MAGNITUDE_LIMIT`.

    Parameters
    ----------
    value : float
        The setting.
    name : str
        Its name, for the message.

    Returns
    -------
    float
        The value.

    Raises
    ------
    ConfigError
        Not a number, not finite, or beyond the magnitude limit.
    """
    v = _scalar(value, name)
    if not np.isfinite(v):
        raise ConfigError(f"{name}: must be finite, got {value!r}")
    if abs(v) > MAGNITUDE_LIMIT:
        raise ConfigError(f"{name}: {v:g} is beyond the supported limit of {MAGNITUDE_LIMIT:g}")
    return v


def check_int(value: object, name: str, *, minimum: int = 1, maximum: int | None = None) -> int:
    """An integer setting (a count, an iteration bound) in ``[minimum, maximum]``.

    Parameters
    ----------
    value : int
        The setting (an integral float such as ``3.0`` is accepted; a bool is not).
    name : str
        Its name, for the message.
    minimum, maximum : int
        Bounds (``maximum`` None: none).

    Returns
    -------
    int
        The value.

    Raises
    ------
    ConfigError
        Not an integer, or out of bounds (the message says which limit).
    """
    if isinstance(value, (bool, np.bool_, str, bytes, complex, np.complexfloating)) \
            or value is None:
        raise ConfigError(f"{name}: expected an integer, got {value!r}")
    try:
        v = float(value)
        ok = np.isfinite(v) and v == int(v)
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        raise ConfigError(f"{name}: expected an integer, got {value!r}")
    n = int(value) if isinstance(value, (int, np.integer)) else int(v)
    if n < minimum:
        raise ConfigError(f"{name}: must be >= {minimum}, got {n}")
    if maximum is not None and n > maximum:
        raise ConfigError(f"{name}: {n} is beyond the supported limit of {maximum}")
    return n


def memory_limit_bytes() -> float:
    """The memory one call may allocate: ``RADIOLOC_MEMORY_LIMIT_GB`` or
    :data:`MEMORY_LIMIT_GB` gigabytes.

    Returns
    -------
    float
        Bytes.
    """
    import os

    text = os.environ.get("RADIOLOC_MEMORY_LIMIT_GB", "")
    try:
        gb = float(text) if text.strip() else MEMORY_LIMIT_GB
    except ValueError:
        gb = MEMORY_LIMIT_GB
    if not np.isfinite(gb) or gb <= 0:
        gb = MEMORY_LIMIT_GB
    return gb * 2**30


def check_memory(n_bytes: float, name: str, what: str = "") -> None:
    """Refuse, before allocating, work whose arrays would need more than the memory limit.

    Parameters
    ----------
    n_bytes : float
        Estimated bytes of the largest arrays the call builds.
    name : str
        The setting or argument that sets the size (named in the message).
    what : str
        What is allocated, e.g. ``"4 x 10^9 particle states"``.

    Returns
    -------
    None

    Raises
    ------
    ConfigError
        ``n_bytes`` exceeds :func:`memory_limit_bytes`.
    """
    limit = memory_limit_bytes()
    if not np.isfinite(n_bytes) or n_bytes > limit:
        need = f"{n_bytes / 2**30:.3g} GiB" if np.isfinite(n_bytes) else "unbounded memory"
        raise ConfigError(f"{name}: needs about {need}{' for ' + what if what else ''}, beyond "
                          f"the memory limit of {limit / 2**30:.3g} GiB "
                          "(RADIOLOC_MEMORY_LIMIT_GB)")


def check_symmetric(matrix: np.ndarray, name: str) -> None:
    """Refuse matrices ``(..., n, n)`` that are not symmetric to 1e-9 relative (a solver
    reading one triangle would otherwise use half of what was given), naming ``name`` and
    the first entry.

    Raises
    ------
    InputError
    """
    m = np.asarray(matrix, dtype=float)
    t = np.swapaxes(m, -1, -2)
    asym = np.abs(m - t) > 1e-9 * (np.abs(m) + np.abs(t)) + 1e-300
    if np.any(asym):
        raise InputError(f"{name}: not symmetric (entry {tuple(int(i) for i in np.argwhere(asym)[0])})")


def check_covariance(cov: np.ndarray, name: str, max_variance: float = 1e12,
                     min_variance: float = 0.0) -> None:
    """Refuse covariance matrices ``(..., n, n)`` that are not symmetric positive definite,
    whose variances exceed ``max_variance`` (a filter's update would then lose every digit
    against metre-scale measurements) or fall below ``min_variance`` (their inverse would
    overflow), naming ``name`` and the entry.

    Raises
    ------
    InputError
    """
    diag = np.diagonal(cov, axis1=-2, axis2=-1)
    if np.any(diag > max_variance):
        idx = tuple(int(i) for i in np.argwhere(diag > max_variance)[0])
        raise InputError(f"{name}: variance {diag[idx]:g} at diagonal index {idx} is beyond "
                         f"the supported {max_variance:g} (the update would lose every digit "
                         "against metre-scale measurements)")
    if np.any(diag < min_variance):
        idx = tuple(int(i) for i in np.argwhere(diag < min_variance)[0])
        raise InputError(f"{name}: variance {diag[idx]:g} at diagonal index {idx} is below "
                         f"the supported floor of {min_variance:g} (its inverse would overflow)")
    check_symmetric(cov, name)
    try:
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        raise InputError(f"{name}: not symmetric positive definite") from None


def check_probability(value: float, name: str) -> float:
    """A scalar in [0, 1] (not a bool, text or None)."""
    v = _scalar(value, name)
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


def ambiguous_fixes(position: np.ndarray, centres: np.ndarray, ranges: np.ndarray,
                    used: np.ndarray, tol_m: float) -> tuple[np.ndarray, Callable]:
    """Where a 2-D fix from ranges to points is not unique: the used points are coincident
    or collinear, or the mirror image of the fix across their best-fit line fits the ranges
    as well (within ``tol_m``) while lying apart from it.

    Parameters
    ----------
    position : ndarray, shape (..., 2)
        The fixes.
    centres : ndarray, shape (..., L, 2)
        The points ranged to.
    ranges : ndarray, shape (..., L)
        The ranges (entries not ``used`` are ignored).
    used : ndarray of bool, shape (..., L)
        Which ranges the fix used.
    tol_m : float
        Range residual (RMS, metres) under which two fits count as equally good.

    Returns
    -------
    mask : ndarray of bool, shape (...)
        True where the fix is ambiguous.
    reason : callable
        ``reason(index)`` words it for one problem.
    """
    w = used.astype(float)
    n = w.sum(-1)
    centroid = np.einsum("...l,...ld->...d", w, centres) / np.maximum(n, 1)[..., None]
    centred = np.where(used[..., None], centres - centroid[..., None, :], 0.0)
    _, sv, vt = np.linalg.svd(centred, full_matrices=False)
    coincident = sv[..., 0] <= 1e-12 * np.maximum(np.abs(centroid).max(-1), 1.0)
    flat = coincident | (sv[..., 1] <= 1e-9 * np.maximum(sv[..., 0], 1e-300)) | (n < 3)
    normal = vt[..., 1, :]
    offset = np.einsum("...d,...d->...", position - centroid, normal)
    mirror = position - 2.0 * offset[..., None] * normal

    def rms(x):
        d = np.linalg.norm(x[..., None, :] - centres, axis=-1)
        return np.sqrt(np.sum(np.where(used, (ranges - d) ** 2, 0.0), -1) / np.maximum(n, 1))
    apart = np.abs(2.0 * offset) > 2.0 * tol_m
    same_fit = rms(mirror) <= rms(position) + tol_m
    mask = flat | (apart & same_fit)

    def reason(index):
        if coincident[index]:
            return "the points ranged to coincide: any direction fits the ranges"
        if flat[index]:
            return ("the points ranged to are collinear (or fewer than 3): the fix and its "
                    "mirror image across their line fit the ranges equally")
        return (f"ambiguous fix: {np.array2string(position[index], precision=3)} and its "
                f"mirror {np.array2string(mirror[index], precision=3)} fit the ranges "
                "equally well (points nearly collinear seen from the node)")
    return mask, reason


def refuse_infinite(arr: np.ndarray, name: str) -> np.ndarray:
    """Refuse an infinite entry in an array where NaN marks a missing measurement.

    Parameters
    ----------
    arr : ndarray
        Measurements (NaN allowed).
    name : str
        Argument name for the message.

    Returns
    -------
    ndarray
        ``arr``.

    Raises
    ------
    InputError
        Naming ``name`` and the index of the first infinite entry.
    """
    bad = np.isinf(arr)
    if np.any(bad):
        idx = _first_bad_index(bad)
        raise InputError(f"{name}: infinite value at index {idx} (NaN marks a missing "
                         "measurement)")
    return arr


#: A measured range more than ``NEGATIVE_RANGE_SIGMAS`` standard deviations of its noise
#: below 0 (below a known range bias, if the caller subtracts one) is refused
#: (:func:`check_ranges`); without a noise level, every negative range is. A distance is
#: >= 0, but a noisy measurement of a short one may fall slightly below 0: a zero-mean
#: Gaussian error reaches -6 sigma with probability 1e-9, so no honest measurement is
#: refused, while a sign slip, an offset or a wrong column is.
NEGATIVE_RANGE_SIGMAS = 6.0


def range_noise_std(noise: object) -> float:
    """The standard deviation that bounds a range-noise model's negative tail.

    Parameters
    ----------
    noise : object or None
        A range-error model: the LOS/NLOS mixture (its ``los_std_m``: NLOS errors are
        positive), a Gaussian (its ``std_m``), a model holding one as ``noise``, or None
        (no noise model: 0).

    Returns
    -------
    float
        Metres.
    """
    for attribute in ("los_std_m", "std_m"):
        value = getattr(noise, attribute, None)
        if value is not None:
            return float(value)
    inner = getattr(noise, "noise", None)           # a range model holding its noise model
    return 0.0 if inner is None else range_noise_std(inner)


def range_floor_m(std_m: object = 0.0, bias_m: object = 0.0) -> np.ndarray:
    """The smallest measured range accepted: ``bias_m - NEGATIVE_RANGE_SIGMAS * std_m``.

    Parameters
    ----------
    std_m : float or array_like
        Range noise standard deviation, metres (NaN counts as 0: no noise level given).
    bias_m : float or array_like
        A known range bias that the caller subtracts from every range, metres.

    Returns
    -------
    ndarray
        The floor (0 where neither is given).
    """
    with np.errstate(invalid="ignore", over="ignore"):
        s = np.nan_to_num(np.asarray(std_m, dtype=float), nan=0.0)
        return np.nan_to_num(np.asarray(bias_m, dtype=float)) - NEGATIVE_RANGE_SIGMAS * s


def check_ranges(ranges: np.ndarray, name: str, std_m: object = 0.0, *,
                 bias_m: object = 0.0, used: np.ndarray | None = None,
                 bias_name: str = "the range bias") -> np.ndarray:
    """The one rule on negative measured ranges, applied by every estimator and model that
    takes ranges and by the log reader.

    A range is refused when it lies below ``bias_m - NEGATIVE_RANGE_SIGMAS * std_m``
    (a bias-corrected range below ``-6 std_m``); ``std_m`` is the range noise the caller
    works with (0 when it has none: then every negative range is refused). NaN (a missing
    range) and entries not ``used`` pass.

    Parameters
    ----------
    ranges : ndarray
        Measured ranges, metres (already checked for dtype and infinities).
    name : str
        Argument name for the message.
    std_m : float or array_like
        Noise standard deviation, broadcastable to ``ranges`` (NaN entries count as 0).
    bias_m : float or array_like
        A known range bias the caller subtracts from every range (default 0).
    used : ndarray of bool, optional
        The entries the caller uses (default all).
    bias_name : str
        What the message calls ``bias_m`` (the caller's argument name) when it sets the floor.

    Returns
    -------
    ndarray
        ``ranges``.

    Raises
    ------
    InputError
        Naming ``name``, the index of the first range below its floor, the value and the
        floor.
    """
    r = check_dtype(ranges, name).astype(float)
    floor = range_floor_m(std_m, bias_m)
    check_shapes(name, r.shape, "its noise standard deviations", floor.shape)
    with np.errstate(invalid="ignore"):
        bad = r < floor
    if used is not None:
        bad = bad & np.asarray(used, dtype=bool)
    if np.any(bad):
        idx = _first_bad_index(bad)
        fl = float(np.broadcast_to(floor, bad.shape)[idx])
        value = float(np.broadcast_to(r, bad.shape)[idx])
        if fl == 0.0:
            raise InputError(f"{name}: negative range {value:.6g} at index {idx} (a range is a "
                             "distance >= 0; no noise level is given that allows it)")
        bias = float(np.broadcast_to(np.asarray(bias_m, dtype=float), bad.shape)[idx])
        if bias != 0.0:
            raise InputError(f"{name}: range {value:.6g} at index {idx} is below its floor of "
                             f"{fl:.4g} m ({bias_name} {bias:.4g} m less "
                             f"{NEGATIVE_RANGE_SIGMAS:g} standard deviations of its noise); "
                             f"is {bias_name} right?")
        raise InputError(f"{name}: range {value:.6g} at index {idx} is below its floor of "
                         f"{fl:.4g} m ({NEGATIVE_RANGE_SIGMAS:g} standard deviations of its "
                         "noise below 0)")
    return r
