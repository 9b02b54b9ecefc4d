"""Time difference of arrival (TDoA) against a reference anchor, in metres.

A row ``i`` is the difference of two arrival times multiplied by the speed of light, the
range difference

    h_i(x) = |x - a_i| - |x - a_ref(i)|  (+ clock_drift * (slot_s[i] - slot_s[ref(i)]))

Noise
-----
Each arrival time carries an independent Gaussian error (in metres) ``e_a ~ N(0, s^2)``;
a row is ``e_i - e_ref``. Rows that share a reference anchor share its error, so the
differencing correlates them:

    R = s^2 (I + S),    S_ij = [ref(i) == ref(j)]

(``R = s^2 (I + 1 1^T)`` for one reference): each difference has variance ``2 s^2`` and two
differences with the same reference have correlation coefficient ``1/2``. ``std_m`` is ``s``,
the standard deviation of ONE arrival time; :meth:`TdoaModel.std` is a row's, ``sqrt(2)
std_m``. A per-row ``Context.std`` (a log's per-row sigma) is the standard deviation of that
row's difference, ``sigma_i``; the rows keep the correlation of differencing,
``R_ij = sigma_i sigma_j (delta_ij + (1 - delta_ij) S_ij / 2)`` (exact when the arrival errors
of a reference's rows are equal, positive definite always). Rows share a reference when their
``reference_index`` is equal (or, without indices, their ``reference`` points are).

:meth:`TdoaModel.logpdf` is the exact joint density of the correlated rows, split into per-row
terms by the chain rule (row ``i`` given rows ``< i``), so the terms of the observed rows sum to
the log-density of what was observed (a NaN row gives 0 and drops out of the others).

Clock terms
-----------
The receiver's clock offset cancels in a difference of two arrival times at the same
receiver: TDoA with synchronised anchors needs no clock state. The clock's *drift* does not
cancel when the two signals were sent at different times (a tag listening to anchors that
transmit in turn, as in UWB downlink TDoA): over the known interval ``tau_i`` between the
reference's transmission and anchor ``i``'s, the tag's clock gains ``drift * tau_i`` metres
(``drift`` is the fractional frequency error times the speed of light, m/s, the
``clock_drift`` state component of :class:`~radioloc.models.measurement.StateLayout`). Give
each anchor's transmission time within the frame as ``slot_s`` (seconds, one per anchor of
the anchor table, indexed by ``Context.index`` and ``Context.reference_index``, so a subset
of rows keeps its intervals) and the model reads ``clock_drift``; evolve it with
:class:`~radioloc.models.clock.ClockModel`. The scale error of the range
difference itself, ``(drift / c) (d_i - d_ref)``, is below ``1e-4`` m for drifts of tens of
ppm over tens of metres and is left out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from radioloc.core.kinds import Kind, Slip, unit_slips
from radioloc.core.plausibility import check_tdoa
from radioloc.core.errors import InputError
from radioloc.core.validation import as_float_array, check_positive
from radioloc.models.measurement import (
    Context,
    MeasurementModel,
    checked_call,
    gaussian_logpdf,
)
from radioloc.models.ranging import range_geometry

__all__ = ["TdoaModel", "shared_reference"]


def shared_reference(context: Context) -> np.ndarray:
    """Which rows share a reference anchor, ``(..., m, m)`` booleans.

    Parameters
    ----------
    context : Context
        With ``reference`` (and optionally ``reference_index``).

    Returns
    -------
    ndarray of bool
    """
    if context.reference_index is not None:
        idx = context.reference_index
        return idx[:, None] == idx[None, :]
    ref = context.reference
    return np.all(ref[..., :, None, :] == ref[..., None, :, :], axis=-1)


# eq=False: the settings hold arrays, so instances compare and hash by identity
@dataclass(frozen=True, eq=False)
class TdoaModel(MeasurementModel):
    """Range difference to anchor ``i`` minus the reference anchor, metres (see the module
    docstring for the correlated noise and the clock term).

    Parameters
    ----------
    std_m : float
        Standard deviation of one arrival time, metres (> 0); a difference has
        ``sqrt(2) std_m``.
    slot_s : array_like, shape (A,), optional
        Transmission time of each anchor of the anchor table within a frame, seconds: with
        it a row's interval is ``slot_s[index] - slot_s[reference_index]`` and the model
        reads the tag's ``clock_drift`` (m/s).

    Examples
    --------
    >>> import numpy as np
    >>> from radioloc.models.measurement import Context, StateLayout
    >>> ctx = Context(points=np.array([[10.0, 0.0], [0.0, 10.0]]),
    ...               reference=np.zeros((2, 2)))
    >>> model = TdoaModel(std_m=0.1)
    >>> model.predict({"position": np.array([3.0, 4.0])}, ctx).round(3).tolist()
    [3.062, 1.708]
    >>> (model.noise_cov(ctx) / 0.01).round(6).tolist()
    [[2.0, 1.0], [1.0, 2.0]]
    """

    std_m: float
    slot_s: np.ndarray | None = None

    kind: ClassVar[str] = "tdoa"

    def __post_init__(self) -> None:
        check_positive(self.std_m, "std_m")
        if self.slot_s is not None:
            object.__setattr__(self, "slot_s", as_float_array(self.slot_s, "slot_s", ndim=1))

    @property
    def reads(self) -> tuple[str, ...]:  # type: ignore[override]
        return ("position",) if self.slot_s is None else ("position", "clock_drift")

    def _check(self, context: Context) -> None:
        if context.reference is None:
            raise InputError("context.reference: a TDoA row needs its reference anchor "
                             "(Context(points=anchor_i, reference=anchor_ref))")

    def interval_s(self, context: Context) -> np.ndarray:
        """Time from each row's reference transmission to its anchor's, seconds ``(m,)``.

        Parameters
        ----------
        context : Context
            With ``index`` and ``reference_index`` (rows of ``slot_s``).

        Returns
        -------
        ndarray, shape (m,)
        """
        A = self.slot_s.size
        for name in ("index", "reference_index"):
            idx = getattr(context, name)
            if idx is None or np.any((idx < 0) | (idx >= A)):
                raise InputError(f"context.{name}: a TDoA model with slot_s needs the anchor-"
                                 f"table row (0..{A - 1}) of every row's "
                                 f"{'anchor' if name == 'index' else 'reference'}")
        return self.slot_s[context.index] - self.slot_s[context.reference_index]

    def predict(self, state, context: Context) -> np.ndarray:
        self._check(context)
        x = state["position"]
        d_i, _ = range_geometry(x, context.points, context.height_m)
        d_r, _ = range_geometry(x, context.reference, context.height_m)
        z = d_i - d_r
        if self.slot_s is not None:
            z = z + np.asarray(state["clock_drift"], dtype=float)[..., None] * self.interval_s(context)
        return z

    def jacobian(self, state, context: Context) -> dict[str, np.ndarray]:
        self._check(context)
        x = state["position"]
        _, u_i = range_geometry(x, context.points, context.height_m)
        _, u_r = range_geometry(x, context.reference, context.height_m)
        out = {"position": u_i - u_r}
        if self.slot_s is not None:
            out["clock_drift"] = np.broadcast_to(self.interval_s(context)[:, None],
                                                 out["position"].shape[:-1] + (1,))
        return out

    def std(self, context: Context) -> np.ndarray:
        """Standard deviation of each difference, ``sqrt(2) std_m`` (the context's per-row
        value where given).

        Parameters
        ----------
        context : Context

        Returns
        -------
        ndarray, shape (..., m)
        """
        return self.row_std(np.sqrt(2.0) * self.std_m, context)

    def noise_cov(self, context: Context) -> np.ndarray:
        """``R_ij = sigma_i sigma_j (delta_ij + (1 - delta_ij) [ref(i) == ref(j)] / 2)``,
        ``(..., m, m)`` (``std_m^2 (I + S)`` without per-row values).

        Parameters
        ----------
        context : Context
            With ``reference`` (and ``reference_index``, which says which rows share one).

        Returns
        -------
        ndarray, shape (..., m, m)
        """
        self._check(context)
        s = self.std(context)
        corr = np.where(np.eye(context.rows, dtype=bool), 1.0, 0.5 * shared_reference(context))
        return s[..., :, None] * s[..., None, :] * corr

    def logpdf(self, z, state, context: Context) -> np.ndarray:
        """Per-row chain-rule terms of the joint Gaussian log-density ``(..., m)`` (they sum
        to the log-density of the observed rows; a NaN row gives 0).

        Parameters
        ----------
        z : ndarray, shape (..., m)
            Measured range differences, metres (NaN: missing).
        state : dict
            Named components of a batch of states.
        context : Context

        Returns
        -------
        ndarray, shape (..., m)
        """
        z = checked_call(z, state, context, self.reads)
        r = self.residual(z, self.predict(state, context))
        R = self.noise_cov(context)
        miss = np.isnan(r)
        if not miss.any():
            # one factorisation for every state of the batch (particles, runs)
            L = np.linalg.cholesky(R)
            w = np.einsum("...ij,...j->...i", np.linalg.inv(L), r)
            d = np.diagonal(L, axis1=-2, axis2=-1)
            return gaussian_logpdf(w * d, d)
        R = np.broadcast_to(R, r.shape[:-1] + R.shape[-2:]).copy()
        # a missing row: decouple it (unit variance, no covariance) and give it residual 0,
        # which leaves the observed rows' joint density unchanged
        keep = ~(miss[..., :, None] | miss[..., None, :])
        R = np.where(keep, R, 0.0)
        diag = np.diagonal(R, axis1=-2, axis2=-1).copy()
        diag[miss] = 1.0
        idx = np.arange(R.shape[-1])
        R[..., idx, idx] = diag
        L = np.linalg.cholesky(R)
        w = np.linalg.solve(L, np.where(miss, 0.0, r)[..., None])[..., 0]
        # row i given rows < i: N(w_i l_ii; 0, l_ii^2) in the residual's units
        lp = gaussian_logpdf(w * np.diagonal(L, axis1=-2, axis2=-1),
                             np.diagonal(L, axis1=-2, axis2=-1))
        return np.where(miss, 0.0, lp)


#: The log-schema kind this module explains (:mod:`radioloc.core.kinds`).
KINDS = (Kind("tdoa", "m", "range to `peer` minus range to `reference` (time difference of "
              "arrival times c)", model=lambda sigma: TdoaModel(std_m=sigma),
              sigma_option="tdoa_std_m", sigma_default=0.3,
              sigma_help="standard deviation of one arrival time in a tdoa row, m", limit=1e7,
              check="tdoa_units", check_values=check_tdoa, reference=True,
              slips=(Slip(np.negative, "negated",
                          "tdoa values with the wrong sign (reference minus peer)?"),
                     unit_slips("tdoa", "m")[0])),)
