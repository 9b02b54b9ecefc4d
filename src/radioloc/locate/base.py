"""Methods of ``radioloc locate``: a registry of functions from a user's log to estimates.

A method is a function ``fn(request: LocateRequest) -> DataFrame`` returning columns
``time, node, x, y`` plus ``uncertainty_m`` (the square root of the trace of the position
covariance, metres) where the method has one, registered with :func:`locate_method`.
Every module of :mod:`radioloc.locate` is imported on first use, so adding a method is
adding a module.

A method declares what it reads, and :func:`run_method` refuses anything else before the
method runs, so that nothing a user gives is silently ignored:

- ``options``: its ``-o key=value`` options, ``{name: help}`` or ``{name: Option(...)}``
  (type, bounds, choices); an unknown key is refused, naming it and listing the known
  ones; a value that is not of the type, not finite or out of bounds is refused.
- ``kinds``: the measurement kinds it uses (``"range"``, ``"rss"``); rows of another kind
  are refused, naming the kind and the count.
- ``inputs``: the files it reads besides the measurements (``"anchors"``, ``"priors"``,
  ``"calibration"``); another file given is refused.
- ``moving_anchors``: whether it takes anchors that move (an anchors file with a ``time``
  column, :func:`radioloc.io.read_anchors`); others refuse such a file.

A method that declares nothing (``None``) accepts anything, as before declarations existed.
Its output is checked too: a non-finite position is a method failure, never printed.

Before a method runs, :func:`radioloc.core.plausibility.check_log` refuses logs that are
well-formed but implausible (degenerate anchors; ranges, anchors, tdoa, pseudoranges,
angles, RSS or time in the wrong unit) and warns of time going backwards within a node; every method accepts
``-o no_check=NAME[,NAME...]`` (or ``all``) to overrule named checks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError, InputError
from radioloc.locate.table import order_rows

INPUTS = ("anchors", "priors", "calibration")
#: Default gap between a node's rows that restarts a track (option ``max_gap_s``), seconds.
MAX_GAP_S = 5.0
_TRUE = ("1", "true", "yes", "on")
_FALSE = ("0", "false", "no", "off")


@dataclass(frozen=True)
class Option:
    """Declaration of one ``-o key=value`` option of a locate method.

    Attributes
    ----------
    help : str
        One line for ``radioloc methods``.
    type : {float, int, bool, str}
        The value's type. ``float`` and ``int`` values must be finite; an ``int`` written
        as ``1e3`` or ``16.0`` is accepted when integral. ``bool`` accepts 0/1, true/false,
        yes/no, on/off.
    min, max : float, optional
        Inclusive bounds (numbers).
    min_exclusive : bool
        Whether ``min`` itself is refused (``min=0, min_exclusive=True``: strictly positive).
    choices : tuple of str, optional
        Allowed values (``str`` options).
    """

    help: str = ""
    type: type = float
    min: float | None = None
    max: float | None = None
    min_exclusive: bool = False
    choices: tuple[str, ...] | None = None

    def parse(self, key: str, text: str) -> Any:
        """The value of ``-o key=text``, converted and checked.

        Parameters
        ----------
        key : str
            The option name, for the message.
        text : str
            The value as typed.

        Returns
        -------
        float, int, bool or str

        Raises
        ------
        ConfigError
            Naming the option, the value and what is expected.
        """
        raw = text.strip()
        if self.type is bool:
            low = raw.lower()
            if low in _TRUE or low in _FALSE:
                return low in _TRUE
            raise ConfigError(f"option {key}: expected 0/1 (or true/false), got {text!r}")
        if self.type is str:
            if self.choices is not None and raw not in self.choices:
                raise ConfigError(f"option {key}: expected one of {', '.join(self.choices)}, "
                                  f"got {text!r}")
            return raw
        try:
            number = float(raw)
        except ValueError:
            raise ConfigError(f"option {key}: expected a number, got {text!r}") from None
        if not math.isfinite(number):
            raise ConfigError(f"option {key}: must be a finite number, got {text!r}")
        if self.type is int:
            if number != math.floor(number):
                raise ConfigError(f"option {key}: expected a whole number, got {text!r}")
            value: Any = int(number)
        else:
            value = number
        if self.min is not None and (value < self.min or (self.min_exclusive and value == self.min)):
            op = ">" if self.min_exclusive else ">="
            raise ConfigError(f"option {key}: must be {op} {self.min:g}{self._range()}, got {text!r}")
        if self.max is not None and value > self.max:
            raise ConfigError(f"option {key}: must be <= {self.max:g}{self._range()}, got {text!r}")
        if self.choices is not None and raw not in self.choices:
            raise ConfigError(f"option {key}: expected one of {', '.join(self.choices)}, got {text!r}")
        return value

    def _range(self) -> str:
        if self.min is not None and self.max is not None:
            low = f"above {self.min:g}" if self.min_exclusive else f"{self.min:g}"
            return f" (allowed: {low} to {self.max:g})"
        return ""

    def describe(self) -> str:
        """``help`` with the type and bounds, for listings."""
        parts = [self.type.__name__]
        if self.min is not None:
            parts.append(f"{'>' if self.min_exclusive else '>='} {self.min:g}")
        if self.max is not None:
            parts.append(f"<= {self.max:g}")
        if self.choices:
            parts.append("one of " + "/".join(self.choices))
        return f"{self.help} [{', '.join(parts)}]" if self.help else f"[{', '.join(parts)}]"


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
    parsed : dict of str to value
        Options already converted and checked against the method's declaration
        (filled by :func:`run_method`); ``parsed["no_check"]`` holds the plausibility
        checks overruled with ``-o no_check`` (a frozenset of names).
    frame : radioloc.locate.frames.Frame or None
        The working frame of the anchors' coordinates (None: local, not on the Earth).
    """

    measurements: pd.DataFrame
    anchors: pd.DataFrame | None = None
    priors: Path | None = None
    calibration: Path | None = None
    options: dict[str, str] = field(default_factory=dict)
    parsed: dict[str, Any] = field(default_factory=dict)
    frame: Any = None

    def option(self, key: str, default: Any = None, cast: type = float):
        """The option ``key`` converted with ``cast``; ``default`` if absent.

        Parameters
        ----------
        key : str
            Option name.
        default : any
            Returned when the user did not give the option.
        cast : type
            Conversion of an undeclared option's text (``float``, ``int``, ...). A declared
            option's value was already converted by its :class:`Option`.

        Returns
        -------
        The value.

        Raises
        ------
        ConfigError
            The text cannot be converted, or a number is not finite (``inf``, ``nan``),
            or an ``int`` is not whole.
        """
        if key in self.parsed:
            value = self.parsed[key]
            return cast(value) if cast in (int, float) and isinstance(value, (int, float)) else value
        if key not in self.options:
            return default
        text = self.options[key]
        if cast in (int, float):
            return cast(Option(type=cast).parse(key, text))
        try:
            return cast(text)
        except (TypeError, ValueError, OverflowError):
            raise ConfigError(f"option {key}: cannot read {text!r} as "
                              f"{getattr(cast, '__name__', 'the expected type')}") from None

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
    """A registered method and what it declares (``None``: not declared, anything goes)."""

    name: str
    summary: str
    fn: Callable[[LocateRequest], pd.DataFrame]
    options: dict[str, Option] | None = None
    kinds: tuple[str, ...] | None = None
    inputs: tuple[str, ...] | None = None
    moving_anchors: bool = False
    planar: bool = False


