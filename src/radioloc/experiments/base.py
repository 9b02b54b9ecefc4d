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


#: Confidence level of every interval the experiments report (claims and metrics).
LEVEL = 0.95
#: The three verdicts of a claim.
HOLDS, FAILS, UNDECIDED = "holds", "does not hold", "undecided at this size"


def _finite(values: Any) -> np.ndarray:
    """The finite entries of ``values`` as a flat float array."""
    x = np.asarray(values, dtype=float).ravel()
    return x[np.isfinite(x)]


def mean_interval(values: Any, level: float = LEVEL) -> tuple[float, float, float, int]:
    """Mean over runs and its Student-t confidence interval.

    Parameters
    ----------
    values : array_like or pandas.Series
        One number per run; non-finite entries are left out.
    level : float
        Confidence level of the interval (0.95: 95 %).

    Returns
    -------
    mean, low, high : float
        The mean and the interval's ends (NaN ends with fewer than two values; the interval
        is the single point when every value is equal).
    n : int
        Runs used.
    """
    from scipy.stats import t as student_t

    x = _finite(values)
    n = int(x.size)
    if n == 0:
        return np.nan, np.nan, np.nan, 0
    mean = float(x.mean())
    if n < 2:
        return mean, np.nan, np.nan, n
    half = float(student_t.ppf(0.5 + level / 2, n - 1) * x.std(ddof=1) / np.sqrt(n))
    return mean, mean - half, mean + half, n


def median_interval(values: Any, level: float = LEVEL) -> tuple[float, float, float, int]:
    """Median over runs and its distribution-free confidence interval.

    The interval's ends are the order statistics ``x_(j)``, ``x_(k)`` whose binomial
    coverage ``P(j <= B < k)``, ``B ~ Bin(n, 1/2)``, is at least ``level`` (the narrowest
    symmetric pair; the whole range when ``n`` is too small to reach ``level``).

    Parameters
    ----------
    values : array_like or pandas.Series
        One number per run; non-finite entries are left out.
    level : float
        Confidence level of the interval.

    Returns
    -------
    median, low, high : float
        The median and the interval's ends (NaN ends with fewer than two values).
    n : int
        Runs used.
    """
    from scipy.stats import binom

    x = np.sort(_finite(values))
    n = int(x.size)
    if n == 0:
        return np.nan, np.nan, np.nan, 0
    med = float(np.median(x))
    if n < 2:
        return med, np.nan, np.nan, n
    j = int(binom.ppf((1 - level) / 2, n, 0.5))        # P(B < j) <= (1 - level) / 2
    j = max(j - 1, 0)
    while j > 0 and binom.cdf(n - j - 1, n, 0.5) - binom.cdf(j - 1, n, 0.5) < level:
        j -= 1
    return med, float(x[j]), float(x[n - 1 - j]), n


def paired_differences(a: Any, b: Any) -> np.ndarray:
    """Per-run differences ``a - b`` over the runs where both are finite.

    Parameters
    ----------
    a, b : pandas.Series indexed by run, or array_like of equal shape
        One number per run of each setting; Series are matched on their index (the run).

    Returns
    -------
    ndarray
        The finite differences.
    """
    if isinstance(a, pd.Series) and isinstance(b, pd.Series):
        d = a.astype(float).sub(b.astype(float)).to_numpy()
    else:
        a_, b_ = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        if a_.shape != b_.shape:
            raise ConfigError(f"paired comparison: {a_.shape} runs against {b_.shape}")
        d = a_ - b_
    return _finite(d)


def per_run(frame: pd.DataFrame, column: str, by: tuple[str, ...] = ("run",)) -> pd.Series:
    """The mean of ``column`` over the rows of each run: one number per run for a claim
    or a metric with its interval.

    Parameters
    ----------
    frame : pandas.DataFrame
        Tidy rows with the ``by`` columns.
    column : str
        The column to average.
    by : tuple of str
        The columns naming one unit (``("run",)``; e.g. ``("run", "vehicle")`` where the
        runs are too few and the units inside a run are independent draws).

    Returns
    -------
    pandas.Series
        Indexed by ``by``: the units of two settings pair on it.
    """
    return frame.groupby(list(by))[column].mean()


