"""Pseudorange: a range measured with the receiver's unsynchronised clock.

A receiver timestamps the arrival of a signal sent at a known time from a known point ``s``
(a satellite, a synchronised anchor) with its own clock, which is ahead by ``clock_offset``
metres (offset times the speed of light); every row of an epoch carries the same offset:

    h(x) = |x - s| + clock_offset

The model reads the ``clock_offset`` state component; a filter evolves it (and its drift)
with :class:`~radioloc.models.clock.ClockModel`. A snapshot fit needs one more row than
position coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from radioloc.core.kinds import Kind, unit_slips
from radioloc.core.plausibility import check_pseudoranges
from radioloc.core.validation import check_positive
from radioloc.models.measurement import Context, MeasurementModel
from radioloc.models.ranging import range_geometry

__all__ = ["PseudorangeModel"]


@dataclass(frozen=True)
class PseudorangeModel(MeasurementModel):
    """Range to a known point plus the receiver's clock offset, metres.

    Parameters
    ----------
    std_m : float
        Standard deviation of a pseudorange error, metres (> 0).

    Examples
    --------
    >>> import numpy as np
    >>> model = PseudorangeModel(std_m=1.0)
    >>> ctx = Context(points=np.array([[0.0, 0.0], [10.0, 0.0]]))
    >>> model.predict({"position": np.array([3.0, 4.0]), "clock_offset": np.array(2.0)},
    ...               ctx).round(3).tolist()
    [7.0, 10.062]
    """

    std_m: float

    kind: ClassVar[str] = "pseudorange"
    reads: ClassVar[tuple[str, ...]] = ("position", "clock_offset")

    def __post_init__(self) -> None:
        check_positive(self.std_m, "std_m")

    def predict(self, state, context: Context) -> np.ndarray:
        d, _ = range_geometry(state["position"], context.points, context.height_m)
        return d + np.asarray(state["clock_offset"], dtype=float)[..., None]

    def jacobian(self, state, context: Context) -> dict[str, np.ndarray]:
        _, u = range_geometry(state["position"], context.points, context.height_m)
        return {"position": u, "clock_offset": np.ones(u.shape[:-1] + (1,))}

    def std(self, context: Context) -> np.ndarray:
        return self.row_std(self.std_m, context)


#: The log-schema kind this module explains (:mod:`radioloc.core.kinds`).
KINDS = (Kind("pseudorange", "m", "range to `peer` plus the receiver's clock offset (times c)",
              model=lambda sigma: PseudorangeModel(std_m=sigma),
              sigma_option="pseudorange_std_m", sigma_default=5.0,
              sigma_help="pseudorange error standard deviation, m", limit=1e8,
              check="pseudorange_units",
              check_values=lambda z, points, reference, **kw: check_pseudoranges(z, points, **kw),
              slips=tuple(unit_slips("pseudorange", "m", ns=True, what="pseudoranges")[i] for i in (1, 2, 0))),)
