"""Heading of the node's own motion, radians: a phone's compass azimuth, a robot's yaw.

A walking user holds the phone pointing roughly along the walking direction, so the
phone's azimuth measures the direction of the node's velocity ``v``:

``h = atan2(v_y, v_x) + offset``,

counter-clockwise from the map's x axis, wrapped to ``(-pi, pi]``. ``offset_rad`` is the
fixed rotation from the map's frame to the sensor's (a compass azimuth is measured in the
magnetometer's frame, e.g. clockwise from magnetic north once its sign is flipped;
:func:`radioloc.locate.heading_offset.estimate_heading_offset` estimates it from a track).
In 3-D only the horizontal velocity counts. Residuals wrap (``angular = True``).

The Jacobian is analytic, ``d h / d (v_x, v_y) = (-v_y, v_x) / |v|^2``. The direction of
a slow velocity is ill defined: ``|v|^2`` is floored at ``min_speed_mps^2``, so below that
speed the Jacobian shrinks in proportion to the speed, to zero at standstill, instead of
growing as ``1 / |v|``. That is the linearised form of a heading noise that grows as the
speed falls, ``std_rad * min_speed_mps / |v|`` below ``min_speed_mps``: a filter standing
still is not turned by its heading rows (the noise of the protocol depends on the rows'
context only, so the speed enters through the Jacobian; the innovation of a heading row
at standstill is large against ``std_rad`` and a NIS gate refuses it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from radioloc.core.validation import check_positive, check_real
from radioloc.models.measurement import Context, MeasurementModel, wrap_angle

__all__ = ["HeadingModel"]


@dataclass(frozen=True)
class HeadingModel(MeasurementModel):
    """Direction of the node's velocity, radians (see the module docstring).

    Parameters
    ----------
    std_rad : float
        Standard deviation of a heading error, radians (> 0).
    offset_rad : float
        Rotation from the map's frame to the sensor's: a row reads the velocity's
        direction plus this angle.
    min_speed_mps : float
        Speed below which the heading is treated as ill defined (the Jacobian is
        scaled down by ``(|v| / min_speed_mps)^2``), m/s (> 0).

    Examples
    --------
    >>> import numpy as np
    >>> model = HeadingModel(std_rad=0.2)
    >>> ctx = Context(points=np.zeros((1, 2)))
    >>> model.predict({"velocity": np.array([0.0, 1.5])}, ctx).round(4).tolist()
    [1.5708]
    """

    std_rad: float
    offset_rad: float = 0.0
    min_speed_mps: float = 0.5

    kind: ClassVar[str] = "heading"
    reads: ClassVar[tuple[str, ...]] = ("velocity",)
    angular: ClassVar[bool] = True

    def __post_init__(self) -> None:
        check_positive(self.std_rad, "std_rad")
        object.__setattr__(self, "offset_rad", check_real(self.offset_rad, "offset_rad"))
        check_positive(self.min_speed_mps, "min_speed_mps")

    def predict(self, state, context: Context) -> np.ndarray:
        v = np.asarray(state["velocity"], dtype=float)
        h = np.arctan2(v[..., 1], v[..., 0]) + self.offset_rad
        return wrap_angle(np.broadcast_to(h[..., None], h.shape + (context.rows,)))

    def jacobian(self, state, context: Context) -> dict[str, np.ndarray]:
        v = np.asarray(state["velocity"], dtype=float)
        speed2 = np.maximum(v[..., 0] ** 2 + v[..., 1] ** 2, self.min_speed_mps ** 2)
        row = np.zeros(v.shape)
        row[..., 0] = -v[..., 1] / speed2
        row[..., 1] = v[..., 0] / speed2
        return {"velocity": np.broadcast_to(row[..., None, :], v.shape[:-1] + (context.rows, v.shape[-1])).copy()}

    def std(self, context: Context) -> np.ndarray:
        return self.row_std(self.std_rad, context)
