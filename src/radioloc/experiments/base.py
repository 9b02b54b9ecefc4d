"""What an experiment is: a config, a function of a block of runs, and a summary.

An experiment subclasses :class:`Experiment` and is registered with :func:`register`.
The runner (:mod:`radioloc.experiments.runner`) calls :meth:`Experiment.run_block` on
blocks of Monte Carlo run indices, each with its own generator, concatenates the tidy
frames, and hands them to :meth:`Experiment.summarize`, which writes figures and returns
the metrics (ours beside the paper's) and the paper's claims checked on our numbers.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError, DataUnavailable


@dataclass
class Metric:
    """One number of the reproduction, beside the paper's where it has one."""

    name: str
    value: float
    paper: float | None = None
    unit: str = ""
    note: str = ""

    def as_dict(self) -> dict[str, Any]:
        v = float(self.value)
        return {
            "name": self.name,
            "value": v if np.isfinite(v) else None,
            "paper": None if self.paper is None else float(self.paper),
            "unit": self.unit,
            "note": self.note,
        }


@dataclass
class Claim:
    """A qualitative statement of the paper and whether it holds on our numbers."""

    claim: str
    holds: bool

    def as_dict(self) -> dict[str, Any]:
        return {"claim": self.claim, "holds": bool(self.holds)}


@dataclass
class Summary:
    """What :meth:`Experiment.summarize` returns."""

    metrics: list[Metric] = field(default_factory=list)
    claims: list[Claim] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


class Experiment:
    """Base class of every reproduction.

    Subclasses set the class attributes and implement :meth:`config`,
    :meth:`run_block` and :meth:`summarize`.

    Class attributes
    ----------------
    id : str
        Command-line id, e.g. ``"p000-montecarlo"``.
    paper : str
        Which paper it reproduces (``"000"``..``"004"``, or ``"-"`` for none).
    description : str
        One line for ``radioloc list``.
    data_folder : str or None
        Folder below the data root this experiment reads; ``None`` if it needs no data.
    timing_columns : tuple of str
        Columns of the results frame that measure this machine's speed (CPU seconds).
        They differ from one execution to the next, so the runner writes them to
        ``timings.csv`` and keeps them out of ``results.csv``, which is identical whatever
        the engine; :meth:`summarize` still receives them.
    """

    id: ClassVar[str] = ""
    paper: ClassVar[str] = "-"
    description: ClassVar[str] = ""
    data_folder: ClassVar[str | None] = None
    timing_columns: ClassVar[tuple[str, ...]] = ()

    # ---- to implement -------------------------------------------------------------
    def config(self, full: bool) -> Any:
        """The experiment's configuration (a dataclass) at the quick or full size.

        Must have integer fields ``runs`` (Monte Carlo runs) and ``block_size`` (runs per
        independently seeded block; fixed, so results do not depend on scheduling).
        """
        raise NotImplementedError

    def run_block(self, config: Any, runs: np.ndarray, rng: np.random.Generator) -> pd.DataFrame:
        """Run the Monte Carlo runs with indices ``runs`` (one block) as one batch and
        return a tidy frame with a ``run`` column."""
        raise NotImplementedError

    def summarize(self, config: Any, results: pd.DataFrame, out_dir: Path) -> Summary:
        """Write the figures into ``out_dir`` and return metrics and claims."""
        raise NotImplementedError

    # ---- provided -----------------------------------------------------------------
    def data_path(self) -> Path:
        """The data set folder; raises :class:`DataUnavailable` if it is absent."""
        if self.data_folder is None:
            raise ConfigError(f"{self.id}: this experiment uses no data set")
        path = data_root(self.data_folder) / self.data_folder
        if not path.is_dir():
            from radioloc.io.datasets import missing_message

            raise DataUnavailable(f"{self.id}: skipped, {missing_message(self.data_folder)}")
        return path

    def check_available(self) -> None:
        """Raise :class:`DataUnavailable` if a needed data set is absent."""
        if self.data_folder is not None:
            self.data_path()

    def with_runs(self, config: Any, runs: int | None) -> Any:
        """A copy of ``config`` with ``runs`` replaced (``--runs``)."""
        if runs is None:
            return config
        if runs < 1:
            raise ConfigError(f"--runs: must be >= 1, got {runs}")
        return dataclasses.replace(config, runs=int(runs))

    def with_options(self, config: Any, options: dict[str, str] | None) -> Any:
        """A copy of ``config`` with fields overridden from text (``reproduce -o key=value``).

        Parameters
        ----------
        config : dataclass
            The experiment's configuration at the chosen size.
        options : dict of str to str, optional
            Field name (``name.field`` for a field of a nested config) to its new value
            as text. The text is read as the field's current
            type: bool (``1/0/true/false/yes/no/on/off``), int, float, str, or a tuple
            of numbers or words separated by commas (optionally in parentheses; ``()``
            is the empty tuple).

        Returns
        -------
        dataclass
            The new configuration; unchanged when ``options`` is empty.

        Raises
        ------
        ConfigError
            An unknown field (the message lists the known ones), a value that does not
            read as the field's type, ``runs`` (use ``--runs``), a nested field, or a
            number whose sign leaves the default's class (a positive default must stay
            positive, a non-negative one non-negative).
        """
        if not options:
            return config
        for key, text in options.items():
            if key == "runs":
                raise ConfigError("-o runs: use --runs")
            config = _set_field(self.id, config, key.split("."), key, text)
        return config


