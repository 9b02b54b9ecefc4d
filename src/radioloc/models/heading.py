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
a slow velocity is undefined, and an extended Kalman update linearised there turns a
velocity that is mostly noise by the full angle of the innovation, which lengthens it
(the linear step is tangential): repeated, the speed grows without bound. So a state
slower than ``min_speed_mps`` predicts NaN (Jacobian zero), and every estimator skips
the row there (a NaN innovation is a missing row; :meth:`logpdf` gives 0): in effect the
heading noise is infinite below ``min_speed_mps``. The noise of the protocol depends on
the rows' context only, so this switch is how the speed enters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from radioloc.core.kinds import Kind
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
        Speed below which the heading is undefined: the prediction is NaN (the row is
        skipped), m/s (> 0).

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
        h = np.where(self._moving(v), h, np.nan)
        return wrap_angle(np.broadcast_to(h[..., None], h.shape + (context.rows,)))

    def _moving(self, v: np.ndarray) -> np.ndarray:
        return v[..., 0] ** 2 + v[..., 1] ** 2 >= self.min_speed_mps ** 2

    def jacobian(self, state, context: Context) -> dict[str, np.ndarray]:
        v = np.asarray(state["velocity"], dtype=float)
        moving = self._moving(v)
        speed2 = np.where(moving, v[..., 0] ** 2 + v[..., 1] ** 2, 1.0)
        row = np.zeros(v.shape)
        row[..., 0] = np.where(moving, -v[..., 1] / speed2, 0.0)
        row[..., 1] = np.where(moving, v[..., 0] / speed2, 0.0)
        return {"velocity": np.broadcast_to(row[..., None, :], v.shape[:-1] + (context.rows, v.shape[-1])).copy()}

    def std(self, context: Context) -> np.ndarray:
        return self.row_std(self.std_rad, context)


#: The log-schema kind this module explains (:mod:`radioloc.core.kinds`).
KINDS = (Kind("heading", "rad", "direction of the node's motion, counter-clockwise from +x "
              "(`peer` names the sensor)", model=lambda sigma: HeadingModel(std_rad=sigma),
              sigma_option="heading_std_rad", sigma_default=0.3,
              sigma_help="heading (direction of motion) error standard deviation, rad",
              sigma_max=10.0, limit=2 * np.pi, bound=2 * np.pi, check="angle_units",
              self_measured=True, slips=()),)