_METHODS: dict[str, LocateMethod] = {}


def locate_method(name: str, summary: str, *, options: Mapping[str, str | Option] | None = None,
                  kinds: tuple[str, ...] | None = None, inputs: tuple[str, ...] | None = None,
                  moving_anchors: bool = False, planar: bool = False):
    """Decorator registering ``fn(request) -> DataFrame`` as ``radioloc locate --method name``.

    Parameters
    ----------
    name : str
        The method's name on the command line.
    summary : str
        One line for ``radioloc methods``.
    options : dict of str to (str or Option), optional
        Its ``-o`` options: name to help text (the value is then read by the method with
        :meth:`LocateRequest.option`) or to an :class:`Option` (type and bounds checked
        before the method runs). ``{}`` declares that it takes none.
    kinds : tuple of str, optional
        Measurement kinds it uses (``"range"``, ``"rss"``).
    inputs : tuple of str, optional
        Files it reads besides the measurements, among ``"anchors"``, ``"priors"``,
        ``"calibration"``.
    moving_anchors : bool
        It takes anchors with a track (a ``time`` column in the anchors file).
    planar : bool
        It locates in the plane from the anchors' ``x, y`` only: anchors with ``z`` are
        refused rather than their heights ignored.

    Returns
    -------
    callable
        The decorator (returns ``fn`` unchanged).
    """
    if inputs is not None and (bad := set(inputs) - set(INPUTS)):
        raise ValueError(f"locate_method {name}: unknown input(s) {sorted(bad)}; known {INPUTS}")
    if kinds is not None:
        from radioloc.core.kinds import kinds as declared

        if bad := set(kinds) - set(declared()):
            raise ValueError(f"locate_method {name}: unknown kind(s) {sorted(bad)}")
    decl = None if options is None else {
        k: v if isinstance(v, Option) else Option(help=str(v), type=str)
        for k, v in options.items()}

    def deco(fn: Callable[[LocateRequest], pd.DataFrame]):
        _METHODS[name] = LocateMethod(name, summary, fn, decl,
                                      None if kinds is None else tuple(kinds),
                                      None if inputs is None else tuple(inputs),
                                      bool(moving_anchors), bool(planar))
        return fn

    return deco


