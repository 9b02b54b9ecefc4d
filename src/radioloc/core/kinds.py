"""The measurement kinds of the log schema, each declared once, by its model's module.

A kind is a :class:`Kind`: its name (the ``kind`` column of a log), its unit and meaning,
the model that explains it and the option naming the model's sigma, the bounds of its
values (a row beyond :attr:`Kind.limit` is refused when the log is read; a median beyond
:attr:`Kind.bound` is a unit slip, check :attr:`Kind.check`), the slips a tracker may name
when the kind's rows fit no track, how its unit scales with the unit of time, and the
anchor-file columns its model reads. Everything that knows kinds by name is generated from
:func:`kinds`: the schema (:func:`radioloc.io.read_measurements`), the plausibility and
unit-slip checks (:mod:`radioloc.core.plausibility`, :mod:`radioloc.locate.slips`), the
models and sigma options of ``radioloc locate`` (:mod:`radioloc.locate.adapter`), the
kinds column of ``radioloc methods`` and the kinds table of the documentation
(:func:`markdown_table`).

Where kinds come from:

- a module of :mod:`radioloc.models` that defines ``KINDS`` (a tuple of :class:`Kind`) at
  module level (found in the modules' source, so that only those modules are imported);
- the entry points of group :data:`ENTRY_POINT_GROUP` (``radioloc.kinds``) of any installed
  package, each naming a :class:`Kind` or a sequence of them::

      [project.entry-points."radioloc.kinds"]
      doppler = "mypackage.doppler:KIND"

A kind is one model file: a new kind of radioloc, or of a user's package, runs through
``radioloc locate`` without another edit.
"""

from __future__ import annotations

import importlib
import re
import warnings
from dataclasses import dataclass, field, replace
from functools import cache
from pathlib import Path
from typing import Any, Callable

import numpy as np

from radioloc.core.constants import SPEED_OF_LIGHT_M_PER_S
from radioloc.core.errors import ConfigError

__all__ = ["Kind", "Slip", "ENTRY_POINT_GROUP", "kinds", "kind", "model_kinds", "unit_slips",
           "markdown_table"]

#: The entry-point group through which another package declares kinds.
ENTRY_POINT_GROUP = "radioloc.kinds"


@dataclass(frozen=True)
class Slip:
    """A slip a log is known to make in one kind's values, as the map that undoes it.

    Attributes
    ----------
    undo : callable
        Elementwise map of the values back to what the schema means.
    how : str
        What ``undo`` does ("divided by 1000").
    question : str
        The question that names the slip ("tdoa values in mm?").
    kinds : tuple of str, optional
        The kinds whose rows slip together (odometry's dx and dy); default the declaring
        kind alone.
    """

    undo: Callable[[np.ndarray], np.ndarray]
    how: str
    question: str
    kinds: tuple[str, ...] = ()


def unit_slips(name: str, unit: str, time_power: int = 0, *, ns: bool = False,
               what: str | None = None) -> tuple[Slip, ...]:
    """The unit slips of values in ``unit``: mm and km for a length (and ns for a time of
    flight, ``ns``), degrees for an angle, mm/s and km/h for a speed (a unit with
    ``time_power`` -1).

    Parameters
    ----------
    name : str
        The kind, for the question.
    unit : {"m", "rad", "m/s", ...}
    time_power : int
        The power of seconds in the unit (-1: per second).
    ns : bool
        Whether the values are times of flight that a log may give in nanoseconds.
    what : str, optional
        The values in the question (default ``"<name> values"``).

    Returns
    -------
    tuple of Slip
    """
    what = what or f"{name} values"
    if unit == "rad":
        return (Slip(np.radians, "converted from degrees", f"{what} in degrees?"),)
    if not unit.startswith("m"):
        return ()
    per = "/s" if time_power == -1 else ""
    out = [Slip(lambda v: v / 1e3, "divided by 1000", f"{what} in mm{per}?"),
           Slip(lambda v: v * 1e3, "times 1000", f"{what} in km{per}?")]
    if time_power == -1:
        out.append(Slip(lambda v: v / 3.6, "divided by 3.6", f"{what} in km/h?"))
    if ns:
        out.append(Slip(lambda v: v * SPEED_OF_LIGHT_M_PER_S * 1e-9, "times c (from ns)",
                        f"{what} in ns?"))
    return tuple(out)


