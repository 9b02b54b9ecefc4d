"""Output formats of ``radioloc locate --out``: CSV, Parquet, TUM trajectory, GeoJSON.

The format is ``--format`` when given, otherwise the suffix of ``--out``: ``.parquet``,
``.tum``, ``.geojson``; anything else is CSV.

- **TUM** (the format of the TUM RGB-D benchmark, read by ``evo``): one line per estimate,
  ``timestamp tx ty tz qx qy qz qw``, space separated, orientation the identity
  (``0 0 0 1``), ``tz`` 0 for 2-D tracks. TUM holds one trajectory per file: with several
  nodes, ``track.tum`` becomes ``track.<node>.tum`` for each node, the id percent-encoded
  as in a URL (every character other than letters, digits, ``.``, ``_``, ``-``, ``~`` as
  ``%XX`` of its UTF-8 bytes: node ``a b`` goes to ``track.a%20b.tum``, ``a_b`` to
  ``track.a_b.tum``), so that the id is read back from the name with
  ``urllib.parse.unquote``. Two ids that differ only in case (one file on a
  case-insensitive file system) are refused, as is a name too long for a file system.
- **GeoJSON** (RFC 7946): a FeatureCollection with one ``LineString`` per node (properties
  ``node``, ``rows``) and one ``Point`` per estimate (properties ``time``, ``node`` and the
  other columns). Coordinates are WGS84 longitude, latitude and height (metres), converted
  from the working frame (:mod:`radioloc.locate.frames`); a run whose frame has no place on
  the Earth (local anchors without ``--origin``) is refused, saying so.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from urllib.parse import quote

import numpy as np
import pandas as pd

from radioloc.core.atomic import atomic_write_with
from radioloc.core.errors import ConfigError, OutputError
from radioloc.io.logs import write_estimates
from radioloc.locate.frames import Frame

FORMATS = ("csv", "parquet", "tum", "geojson")


def output_format(path: Path | None, given: str | None) -> str:
    """The format of ``--out path`` (``--format`` when given, else the suffix).

    Parameters
    ----------
    path : Path or None
        ``--out`` (None: standard output).
    given : str or None
        ``--format``.

    Returns
    -------
    str
        One of :data:`FORMATS`.

    Raises
    ------
    ConfigError
        An unknown format, or a binary format to standard output.
    """
    if given is not None:
        fmt = given.lower()
        if fmt not in FORMATS:
            raise ConfigError(f"--format {given!r}: expected one of {', '.join(FORMATS)}")
    elif path is None or str(path) == "-":
        fmt = "csv"
    else:
        fmt = {".parquet": "parquet", ".tum": "tum", ".geojson": "geojson"}.get(
            path.suffix.lower(), "csv")
    if fmt == "parquet" and (path is None or str(path) == "-"):
        raise ConfigError("--format parquet: needs a file (--out FILE.parquet)")
    return fmt


def _tum_text(frame: pd.DataFrame) -> str:
    z = frame["z"] if "z" in frame else pd.Series(0.0, index=frame.index)
    lines = [f"{t!r} {x!r} {y!r} {zz!r} 0 0 0 1" for t, x, y, zz in
             zip(frame["time"].astype(float), frame["x"].astype(float),
                 frame["y"].astype(float), z.astype(float))]
    return "# timestamp tx ty tz qx qy qz qw\n" + "\n".join(lines) + "\n"


def _json_value(v):
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    if isinstance(v, np.bool_):
        return bool(v)
    return v


def with_geodetic(frame: pd.DataFrame, where: Frame | None) -> pd.DataFrame:
    """``frame`` with columns ``lat, lon, height`` (WGS84 degrees, metres) of its positions
    when the working frame ``where`` has a place on the Earth; unchanged otherwise.

    Parameters
    ----------
    frame : DataFrame
        A ``locate`` output table (``x, y[, z]`` in the working frame).
    where : Frame or None

    Returns
    -------
    DataFrame
    """
    if where is None or not where.georeferenced or frame.empty:
        return frame
    dims = ["x", "y"] + (["z"] if "z" in frame else [])
    llh = where.geodetic(frame[dims].to_numpy(float))
    out = frame.assign(lat=llh[:, 0], lon=llh[:, 1], height=llh[:, 2])
    out.attrs = dict(frame.attrs)
    return out


def _lon_lat_h(table: pd.DataFrame, where: Frame) -> list:
    dims = ["x", "y"] + (["z"] if "z" in table else [])
    llh = where.geodetic(table[dims].to_numpy(float))
    return np.column_stack([llh[:, 1], llh[:, 0], llh[:, 2]]).tolist()


def geojson(frame: pd.DataFrame, anchors: pd.DataFrame | None = None,
            where: Frame | None = None) -> dict:
    """The estimates as a GeoJSON FeatureCollection (see the module docstring).

    Parameters
    ----------
    frame : DataFrame
        A ``locate`` output table.
    anchors : DataFrame, optional
        Anchors, added as ``Point`` features with ``"anchor": id`` (fixed anchors only:
        a moving anchor, such as a satellite, is left out).
    where : Frame
        The working frame of the positions (it must have a place on the Earth).

    Returns
    -------
    dict

    Raises
    ------
    ConfigError
        ``where`` is None or local (no place on the Earth), saying so.
    """
    if where is None or not where.georeferenced:
        raise ConfigError("GeoJSON is longitude and latitude (RFC 7946), and "
                          + (where or Frame()).why_not_georeferenced())
    features = []
    for node, g in frame.groupby("node", sort=False):
        features.append({"type": "Feature", "properties": {"node": str(node), "rows": len(g)},
                         "geometry": {"type": "LineString", "coordinates": _lon_lat_h(g, where)}})
    dims = {"x", "y", "z", "lat", "lon", "height"}
    other = [c for c in frame.columns if c not in dims]
    for rec, xyz in zip(frame[other].to_dict("records"), _lon_lat_h(frame, where)):
        features.append({"type": "Feature",
                         "properties": {k: _json_value(v) for k, v in rec.items()},
                         "geometry": {"type": "Point", "coordinates": xyz}})
    if anchors is not None and not ("time" in anchors and anchors["time"].notna().any()):
        for aid, xyz in zip(anchors["id"], _lon_lat_h(anchors, where)):
            features.append({"type": "Feature", "properties": {"anchor": str(aid)},
                             "geometry": {"type": "Point", "coordinates": xyz}})
    return {"type": "FeatureCollection", "features": features}


def output_files(nodes: list, path: Path | None, fmt: str) -> dict[Path, object]:
    """The files :func:`write_output` writes: for TUM with several nodes one per node.

    Parameters
    ----------
    nodes : list
        The output's node ids, in order.
    path : Path or None
        ``--out`` (None or ``-``: standard output, no file).
    fmt : str
        From :func:`output_format`.

    Returns
    -------
    dict of Path to node id
        Each file and the node it holds (None: every node).

    Raises
    ------
    ConfigError
        TUM to standard output with several nodes.
    OutputError
        Two nodes whose files would be one on a case-insensitive file system, or a
        per-node name too long for a file system (255 bytes).
    """
    if path is None or str(path) == "-":
        if fmt == "tum" and len(nodes) > 1:
            raise ConfigError("--format tum: one trajectory per file; with several nodes give "
                              "--out FILE.tum (one file per node)")
        return {}
    path = Path(path)
    if fmt != "tum" or len(nodes) == 1:
        return {path: None}
    files: dict[Path, object] = {}
    folded: dict[str, object] = {}
    for node in nodes:
        name = f"{path.stem}.{quote(str(node), safe='')}{path.suffix}"
        if name.casefold() in folded:
            raise OutputError(f"--out {path}: nodes {folded[name.casefold()]!r} and {node!r} "
                              "differ only in case and would write one file on a "
                              "case-insensitive file system; rename one")
        if len(name.encode()) > 255:
            raise OutputError(f"--out {path}: the file name of node {node!r} would be "
                              f"{len(name.encode())} bytes long (a file system allows 255); "
                              "give a shorter --out name or id")
        folded[name.casefold()] = node
        files[path.with_name(name)] = node
    return files


def write_output(frame: pd.DataFrame, path: Path | None, fmt: str,
                 anchors: pd.DataFrame | None = None, where: Frame | None = None) -> list[Path]:
    """Write ``frame`` to ``path`` (None: standard output) in format ``fmt``.

    Parameters
    ----------
    frame : DataFrame
        A ``locate`` output table.
    path : Path or None
    fmt : str
        From :func:`output_format`.
    anchors : DataFrame, optional
        For GeoJSON.
    where : Frame, optional
        The working frame (GeoJSON needs one with a place on the Earth).

    Returns
    -------
    list of Path
        Files written (empty for standard output), those of :func:`output_files`.
    """
    files = output_files(list(frame["node"].unique()), path, fmt)
    if fmt in ("csv", "parquet"):
        write_estimates(frame, path)
        return list(files)

    def render(part: pd.DataFrame) -> str:
        if fmt == "geojson":
            return json.dumps(geojson(part, anchors, where), indent=1) + "\n"
        return _tum_text(part)

    if not files:
        import sys
        sys.stdout.write(render(frame))
        return []
    for target, node in files.items():
        text = render(frame if node is None else frame[frame["node"] == node])
        atomic_write_with(target, lambda f, text=text: f.write(text))
    return list(files)