def check_request(method: LocateMethod, request: LocateRequest) -> None:
    """Refuse what ``method`` does not declare; convert its declared options.

    Parameters
    ----------
    method : LocateMethod
        The registered method.
    request : LocateRequest
        Updated in place: ``request.parsed`` receives the converted typed options.

    Returns
    -------
    None

    Raises
    ------
    ConfigError
        An unknown option key (the known ones are listed), or a bad option value.
    InputError
        A file the method does not read, rows of a kind it does not use, or anchors with
        heights for a planar method.
    """
    name = method.name
    if method.options is not None:
        for key, text in request.options.items():
            if key not in method.options:
                known = ", ".join(sorted(method.options)) or "none"
                raise ConfigError(f"method {name}: unknown option {key!r}; its options: {known}")
            spec = method.options[key]
            if spec.type is not str or spec.choices is not None:
                request.parsed[key] = spec.parse(key, text)
    if method.inputs is not None:
        for what in INPUTS:
            if getattr(request, what) is not None and what not in method.inputs:
                raise InputError(f"method {name}: does not read a {what} file; remove "
                                 f"--{what} (it reads: {', '.join(method.inputs) or 'none'})")
    from radioloc.locate.adapter import moving_anchors

    if method.planar and request.anchors is not None and "z" in request.anchors.columns:
        raise InputError(f"method {name}: locates in the plane from the anchors' x and y and "
                         "would ignore their z column; remove z from the anchors file (the "
                         "distances are then taken in the plane)")
    if moving_anchors(request.anchors) and not method.moving_anchors:
        takers = ", ".join(sorted(n for n, m in _METHODS.items() if m.moving_anchors)) or "none"
        raise InputError(f"method {name}: the anchors file has a time column (anchors that "
                         f"move); methods that take moving anchors: {takers}")
    if method.kinds is not None:
        from radioloc.io.logs import check_kinds

        check_kinds(request.measurements, method.kinds, name)


