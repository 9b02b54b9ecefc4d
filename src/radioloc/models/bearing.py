"""Angle of arrival (bearing) measured at an anchor, radians.

With ``d = x - a`` the vector from the anchor to the tag:

- ``component="azimuth"`` (kind ``"aoa"``): ``h = atan2(d_y, d_x) - yaw``, the angle in the
  anchor's horizontal frame, counter-clockwise from its x axis, wrapped to ``(-pi, pi]``;
  2-D or 3-D (the vertical coordinate is ignored);
- ``component="elevation"`` (kind ``"aoa_elevation"``): ``h = atan2(d_z, |d_xy|)``, the
  angle above the anchor's horizontal plane, in ``[-pi/2, pi/2]``; 3-D only (or 2-D
  positions with 3-D anchors and a known ``Context.height_m``).

A 3-D angle of arrival is two observations, one per component, over the same anchors.

The anchor's frame is turned by its yaw (radians, counter-clockwise from the world x axis)
about the vertical, so a measured azimuth is relative to the array's boresight (what a BLE
5.1 or UWB angle-of-arrival kit reports): the anchors file's ``yaw`` column
(:data:`ORIENTATION_COLUMNS`, each row's anchor's value in ``Context.columns``; an empty
cell is a frame aligned with the world's), or, without that column, the model's
``orientation_rad``: one angle for every anchor, or one per anchor of the anchor table
(indexed by ``Context.index``). A tilted array (pitch, roll) is not modelled. Residuals
wrap (``angular = True``). The Jacobian is analytic: with ``rho = |d_xy|`` and ``r = |d|``,
``d azimuth / d (x, y) = (-d_y, d_x) / rho^2`` and ``d elevation / d (x, y, z) =
(-d_x d_z / rho, -d_y d_z / rho, rho) / r^2``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.kinds import Kind, Slip, unit_slips
from radioloc.core.validation import as_float_array, check_positive
from radioloc.models.measurement import Context, MeasurementModel, wrap_angle

__all__ = ["BearingModel", "ORIENTATION_COLUMNS", "DEFAULT_STD_RAD"]

_KINDS = {"azimuth": "aoa", "elevation": "aoa_elevation"}

#: Anchors-file column of an anchor's yaw, radians counter-clockwise from the world x axis.
ORIENTATION_COLUMNS = ("yaw",)

#: Default angle error, radians: 6 degrees, what BLE 5.1 angle-of-arrival kits deliver
#: indoors with reflections (5-7 degrees).
DEFAULT_STD_RAD = float(np.radians(6.0))


# eq=False: the settings hold arrays, so instances compare and hash by identity
@dataclass(frozen=True, eq=False)
class BearingModel(MeasurementModel):
    """Azimuth or elevation of the tag seen from an anchor, radians (see the module
    docstring).

    Parameters
    ----------
    std_rad : float
        Standard deviation of an angle error, radians (> 0).
    component : {"azimuth", "elevation"}
        Which angle the rows hold.
    orientation_rad : float or array_like, shape (A,)
        Yaw of the anchors' frames, radians: one for all, or one per anchor-table row
        (then ``Context.index`` is required); refused beside a ``yaw`` column in the
        context (one source of the orientation). The elevation does not depend on it.
    min_distance_m : float
        Horizontal distances are floored here so the Jacobian stays finite above an anchor.

    Examples
    --------
    >>> import numpy as np
    >>> model = BearingModel(std_rad=0.01)
    >>> ctx = Context(points=np.array([[0.0, 0.0], [10.0, 0.0]]))
    >>> model.predict({"position": np.array([0.0, 5.0])}, ctx).round(4).tolist()
    [1.5708, 2.6779]
    """

    std_rad: float
    component: str = "azimuth"
    orientation_rad: float | np.ndarray = 0.0
    min_distance_m: float = 1e-9

    angular: ClassVar[bool] = True

    def __post_init__(self) -> None:
        check_positive(self.std_rad, "std_rad")
        if self.component not in _KINDS:
            raise InputError(f"component: expected 'azimuth' or 'elevation', got "
                             f"{self.component!r}")
        yaw = as_float_array(self.orientation_rad, "orientation_rad")
        if yaw.ndim > 1:
            raise InputError(f"orientation_rad: one angle or one per anchor, got shape {yaw.shape}")
        object.__setattr__(self, "orientation_rad", yaw)
        check_positive(self.min_distance_m, "min_distance_m")

    @property
    def kind(self) -> str:  # type: ignore[override]
        return _KINDS[self.component]

    def _yaw(self, context: Context) -> np.ndarray | float:
        yaw = self.orientation_rad
        column = (context.columns or {}).get(ORIENTATION_COLUMNS[0])
        if column is not None:
            if np.any(yaw != 0):
                raise ConfigError("orientation_rad: the rows carry their anchors' yaw "
                                  "(Context.columns['yaw']); give the orientation once")
            return np.nan_to_num(column)
        if yaw.ndim == 0:
            return float(yaw)
        if context.index is None:
            raise InputError("context.index: per-anchor orientation_rad needs the anchor-table "
                             "row of every measurement")
        if np.any((context.index < 0) | (context.index >= yaw.size)):
            raise InputError(f"context.index: rows must index the {yaw.size} orientations "
                             f"of orientation_rad, got {context.index.tolist()}")
        return yaw[context.index]

    def _offsets(self, state, context: Context) -> tuple[np.ndarray, np.ndarray | None]:
        """Horizontal vectors ``(..., m, 2)`` from the anchors to the tag and the vertical
        offsets ``(..., m)`` (None when unknown)."""
        x = np.asarray(state["position"], dtype=float)
        a = context.points
        D = x.shape[-1]
        if context.height_m is not None:
            if a.shape[-1] != D + 1:
                raise InputError(f"context.points: height_m needs {D + 1}-D anchors, got "
                                 f"{a.shape[-1]}-D")
            return x[..., None, :2] - a[..., :2], float(context.height_m) - a[..., D]
        if a.shape[-1] != D:
            raise InputError(f"context.points: {a.shape[-1]} coordinates but positions have {D}")
        d = x[..., None, :] - a
        return d[..., :2], (d[..., 2] if D == 3 else None)

    def predict(self, state, context: Context) -> np.ndarray:
        dxy, dz = self._offsets(state, context)
        if self.component == "azimuth":
            return wrap_angle(np.arctan2(dxy[..., 1], dxy[..., 0]) - self._yaw(context))
        if dz is None:
            raise InputError("component: an elevation needs 3-D positions (or 3-D anchors "
                             "with Context.height_m)")
        return np.arctan2(dz, np.sqrt(np.sum(dxy**2, axis=-1)))

    def jacobian(self, state, context: Context) -> dict[str, np.ndarray]:
        dxy, dz = self._offsets(state, context)
        D = np.shape(state["position"])[-1]
        rho2 = np.maximum(np.sum(dxy**2, axis=-1), self.min_distance_m**2)
        H = np.zeros(rho2.shape + (D,))
        if self.component == "azimuth":
            H[..., 0] = -dxy[..., 1] / rho2
            H[..., 1] = dxy[..., 0] / rho2
            return {"position": H}
        if dz is None:
            raise InputError("component: an elevation needs 3-D positions (or 3-D anchors "
                             "with Context.height_m)")
        rho = np.sqrt(rho2)
        r2 = rho2 + dz**2
        H[..., 0] = -dxy[..., 0] * dz / (rho * r2)
        H[..., 1] = -dxy[..., 1] * dz / (rho * r2)
        if D == 3:
            H[..., 2] = rho / r2
        return {"position": H}

    def std(self, context: Context) -> np.ndarray:
        return self.row_std(self.std_rad, context)


def _angle_kind(name: str, component: str, bound: float, meaning: str, slips: tuple) -> Kind:
    return Kind(name, "rad", meaning,
                model=lambda sigma: BearingModel(std_rad=sigma, component=component),
                sigma_option="aoa_std_rad", sigma_default=DEFAULT_STD_RAD,
                sigma_help="angle-of-arrival error standard deviation, rad", sigma_max=10.0,
                limit=2 * np.pi, bound=bound, check="angle_units",
                anchor_columns=ORIENTATION_COLUMNS if component == "azimuth" else (),
                slips=slips + unit_slips(name, "rad"))


#: The log-schema kinds this module explains (:mod:`radioloc.core.kinds`).
KINDS = (
    _angle_kind("aoa", "azimuth", 2 * np.pi, "bearing from `peer` to the node, "
                "counter-clockwise from the anchor's boresight (its `yaw`; +x without one)",
                (Slip(np.negative, "negated", "aoa values counted clockwise?"),
                 Slip(lambda v: np.pi / 2 - v, "as pi/2 minus the value",
                      "aoa values as compass bearings (clockwise from north)?"))),
    _angle_kind("aoa_elevation", "elevation", np.pi / 2, "elevation of the node seen from "
                "`peer`", (Slip(np.negative, "negated",
                                "aoa_elevation values with the wrong sign?"),)),
)
