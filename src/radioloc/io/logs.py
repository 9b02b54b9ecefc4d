"""Users' measurement logs: reading and validating the CSV schema of ``radioloc locate``.

Measurements CSV, one row per measurement:

==========  =======================================================================
column      meaning
==========  =======================================================================
``time``    time stamp in seconds (number); rows with equal time form one epoch
``node``    id of the node that measured (text)
``peer``    id of the other end: an anchor id or another node's id (text)
``kind``    ``range`` (metres) or ``rss`` (dBm)
``value``   the measured value (number; a range must be >= 0)
==========  =======================================================================

Anchors CSV: ``id, x, y`` and optionally ``z`` (metres); ids unique.

Errors name the file, the line (as a spreadsheet shows it: the header is line 1) and the
column, so that a user can open the file and fix it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import numpy as np
import pandas as pd

from radioloc.core.errors import InputError

MEASUREMENT_COLUMNS = ("time", "node", "peer", "kind", "value")
KINDS = ("range", "rss")


def _read_csv(path: Path | str, what: str) -> pd.DataFrame:
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} file {path}: not found")
    try:
        frame = pd.read_csv(path, dtype=str, skipinitialspace=True, keep_default_na=False)
    except pd.errors.EmptyDataError:
        raise InputError(f"{path}: the file is empty") from None
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a readable CSV file ({str(exc).strip()})") from None
    frame.columns = [c.strip().lower() for c in frame.columns]
    if frame.empty:
        raise InputError(f"{path}: no data rows below the header")
    return frame


def _require_columns(frame: pd.DataFrame, columns: Iterable[str], path: Path | str) -> None:
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise InputError(f"{path}: missing column(s) {', '.join(missing)}; "
                         f"found {', '.join(frame.columns)}")


def _numeric(frame: pd.DataFrame, column: str, path: Path | str) -> pd.Series:
    raw = frame[column].str.strip()
    values = pd.to_numeric(raw, errors="coerce")
    bad = values.isna() & (raw.str.lower() != "nan") | (raw == "")
    if bad.any():
        i = int(np.flatnonzero(bad.to_numpy())[0])
        raise InputError(f"{path}: line {i + 2}, column '{column}': not a number: {raw.iloc[i]!r}")
    nonfinite = ~np.isfinite(values.to_numpy())
    if nonfinite.any():
        i = int(np.flatnonzero(nonfinite)[0])
        raise InputError(f"{path}: line {i + 2}, column '{column}': {raw.iloc[i]} is not a finite number")
    return values.astype(float)


def _ids(frame: pd.DataFrame, column: str, path: Path | str) -> pd.Series:
    ids = frame[column].str.strip()
    empty = ids == ""
    if empty.any():
        i = int(np.flatnonzero(empty.to_numpy())[0])
        raise InputError(f"{path}: line {i + 2}, column '{column}': empty id")
    return ids


def read_anchors(path: Path | str) -> pd.DataFrame:
    """Read and validate an anchors CSV (``id, x, y[, z]``).

    Returns a frame with columns ``id`` (str), ``x``, ``y`` and ``z`` if present.

    Raises
    ------
    InputError
        Missing column, text in a coordinate, non-finite coordinate, duplicate or empty id.
    """
    frame = _read_csv(path, "anchors")
    _require_columns(frame, ("id", "x", "y"), path)
    out = pd.DataFrame({"id": _ids(frame, "id", path)})
    for c in ("x", "y", "z"):
        if c in frame.columns:
            out[c] = _numeric(frame, c, path)
    dup = out["id"].duplicated()
    if dup.any():
        i = int(np.flatnonzero(dup.to_numpy())[0])
        raise InputError(f"{path}: line {i + 2}, column 'id': duplicate anchor id {out['id'].iloc[i]!r}")
    return out


def read_measurements(path: Path | str, *, anchors: pd.DataFrame | None = None) -> pd.DataFrame:
    """Read and validate a measurements CSV (``time, node, peer, kind, value``).

    Parameters
    ----------
    path : path
    anchors : DataFrame, optional
        The anchors table. If given, every ``peer`` must be an anchor id or an id that
        appears in the ``node`` column, otherwise :class:`InputError` names the row.

    Returns
    -------
    DataFrame with ``time`` (float), ``node``, ``peer`` (str), ``kind`` (str), ``value``
    (float), and ``line`` (the file line of each row, for later error messages).
    """
    frame = _read_csv(path, "measurements")
    _require_columns(frame, MEASUREMENT_COLUMNS, path)
    out = pd.DataFrame({
        "time": _numeric(frame, "time", path),
        "node": _ids(frame, "node", path),
        "peer": _ids(frame, "peer", path),
        "kind": frame["kind"].str.strip().str.lower(),
        "value": _numeric(frame, "value", path),
        "line": np.arange(2, len(frame) + 2),
    })
    bad_kind = ~out["kind"].isin(KINDS)
    if bad_kind.any():
        i = int(np.flatnonzero(bad_kind.to_numpy())[0])
        raise InputError(f"{path}: line {i + 2}, column 'kind': {frame['kind'].iloc[i]!r} is not one "
                         f"of {', '.join(KINDS)}")
    neg = (out["kind"] == "range") & (out["value"] < 0)
    if neg.any():
        i = int(np.flatnonzero(neg.to_numpy())[0])
        raise InputError(f"{path}: line {i + 2}, column 'value': negative range {out['value'].iloc[i]}")
    self_link = out["node"] == out["peer"]
    if self_link.any():
        i = int(np.flatnonzero(self_link.to_numpy())[0])
        raise InputError(f"{path}: line {i + 2}: node {out['node'].iloc[i]!r} measured itself")
    if anchors is not None:
        known = set(anchors["id"]) | set(out["node"])
        unknown = ~out["peer"].isin(known)
        if unknown.any():
            i = int(np.flatnonzero(unknown.to_numpy())[0])
            raise InputError(f"{path}: line {i + 2}, column 'peer': unknown anchor or node "
                             f"{out['peer'].iloc[i]!r} (not in the anchors file nor a node)")
        clash = out["node"].isin(set(anchors["id"]))
        if clash.any():
            i = int(np.flatnonzero(clash.to_numpy())[0])
            raise InputError(f"{path}: line {i + 2}, column 'node': {out['node'].iloc[i]!r} is an "
                             "anchor id; anchors do not need locating")
    return out


def write_estimates(frame: pd.DataFrame, path: Path | str | None) -> None:
    """Write ``time, node, x, y[, ...]`` estimates as CSV (stdout if ``path`` is None or '-')."""
    if path is None or str(path) == "-":
        import sys

        frame.to_csv(sys.stdout, index=False, float_format="%.6f")
    else:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        frame.to_csv(path, index=False, float_format="%.6f")
