"""Methods of ``radioloc locate``: a registry of functions from a user's log to estimates.

A method is a function ``fn(request: LocateRequest) -> DataFrame`` returning columns
``time, node, x, y`` plus ``uncertainty_m`` (the square root of the trace of the position
covariance, metres) where the method has one, registered with :func:`locate_method`.
Every module of :mod:`radioloc.locate` is imported on first use, so adding a method is
adding a module.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import pandas as pd

from radioloc.core.errors import ConfigError, InputError


@dataclass
class LocateRequest:
    """Everything ``radioloc locate`` passes to a method.

    Attributes
    ----------
    measurements : DataFrame
        Validated by :func:`radioloc.io.read_measurements`.
    anchors : DataFrame or None
        Validated by :func:`radioloc.io.read_anchors`.
    priors : Path or None
        Method-specific prior file (see the method's documentation).
    calibration : Path or None
        Method-specific calibration file (see the method's documentation).
    options : dict of str to str
        ``-o key=value`` pairs; read them with :meth:`option`.
    """

    measurements: pd.DataFrame
    anchors: pd.DataFrame | None = None
    priors: Path | None = None
    calibration: Path | None = None
    options: dict[str, str] = field(default_factory=dict)

    def option(self, key: str, default: float | None = None, cast: type = float):
        """The option ``key`` converted with ``cast``; ``default`` if absent."""
        if key not in self.options:
            return default
        try:
            return cast(self.options[key])
        except ValueError:
            raise ConfigError(f"option {key}: cannot read {self.options[key]!r} as "
                              f"{cast.__name__}") from None

    def require_anchors(self, method: str) -> pd.DataFrame:
        if self.anchors is None:
            raise InputError(f"method {method}: needs an anchors file (--anchors)")
        return self.anchors

    def kind(self, kind: str, method: str) -> pd.DataFrame:
        """The rows of one measurement kind; :class:`InputError` if there are none."""
        rows = self.measurements[self.measurements["kind"] == kind]
        if rows.empty:
            raise InputError(f"method {method}: the measurements hold no '{kind}' rows")
        return rows


@dataclass(frozen=True)
class LocateMethod:
    name: str
    summary: str
    fn: Callable[[LocateRequest], pd.DataFrame]


_METHODS: dict[str, LocateMethod] = {}


def locate_method(name: str, summary: str):
    """Decorator registering ``fn(request) -> DataFrame`` as ``radioloc locate --method name``."""

    def deco(fn: Callable[[LocateRequest], pd.DataFrame]):
        _METHODS[name] = LocateMethod(name, summary, fn)
        return fn

    return deco


def methods() -> dict[str, LocateMethod]:
    """All registered methods by name."""
    import importlib
    import pkgutil

    import radioloc.locate as pkg

    for mod in pkgutil.iter_modules(pkg.__path__):
        if mod.name != "base":
            importlib.import_module(f"radioloc.locate.{mod.name}")
    return dict(sorted(_METHODS.items()))


def run_method(name: str, request: LocateRequest) -> pd.DataFrame:
    """Apply method ``name`` to ``request``."""
    known = methods()
    if name not in known:
        raise ConfigError(f"unknown method {name!r}; known: {', '.join(known)}")
    out = known[name].fn(request)
    missing = [c for c in ("time", "node", "x", "y") if c not in out.columns]
    if missing:  # a method bug, not a user error
        raise RuntimeError(f"method {name} returned no column(s) {missing}")
    return out
