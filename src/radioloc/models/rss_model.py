"""Received signal strength as a measurement model.

- :class:`RssModel`: the log-distance Gaussian channel
  (:class:`~radioloc.models.rssi_logdistance.LogDistanceGaussian`) as a Gaussian
  measurement function ``h(x) = a - 10 n log10(max(|x - a_k|, d_ref))`` with standard
  deviation ``s`` and the Jacobian ``-10 n / (ln 10 d) u`` (``u`` the unit vector from the
  anchor; zero inside ``d_ref``, where the mean is flat). Any estimator takes it.
- :class:`AnchorRssModel`: the same log-distance model with its own ``a``, ``n`` and ``s``
  for every anchor (indexed by the context's anchor-table rows), e.g. self-calibrated
  access points (:mod:`radioloc.locate.path_loss`).
- :class:`TrapezoidRssModel`: the data-driven trapezoids of paper 003
  (:class:`~radioloc.models.rssi_trapezoid.TrapezoidModel`) as a likelihood on positions,
  ``log L(|x - a_k| | rssi)`` (Sect. III-A, normalised over the distance): it has no
  measurement function, so only estimators that use a model's ``logpdf``
  (``Tags.uses == "logpdf"``: particle and grid filters) take it. Outside a trapezoid the
  log-likelihood is ``-inf``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.kinds import Kind
from radioloc.core.validation import check_positive
from radioloc.models.measurement import Context, LikelihoodModel, MeasurementModel, checked_call
from radioloc.models.ranging import range_geometry
from radioloc.models.rssi_logdistance import LogDistanceGaussian
from radioloc.models.rssi_trapezoid import TrapezoidModel

__all__ = ["RssModel", "AnchorRssModel", "TrapezoidRssModel"]

_LN10 = float(np.log(10.0))


@dataclass(frozen=True)
class RssModel(MeasurementModel):
    """Log-distance Gaussian RSS to an anchor, in the channel model's unit (dBm or 0..100).

    Parameters
    ----------
    model : LogDistanceGaussian
        The channel: mean ``a - 10 n log10(max(d, d_ref_m))``, standard deviation ``s``.

    Examples
    --------
    >>> import numpy as np
    >>> rss = RssModel(LogDistanceGaussian(a=-40.0, n=2.0, s=4.0))
    >>> ctx = Context(points=np.array([[0.0, 0.0]]))
    >>> rss.predict({"position": np.array([10.0, 0.0])}, ctx).tolist()
    [-60.0]
    """

    model: LogDistanceGaussian

    kind: ClassVar[str] = "rss"

    def __post_init__(self) -> None:
        if not isinstance(self.model, LogDistanceGaussian):
            raise InputError(f"model: expected a LogDistanceGaussian, got "
                             f"{type(self.model).__name__}")

    def predict(self, state, context: Context) -> np.ndarray:
        d, _ = range_geometry(state["position"], context.points, context.height_m)
        return self.model.mean(d)

    def jacobian(self, state, context: Context) -> dict[str, np.ndarray]:
        d, u = range_geometry(state["position"], context.points, context.height_m)
        slope = np.where(d > self.model.d_ref_m,
                         -10.0 * self.model.n / (_LN10 * np.maximum(d, self.model.d_ref_m)), 0.0)
        return {"position": slope[..., None] * u}

    def std(self, context: Context) -> np.ndarray:
        return self.row_std(self.model.s, context)


@dataclass(frozen=True, eq=False)
class AnchorRssModel(MeasurementModel):
    """Log-distance Gaussian RSS with parameters per anchor:
    ``h(x) = a_k - 10 n_k log10(max(|x - p_k|, d_ref_m))``, standard deviation ``s_k``, for
    the row of anchor ``k`` (``context.index``).

    Parameters
    ----------
    a_dbm : array_like, shape (A,)
        Mean RSS at 1 m of each anchor of the table.
    n : array_like, shape (A,)
        Path-loss exponents.
    s_db : array_like, shape (A,)
        Residual standard deviations (> 0).
    d_ref_m : float
        Distances below this read as ``d_ref_m``, metres.

    Examples
    --------
    >>> import numpy as np
    >>> rss = AnchorRssModel([-40.0, -30.0], [2.0, 3.0], [4.0, 4.0])
    >>> ctx = Context(points=np.array([[0.0, 0.0], [0.0, 10.0]]), index=np.array([0, 1]))
    >>> rss.predict({"position": np.array([10.0, 10.0])}, ctx).round(1).tolist()
    [-63.0, -60.0]
    """

    a_dbm: np.ndarray
    n: np.ndarray
    s_db: np.ndarray
    d_ref_m: float = 1.0

    kind: ClassVar[str] = "rss"

    def __post_init__(self) -> None:
        for name in ("a_dbm", "n", "s_db"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.ndim != 1 or not np.all(np.isfinite(v)):
                raise InputError(f"{name}: expected one finite value per anchor, got {v}")
            object.__setattr__(self, name, v)
        if not self.a_dbm.shape == self.n.shape == self.s_db.shape:
            raise InputError(f"a_dbm, n, s_db: one value per anchor each, got shapes "
                             f"{self.a_dbm.shape}, {self.n.shape}, {self.s_db.shape}")
        if np.any(self.s_db <= 0):
            raise InputError(f"s_db: standard deviations must be > 0, got {self.s_db}")
        check_positive(self.d_ref_m, "d_ref_m")

    def _of(self, values: np.ndarray, context: Context) -> np.ndarray:
        if context.index is None or np.any(context.index < 0) or np.any(
                context.index >= values.size):
            raise InputError(f"context.index: every row needs its anchor's row in the table of "
                             f"{values.size} anchors with RSS parameters")
        return values[context.index]

    def predict(self, state, context: Context) -> np.ndarray:
        d, _ = range_geometry(state["position"], context.points, context.height_m)
        return (self._of(self.a_dbm, context)
                - 10.0 * self._of(self.n, context) * np.log10(np.maximum(d, self.d_ref_m)))

    def jacobian(self, state, context: Context) -> dict[str, np.ndarray]:
        d, u = range_geometry(state["position"], context.points, context.height_m)
        slope = np.where(d > self.d_ref_m, -10.0 * self._of(self.n, context)
                         / (_LN10 * np.maximum(d, self.d_ref_m)), 0.0)
        return {"position": slope[..., None] * u}

    def std(self, context: Context) -> np.ndarray:
        return self.row_std(self._of(self.s_db, context), context)


@dataclass(frozen=True)
class TrapezoidRssModel(LikelihoodModel):
    """Likelihood-only RSS model over paper 003's trapezoids (see the module docstring).

    Parameters
    ----------
    model : TrapezoidModel
        Per-RSSI trapezoids; readings are integers 0..100 (map dBm with
        :func:`~radioloc.models.rssi_trapezoid.dbm_to_rssi100`).
    """

    model: TrapezoidModel

    kind: ClassVar[str] = "rss"

    def __post_init__(self) -> None:
        if not isinstance(self.model, TrapezoidModel):
            raise InputError(f"model: expected a TrapezoidModel, got {type(self.model).__name__}")

    def sample(self, state, context: Context, rng: np.random.Generator) -> np.ndarray:
        self.refuse("sampler of readings")

    def logpdf(self, z, state, context: Context) -> np.ndarray:
        """``log L(|x - a| | rssi)`` per row ``(..., m)`` (NaN rows give 0; ``-inf`` outside
        the trapezoid).

        Parameters
        ----------
        z : ndarray, shape (..., m)
            Readings, integers 0..100 (NaN: missing).
        state : dict
            Named components of a batch of states.
        context : Context

        Returns
        -------
        ndarray, shape (..., m)
        """
        z = checked_call(z, state, context, self.reads)
        miss = np.isnan(z)
        d, _ = range_geometry(state["position"], context.points, context.height_m)
        rssi = np.where(miss, 0.0, z)
        lp = self.model.logpdf(d, rssi)
        return np.where(miss, 0.0, lp)


#: The log-schema kind this module explains (:mod:`radioloc.core.kinds`): its model, a
#: path-loss model per anchor, is built from the anchors file's columns.
KINDS = (Kind("rss", "dBm", "received signal strength from `peer`",
              anchor_columns=("rss_a_dbm", "rss_n", "rss_std_db"), slips=()),)