def _check_output(name: str, out: pd.DataFrame) -> None:
    missing = [c for c in ("time", "node", "x", "y") if c not in out.columns]
    if missing:  # a method bug, not a user error
        raise RuntimeError(f"method {name} returned no column(s) {missing}")
    value_cols = [c for c in out.columns
                  if c in ("x", "y", "z", "uncertainty_m") or c.startswith("cov_")]
    values = out[value_cols].to_numpy(dtype=float)
    bad = ~np.isfinite(values)
    if bad.any():
        i, j = (int(v) for v in np.argwhere(bad)[0])
        raise RuntimeError(f"method {name} produced a non-finite {value_cols[j]} for node "
                           f"{out['node'].iloc[i]!r} at time {out['time'].iloc[i]!r}")
    twice = out.duplicated(["time", "node"])
    if twice.any():
        i = int(np.flatnonzero(twice.to_numpy())[0])
        raise RuntimeError(f"method {name} returned two rows for node {out['node'].iloc[i]!r} "
                           f"at time {out['time'].iloc[i]!r}")


#: The module of each method not named after it (``ekf-track`` is in ``ekf_track``): a run
#: imports its own method's module only (start-up time), never every method's.
MODULE_OF = {"gn": "gauss_newton", "smoother": "batch_smooth", "rls": "network",
             "ekf": "network", "closed-form": "single_sensor", "newton": "single_sensor",
             "localml": "snapshot", "ransac": "snapshot", "lsq": "snapshot"}


def method(name: str) -> LocateMethod | None:
    """The method ``name``, importing only its module (:data:`MODULE_OF`, else the module
    named after it: ``ekf-track``, ``ekf_track``); else every method's (:func:`methods`).
    None if unknown."""
    import importlib

    module = MODULE_OF.get(name, name.replace("-", "_"))
    if name not in _METHODS and module.isidentifier():
        try:
            importlib.import_module(f"radioloc.locate.{module}")
        except ModuleNotFoundError as exc:
            if exc.name != f"radioloc.locate.{module}":
                raise
    return _METHODS.get(name) or methods().get(name)


def methods() -> dict[str, LocateMethod]:
    """All registered methods by name."""
    import importlib
    import pkgutil

    import radioloc.locate as pkg

    for mod in pkgutil.iter_modules(pkg.__path__):
        if mod.name != "base":
            importlib.import_module(f"radioloc.locate.{mod.name}")
    return dict(sorted(_METHODS.items()))


def _plausibility_skip(request: LocateRequest) -> frozenset[str]:
    from radioloc.core.plausibility import parse_skip

    return parse_skip(request.options.pop("no_check", None))


def check_plausible(method: LocateMethod, request: LocateRequest,
                    skip: frozenset[str] = frozenset()) -> None:
    """The plausibility checks of :mod:`radioloc.core.plausibility` for ``method``.

    The positions are 3-D when the anchors have ``z`` and no ``tag_height_m`` is given; the
    time-unit check applies to methods with a ``max_gap_s`` option; methods that read node
    priors skip the anchor-geometry check (the priors fix what the anchors leave open).

    Parameters
    ----------
    method : LocateMethod
    request : LocateRequest
    skip : frozenset of str
        Checks overruled with ``-o no_check``.

    Returns
    -------
    None

    Raises
    ------
    GeometryError, InputError
        One line naming the likely cause.
    """
    from radioloc.core.plausibility import check_log
    from radioloc.locate.adapter import moving_anchors

    anchors = request.anchors
    moving = moving_anchors(anchors)
    if moving:                  # a track: checked at its first position, no fixed geometry
        anchors = anchors.drop_duplicates("id")
    dim = None
    if anchors is not None:
        dim = 3 if "z" in anchors.columns and request.option("tag_height_m") is None else 2
    declared = method.options or {}
    gap = request.option("max_gap_s", MAX_GAP_S) if "max_gap_s" in declared else None
    reads_priors = method.inputs is not None and "priors" in method.inputs
    check_log(request.measurements, anchors, kinds=method.kinds, dim=dim, max_gap_s=gap,
              geometry=not reads_priors and not moving, fixed_anchors=not moving, skip=skip)
    if reads_priors and request.priors is not None:
        from radioloc.core.plausibility import check_node_ranges
        from radioloc.io.priors import read_node_priors

        mean = read_node_priors(request.priors).set_index("node")[["x", "y"]]
        m = request.measurements
        rows = m[(m["kind"] == "range") & m["node"].isin(mean.index) & m["peer"].isin(mean.index)]
        if not rows.empty:
            gap_m = np.linalg.norm(mean.loc[rows["node"]].to_numpy(float)
                                   - mean.loc[rows["peer"]].to_numpy(float), axis=1)
            check_node_ranges(rows["value"].to_numpy(float), gap_m, skip=skip,
                              where="measurements")