def seed_agreement(estimates: Any, lows: Any, highs: Any) -> tuple[float, float]:
    """How the intervals of independent repetitions (seeds) of one experiment agree.

    Parameters
    ----------
    estimates, lows, highs : array_like (S,)
        One estimate and its interval's ends per seed (seeds with a non-finite entry are
        left out).

    Returns
    -------
    coverage : float
        Fraction of the seeds whose interval holds the mean of every seed's estimate (a
        stand-in for the true value, from S times the runs): near the level for honest
        intervals.
    misses : float
        Fraction of the ordered pairs ``(i, j)``, ``i != j``, in which seed ``j``'s estimate
        lies outside seed ``i``'s interval: about 0.17 for honest 95 % intervals over many
        units (``P(|Z| > 1.96 / sqrt 2)``), a little less over few (Student t), far more
        where the units of an interval are not independent.
    """
    e, lo, hi = (np.asarray(a, dtype=float).ravel() for a in (estimates, lows, highs))
    ok = np.isfinite(e) & np.isfinite(lo) & np.isfinite(hi)
    e, lo, hi = e[ok], lo[ok], hi[ok]
    if e.size < 2:
        raise ConfigError(f"seed_agreement: needs at least 2 seeds with an interval, got {e.size}")
    ref = e.mean()
    coverage = float(np.mean((lo <= ref) & (ref <= hi)))
    outside = (e[None, :] < lo[:, None]) | (e[None, :] > hi[:, None])
    misses = float(outside[~np.eye(e.size, dtype=bool)].mean())
    return coverage, misses


@dataclass
class Metric:
    """One number of the reproduction, beside the paper's where it has one.

    ``ci`` is the confidence interval (at :data:`LEVEL`) of ``value`` over the runs, where
    the value is a statistic over runs (see :meth:`over_runs`). ``predicted`` is non-empty
    where the paper itself predicts this number to depart (e.g. a method it says may
    diverge): the text says where, and the report shows the departure apart from our gaps.
    """

    name: str
    value: float
    paper: float | None = None
    unit: str = ""
    note: str = ""
    ci: tuple[float, float] | None = None
    predicted: str = ""

    @classmethod
    def over_runs(cls, name: str, values: Any, paper: float | None = None, unit: str = "",
                  note: str = "", stat: str = "mean") -> "Metric":
        """The mean (or median, or root mean) of one number per run, with its confidence
        interval.

        Parameters
        ----------
        name, paper, unit, note
            As the fields.
        values : array_like or pandas.Series
            One number per run (non-finite ones left out); squared errors for ``"rms"``.
        stat : {"mean", "median", "rms"}
            Mean with its t interval, median with its order-statistic interval, or the root
            of the mean (an RMSE from per-run squared errors) with the roots of the mean's
            t interval (a negative lower end read as 0).

        Returns
        -------
        Metric
        """
        if stat not in ("mean", "median", "rms"):
            raise ConfigError("Metric.over_runs: stat must be 'mean', 'median' or 'rms', "
                              f"got {stat!r}")
        value, low, high, _ = (median_interval if stat == "median" else mean_interval)(values)
        if stat == "rms":
            value, low, high = (float(np.sqrt(max(v, 0.0))) if np.isfinite(v) else v
                                for v in (value, low, high))
        return cls(name, value, paper, unit, note, (low, high))

    def as_dict(self) -> dict[str, Any]:
        v = float(self.value)
        lo, hi = (np.nan, np.nan) if self.ci is None else map(float, self.ci)
        return {
            "name": self.name,
            "value": v if np.isfinite(v) else None,
            "paper": None if self.paper is None else float(self.paper),
            "unit": self.unit,
            "note": self.note,
            "ci_low": lo if np.isfinite(lo) else None,
            "ci_high": hi if np.isfinite(hi) else None,
            "predicted": self.predicted,
        }