@dataclass(frozen=True)
class Kind:
    """One measurement kind of the log schema (see the module docstring).

    Attributes
    ----------
    name : str
        The ``kind`` cell of a log row.
    unit : str
        The unit of its values (``m``, ``rad``, ``dBm``, ``m/s``).
    meaning : str
        What a row measures, one line (the schema's and the docs' tables).
    model : callable, optional
        ``model(sigma) -> MeasurementModel``: the model that explains the rows, from the
        sigma in force. None: the methods build it themselves (``rss`` from the anchors
        file, odometry as the motion's control).
    sigma_option : str, optional
        The ``-o`` option of ``locate`` that sets the sigma (``range_std_m``).
    sigma_default : float, optional
        The sigma when the option is not given.
    sigma_help : str
        What the sigma is, for ``radioloc methods``.
    sigma_max : float
        Largest sigma the option takes.
    limit : float, optional
        Largest ``|value|`` a real log holds: a row beyond it is refused when the log is
        read, naming the line.
    bound : float, optional
        Largest ``|value|`` for any position (an angle's ``2 pi``): a median magnitude
        beyond :data:`radioloc.core.plausibility.ANGLE_FACTOR` times it is a unit slip,
        refused by the check :attr:`check`.
    check : str, optional
        The plausibility check of the values (``-o no_check`` name).
    check_values : callable, optional
        ``check_values(values, points, reference, skip=, where=)``: a check that needs the
        anchors (a time difference's, a pseudorange's); without it the check is the
        :attr:`bound`'s.
    time_power : int
        The power of seconds in the unit (0: a length or an angle; -1: a rate, m/s): how
        the values scale with the unit of time.
    anchor_columns : tuple of str
        Columns of the anchors file the model reads (each row's anchor's value, in
        :attr:`radioloc.models.measurement.Context.columns`).
    reference : bool
        A row needs a ``reference`` anchor (a time difference).
    self_measured : bool
        A row measures the node itself: ``peer`` names the sensor, not an anchor.
    slips : tuple of Slip, optional
        The slips the trackers may name; default :func:`unit_slips` of the unit.
    """

    name: str
    unit: str
    meaning: str
    model: Callable[[float], Any] | None = None
    sigma_option: str | None = None
    sigma_default: float | None = None
    sigma_help: str = ""
    sigma_max: float = 1e6
    limit: float | None = None
    bound: float | None = None
    check: str | None = None
    check_values: Callable[..., None] | None = None
    time_power: int = 0
    anchor_columns: tuple[str, ...] = ()
    reference: bool = False
    self_measured: bool = False
    slips: tuple[Slip, ...] | None = None
    source: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if not re.fullmatch(r"[a-z][a-z0-9_]*", str(self.name)):
            raise ConfigError(f"Kind name: lower-case letters, digits and _, got {self.name!r}")
        if self.model is not None and (self.sigma_option is None or self.sigma_default is None):
            raise ConfigError(f"Kind {self.name}: a kind with a model needs sigma_option and "
                              "sigma_default")
        if self.slips is None:
            object.__setattr__(self, "slips", unit_slips(self.name, self.unit, self.time_power))

    @property
    def reads(self) -> tuple[str, ...]:
        """The state components its model reads (none without a model)."""
        return () if self.model is None else tuple(self.model(self.sigma_default).reads)

    def build(self, sigma: float | None = None):
        """Its model with ``sigma`` (default :attr:`sigma_default`)."""
        if self.model is None:
            raise ConfigError(f"kind {self.name}: has no model of its own")
        return self.model(self.sigma_default if sigma is None else float(sigma))


def _builtin_modules() -> list[str]:
    """The modules of :mod:`radioloc.models` that define ``KINDS`` (found in their source)."""
    root = Path(__file__).resolve().parent.parent / "models"
    declares = re.compile(r"^KINDS\b", re.MULTILINE)
    return [f"radioloc.models.{p.stem}" for p in sorted(root.glob("*.py"))
            if declares.search(p.read_text(encoding="utf-8"))]


def _as_kinds(value, source: str) -> list[Kind]:
    items = [value] if isinstance(value, Kind) else list(value)
    bad = [type(v).__name__ for v in items if not isinstance(v, Kind)]
    if bad:
        raise ConfigError(f"{source}: expected Kind declarations, got {bad[0]}")
    return [replace(v, source=source) for v in items]


def _entry_point_kinds() -> list[Kind]:
    from importlib.metadata import entry_points

    out = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        source = f"entry point {ep.name} = {ep.value}"
        try:
            out.extend(_as_kinds(ep.load(), source))
        except Exception as exc:          # a broken plug-in is named, radioloc still runs
            warnings.warn(f"{ENTRY_POINT_GROUP}: {source} not loaded ({type(exc).__name__}: "
                          f"{exc})", stacklevel=3)
    return out


@cache
def kinds() -> dict[str, Kind]:
    """Every kind: radioloc's (:mod:`radioloc.models`) and the entry points', by name in
    alphabetical order.

    Returns
    -------
    dict of str to Kind

    Raises
    ------
    ConfigError
        Two declarations of one name (naming both).
    """
    found: list[Kind] = []
    for module in _builtin_modules():
        found.extend(_as_kinds(importlib.import_module(module).KINDS, module))
    found.extend(_entry_point_kinds())
    out: dict[str, Kind] = {}
    for k in found:
        if k.name in out:
            raise ConfigError(f"kind {k.name!r} declared twice: by {out[k.name].source} and by "
                              f"{k.source}")
        out[k.name] = k
    return dict(sorted(out.items()))


def kind(name: str) -> Kind | None:
    """The kind ``name`` (None: not declared)."""
    return kinds().get(name)


def model_kinds() -> dict[str, Kind]:
    """The kinds with a model of their own (what the generic estimators read)."""
    return {n: k for n, k in kinds().items() if k.model is not None}


def markdown_table() -> str:
    """The kinds table of the documentation: kind, unit, meaning, sigma option (default),
    state read, anchor columns, where declared.

    Returns
    -------
    str
        A Markdown table, one row per kind.
    """
    rows = ["| kind | unit | a row measures | sigma option (default) | state read | "
            "anchor columns | declared by |", "|---|---|---|---|---|---|---|"]
    for k in kinds().values():
        sigma = f"`{k.sigma_option}` ({k.sigma_default:g})" if k.sigma_option else ""
        cols = ", ".join(f"`{c}`" for c in k.anchor_columns)
        rows.append(f"| `{k.name}` | {k.unit} | {k.meaning} | {sigma} | "
                    f"{', '.join(k.reads)} | {cols} | `{k.source}` |")
    return "\n".join(rows) + "\n"