def run_method(name: str, request: LocateRequest) -> pd.DataFrame:
    """Apply method ``name`` to ``request``.

    Parameters
    ----------
    name : str
        A registered method.
    request : LocateRequest
        The inputs; checked against the method's declarations first (:func:`check_request`).

    Returns
    -------
    DataFrame
        ``time, node, x, y[, z][, uncertainty_m, cov_*][, flags]``, every value finite, one
        row per ``(time, node)``, sorted by time then node (nodes in the order they first
        appear in the measurements); ``attrs["summary"]``: what the method reports about
        the run (counts, fitted parameters, seed), a dict of JSON values.

    Raises
    ------
    ConfigError, InputError
        Unknown method, or input the method does not take (see :func:`check_request`).
    RuntimeError
        The method returned no position columns or a non-finite value (a method bug).
    """
    chosen = prepare_method(name, request)
    return checked_output(chosen, request, chosen.fn(request), rerun=chosen.fn)


def prepare_method(name: str, request: LocateRequest) -> LocateMethod:
    """The method ``name``, with ``request`` checked against its declarations
    (:func:`check_request`) and for plausibility (:func:`check_plausible`): the part of
    :func:`run_method` before the method runs.

    Parameters
    ----------
    name : str
    request : LocateRequest
        Its ``parsed`` options are filled.

    Returns
    -------
    LocateMethod
    """
    chosen = method(name)
    if chosen is None:
        raise ConfigError(f"unknown method {name!r}; known: {', '.join(methods())}")
    skip = _plausibility_skip(request)
    check_request(chosen, request)
    request.parsed["no_check"] = skip
    check_plausible(chosen, request, skip)
    return chosen


def checked_output(chosen: LocateMethod, request: LocateRequest, out: pd.DataFrame,
                   rerun=None, node_order: list[str] | None = None) -> pd.DataFrame:
    """The part of :func:`run_method` after the method ran: its output checked, the health
    check (:func:`radioloc.locate.health.check_run`) on the log of ``request``, the rows
    ordered.

    Parameters
    ----------
    chosen : LocateMethod
    request : LocateRequest
    out : DataFrame
        The method's output for the rows of ``request``.
    rerun : callable, optional
        The method, for the health check's retry with the noise the residuals say.
    node_order : list of str, optional
        Nodes in the order of the rows within one time (default: as they first appear in
        the log of ``request``).

    Returns
    -------
    DataFrame
        As :func:`run_method`.
    """
    _check_output(chosen.name, out)
    from radioloc.locate.health import check_run

    out, health = check_run(chosen.name, request, out, rerun=rerun,
                            options=chosen.options or ())
    summary = {**out.attrs.get("summary", {}), "health": health.summary()}
    out = order_rows(out, list(request.measurements["node"].unique()) if node_order is None
                     else node_order)
    out.attrs["summary"] = summary
    return out
