"""The estimator contract (see ``docs/architecture.md``).

* Settings go to the constructor and are validated there (a bad setting raises
  :class:`~radioloc.core.errors.ConfigError` or :class:`~radioloc.core.errors.InputError`
  at construction, not at the first call).
* A *snapshot* estimator has ``locate(measurements, ...) -> Estimate``.
* A *recursive* estimator has ``init(...) -> state``, ``step(state, measurements_t, ...)
  -> state`` (pure: the input state is not modified; batched over leading axes),
  ``estimate(state) -> Estimate`` and ``run(...) -> Track``.
* Batch axes lead, time follows, coordinates last; positions are ``(x, y[, z])``.
* A missing measurement is NaN and is skipped: never an error, never a NaN estimate.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from radioloc.core.results import Estimate, Track

__all__ = ["SnapshotEstimator", "RecursiveEstimator", "Tags", "layout_track"]


def layout_track(layout: Any, means: np.ndarray, covs: np.ndarray, time: np.ndarray,
                 diagnostics: Mapping[str, np.ndarray], step_axes: Mapping[str, int | None]
                 ) -> Track:
    """The :class:`Track` of a filter's or smoother's states over a state layout: the
    position and its covariance (:meth:`StateLayout.position_moments`); for a network of
    ``K`` nodes (:class:`~radioloc.models.pair_range.NetworkLayout`) one track per node,
    the node axis before the time axis (``position (..., K, T, D)``), the time and the
    diagnostics given an axis of 1 there.

    Parameters
    ----------
    layout : StateLayout
    means : ndarray, shape (..., T, n)
    covs : ndarray, shape (..., T, n, n)
    time : ndarray, shape (T,) or (..., T)
    diagnostics : mapping of str to ndarray
    step_axes : mapping of str to int or None
        Per diagnostic: the axes after its time axis (``state`` 1, ``state_covariance``
        2, ``nis`` 0), or None for one value per run (no time axis).

    Returns
    -------
    Track
    """
    pos, cov = layout.position_moments(means, covs)
    if pos.ndim == means.ndim:
        return Track(pos, cov, time, dict(diagnostics))
    pos, cov = np.moveaxis(pos, -2, -3), np.moveaxis(cov, -3, -4)
    time = np.asarray(time)
    if time.ndim > 1:
        time = time[..., None, :]

    def node_axis(key, value):
        after = step_axes[key]
        return value[..., None] if after is None else np.expand_dims(value, -2 - after)
    return Track(pos, cov, time, {k: node_axis(k, v) for k, v in diagnostics.items()})


@dataclass(frozen=True)
class Tags:
    """What an estimator supports (scikit-learn's estimator tags), read by the contract
    tests and by ``radioloc methods``.

    Attributes
    ----------
    kinds : tuple of str or None
        Measurement kinds it takes (``"range"``, ``"tdoa"``, ``"aoa"``, ``"rss"``, ...);
        None: any :class:`~radioloc.models.measurement.MeasurementModel`.
    uses : {"jacobian", "logpdf"}
        What it needs of a model: ``"jacobian"`` (Gaussian linearisation: ``predict``,
        ``jacobian``, ``noise_cov``) or ``"logpdf"`` (any density: ``predict``,
        ``logpdf``, ``sample``).
    dims : tuple of int
        Position dimensions it supports.
    recursive : bool
        Whether it filters over time (``run -> Track``) or fits one epoch
        (``locate -> Estimate``).
    missing : str
        What a NaN measurement does: ``"skip"`` (the row is left out).
    modes : bool
        Whether it integrates a model's discrete per-row states (LOS/NLOS).
    generic : bool
        Whether it takes :class:`~radioloc.models.measurement.Observation` inputs of any
        model it supports (the generic estimators), or only its paper's arrays.
    reads : tuple of str or None
        State components it can estimate (names of
        :data:`~radioloc.models.measurement.COMPONENTS`); a model that reads another is
        refused. None: any (the state grows to what the models read).
    """

    kinds: tuple[str, ...] | None = ("range",)
    uses: str = "jacobian"
    dims: tuple[int, ...] = (2, 3)
    recursive: bool = False
    missing: str = "skip"
    modes: bool = False
    generic: bool = False
    reads: tuple[str, ...] | None = None

    def accepts(self, model: Any) -> bool:
        """Whether a measurement model fits these tags (its kind, and what it offers)."""
        if self.kinds is not None and getattr(model, "kind", None) not in self.kinds:
            return False
        if self.uses == "jacobian" and not getattr(model, "gaussian", True):
            return False  # a likelihood-only model has no h(x) to linearise
        if self.reads is not None and not set(getattr(model, "reads", ())) <= set(self.reads):
            return False
        need = ("predict", "jacobian", "noise_cov") if self.uses == "jacobian" else ("predict", "logpdf")
        return all(hasattr(model, n) for n in need)

    def require(self, model: Any, where: str, estimator: str) -> None:
        """Refuse a model these tags do not accept.

        Parameters
        ----------
        model : MeasurementModel
        where : str
            The argument it came in (``"observations[0].model"``), for the message.
        estimator : str
            The estimator's class name, for the message.

        Raises
        ------
        ConfigError
            Naming the model, its kind and what the estimator needs.
        """
        if self.accepts(model):
            return
        from radioloc.core.errors import ConfigError
        kind = getattr(model, "kind", None)
        if self.kinds is not None and kind not in self.kinds:
            why = f"kind {kind!r} is not one of {', '.join(self.kinds)}"
        elif self.reads is not None and not set(getattr(model, "reads", ())) <= set(self.reads):
            extra = sorted(set(model.reads) - set(self.reads))
            why = f"it reads {', '.join(extra)}, which the estimator's state does not hold"
        elif self.uses == "jacobian":
            why = ("it has no measurement function to linearise (a likelihood-only model: use "
                   "an estimator whose tags.uses is 'logpdf')")
        else:
            why = "it lacks predict/logpdf"
        raise ConfigError(f"{where}: {estimator} does not take {type(model).__name__}: {why}")


class SnapshotEstimator:
    """Base class of one-epoch estimators: ``locate(...) -> Estimate``."""

    #: how the estimator is named in tables and on the command line
    name: str = ""
    #: what it supports (see :class:`Tags`)
    tags: Tags = Tags()

    def locate(self, *args: Any, **kwargs: Any) -> Estimate:  # pragma: no cover - abstract
        """Estimate positions for a batch of problems.

        Returns
        -------
        Estimate
        """
        raise NotImplementedError

    def get_params(self) -> dict[str, Any]:
        """The constructor settings (scikit-learn habit).

        Returns
        -------
        dict
            Public attributes set in ``__init__``.
        """
        return {k: v for k, v in vars(self).items() if not k.startswith("_")}

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"


class RecursiveEstimator(SnapshotEstimator):
    """Base class of filters: ``init``, ``step``, ``estimate`` and ``run``."""

    tags: Tags = Tags(recursive=True)

    def init(self, *args: Any, **kwargs: Any) -> Any:  # pragma: no cover - abstract
        """The filter state before the first measurement.

        Returns
        -------
        state
        """
        raise NotImplementedError

    def step(self, state: Any, *args: Any, **kwargs: Any) -> Any:  # pragma: no cover
        """Advance every run of the batch by one time step.

        Parameters
        ----------
        state
            The current state (not modified).

        Returns
        -------
        state
            A new state.
        """
        raise NotImplementedError

    def estimate(self, state: Any) -> Estimate:  # pragma: no cover - abstract
        """The position estimate held by a state.

        Parameters
        ----------
        state

        Returns
        -------
        Estimate
        """
        raise NotImplementedError

    def run(self, *args: Any, **kwargs: Any) -> Track:  # pragma: no cover - abstract
        """Filter a whole series.

        Returns
        -------
        Track
        """
        raise NotImplementedError

    def locate(self, *args: Any, **kwargs: Any) -> Estimate:
        """A recursive estimator locates by running and keeping the last step.

        Returns
        -------
        Estimate
            The last step of :meth:`run`.
        """
        track = self.run(*args, **kwargs)
        return track.at(track.steps - 1)