def _set_field(exp_id: str, config: Any, path: list[str], key: str, text: str) -> Any:
    """``config`` with the (dotted) field ``path`` set from ``text``."""
    fields = {f.name for f in dataclasses.fields(config)}
    head = path[0]
    if head not in fields:
        where = exp_id if len(path) == len(key.split(".")) else \
            f"{exp_id} {key.rsplit('.', len(path))[0]}"
        raise ConfigError(f"-o {key}: {where} has no such option; known: "
                          f"{', '.join(sorted(k for k in fields if k != 'runs'))}")
    current = getattr(config, head)
    if len(path) > 1:
        if not dataclasses.is_dataclass(current):
            raise ConfigError(f"-o {key}: {head} has no fields")
        value = _set_field(exp_id, current, path[1:], key, text)
    else:
        if dataclasses.is_dataclass(current):
            raise ConfigError(f"-o {key}: set its fields as {key}.FIELD=VALUE; known: "
                              f"{', '.join(f.name for f in dataclasses.fields(current))}")
        optional = _optional_number(type(config), head)
        if optional is not None and text.strip().lower() == "none":
            value = None
        elif optional is not None and current is None:
            value = _read_as(f"-o {key}", text, optional(1))
            if value <= 0:        # an optional number is a positive size or scale
                raise ConfigError(f"-o {key}: must be > 0 (or none), got {value!r}")
        else:
            value = _read_as(f"-o {key}", text, current)
            _check_sign(f"-o {key}", value, current)
    return dataclasses.replace(config, **{head: value})


def _optional_number(cls: type, name: str) -> type | None:
    """``int`` or ``float`` where the field ``name`` of dataclass ``cls`` is annotated as
    that type or None (``-o name=none`` then sets None), else None."""
    import types
    import typing
    try:
        hint = typing.get_type_hints(cls).get(name)
    except Exception:  # noqa: BLE001 - an unresolvable annotation: not an optional number
        return None
    args = set(typing.get_args(hint)) if typing.get_origin(hint) in (typing.Union,
                                                                     types.UnionType) else set()
    if type(None) in args and len(args) == 2:
        (other,) = args - {type(None)}
        if other in (int, float):
            return other
    return None


_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}


