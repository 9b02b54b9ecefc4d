"""Node priors CSV for the cooperative network methods (``radioloc locate --method rls|ekf``).

One row per node, prior mean and per-axis prior variance:

==========  ===============================================================
column      meaning
==========  ===============================================================
``node``    node id (text), as in the measurements' ``node``/``peer`` columns
``x, y``    prior mean position, metres
``var_x``   prior variance of ``x``, m^2 (> 0)
``var_y``   prior variance of ``y``, m^2 (> 0)
==========  ===============================================================

Example (a GPS-assisted node with 10 m standard deviation, an unassisted one with 100 m)::

    node,x,y,var_x,var_y
    A,120.0,40.0,100,100
    B,600.0,300.0,10000,10000
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.errors import InputError
from radioloc.io.logs import LIMITS, _check_magnitude, _ids, _numeric, _read_csv, _require_columns

PRIOR_COLUMNS = ("node", "x", "y", "var_x", "var_y")


def read_node_priors(path: Path | str) -> pd.DataFrame:
    """Read and validate a priors CSV (``node, x, y, var_x, var_y``).

    Parameters
    ----------
    path : Path or str
        The CSV file.

    Returns
    -------
    DataFrame with ``node`` (str), ``x``, ``y``, ``var_x``, ``var_y`` (float) and ``line``.

    Raises
    ------
    InputError
        Missing column, non-numeric or non-finite value, a coordinate or variance beyond
        :data:`radioloc.io.logs.LIMITS`, variance <= 0, duplicate node;
        the message names the file, line and column.
    """
    frame = _read_csv(path, "priors")
    _require_columns(frame, PRIOR_COLUMNS, path)
    out = pd.DataFrame({"node": _ids(frame, "node", path)})
    for c in PRIOR_COLUMNS[1:]:
        out[c] = _numeric(frame, c, path)
    out["line"] = np.arange(2, len(frame) + 2)
    for c in ("x", "y"):
        _check_magnitude(frame, out[c], c, LIMITS["coordinate_m"], "m", path)
    for c in ("var_x", "var_y"):
        _check_magnitude(frame, out[c], c, LIMITS["coordinate_m"] ** 2, "m^2", path)
        bad = out[c] <= 0
        if bad.any():
            i = int(np.flatnonzero(bad.to_numpy())[0])
            raise InputError(f"{path}: line {i + 2}, column '{c}': prior variance must be > 0 "
                             f"(m^2), got {out[c].iloc[i]}")
    dup = out["node"].duplicated()
    if dup.any():
        i = int(np.flatnonzero(dup.to_numpy())[0])
        raise InputError(f"{path}: line {i + 2}, column 'node': duplicate node "
                         f"{out['node'].iloc[i]!r}")
    return out
