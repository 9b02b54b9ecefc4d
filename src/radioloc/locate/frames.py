"""Coordinate frames of ``radioloc locate``: local metres, ECEF, WGS84, and where a map puts them.

The anchors file declares its frame in a ``frame`` column (one value for every row), or
``locate --frame`` does:

- ``local`` (default): metres in a frame of the user's; it lands on a map only when
  ``--origin lat,lon,h`` says it is the east-north-up (ENU) frame at that point;
- ``ecef``: Earth-centred, Earth-fixed metres (WGS84), e.g. satellite positions;
- ``wgs84``: ``x`` longitude and ``y`` latitude in degrees, ``z`` height above the ellipsoid
  in metres (the order of GeoJSON).

The estimators work in one Cartesian frame, the **working frame**: with ``--origin``, the ENU
frame at the origin (geodetic anchors are converted to it); without, ECEF for geodetic
anchors and the anchors' own frame for local ones. Every conversion is pymap3d's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError, InputError

__all__ = ["FRAMES", "Frame", "declared_frame", "horizontal_at_start", "parse_origin",
           "to_working", "working_frame"]

#: Frames an anchors file may be in.
FRAMES = ("local", "ecef", "wgs84")


def parse_origin(text: str | None) -> tuple[float, float, float] | None:
    """``--origin lat,lon[,h]`` (degrees, degrees, metres; h default 0) as a tuple.

    Raises
    ------
    ConfigError
        Not two or three numbers, or a latitude beyond +-90 or a longitude beyond +-180.
    """
    if text is None:
        return None
    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) not in (2, 3) or not np.isfinite(values).all():
        raise ConfigError(f"--origin {text!r}: expected lat,lon[,h] (degrees, degrees, metres)")
    lat, lon, h = (values + [0.0])[:3]
    if abs(lat) > 90 or abs(lon) > 180:
        raise ConfigError(f"--origin {text!r}: latitude must be within +-90 and longitude "
                          "within +-180 degrees (lat first)")
    return lat, lon, h


def declared_frame(table: pd.DataFrame | None, option: str | None = None,
                   what: str = "anchors") -> str:
    """The frame of a table: its ``frame`` column, else ``option``, else ``local``.

    Raises
    ------
    InputError
        Rows in more than one frame, an unknown frame, or a column that contradicts the
        option.
    """
    if option is not None and option not in FRAMES:
        raise ConfigError(f"--frame {option!r}: expected one of {', '.join(FRAMES)}")
    if table is None or "frame" not in table.columns:
        return option or "local"
    found = sorted(set(str(v).strip().lower() for v in table["frame"]))
    if len(found) != 1 or found[0] not in FRAMES:
        raise InputError(f"{what}: column 'frame' holds {', '.join(map(repr, found))}; expected "
                         f"one of {', '.join(FRAMES)} for every row")
    if option is not None and option != found[0]:
        raise InputError(f"{what}: column 'frame' says {found[0]!r} but --frame {option!r}")
    return found[0]


@dataclass(frozen=True)
class Frame:
    """The working frame of a run.

    Attributes
    ----------
    kind : {"local", "ecef", "enu"}
        ``local``: not tied to the Earth; ``ecef``; ``enu``: east-north-up at ``origin``.
    origin : (lat, lon, h) or None
        The ENU origin (degrees, degrees, metres).
    """

    kind: str = "local"
    origin: tuple[float, float, float] | None = None

    @property
    def georeferenced(self) -> bool:
        """Whether positions in this frame have a place on the Earth."""
        return self.kind != "local"

    def why_not_georeferenced(self) -> str:
        return ("the anchors are in a local frame with no known place on the Earth: give "
                "--origin lat,lon,h (the local frame is then east-north-up at that point) or "
                "anchors in ecef or wgs84 (a 'frame' column or --frame)")

    def to_ecef(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(rotation, origin)`` with ``ecef = rotation @ p + origin``; None when not
        georeferenced. ECEF itself: the identity."""
        if self.kind == "local":
            return None
        if self.kind == "ecef":
            return np.eye(3), np.zeros(3)
        import pymap3d

        lat, lon, h = self.origin
        rot = np.column_stack([pymap3d.enu2uvw(*e, lat, lon) for e in np.eye(3)])
        return rot, np.array(pymap3d.geodetic2ecef(lat, lon, h))

    def from_frame(self, xyz: np.ndarray, frame: str) -> np.ndarray:
        """Points ``(N, 3)`` given in ``frame`` (:data:`FRAMES`) in this working frame."""
        import pymap3d

        x, y, z = np.asarray(xyz, dtype=float).T
        if frame == "local":
            return np.column_stack([x, y, z])
        if frame == "wgs84":
            x, y, z = pymap3d.geodetic2ecef(y, x, z)
        if self.kind == "ecef":
            return np.column_stack([x, y, z])
        return np.column_stack(pymap3d.ecef2enu(x, y, z, *self.origin))

    def geodetic(self, xyz: np.ndarray) -> np.ndarray:
        """``(N, 3)`` latitude, longitude (degrees), height (metres) of working-frame points."""
        import pymap3d

        if not self.georeferenced:
            raise ConfigError(f"no geographic coordinates: {self.why_not_georeferenced()}")
        p = np.asarray(xyz, dtype=float)
        if p.shape[-1] == 2:
            p = np.column_stack([p, np.zeros(len(p))])
        if self.kind == "ecef":
            return np.column_stack(pymap3d.ecef2geodetic(*p.T))
        return np.column_stack(pymap3d.enu2geodetic(*p.T, *self.origin))


