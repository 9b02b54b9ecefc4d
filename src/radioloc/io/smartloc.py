"""Reader of the smartLoc GNSS text format (TU Chemnitz, as preprocessed for libRSF).

One measurement per line, space separated, the first word its type (see the data set's
SOURCE.md; Reisdorf, Pfeifer, Bressler, Bauer, Weissig, Lange, CC BY-SA 4.0):

- ``pseudorange3 t rho var sx sy sz sat system elevation_deg cn0_dbhz``: a pseudorange
  (metres, atmospheric errors and the satellite clock removed, the receiver clock NOT
  removed), its variance (m^2), the satellite's ECEF position at the epoch (metres), its id,
  its system (1 GPS, 2 SBAS, 4 GLONASS, 8 Galileo, 16 QZSS, 32 BeiDou), elevation, C/N0;
- ``odom3 t vx vy vz wx wy wz`` and the six variances: the car's velocity in its own body
  frame (m/s; ``vx`` forward) and turn rates (rad/s; ``wz`` the yaw rate);
- ``point3 t x y z`` and nine covariance cells: the reference position in ECEF (metres).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.errors import DataUnavailable, InputError

__all__ = ["SYSTEMS", "SmartLoc", "load", "satellite_id", "DRIVES"]

#: The system codes of the format and their names (the ``group`` of a satellite).
SYSTEMS = {1: "GPS", 2: "SBAS", 4: "GLONASS", 8: "Galileo", 16: "QZSS", 32: "BeiDou"}
#: The one-letter prefix of a satellite id per system (RINEX convention).
_PREFIX = {1: "G", 2: "S", 4: "R", 8: "E", 16: "J", 32: "C"}
#: The drives of the data set: name -> file stem.
DRIVES = {"berlin-potsdamer-platz": "Berlin_Potsdamer_Platz"}

_WIDTH = {"pseudorange3": 11, "odom3": 14, "point3": 14}


@dataclass(frozen=True)
class SmartLoc:
    """One drive of the smartLoc set.

    Attributes
    ----------
    pseudoranges : DataFrame
        ``time, satellite, system, value, variance, x, y, z, elevation_deg, cn0_dbhz``:
        one row per pseudorange; ``satellite`` e.g. ``"G12"``, ``"R20"``; ``system`` the
        name of :data:`SYSTEMS`; ``x, y, z`` the satellite's ECEF position.
    odometry : DataFrame
        ``time, speed_mps, vertical_mps, yaw_rate_rps, speed_var, vertical_var,
        yaw_rate_var`` (forward and vertical body-frame speeds and the turn rate about the
        vertical, with their variances).
    reference : DataFrame
        ``time, x, y, z``: the reference positions, ECEF metres.
    """

    pseudoranges: pd.DataFrame
    odometry: pd.DataFrame
    reference: pd.DataFrame


def satellite_id(number, system) -> np.ndarray:
    """Satellite ids ``<letter><nn>`` from the format's number and system code.

    GLONASS numbers are written above 300 (``320`` is slot 20: ``R20``), other systems as
    their PRN.

    Parameters
    ----------
    number, system : array_like of int

    Returns
    -------
    ndarray of str
    """
    number = np.asarray(number, dtype=int)
    system = np.asarray(system, dtype=int)
    prn = np.where((system == 4) & (number > 300), number - 300, number)
    return np.array([f"{_PREFIX.get(int(s), 'X')}{int(p):02d}" for s, p in zip(system, prn)],
                    dtype=object)


def _rows(path: Path, kind: str) -> np.ndarray:
    """The numeric cells of the lines of type ``kind`` in ``path`` (``(N, width - 1)``)."""
    if not path.is_file():
        raise DataUnavailable(f"{path}: not found")
    width = _WIDTH[kind]
    out = []
    with path.open() as fh:
        for number, line in enumerate(fh, start=1):
            cells = line.split()
            if not cells or cells[0] != kind:
                continue
            if len(cells) != width:
                raise InputError(f"{path}: line {number}: {kind} has {len(cells)} fields, "
                                 f"expected {width}")
            try:
                out.append([float(c) for c in cells[1:]])
            except ValueError:
                raise InputError(f"{path}: line {number}: a {kind} field is not a number") from None
    if not out:
        raise InputError(f"{path}: no {kind} line")
    values = np.asarray(out)
    if not np.isfinite(values).all():
        raise InputError(f"{path}: a {kind} field is not finite")
    return values


def load(folder: Path | str, drive: str = "berlin-potsdamer-platz") -> SmartLoc:
    """Read one drive: pseudoranges and odometry (``*_Input.txt``), reference (``*_GT.txt``).

    Parameters
    ----------
    folder : path
        The data set folder.
    drive : str
        A key of :data:`DRIVES`.

    Returns
    -------
    SmartLoc

    Raises
    ------
    DataUnavailable
        A file is absent.
    InputError
        A line with the wrong number of fields or a field that is not a finite number
        (naming the file and the line).
    """
    if drive not in DRIVES:
        raise InputError(f"drive {drive!r}: known drives {', '.join(DRIVES)}")
    folder = Path(folder)
    stem = DRIVES[drive]
    src = folder / f"{stem}_Input.txt"
    pr = _rows(src, "pseudorange3")
    system = pr[:, 7].astype(int)
    pseudoranges = pd.DataFrame({
        "time": pr[:, 0], "satellite": satellite_id(pr[:, 6], system),
        "system": [SYSTEMS.get(int(s), str(int(s))) for s in system],
        "value": pr[:, 1], "variance": pr[:, 2], "x": pr[:, 3], "y": pr[:, 4], "z": pr[:, 5],
        "elevation_deg": pr[:, 8], "cn0_dbhz": pr[:, 9]})
    od = _rows(src, "odom3")
    odometry = pd.DataFrame({"time": od[:, 0], "speed_mps": od[:, 1], "vertical_mps": od[:, 3],
                             "yaw_rate_rps": od[:, 6], "speed_var": od[:, 7],
                             "vertical_var": od[:, 9], "yaw_rate_var": od[:, 12]})
    gt = _rows(folder / f"{stem}_GT.txt", "point3")
    reference = pd.DataFrame({"time": gt[:, 0], "x": gt[:, 1], "y": gt[:, 2], "z": gt[:, 3]})
    return SmartLoc(pseudoranges, odometry, reference)
