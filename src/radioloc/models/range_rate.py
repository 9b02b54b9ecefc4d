"""Range rate (Doppler): how fast the range between the node and a known point changes.

A Doppler shift ``f_D`` of a carrier of wavelength ``lambda`` is a range rate
``-lambda f_D``: the relative velocity projected on the line of sight,

    h(x) = (p - a) . (v - v_a) / |p - a|

with ``p``, ``v`` the node's position and velocity and ``a``, ``v_a`` the anchor's (a
satellite, a moving beacon; ``v_a`` is the anchors file's ``vx, vy[, vz]``, empty or absent
for an anchor at rest). The model reads the ``position`` and ``velocity`` state components:
a filter needs a motion model with velocity; a snapshot fit estimates both (twice as many
rows as position coordinates).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from radioloc.core.kinds import Kind
from radioloc.core.validation import check_positive
from radioloc.models.measurement import Context, MeasurementModel

__all__ = ["RangeRateModel"]

#: Anchors-file columns of an anchor's velocity (m/s).
VELOCITY_COLUMNS = ("vx", "vy", "vz")


@dataclass(frozen=True)
class RangeRateModel(MeasurementModel):
    """Rate of change of the range to a known point, m/s (see the module docstring).

    Parameters
    ----------
    std_mps : float
        Standard deviation of a range-rate error, m/s (> 0).
    min_distance_m : float
        Distances are floored here so that the line of sight stays defined at an anchor.

    Examples
    --------
    >>> import numpy as np
    >>> model = RangeRateModel(std_mps=0.1)
    >>> ctx = Context(points=np.array([[0.0, 0.0], [10.0, 0.0]]))
    >>> state = {"position": np.array([3.0, 4.0]), "velocity": np.array([1.0, 0.0])}
    >>> model.predict(state, ctx).round(3).tolist()
    [0.6, -0.868]
    """

    std_mps: float
    min_distance_m: float = 1e-9

    kind: ClassVar[str] = "range_rate"
    reads: ClassVar[tuple[str, ...]] = ("position", "velocity")

    def __post_init__(self) -> None:
        check_positive(self.std_mps, "std_mps")
        check_positive(self.min_distance_m, "min_distance_m")

    def _geometry(self, state, context: Context):
        """Line-of-sight unit vectors ``u``, distances ``r`` and relative velocities ``w``
        (``(..., m, P)``, ``P`` the points' coordinates) and the node's dimension."""
        p = np.asarray(state["position"], dtype=float)
        v = np.asarray(state["velocity"], dtype=float)
        P, D = context.points.shape[-1], p.shape[-1]
        if D < P:               # a 2-D node at height_m among 3-D points: no vertical motion
            p = np.concatenate([p, np.full(p.shape[:-1] + (1,), float(context.height_m))], -1)
            v = np.concatenate([v, np.zeros(v.shape[:-1] + (1,))], -1)
        cols = context.columns or {}
        va = np.stack([np.nan_to_num(cols.get(c, np.zeros(context.rows)))
                       for c in VELOCITY_COLUMNS[:P]], axis=-1)
        d = p[..., None, :] - context.points
        r = np.maximum(np.linalg.norm(d, axis=-1), self.min_distance_m)
        return d / r[..., None], r, v[..., None, :] - va, D

    def predict(self, state, context: Context) -> np.ndarray:
        u, _, w, _ = self._geometry(state, context)
        return np.sum(u * w, axis=-1)

    def predict_with_jacobian(self, state, context: Context):
        u, r, w, D = self._geometry(state, context)
        z = np.sum(u * w, axis=-1)
        d_position = (w - z[..., None] * u) / r[..., None]
        return z, {"position": d_position[..., :D], "velocity": u[..., :D]}

    def jacobian(self, state, context: Context) -> dict[str, np.ndarray]:
        return self.predict_with_jacobian(state, context)[1]

    def std(self, context: Context) -> np.ndarray:
        return self.row_std(self.std_mps, context)


#: The log-schema kind this module explains (:mod:`radioloc.core.kinds`).
KINDS = (Kind("range_rate", "m/s", "rate of change of the range to `peer` (a Doppler shift "
              "times the wavelength, negated); the anchor's velocity from the anchors file",
              model=lambda sigma: RangeRateModel(std_mps=sigma),
              sigma_option="range_rate_std_mps", sigma_default=0.1,
              sigma_help="range-rate error standard deviation, m/s", limit=1e4, time_power=-1,
              anchor_columns=VELOCITY_COLUMNS),)
