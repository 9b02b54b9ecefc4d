"""Keyword arguments renamed in the public API, accepted for one release with a warning.

:func:`renamed_keywords` decorates a function (or ``__init__``) whose argument was renamed:
a call with the old keyword (or, for an argument that was positional, a value in the old
position) still works, converted to the new argument, and raises a ``FutureWarning`` that
names the new keyword. Range noise was renamed this way to ``std_m`` (standard deviation,
metres) everywhere; an old variance keyword is converted by its square root.
"""

from __future__ import annotations

import functools
import inspect
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import ConfigError

__all__ = ["Renamed", "renamed_keywords"]


def _sqrt_of_variance(value: object) -> object:
    """The standard deviation of a variance; an invalid variance passes unchanged, so the new
    argument's own validation rejects it by its new name."""
    if value is None:
        return None
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return value
    if not np.all(np.isfinite(arr) & (arr >= 0)):
        return value
    return float(np.sqrt(arr)) if arr.ndim == 0 else np.sqrt(arr)


@dataclass(frozen=True)
class Renamed:
    """The new name of a renamed keyword.

    Parameters
    ----------
    new : str
        The keyword that replaces it.
    variance : bool
        The old keyword was the square of the new one (a variance for a standard
        deviation): its value is converted by the square root.
    """

    new: str
    variance: bool = False

    def convert(self, value: object) -> object:
        return _sqrt_of_variance(value) if self.variance else value

    def message(self, owner: str, old: str) -> str:
        how = f" (a standard deviation: {self.new} = sqrt({old}))" if self.variance else ""
        return (f"{owner}: {old}= is renamed {self.new}={how}; {old}= will stop working in "
                f"the next release")


def renamed_keywords(renames: dict[str, Renamed],
                     positional: tuple[str, ...] = ()) -> Callable[[Callable], Callable]:
    """Decorate a function so that its old keyword names keep working, with a ``FutureWarning``.

    Parameters
    ----------
    renames : dict of str to Renamed
        Old keyword -> its new name (and conversion).
    positional : tuple of str
        Old keywords that callers could pass by position, in order, right after the
        function's remaining positional parameters. A call with more positional values than
        the function takes gives the extra values to these old names.

    Returns
    -------
    callable
        The decorator. Giving an old keyword together with its new name raises
        :class:`~radioloc.core.errors.ConfigError`.
    """
    def decorate(func: Callable) -> Callable:
        params = inspect.signature(func).parameters.values()
        n_pos = sum(p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) for p in params)
        owner = func.__qualname__.removesuffix(".__init__")

        @functools.wraps(func)
        def wrapper(*args, **kwargs):
            if len(args) > n_pos:
                extra = args[n_pos:]
                if len(extra) > len(positional):
                    raise TypeError(f"{owner}: takes at most {n_pos + len(positional)} "
                                    f"positional arguments, got {len(args)}")
                for old, value in zip(positional, extra):
                    if old in kwargs:
                        raise TypeError(f"{owner}: got multiple values for {old!r}")
                    kwargs[old] = value
                args = args[:n_pos]
            for old, rename in renames.items():
                if old not in kwargs:
                    continue
                if rename.new in kwargs:
                    raise ConfigError(f"{owner}: give {rename.new} (the new name of {old}), "
                                      f"not both")
                warnings.warn(rename.message(owner, old), FutureWarning, stacklevel=2)
                kwargs[rename.new] = rename.convert(kwargs.pop(old))
            return func(*args, **kwargs)
        return wrapper
    return decorate