def _check_sign(field_name: str, value: Any, current: Any) -> None:
    """Refuse ``value`` when it leaves the sign class of the default ``current``."""
    pairs = (zip(value, current) if isinstance(value, tuple) and isinstance(current, tuple)
             and len(current) else [(value, current)])
    ref = [c for _, c in pairs] if isinstance(value, tuple) else [current]
    vals = list(value) if isinstance(value, tuple) else [value]
    numeric = [c for c in ref if isinstance(c, (int, float, np.integer, np.floating))
               and not isinstance(c, bool)]
    if not numeric or len(numeric) != len(ref):
        return
    if min(numeric) > 0 and min(vals) <= 0:
        raise ConfigError(f"{field_name}: must be > 0, got {value!r}")
    if min(numeric) >= 0 and min(vals) < 0:
        raise ConfigError(f"{field_name}: must be >= 0, got {value!r}")


def _read_as(field_name: str, text: str, current: Any) -> Any:
    """``text`` read as the type of ``current`` (the field's value at the chosen size)."""
    t = text.strip()
    try:
        if isinstance(current, bool):
            if t.lower() in _TRUE | _FALSE:
                return t.lower() in _TRUE
            raise ValueError("expected one of 1/0/true/false/yes/no/on/off")
        if isinstance(current, (int, np.integer)):
            return int(t)
        if isinstance(current, (float, np.floating)):
            value = float(t)
            if not np.isfinite(value):
                raise ValueError("expected a finite number")
            return value
        if isinstance(current, str) or current is None:
            return t
        if isinstance(current, tuple):
            if t.startswith("(") and t.endswith(")"):
                t = t[1:-1].strip()
            items = [s.strip() for s in t.split(",") if s.strip()]
            if not items:
                if not t:                   # "()": the empty tuple
                    return ()
                raise ValueError("expected comma-separated values")
            kinds = {type(v) for v in current}
            if current and kinds <= {int, np.int64}:
                return tuple(int(s) for s in items)
            if current and kinds <= {int, float, np.int64, np.float64}:
                values = tuple(float(s) for s in items)
                if not all(np.isfinite(values)):
                    raise ValueError("expected finite numbers")
                return values
            return tuple(items)
    except ValueError as exc:
        raise ConfigError(f"{field_name}={text!r}: {exc}") from None
    raise ConfigError(f"{field_name}: a {type(current).__name__} field cannot be set from "
                      "the command line")


def data_root(folder: str | None = None) -> Path:
    """Root folder of the real data sets.

    Parameters
    ----------
    folder : str, optional
        A data set folder name: the root returned is the first that holds it.

    Returns
    -------
    Path
        ``$RADIOLOC_DATA`` when set; otherwise the first of the platform cache and the
        ``shared/data`` folder next to the source checkout that holds ``folder`` (or, without
        ``folder``, any known data set), else the first of them (see
        :func:`radioloc.io.datasets.data_roots`). Never relative to the current directory.
    """
    from radioloc.io.datasets import DATASETS, data_roots

    roots = data_roots()
    names = [folder] if folder else list(DATASETS)
    for root in roots:
        if any((root / n).is_dir() for n in names):
            return root
    return roots[0]


_REGISTRY: dict[str, Experiment] = {}


def register(cls: type[Experiment]) -> type[Experiment]:
    """Class decorator: register an experiment under its ``id``."""
    if not cls.id:
        raise ConfigError(f"{cls.__name__}: experiment id is empty")
    if cls.id in _REGISTRY and type(_REGISTRY[cls.id]) is not cls:
        raise ConfigError(f"experiment id {cls.id!r} registered twice")
    _REGISTRY[cls.id] = cls()
    return cls


def registry() -> dict[str, Experiment]:
    """All registered experiments by id (after importing every experiment module)."""
    from radioloc.experiments import discover

    discover()
    return dict(sorted(_REGISTRY.items()))


def get_experiment(exp_id: str) -> Experiment:
    """The registered experiment ``exp_id``; :class:`ConfigError` listing the ids if unknown."""
    reg = registry()
    if exp_id not in reg:
        raise ConfigError(f"unknown experiment {exp_id!r}; known: {', '.join(reg)}")
    return reg[exp_id]
