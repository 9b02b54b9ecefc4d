"""Angle of arrival (bearing) measured at an anchor, radians.

With ``d`` the vector from the anchor to the tag in the anchor's frame (below):

- ``component="azimuth"`` (kind ``"aoa"``): ``h = atan2(d_y, d_x)``, the angle in the
  anchor's horizontal plane, counter-clockwise from its boresight, in ``(-pi, pi]``; 2-D or
  3-D (an untilted anchor ignores the vertical coordinate);
- ``component="elevation"`` (kind ``"aoa_elevation"``): ``h = atan2(d_z, |d_xy|)``, the
  angle above the anchor's horizontal plane, in ``[-pi/2, pi/2]``; 3-D only (or 2-D
  positions with 3-D anchors and a known ``Context.height_m``).

A 3-D angle of arrival is two observations, one per component, over the same anchors.

Each anchor (an antenna array) measures in its own frame, so a measured angle is relative
to the array's boresight (what a BLE 5.1 or UWB angle-of-arrival kit reports). The frame is
turned from the world's by ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (right-handed rotations about
the world z, then the array's y, then its x axis; the boresight is the array's x axis:
positive yaw turns it counter-clockwise seen from above, positive pitch turns it down,
positive roll turns the array's y axis up), and the angles are those of ``R^T d``. The
angles come from the anchors file's columns ``yaw, pitch, roll``
(:data:`ORIENTATION_COLUMNS`, each row's anchor's values in ``Context.columns``; an empty
cell or an absent column is 0); without a ``yaw`` column the model's ``orientation_rad`` is
the yaw: one angle for every anchor, or one per anchor of the anchor table (indexed by
``Context.index``). A pitch or roll needs 3-D positions (or ``Context.height_m``).

Residuals wrap (``angular = True``). The Jacobian is analytic, in the array's frame and
turned back to the world's by ``R``: with ``rho = |d_xy|`` and ``r = |d|``,
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

#: Anchors-file columns of an array's orientation, radians (see the module docstring).
ORIENTATION_COLUMNS = ("yaw", "pitch", "roll")

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
        context (one source of the orientation).
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

    def _rotation(self, context: Context) -> tuple[np.ndarray, bool]:
        """World-from-array rotations ``R = Rz(yaw) Ry(pitch) Rx(roll)`` of the rows
        ``(m, 3, 3)``, and whether any row is tilted (a pitch or a roll)."""
        m = context.rows
        cols = context.columns or {}
        yaw = np.broadcast_to(self._yaw(context), (m,))
        one, zero = np.ones(m), np.zeros(m)
        pitch, roll = (zero if cols.get(c) is None else np.nan_to_num(cols[c])
                       for c in ORIENTATION_COLUMNS[1:])

        def turn(angle, i, j):       # rotation by ``angle`` in the plane of axes i -> j
            R = np.zeros((m, 3, 3))
            R[:, i, i] = R[:, j, j] = np.cos(angle)
            R[:, j, i], R[:, i, j] = np.sin(angle), -np.sin(angle)
            R[:, 3 - i - j, 3 - i - j] = one
            return R

        tilted = bool(np.any(pitch != zero) or np.any(roll != zero))
        R = turn(yaw, 0, 1)
        return (R @ turn(pitch, 2, 0) @ turn(roll, 1, 2) if tilted else R), tilted

    def _local(self, state, context: Context):
        """Vectors from the anchors to the tag in each array's frame: horizontal
        ``(..., m, 2)`` and vertical ``(..., m)`` (None when unknown), the rotations and
        the number of position coordinates the rows depend on."""
        x = np.asarray(state["position"], dtype=float)
        a = context.points
        D = x.shape[-1]
        if context.height_m is not None:
            if a.shape[-1] != D + 1:
                raise InputError(f"context.points: height_m needs {D + 1}-D anchors, got "
                                 f"{a.shape[-1]}-D")
            dxy, dz = x[..., None, :2] - a[..., :2], float(context.height_m) - a[..., D]
        elif a.shape[-1] != D:
            raise InputError(f"context.points: {a.shape[-1]} coordinates but positions have {D}")
        else:
            d = x[..., None, :] - a
            dxy, dz = d[..., :2], (d[..., 2] if D == 3 else None)
        R, tilted = self._rotation(context)
        if not tilted:
            return np.einsum("mji,...mj->...mi", R[:, :2, :2], dxy), dz, R, D
        if dz is None:
            raise InputError("context.columns: a pitch or roll needs 3-D positions (or 3-D "
                             "anchors with Context.height_m)")
        d = np.einsum("mji,...mj->...mi", R, np.concatenate([dxy, dz[..., None]], axis=-1))
        return d[..., :2], d[..., 2], R, D

    def predict(self, state, context: Context) -> np.ndarray:
        dxy, dz, _, _ = self._local(state, context)
        if self.component == "azimuth":
            return np.arctan2(dxy[..., 1], dxy[..., 0])
        if dz is None:
            raise InputError("component: an elevation needs 3-D positions (or 3-D anchors "
                             "with Context.height_m)")
        return np.arctan2(dz, np.sqrt(np.sum(dxy**2, axis=-1)))

    def jacobian(self, state, context: Context) -> dict[str, np.ndarray]:
        dxy, dz, R, D = self._local(state, context)
        rho2 = np.maximum(np.sum(dxy**2, axis=-1), self.min_distance_m**2)
        H = np.zeros(rho2.shape + (3,))          # over the array frame's x, y, z
        if self.component == "azimuth":
            H[..., 0] = -dxy[..., 1] / rho2
            H[..., 1] = dxy[..., 0] / rho2
        elif dz is None:
            raise InputError("component: an elevation needs 3-D positions (or 3-D anchors "
                             "with Context.height_m)")
        else:
            rho = np.sqrt(rho2)
            r2 = rho2 + dz**2
            H[..., 0] = -dxy[..., 0] * dz / (rho * r2)
            H[..., 1] = -dxy[..., 1] * dz / (rho * r2)
            H[..., 2] = rho / r2
        return {"position": np.einsum("...mi,mji->...mj", H, R)[..., :D]}

    def std(self, context: Context) -> np.ndarray:
        return self.row_std(self.std_rad, context)


def _angle_kind(name: str, component: str, bound: float, meaning: str, slips: tuple) -> Kind:
    return Kind(name, "rad", meaning,
                model=lambda sigma: BearingModel(std_rad=sigma, component=component),
                sigma_option="aoa_std_rad", sigma_default=DEFAULT_STD_RAD,
                sigma_help="angle-of-arrival error standard deviation, rad", sigma_max=10.0,
                limit=2 * np.pi, bound=bound, check="angle_units",
                anchor_columns=ORIENTATION_COLUMNS,
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
