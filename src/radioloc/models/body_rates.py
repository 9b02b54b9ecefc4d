"""A vehicle's own odometry in its body frame: forward speed and yaw rate.

A car's wheel odometry gives its speed along its own heading and its gyroscope the turn
rate about its vertical axis; neither carries the heading itself. Both are measurements
of the node's kinematic state, in any Cartesian frame whose "up" is known:

- ``speed`` (m/s): ``h = |v_h|``, the norm of the horizontal velocity (the velocity minus
  its component along "up"); ``d h / d v = v_h / |v_h|``.
- ``vertical_speed`` (m/s, up): ``h = up . v``; a car's body frame measures ~0 (it drives
  on the road), which holds its height between NLOS-biased fixes.
- ``yaw_rate`` (rad/s, counter-clockwise seen from above): the turn rate of the horizontal
  velocity, ``h = up . (v x a) / |v_h|^2`` with the acceleration ``a``; it reads the
  constant-acceleration state (:class:`~radioloc.models.motion.WhiteJerkCA`).

"Up" is ``z`` in a local frame (east-north-up, or any frame with a vertical ``z``; a 2-D
state is horizontal), or, with ``geocentric``, the direction from the Earth's centre to the
node (ECEF states; it is within 0.2 degrees of the ellipsoid's normal). Below
``min_speed_mps`` the direction of motion is undefined: the yaw rate predicts NaN there (the
row is skipped, as :class:`~radioloc.models.heading.HeadingModel` does), and the speed's
Jacobian is floored.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.kinds import Kind, unit_slips
from radioloc.core.validation import check_positive
from radioloc.models.measurement import Context, MeasurementModel

__all__ = ["SpeedModel", "VerticalSpeedModel", "YawRateModel"]


def _up(position: np.ndarray, geocentric: bool) -> np.ndarray | None:
    """Unit "up" vectors ``(..., 3)`` of 3-D positions (None for a 2-D state)."""
    p = np.asarray(position, dtype=float)
    if p.shape[-1] == 2:
        return None
    if geocentric:
        return p / np.linalg.norm(p, axis=-1, keepdims=True)
    return np.broadcast_to(np.array([0.0, 0.0, 1.0]), p.shape)


def _horizontal(vector: np.ndarray, up: np.ndarray | None) -> np.ndarray:
    return vector if up is None else vector - np.sum(vector * up, -1, keepdims=True) * up


def _rows(value: np.ndarray, context: Context) -> np.ndarray:
    return np.broadcast_to(value[..., None], value.shape + (context.rows,))


def _row_jacobian(d: np.ndarray, context: Context) -> np.ndarray:
    """The Jacobian ``d`` ``(..., n)`` of a value every row shares, one per row
    ``(..., m, n)``."""
    return np.broadcast_to(d[..., None, :], d.shape[:-1] + (context.rows, d.shape[-1]))


class _OwnMotion(MeasurementModel):
    """What the three models share: ``h`` and its Jacobian computed together, a constant
    standard deviation (the field ``std_mps`` or ``std_rps``)."""

    def predict(self, state, context: Context) -> np.ndarray:
        return self.predict_with_jacobian(state, context)[0]

    def jacobian(self, state, context: Context) -> dict[str, np.ndarray]:
        return self.predict_with_jacobian(state, context)[1]

    def std(self, context: Context) -> np.ndarray:
        return self.row_std(getattr(self, "std_mps", None) or self.std_rps, context)


@dataclass(frozen=True)
class SpeedModel(_OwnMotion):
    """Horizontal speed of the node, m/s (see the module docstring).

    Parameters
    ----------
    std_mps : float
        Standard deviation of a speed error, m/s (> 0).
    geocentric : bool
        "Up" is the direction from the Earth's centre (ECEF states), else ``z``.
    min_speed_mps : float
        Speeds are floored here in the Jacobian's denominator, m/s (> 0).

    Examples
    --------
    >>> import numpy as np
    >>> model = SpeedModel(std_mps=0.1)
    >>> ctx = Context(points=np.zeros((1, 3)))
    >>> model.predict({"position": np.zeros(3), "velocity": np.array([3.0, 4.0, 9.0])},
    ...               ctx).tolist()
    [5.0]
    """

    std_mps: float
    geocentric: bool = False
    min_speed_mps: float = 0.1

    kind: ClassVar[str] = "speed"
    reads: ClassVar[tuple[str, ...]] = ("position", "velocity")

    def __post_init__(self) -> None:
        check_positive(self.std_mps, "std_mps")
        check_positive(self.min_speed_mps, "min_speed_mps")

    def predict_with_jacobian(self, state, context: Context):
        up = _up(state["position"], self.geocentric)
        vh = _horizontal(np.asarray(state["velocity"], dtype=float), up)
        speed = np.linalg.norm(vh, axis=-1)
        d_v = vh / np.maximum(speed, self.min_speed_mps)[..., None]
        d_p = np.zeros(np.shape(state["position"]))     # "up" turns slowly: neglected
        return _rows(speed, context), {
            "velocity": _row_jacobian(d_v, context), "position": _row_jacobian(d_p, context)}


@dataclass(frozen=True)
class VerticalSpeedModel(_OwnMotion):
    """Vertical speed of the node (along "up"), m/s (see the module docstring); 3-D states.

    Parameters
    ----------
    std_mps : float
        Standard deviation of a vertical-speed error, m/s (> 0).
    geocentric : bool
        "Up" is the direction from the Earth's centre (ECEF states), else ``z``.

    Examples
    --------
    >>> import numpy as np
    >>> model = VerticalSpeedModel(std_mps=0.03)
    >>> ctx = Context(points=np.zeros((1, 3)))
    >>> model.predict({"position": np.zeros(3), "velocity": np.array([3.0, 4.0, -0.5])},
    ...               ctx).tolist()
    [-0.5]
    """

    std_mps: float
    geocentric: bool = False

    kind: ClassVar[str] = "vertical_speed"
    reads: ClassVar[tuple[str, ...]] = ("position", "velocity")

    def __post_init__(self) -> None:
        check_positive(self.std_mps, "std_mps")

    def predict_with_jacobian(self, state, context: Context):
        up = _up(state["position"], self.geocentric)
        if up is None:
            raise InputError("vertical_speed: needs a 3-D state (a 2-D state is horizontal)")
        v = np.asarray(state["velocity"], dtype=float)
        zero = np.zeros(np.broadcast_shapes(up.shape, v.shape))
        return _rows(np.sum(up * v, -1), context), {
            "velocity": _row_jacobian(up, context), "position": _row_jacobian(zero, context)}


@dataclass(frozen=True)
class YawRateModel(_OwnMotion):
    """Turn rate of the node's horizontal velocity, rad/s (see the module docstring).

    Parameters
    ----------
    std_rps : float
        Standard deviation of a yaw-rate error, rad/s (> 0).
    geocentric : bool
        "Up" is the direction from the Earth's centre (ECEF states), else ``z``.
    min_speed_mps : float
        Speed below which the yaw rate is undefined (NaN: the row is skipped), m/s (> 0).

    Examples
    --------
    >>> import numpy as np
    >>> model = YawRateModel(std_rps=0.01)
    >>> ctx = Context(points=np.zeros((1, 2)))
    >>> state = {"position": np.zeros(2), "velocity": np.array([10.0, 0.0]),
    ...          "acceleration": np.array([0.0, 2.0])}
    >>> model.predict(state, ctx).tolist()
    [0.2]
    """

    std_rps: float
    geocentric: bool = False
    min_speed_mps: float = 1.0

    kind: ClassVar[str] = "yaw_rate"
    reads: ClassVar[tuple[str, ...]] = ("position", "velocity", "acceleration")

    def __post_init__(self) -> None:
        check_positive(self.std_rps, "std_rps")
        check_positive(self.min_speed_mps, "min_speed_mps")

    def predict_with_jacobian(self, state, context: Context):
        p = np.asarray(state["position"], dtype=float)
        v = np.asarray(state["velocity"], dtype=float)
        a = np.asarray(state["acceleration"], dtype=float)
        up = _up(p, self.geocentric)
        if up is None:                                  # 2-D: up is the z axis
            cross = v[..., 0] * a[..., 1] - v[..., 1] * a[..., 0]
            d_cross_v = np.stack([a[..., 1], -a[..., 0]], -1)
            d_cross_a = np.stack([-v[..., 1], v[..., 0]], -1)
        else:                                           # up . (v x a)
            cross = np.sum(up * np.cross(v, a), -1)
            d_cross_v = np.cross(a, up)
            d_cross_a = np.cross(up, v)
        vh = _horizontal(v, up)
        s2 = np.sum(vh * vh, -1)
        moving = s2 >= self.min_speed_mps ** 2
        s2 = np.where(moving, s2, 1.0)
        rate = np.where(moving, cross / s2, np.nan)
        d_v = (d_cross_v - 2.0 * (cross / s2)[..., None] * vh) / s2[..., None]
        d_a = d_cross_a / s2[..., None]
        zero = np.zeros_like(p)

        def rows(d):
            return _row_jacobian(np.where(moving[..., None], d, 0.0), context)

        return _rows(rate, context), {"velocity": rows(d_v), "acceleration": rows(d_a),
                                      "position": rows(zero)}


def _kind(name: str, unit: str, meaning: str, model, sigma_option: str, sigma_default: float,
          what: str, limit: float) -> Kind:
    return Kind(name, unit, meaning + " (`peer` names the sensor)", model=model,
                sigma_option=sigma_option, sigma_default=sigma_default,
                sigma_help=f"{what} error standard deviation, {unit}", sigma_max=limit,
                limit=limit, time_power=-1, self_measured=True,
                slips=unit_slips(name, unit, -1) if unit == "m/s" else unit_slips(name, "rad"))


#: The log-schema kinds of a vehicle's body-frame odometry (:mod:`radioloc.core.kinds`);
#: limits: ten times a fast train's speed, 16 turns a second.
KINDS = (
    _kind("speed", "m/s", "the node's horizontal speed (wheel odometry)",
          lambda sigma: SpeedModel(std_mps=sigma), "speed_std_mps", 0.1,
          "speed (body-frame odometry)", 1e3),
    _kind("vertical_speed", "m/s", "the node's vertical speed, up",
          lambda sigma: VerticalSpeedModel(std_mps=sigma), "vertical_speed_std_mps", 0.1,
          "vertical-speed (body-frame odometry)", 1e3),
    _kind("yaw_rate", "rad/s", "the node's turn rate about the vertical, counter-clockwise "
          "seen from above (a gyroscope)", lambda sigma: YawRateModel(std_rps=sigma),
          "yaw_rate_std_rps", 0.01, "yaw-rate (gyroscope)", 100.0),
)