def working_frame(declared: str, origin: tuple[float, float, float] | None) -> Frame:
    """The working frame for anchors in ``declared`` (module docstring)."""
    if origin is not None:
        return Frame("enu", origin)
    return Frame("local") if declared == "local" else Frame("ecef")


def to_working(table: pd.DataFrame, declared: str, frame: Frame, what: str = "anchors"
               ) -> pd.DataFrame:
    """``table`` (``x, y[, z]``) with its coordinates in the working frame ``frame``.

    Raises
    ------
    InputError
        Geodetic coordinates without ``z`` (ECEF needs three), or a latitude beyond 90.
    """
    if declared == "local":
        return table
    if "z" not in table.columns:
        raise InputError(f"{what}: frame {declared!r} needs a 'z' column (the height or the "
                         "ECEF z)")
    if declared == "wgs84" and (np.abs(table["y"].to_numpy(float)) > 90).any():
        raise InputError(f"{what}: frame 'wgs84' reads x as longitude and y as latitude "
                         "(degrees); a y beyond 90 is not a latitude")
    xyz = frame.from_frame(table[["x", "y", "z"]].to_numpy(float), declared)
    return table.assign(x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2])


def horizontal_at_start(estimates: pd.DataFrame, reference: pd.DataFrame, frame: Frame
                        ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Estimates and reference of an ECEF run in the east-north-up frame at the reference's
    first point, horizontal only (``x`` east, ``y`` north, the covariance's horizontal
    block): what ``--reference`` scores, as the GNSS literature reports horizontal errors.
    Other frames are returned unchanged.

    Parameters
    ----------
    estimates : DataFrame
        A ``locate`` output table in the working frame.
    reference : DataFrame
        The reference in the working frame (``x, y, z``).
    frame : Frame

    Returns
    -------
    estimates, reference : DataFrame
    """
    from radioloc.locate.table import COVARIANCE_COLUMNS, add_covariance, covariance_of

    if frame.kind != "ecef" or "z" not in estimates or "z" not in reference:
        return estimates, reference
    import pymap3d

    origin = pymap3d.ecef2geodetic(*reference[["x", "y", "z"]].to_numpy(float)[0])
    rot, _ = Frame("enu", origin).to_ecef()

    def enu(table):
        e, n, _ = pymap3d.ecef2enu(*table[["x", "y", "z"]].to_numpy(float).T, *origin)
        return table.drop(columns="z").assign(x=e, y=n)

    cov = covariance_of(estimates)
    out = enu(estimates.drop(columns=[c for c in COVARIANCE_COLUMNS[3] + ("uncertainty_m",)
                                      if c in estimates]))
    if cov is not None and cov.shape[-1] == 3:
        out = add_covariance(out, (rot.T @ cov @ rot)[:, :2, :2])
    return out, enu(reference)