@dataclass
class Claim:
    """A qualitative statement of the paper and its verdict on our numbers.

    A claim is decided on a mean over runs of one number per run (a paired difference of
    two settings, or one setting's number against a bound): ``estimate`` is that mean,
    ``ci`` its confidence interval at ``level``, ``n`` the runs. It **holds** when the whole
    interval lies where the claim says, **does not hold** when the whole interval lies
    outside, and is **undecided at this size** otherwise (``holds`` is then None). Build
    claims with :meth:`lower`, :meth:`below`, :meth:`above`, :meth:`within` and
    :meth:`all_of`; ``Claim(text, holds)`` remains for a statement with no runs to average
    over (``ci`` stays None).
    """

    claim: str
    holds: bool | None
    estimate: float = np.nan
    ci: tuple[float, float] | None = None
    n: int = 0
    unit: str = ""
    level: float = LEVEL
    what: str = ""
    parts: tuple["Claim", ...] = ()

    @property
    def verdict(self) -> str:
        """``"holds"``, ``"does not hold"`` or ``"undecided at this size"``."""
        return UNDECIDED if self.holds is None else HOLDS if self.holds else FAILS

    @classmethod
    def decide(cls, claim: str, values: Any, low: float = -np.inf, high: float = np.inf,
               unit: str = "", what: str = "mean", level: float = LEVEL,
               stat: str = "mean") -> "Claim":
        """The claim "the mean (or median) of ``values`` lies in (``low``, ``high``]", over runs.

        Parameters
        ----------
        claim : str
            The statement.
        values : array_like
            One number per run (non-finite ones left out).
        low, high : float
            The interval the claim puts the mean in.
        unit, what : str
            Unit of ``values`` and what their mean is (shown beside the interval).
        level : float
            Confidence level.
        stat : {"mean", "median"}
            The statistic: the mean (t interval) or the median (order-statistic interval).

        Returns
        -------
        Claim
            Holds if the confidence interval lies inside (``low``, ``high``], does not hold
            if it lies outside, else undecided (also with fewer than two runs).
        """
        if stat not in ("mean", "median"):
            raise ConfigError(f"Claim.decide: stat must be 'mean' or 'median', got {stat!r}")
        mean, lo, hi, n = (mean_interval if stat == "mean" else median_interval)(values, level)
        if not (np.isfinite(lo) and np.isfinite(hi)):
            holds = None
        elif lo > low and hi <= high:
            holds = True
        elif hi <= low or lo > high:
            holds = False
        else:
            holds = None
        return cls(claim, holds, mean, (lo, hi), n, unit, level, what)

    @classmethod
    def lower(cls, claim: str, a: Any, b: Any, margin: float = 0.0, unit: str = "",
              level: float = LEVEL, stat: str = "mean") -> "Claim":
        """"``a`` is lower than ``b`` (by more than ``margin``)", paired over runs.

        Parameters
        ----------
        claim : str
            The statement.
        a, b : pandas.Series indexed by run, or array_like of equal shape
            One number per run of each setting (same runs: a paired comparison).
        margin : float
            Difference ``b - a`` the claim requires (0: ``a`` lower at all).
        unit : str
            Unit of ``a`` and ``b``.
        level : float
            Confidence level.
        stat : {"mean", "median"}
            Decide on the mean or the median of the paired differences.

        Returns
        -------
        Claim
            Decided on the mean (median) of ``b - a`` over the runs where both are finite.
        """
        return cls.decide(claim, paired_differences(b, a), low=margin, unit=unit,
                          what=f"{stat} paired difference", level=level, stat=stat)

    @classmethod
    def below(cls, claim: str, values: Any, bound: float, unit: str = "",
              level: float = LEVEL, stat: str = "mean") -> "Claim":
        """"The mean (or median) of ``values`` is at most ``bound``", over runs."""
        return cls.decide(claim, values, high=bound, unit=unit, level=level, stat=stat,
                          what=stat)

    @classmethod
    def above(cls, claim: str, values: Any, bound: float, unit: str = "",
              level: float = LEVEL, stat: str = "mean") -> "Claim":
        """"The mean (or median) of ``values`` is above ``bound``", over runs."""
        return cls.decide(claim, values, low=bound, unit=unit, level=level, stat=stat,
                          what=stat)

    @classmethod
    def within(cls, claim: str, a: Any, b: Any, rel_tol: float, unit: str = "",
               level: float = LEVEL, stat: str = "mean") -> "Claim":
        """"``a`` and ``b`` are equal within ``rel_tol`` of ``b``'s mean", paired over runs.

        Holds if the interval of the mean of ``a - b`` lies within +- ``rel_tol`` x the
        mean of ``b`` (an equivalence test), does not hold if it lies outside.
        """
        centre = np.mean if stat == "mean" else np.median
        tol = rel_tol * abs(float(centre(_finite(b)))) if _finite(b).size else np.nan
        return cls.decide(claim, paired_differences(a, b), low=-tol, high=tol, unit=unit,
                          what=f"{stat} paired difference", level=level, stat=stat)

    @classmethod
    def all_of(cls, claim: str, parts: list["Claim"]) -> "Claim":
        """A claim that holds when every part holds (e.g. a monotone chain of pairs).

        Does not hold when some part does not hold, else is undecided. The interval shown
        is that of the deciding part: the first that does not hold, else the first
        undecided one, else the one with the widest interval below its mean. Which part
        decides can differ between repetitions, so each part's own estimate and interval
        are kept (``parts``, in ``summary.json``): those are what repetitions compare.
        """
        if not parts:
            raise ConfigError(f"Claim.all_of: {claim!r} has no parts")
        fails = [p for p in parts if p.holds is False]
        open_ = [p for p in parts if p.holds is None]
        if fails:
            key, holds = fails[0], False
        elif open_:
            key, holds = open_[0], None
        else:
            key, holds = min(parts, key=lambda p: p.ci[0] - p.estimate), True
        return cls(claim, holds, key.estimate, key.ci, key.n, key.unit, key.level,
                   f"{key.what} of the deciding step ({len(parts)} steps)", tuple(parts))

    def as_dict(self) -> dict[str, Any]:
        lo, hi = (np.nan, np.nan) if self.ci is None else map(float, self.ci)
        est = float(self.estimate)
        return {"claim": self.claim, "holds": None if self.holds is None else bool(self.holds),
                "verdict": self.verdict,
                "estimate": est if np.isfinite(est) else None,
                "ci_low": lo if np.isfinite(lo) else None,
                "ci_high": hi if np.isfinite(hi) else None,
                "level": float(self.level), "n": int(self.n), "unit": self.unit,
                "what": self.what,
                **({"parts": [p.as_dict() for p in self.parts]} if self.parts else {})}


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
