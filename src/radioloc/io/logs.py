"""Users' measurement logs: reading and validating the CSV schema of ``radioloc locate``.

Measurements CSV, one row per measurement:

==========  =======================================================================
column      meaning
==========  =======================================================================
``time``    time stamp in seconds (number); rows with equal time form one epoch
``node``    id of the node that measured (text)
``peer``    id of the other end: an anchor id or another node's id (text)
``kind``    one of the kinds of :func:`radioloc.core.kinds.kinds` (their units and
            meanings: the kinds table of the docs): ``range`` (metres), ``rss``
            (dBm), ``tdoa`` (range to ``peer`` minus to ``reference``, metres), ``aoa``,
            ``aoa_elevation``, ``heading`` (radians), ``pseudorange`` (metres),
            ``odometry_dx`` / ``odometry_dy`` (the node's displacement, metres, in pairs
            with the same time; ``peer`` names the sensor), ``speed``,
            ``vertical_speed`` (m/s) and ``yaw_rate`` (rad/s: a vehicle's body-frame
            odometry; ``peer`` names the sensor), and any kind another package declares
``value``   the measured value (number; a range must be >= 0, or above -6 times the
            row's ``std`` (:func:`~radioloc.core.validation.check_ranges`), then read as 0)
``reference`` optional: the second reference point of a ``tdoa`` row (its reference
            anchor); empty for other kinds (a cell on another kind is refused)
``std``     optional: the standard deviation of this measurement in the value's unit
            (at least 1e-30, below which its inverse squared overflows; empty: the
            method's default), e.g. the sigma a WiFi RTT phone reports
==========  =======================================================================

Anchors CSV: ``id, x, y`` and optionally ``z`` (metres); ids unique. Optional: ``frame``
(``local``, ``ecef`` or ``wgs84``, see :mod:`radioloc.locate.frames`), ``group`` (the
receiver clock a pseudorange to the anchor is read with: its constellation, e.g. ``GPS``),
``time`` (a moving anchor, one row per position).

Errors name the file, the line (as a text editor shows it: the header is line 1; blank
lines and quoted line breaks counted) and the column, so that a user can open the file and
fix it. Refused besides malformed cells: a column named twice, a row with more or fewer
cells than the header, magnitudes no real log holds (see :data:`LIMITS`: a range beyond
10,000 km, an RSS above +30 dBm, such as the +100 dBm "not detected" sentinel of WiFi
fingerprint sets, or below -200 dBm, a time stamp beyond 1e12 s, an anchor coordinate
beyond 50,000 km, which admits satellites in ECEF).

Estimates are written with every float in its shortest exact form (``repr``), so that the
times and positions read back are bit-for-bit the ones computed; the file is written to a
temporary name and renamed, so it is complete or absent.

Spreadsheets run a CSV cell that begins with ``=``, ``+``, ``-`` or ``@`` as a formula. A
text cell written to CSV (a node or anchor id) that begins with one of them, after any
apostrophes, and is not a number gets one more apostrophe in front (``=A1`` is written
``'=A1``, ``'=A1`` is written ``''=A1``), as spreadsheets expect of literal text; the
readers of this module take that apostrophe off again, so ids survive a round trip
(:func:`spreadsheet_cell`, :func:`spreadsheet_text`).
"""

from __future__ import annotations

import codecs
import csv
import io
import itertools
import os
import re
import sys
import warnings
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np
import pandas as pd

from radioloc.core.atomic import atomic_write_with
from radioloc.core.errors import InputError
from radioloc.core.kinds import kinds
from radioloc.core.validation import NEGATIVE_RANGE_SIGMAS, POSITIVE_FLOOR, range_floor_m

MEASUREMENT_COLUMNS = ("time", "node", "peer", "kind", "value")
#: Anchors-file columns radioloc reads, or writes with ``radioloc calibrate`` (the
#: calibrated positions' covariance and bound, a record kept with them); the kinds' models
#: read theirs (:attr:`radioloc.core.kinds.Kind.anchor_columns`); any other is refused.
ANCHOR_COLUMNS = ("id", "x", "y", "z", "time", "frame", "group", "std_m", "bias_m",
                  "bias_std_m", "cov_xx", "cov_xy", "cov_xz", "cov_yy", "cov_yz", "cov_zz",
                  "crb_std_m")
#: Kinds that are motion inputs of the node itself (their ``peer`` names the sensor).
MOTION_KINDS = ("odometry_dx", "odometry_dy")
#: Anchor columns of a log-distance RSS model per anchor: mean RSS at 1 m (dBm), path-loss
#: exponent, residual standard deviation (dB).
ANCHOR_RSS_COLUMNS = ("rss_a_dbm", "rss_n", "rss_std_db")

#: Plausibility limits of the input values (refused beyond, naming line and column); a
#: kind's values have their kind's limit (:attr:`radioloc.core.kinds.Kind.limit`).
LIMITS = {
    "range_m": 1e7,          # 10,000 km: beyond any terrestrial link
    "coordinate_m": 5e7,     # |x|, |y|, |z| of an anchor: satellites in ECEF (GNSS orbits
                             # 2.7e7 m from the Earth's centre, geostationary 4.2e7 m) fit
    "rss_max_dbm": 30.0,     # 1 W received
    "rss_min_dbm": -200.0,   # far below thermal noise in any bandwidth
    "time_s": 1e12,          # ~31,700 years; epoch milliseconds are 1.7e12
}
RSS_NOT_DETECTED_DBM = 100.0


def _line(frame: pd.DataFrame, i: int) -> int:
    """File line of row ``i`` (position) of a frame read by :func:`_read_csv`."""
    lines = frame.attrs.get("lines")
    return int(lines[i]) if lines is not None and i < len(lines) else i + 2


def _table_text(path: Path) -> str:
    """The text of the table: the CSV file itself, or a Parquet file's cells as CSV."""
    if path.suffix.lower() == ".parquet":
        from radioloc.io.datasets import read_table_text

        return read_table_text(path).to_csv(index=False)
    from radioloc.core.textfile import decode_text

    return decode_text(path.read_bytes(), path)


def _open_table(path: Path):
    """A text stream of :func:`_table_text`."""
    return io.StringIO(_table_text(path), newline="")


def _read_plain_csv(path: Path, preserve_case: bool) -> pd.DataFrame | None:
    """:func:`_read_csv` by a CSV parser in C for a plain file, else None.

    Plain: no quote character, the header on line 1, every line (none blank or of empty
    cells) with as many cells as the header, lines ending in ``\n`` or ``\r\n``, unique
    non-empty column names. Then each row is one line, so the result (cells, line
    numbers) is the one of the general reader, which reads every other file and words
    every error.
    """
    try:
        data = _table_bytes(path)
    except (OSError, InputError):
        return None
    return plain_cells(data, preserve_case)


def plain_cells(data: bytes, preserve_case: bool = False) -> pd.DataFrame | None:
    """The text cells of a plain CSV (see :func:`_read_plain_csv`) in UTF-8 ``data``, with
    ``attrs["lines"]`` counted from line 2; None when ``data`` is not plain."""
    if b'"' in data or not data or data[:1] in (b"\r", b"\n"):
        return None
    if b"\r" in data and data.count(b"\r") != data.count(b"\r\n"):
        return None                              # a line break other than \n or \r\n
    end = data.find(b"\n")
    first = (data if end < 0 else data[:end]).decode("utf-8").rstrip("\r")
    names = [c.strip() if preserve_case else c.strip().lower() for c in first.split(",")]
    if "" in names or len(set(names)) != len(names):
        return None
    frame = _plain_cells(data, len(names))
    if frame is None or frame.empty:
        return None
    empty = np.ones(len(frame), dtype=bool)
    for c in frame.columns:
        col = frame[c]
        if col.isna().any():
            return None
        empty &= (col.str.strip() == "").to_numpy()
        if not empty.any():   # a cell with text in every row: no row of empty cells
            break
    if empty.any():
        return None
    frame.columns = names
    frame = frame.astype(str)
    frame.attrs["lines"] = np.arange(2, len(frame) + 2)
    return frame


def measurement_blocks(path: Path | str, rows: int) -> Iterator[pd.DataFrame | None]:
    """The text cells of a plain CSV file (:func:`plain_cells`) in blocks of ``rows`` lines,
    read one block at a time (a Parquet file: a batch of ``rows`` rows at a time, its cells
    as the whole file's reader writes them as CSV); ``attrs["lines"]`` holds each row's
    file line.

    Parameters
    ----------
    path : path
    rows : int

    Yields
    ------
    DataFrame or None
        None (and nothing more) where the file, or a block of it, is not plain (a quote
        character, a blank line, a byte-order mark, bytes that are not UTF-8, ...): such a
        file is read whole by :func:`read_measurements`.
    """
    parquet = Path(path).suffix.lower() == ".parquet"
    done = 0
    for data, count in (_parquet_data if parquet else _csv_data)(path, rows):
        try:
            frame = None if data is None else plain_cells(data)
        except UnicodeDecodeError:
            frame = None
        if frame is None or len(frame) != count:
            yield None
            return
        frame.attrs["lines"] = frame.attrs["lines"] + done
        done += count
        yield frame


def _csv_data(path: Path | str, rows: int) -> Iterator[tuple[bytes | None, int]]:
    """The header and the next ``rows`` lines of a CSV file, as bytes, and their count
    (None: a byte-order mark)."""
    with open(path, "rb") as fh:
        header = fh.readline()
        if header.startswith((codecs.BOM_UTF8, codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
            yield None, 0
            return
        while lines := list(itertools.islice(fh, rows)):
            yield header + b"".join(lines), len(lines)


def _parquet_data(path: Path | str, rows: int) -> Iterator[tuple[bytes | None, int]]:
    """The next ``rows`` rows of a Parquet file as the CSV text :func:`_table_text` writes of
    the whole table, and their count (None: a file pyarrow cannot read)."""
    from radioloc.io.datasets import parquet_text_blocks

    try:
        for cells in parquet_text_blocks(path, rows):
            yield cells.to_csv(index=False).encode("utf-8"), len(cells)
    except Exception:        # noqa: BLE001 - the whole file's reader words the error
        yield None, 0


def _table_bytes(path: Path) -> bytes:
    """:func:`_table_text` as UTF-8 bytes (the file's own bytes when they are UTF-8 without
    a byte-order mark)."""
    if path.suffix.lower() == ".parquet":
        return _table_text(path).encode("utf-8")
    from radioloc.core.textfile import decode_text

    raw = path.read_bytes()
    text = decode_text(raw, path)        # refuses bytes that are not text
    if raw.startswith((codecs.BOM_UTF8, codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        return text.encode("utf-8")
    return raw


def _plain_cells(data: bytes, width: int) -> pd.DataFrame | None:
    """The cells below the header of a plain CSV (see :func:`_read_plain_csv`) as text,
    spaces after a comma skipped; None if a line has another number of cells than
    ``width`` or the parser refuses the file.

    pyarrow's CSV reader when installed (no quoting), else pandas' C parser.
    """
    try:
        from pyarrow import csv as pa_csv
        import pyarrow as pa
        import pyarrow.compute as pc
    except ImportError:
        # every line (the header's included) must have as many cells: count its commas
        raw = np.frombuffer(data, dtype=np.uint8)
        ends = np.flatnonzero(raw == 10)
        if not data.endswith(b"\n"):
            ends = np.append(ends, raw.size)
        commas = np.searchsorted(np.flatnonzero(raw == 44), ends)   # before each line end
        if np.any(np.diff(commas, prepend=0) != width - 1):
            return None
        try:
            return pd.read_csv(io.BytesIO(data), header=None, skiprows=1, names=range(width),
                               dtype=str, na_filter=False, skipinitialspace=True,
                               skip_blank_lines=False, engine="c", on_bad_lines="error")
        except (ValueError, pd.errors.ParserError):
            return None
    names = [str(j) for j in range(width)]
    try:   # refuses a line with more or fewer cells; a blank line is a row of empty cells
        table = pa_csv.read_csv(
            io.BytesIO(data),
            read_options=pa_csv.ReadOptions(use_threads=False, skip_rows=1, column_names=names),
            parse_options=pa_csv.ParseOptions(quote_char=False, ignore_empty_lines=False),
            convert_options=pa_csv.ConvertOptions(   # pandas' own string type: no copy
                column_types={n: pa.large_string() for n in names}, strings_can_be_null=False))
    except (pa.ArrowInvalid, ValueError):
        return None
    if b", " in data or b"\n " in data or data.startswith(b" "):   # spaces to skip
        table = pa.table([pc.utf8_ltrim(table.column(n), characters=" ") for n in names], names)
    frame = table.to_pandas()
    frame.columns = range(width)
    return frame


def _read_csv(path: Path | str, what: str, preserve_case: bool = False) -> pd.DataFrame:
    """Read a CSV as text cells with lower-case (or, with ``preserve_case``, as written),
    stripped, unique column names.

    The frame's ``attrs["lines"]`` holds the file line where each row starts (blank lines
    and rows of empty cells are skipped but counted).
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{what} file {path}: not found")
    if path.is_dir():
        raise InputError(f"{what} file {path}: is a folder, not a file")
    fast = _read_plain_csv(path, preserve_case)
    if fast is not None:
        return fast
    header: list[str] | None = None
    header_line = 1
    rows: list[list[str]] = []
    lines: list[int] = []
    line = 0
    try:
        with _open_table(path) as fh:
            reader = csv.reader(fh, skipinitialspace=True)
            while True:
                line = reader.line_num + 1
                try:
                    rec = next(reader)
                except StopIteration:
                    break
                if not any(c.strip() for c in rec):
                    continue
                if header is None:
                    header, header_line = rec, line
                else:
                    rows.append(rec)
                    lines.append(line)
    except csv.Error as exc:
        raise InputError(f"{path}: line {line}: not readable as CSV ({exc})") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if header is None:
        raise InputError(f"{path}: the file is empty")
    names = [c.strip() if preserve_case else c.strip().lower() for c in header]
    width = len(names)
    for k, rec in enumerate(rows):
        if len(rec) != width and any(c.strip() for c in rec[width:]) or len(rec) < width:
            raise InputError(f"{path}: line {lines[k]}: {len(rec)} cells, the header (line "
                             f"{header_line}) has {width}")
        if len(rec) > width:
            rows[k] = rec[:width]
    if not rows:
        raise InputError(f"{path}: no data rows below the header")
    keep = []
    for j, name in enumerate(names):
        if name == "":
            if any(r[j].strip() for r in rows):
                raise InputError(f"{path}: line {header_line}: column {j + 1} holds values but "
                                 "has no name in the header")
            continue
        if name in names[:j]:
            first = names.index(name)
            raise InputError(f"{path}: line {header_line}: column '{name}' appears twice "
                             f"(columns {first + 1} and {j + 1}); which one is meant?")
        keep.append(j)
    frame = pd.DataFrame([[r[j] for j in keep] for r in rows],
                         columns=[names[j] for j in keep], dtype=str)
    frame.attrs["lines"] = np.asarray(lines)
    return frame


def read_cells(path: Path | str, what: str) -> pd.DataFrame:
    """Read a CSV as text cells keeping the column names' case (e.g. a calibration file whose
    columns are station ids), with the checks of the measurements reader: a column named
    twice, a row with more or fewer cells than the header, an unnamed column holding values.

    Parameters
    ----------
    path : path
        The file (CSV, or Parquet read as its cells).
    what : str
        What the file is, for messages ("calibration").

    Returns
    -------
    DataFrame
        Text cells, column names stripped; ``attrs["lines"]`` = the file line of each row.

    Raises
    ------
    InputError
        Naming the file and line.
    """
    return _read_csv(path, what, preserve_case=True)


def _require_columns(frame: pd.DataFrame, columns: Iterable[str], path: Path | str) -> None:
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise InputError(f"{path}: missing column(s) {', '.join(missing)}; "
                         f"found {', '.join(frame.columns)}")


def _floats(cells: pd.Series) -> np.ndarray | None:
    """``cells`` (stripped text) as numbers by pyarrow's parser when every one is a finite
    number; None otherwise (or without pyarrow), for the general parser to word the error."""
    try:
        import pyarrow as pa
        import pyarrow.compute as pc
    except ImportError:
        return None
    try:
        values = pc.cast(pa.array(cells), pa.float64()).to_numpy(zero_copy_only=False)
    except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError):
        return None
    return values if np.isfinite(values).all() else None


def _text(frame: pd.DataFrame, column: str, lower: bool = False) -> pd.Series:
    """The cells of ``column`` stripped (and lower-cased), worked out once per distinct cell."""
    cells = frame[column].astype(str)
    codes, distinct = pd.factorize(cells)
    text = pd.Series(distinct, dtype=cells.dtype).str.strip()
    if lower:
        text = text.str.lower()
    if np.array_equal(text.to_numpy(), np.asarray(distinct, dtype=object)):
        return cells
    return pd.Series(text.array.take(codes), index=cells.index, name=cells.name)


def _numeric(frame: pd.DataFrame, column: str, path: Path | str) -> pd.Series:
    cells = frame[column].astype(str)
    fast = _floats(cells)                # cells without spaces around the number
    if fast is not None:
        return pd.Series(fast, index=cells.index, name=cells.name)
    raw = cells.str.strip()
    fast = _floats(raw)
    if fast is not None:
        return pd.Series(fast, index=raw.index, name=raw.name)
    values = pd.to_numeric(raw, errors="coerce").astype(float)
    bad = values.isna() & (raw.str.lower() != "nan") | (raw == "")
    if bad.any():
        i = int(np.flatnonzero(bad.to_numpy())[0])
        raise InputError(f"{path}: line {_line(frame, i)}, column '{column}': not a number: "
                         f"{raw.iloc[i]!r}")
    nonfinite = ~np.isfinite(values.to_numpy())
    if nonfinite.any():
        i = int(np.flatnonzero(nonfinite)[0])
        raise InputError(f"{path}: line {_line(frame, i)}, column '{column}': {raw.iloc[i]} is "
                         "not a finite number")
    return values


def _optional_number(frame: pd.DataFrame, column: str, path: Path | str, *,
                     minimum: float | None = None, exclusive: bool = False) -> pd.Series:
    """An optional number column: empty cells NaN, others finite (and above ``minimum``)."""
    raw = frame[column].astype(str).str.strip()
    empty = (raw == "") | (raw.str.lower() == "nan")
    values = _numeric(frame.assign(**{column: raw.where(~empty, "0")}), column, path)
    values = values.where(~empty, np.nan)
    if minimum is not None:
        v = values.to_numpy()
        below = (v <= minimum) if exclusive else (v < minimum)
        if (i := _first(below)) is not None:
            raise InputError(f"{path}: line {_line(frame, i)}, column '{column}': {raw.iloc[i]} "
                             f"must be {'>' if exclusive else '>='} {minimum:g} (leave the cell "
                             "empty for the default)")
    return values


# ids that CSV readers (pandas, R) read back as a missing value: a node called "nan" would
# vanish from whoever reads our output, so such ids are refused (compared case-blind)
MISSING_IDS = frozenset(v.lower() for v in (
    "#N/A", "#N/A N/A", "#NA", "-1.#IND", "-1.#QNAN", "-NaN", "-nan", "1.#IND", "1.#QNAN",
    "<NA>", "N/A", "NA", "NULL", "NaN", "None", "n/a", "nan", "null"))


#: A text cell a spreadsheet would run as a formula, after the apostrophes that escape it.
_FORMULA = re.compile(r"'*[=+\-@]")


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def spreadsheet_cell(text: str) -> str:
    """``text`` as a CSV cell: one apostrophe in front when a spreadsheet would run it as
    a formula (see the module docstring); :func:`spreadsheet_text` undoes it.

    Parameters
    ----------
    text : str

    Returns
    -------
    str
    """
    return "'" + text if _FORMULA.match(text) and not _is_number(text) else text


def spreadsheet_text(cell: str) -> str:
    """The text of a CSV cell written by :func:`spreadsheet_cell` (its escaping apostrophe
    taken off).

    Parameters
    ----------
    cell : str

    Returns
    -------
    str
    """
    return cell[1:] if cell.startswith("'") and _FORMULA.match(cell, 1) else cell


def _spreadsheet_safe(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` with every text cell through :func:`spreadsheet_cell` (a copy only when
    a cell changes)."""
    changed = {}
    for name in frame.columns:
        col = frame[name]
        if isinstance(col.dtype, pd.StringDtype) or col.dtype.kind in "OU":
            distinct = [v for v in col.unique() if isinstance(v, str)]
            escaped = {v: spreadsheet_cell(v) for v in distinct}
            if any(k != v for k, v in escaped.items()):
                changed[name] = col.map(lambda v: escaped.get(v, v) if isinstance(v, str) else v)
    return frame.assign(**changed) if changed else frame


def _unescaped(cells: pd.Series) -> pd.Series:
    """Text cells through :func:`spreadsheet_text` (worked out once per distinct cell)."""
    distinct = cells.unique()
    if any(c.startswith("'") for c in distinct):
        return cells.map({c: spreadsheet_text(c) for c in distinct})
    return cells


def _ids(frame: pd.DataFrame, column: str, path: Path | str) -> pd.Series:
    ids = _unescaped(_text(frame, column))
    empty = ids == ""
    if empty.any():
        i = int(np.flatnonzero(empty.to_numpy())[0])
        raise InputError(f"{path}: line {_line(frame, i)}, column '{column}': empty id")
    missing = ids.isin([i for i in ids.unique() if i.lower() in MISSING_IDS])
    if missing.any():
        i = int(np.flatnonzero(missing.to_numpy())[0])
        raise InputError(f"{path}: line {_line(frame, i)}, column '{column}': id "
                         f"{ids.iloc[i]!r} reads as a missing value in CSV readers; rename it")
    return ids


def _first(mask: pd.Series | np.ndarray) -> int | None:
    idx = np.flatnonzero(np.asarray(mask))
    return int(idx[0]) if idx.size else None


def _check_magnitude(frame: pd.DataFrame, values: pd.Series, column: str, limit: float,
                     unit: str, path: Path | str) -> None:
    i = _first(np.abs(values.to_numpy()) > limit)
    if i is not None:
        raise InputError(f"{path}: line {_line(frame, i)}, column '{column}': {values.iloc[i]:g}"
                         f" {unit} is beyond the limit of {limit:g} {unit}")


def _std_column(frame: pd.DataFrame, column: str, path: Path | str) -> pd.Series:
    """An optional standard deviation column of the anchors file: empty or 0 (known), or
    between :data:`~radioloc.core.validation.POSITIVE_FLOOR` (a smaller one's inverse
    squared overflows) and the range limit, metres."""
    values = _optional_number(frame, column, path, minimum=0.0)
    v = values.fillna(0.0).to_numpy()
    if (i := _first((v > 0) & (v < POSITIVE_FLOOR))) is not None:
        raise InputError(f"{path}: line {_line(frame, i)}, column '{column}': {v[i]:g} m is "
                         f"below the supported floor of {POSITIVE_FLOOR:g} m (0 or empty: "
                         "known exactly)")
    _check_magnitude(frame, values.fillna(0.0), column, LIMITS["range_m"], "m", path)
    return values


def read_anchors(path: Path | str) -> pd.DataFrame:
    """Read and validate an anchors CSV (``id, x, y[, z]``).

    Parameters
    ----------
    path : path
        The file.

    Returns
    -------
    DataFrame
        Columns ``id`` (str), ``x``, ``y`` and ``z`` if present, and ``line``; and, when the
        file has them, ``std_m`` (prior standard deviation of a rough anchor, NaN: surveyed)
        and ``bias_m`` (a range bias that ``locate`` subtracts, written by ``radioloc
        calibrate``), and the columns the kinds' models read
        (:attr:`radioloc.core.kinds.Kind.anchor_columns`: the per-anchor RSS model
        ``rss_a_dbm, rss_n, rss_std_db``, written by
        :func:`radioloc.locate.path_loss.fit_path_loss`; an angle-of-arrival array's
        ``yaw, pitch, roll``), numbers (empty: NaN). With a ``time`` column (seconds, on the measurements' clock) an anchor
        may move: each of its rows is its position at that time (rows sorted by time
        within an anchor; :func:`radioloc.locate.adapter.anchor_points` interpolates
        between them); an empty time marks a fixed anchor (one row).

    Raises
    ------
    InputError
        Missing or duplicated column, a column no one reads (naming it: not one of
        :data:`ANCHOR_COLUMNS` nor a kind's), text in a coordinate, non-finite coordinate or one
        beyond 5e7 m, an empty ``frame`` or ``group`` cell, duplicate or empty id; with
        ``time``: a second row of one anchor at
        one time, or of a fixed anchor.
    """
    frame = _read_csv(path, "anchors")
    _require_columns(frame, ("id", "x", "y"), path)
    columns = dict.fromkeys(c for k in kinds().values() for c in k.anchor_columns)
    known = ANCHOR_COLUMNS + tuple(columns)
    unknown = [c for c in frame.columns if c not in known]
    if unknown:
        raise InputError(f"{path}: column {unknown[0]!r}: not read by radioloc (an anchors "
                         f"file holds {', '.join(known)}; remove the column or rename it)")
    out = pd.DataFrame({"id": _ids(frame, "id", path)})
    for c in ("x", "y", "z"):
        if c in frame.columns:
            out[c] = _numeric(frame, c, path)
            _check_magnitude(frame, out[c], c, LIMITS["coordinate_m"], "m", path)
    for c in ("frame", "group"):                     # the coordinates' frame, a clock group
        if c in frame.columns:
            out[c] = _text(frame, c)
            if (i := _first(out[c] == "")) is not None:
                raise InputError(f"{path}: line {_line(frame, i)}, column '{c}': empty")
    if "std_m" in frame.columns:                     # prior std of a rough anchor (calibrate)
        out["std_m"] = _std_column(frame, "std_m", path)
    if "bias_m" in frame.columns:                    # a calibrated range bias (calibrate)
        out["bias_m"] = _optional_number(frame, "bias_m", path).fillna(0.0)
        _check_magnitude(frame, out["bias_m"], "bias_m", LIMITS["range_m"], "m", path)
    for c in columns:                                # read by a kind's model (RSS path loss)
        if c in frame.columns:
            out[c] = _optional_number(frame, c, path)
    if "bias_std_m" in frame.columns:                # its standard deviation (calibrate)
        out["bias_std_m"] = _std_column(frame, "bias_std_m", path)
    tracked = "time" in frame.columns
    if tracked:                                      # a moving anchor: one row per position
        out["time"] = _optional_number(frame, "time", path)
        _check_magnitude(frame, out["time"], "time", LIMITS["time_s"], "s", path)
    dup = out.duplicated(["id", "time"] if tracked else ["id"])
    if tracked:                                      # a fixed anchor (empty time) has one row
        fixed = set(out.loc[out["time"].isna(), "id"])
        dup |= out["id"].isin(fixed) & out["id"].duplicated(keep=False) & out["time"].notna()
    if dup.any():
        i = int(np.flatnonzero(dup.to_numpy())[0])
        a = out["id"].iloc[i]
        if not tracked:
            what = f"duplicate anchor id {a!r}"
        elif a in fixed:
            what = f"anchor {a!r} has a row without a time (fixed) and other rows"
        else:
            what = f"a second position of anchor {a!r} at time {float(out['time'].iloc[i])!r}"
        raise InputError(f"{path}: line {_line(frame, i)}, column '{'time' if tracked else 'id'}"
                         f"': {what}")
    out["line"] = frame.attrs["lines"]
    if tracked:
        order = {a: k for k, a in enumerate(dict.fromkeys(out["id"]))}
        out = out.assign(_o=out["id"].map(order)).sort_values(["_o", "time"], kind="stable")
        out = out.drop(columns="_o").reset_index(drop=True)
    return out


def read_measurements(path: Path | str, *, anchors: pd.DataFrame | None = None,
                      not_detected: float | None = None) -> pd.DataFrame:
    """Read and validate a measurements CSV (``time, node, peer, kind, value``).

    Parameters
    ----------
    path : path
        The file, or a folder of Parquet files (a log in parts: :func:`measurement_parts`).
    anchors : DataFrame, optional
        The anchors table. If given, every ``peer`` must be an anchor id or an id that
        appears in the ``node`` column, otherwise :class:`InputError` names the row.
    not_detected : float, optional
        An RSS value that marks "not detected" (UJIIndoorLoc writes ``100``): rss rows with
        exactly this value are dropped (a station not received has no row), with one
        warning giving their count. ``locate`` passes ``-o not_detected=V`` here.

    Returns
    -------
    DataFrame
        ``time`` (float), ``node``, ``peer`` (str), ``kind`` (str), ``value`` (float),
        ``std`` (float, NaN: the method's default) when the file has that column, and
        ``line`` (the file line of each row, for later error messages).

    Raises
    ------
    InputError
        Naming the file, line and column: a malformed cell, a column named twice, an
        unknown kind, a negative range, a value beyond :data:`LIMITS` (an RSS of +100 dBm
        is named as the "not detected" sentinel), a node measuring itself, an unknown peer.
    """
    if Path(path).is_dir():
        return read_measurement_parts(measurement_parts(path), anchors=anchors,
                                      not_detected=not_detected)
    return measurements_of_cells(_read_csv(path, "measurements"), path, anchors=anchors,
                                 not_detected=not_detected)


def measurement_parts(path: Path | str) -> list[tuple[Path, str | None]]:
    """The Parquet files of a log written in parts to a folder (for example by pandas'
    ``to_parquet(folder, partition_cols=["node"])``), in sorted path order, each with the
    node its Hive partition names (a ``node=ID`` folder on its path, URL-quoted as pyarrow
    writes it) or None.

    Raises
    ------
    InputError
        The folder holds no ``*.parquet`` file.
    """
    from urllib.parse import unquote

    root = Path(path)
    files = sorted(p for p in root.rglob("*.parquet") if p.is_file())
    if not files:
        raise InputError(f"measurements file {root}: is a folder, not a file, and holds no "
                         "*.parquet file (a log in parts is a folder of Parquet files, e.g. "
                         "node=ID/part.parquet)")
    parts = []
    for f in files:
        node = None
        for folder in f.relative_to(root).parts[:-1]:
            key, sep, value = folder.partition("=")
            if sep and key.strip().lower() == "node":
                node = unquote(value)
        parts.append((f, node))
    return parts


def read_measurement_parts(parts: list[tuple[Path, str | None]], *,
                           nodes: set | None = None, anchors: pd.DataFrame | None = None,
                           not_detected: float | None = None) -> pd.DataFrame:
    """:func:`read_measurements` of a log in parts (:func:`measurement_parts`), their rows
    in the parts' order: each file is checked as a file of its own (a message names the
    file and the row's line as in its CSV text), with its partition's node as its ``node``
    column; with ``nodes``, only those nodes' rows (a part whose partition names another
    node is not read). A peer is known when it is an anchor or a node of any part read.

    Raises
    ------
    InputError
        As :func:`read_measurements`; a part whose ``node`` column disagrees with its
        partition.
    """
    from radioloc.io.datasets import read_table_text

    frames, unknown = [], {}
    for path, node in parts:
        if nodes is not None and node is not None and node not in nodes:
            continue
        cells = read_table_text(path)
        cells.columns = [str(c).strip().lower() for c in cells.columns]
        lines = np.arange(2, len(cells) + 2)
        if node is not None:
            if "node" in cells and not (cells["node"].str.strip() == node).all():
                row = int(np.flatnonzero((cells["node"].str.strip() != node).to_numpy())[0])
                raise InputError(f"{path}: line {row + 2}, column 'node': "
                                 f"{cells['node'].iloc[row]!r} in the partition of node "
                                 f"{node!r}")
            cells["node"] = node
        if nodes is not None and "node" in cells:
            keep = cells["node"].str.strip().isin(nodes).to_numpy()
            cells, lines = cells[keep].reset_index(drop=True), lines[keep]
        cells.attrs["lines"] = lines
        found: dict = {}
        frames.append(measurements_of_cells(cells, path, anchors=anchors,
                                            not_detected=not_detected, unknown_peers=found))
        for peer, line in found.items():
            unknown.setdefault(peer, (path, line))
    if not frames:
        raise InputError(f"measurements folder {parts[0][0].parent}: no part holds the "
                         f"nodes {sorted(nodes or ())}")
    out = pd.concat(frames, ignore_index=True)
    known = set(out["node"])
    for peer, (path, line) in unknown.items():
        if peer not in known:
            refuse_unknown_peer(path, line, peer)
    return out


def measurements_of_cells(frame: pd.DataFrame, path: Path | str, *,
                          anchors: pd.DataFrame | None = None,
                          not_detected: float | None = None,
                          unknown_peers: dict | None = None) -> pd.DataFrame:
    """:func:`read_measurements` of text cells already read (``attrs["lines"]``: their
    file lines), e.g. one block of a long file (:func:`measurement_blocks`).

    Parameters
    ----------
    frame : DataFrame
        Text cells, lower-case column names.
    path : path
        The file, for messages.
    anchors : DataFrame, optional
    not_detected : float, optional
        As for :func:`read_measurements`.
    unknown_peers : dict, optional
        Given, a row whose peer is neither an anchor nor a node of ``frame`` is not refused
        here: its peer is added with the row's line (the first one), for the caller to
        refuse once the whole file is read (a node of a later block is a known peer).

    Returns
    -------
    DataFrame
        As :func:`read_measurements`.
    """
    _require_columns(frame, MEASUREMENT_COLUMNS, path)
    out = pd.DataFrame({
        "time": _numeric(frame, "time", path),
        "node": _ids(frame, "node", path),
        "peer": _ids(frame, "peer", path),
        "kind": _text(frame, "kind", lower=True),
        "value": _numeric(frame, "value", path),
        "line": frame.attrs["lines"],
    })
    if "reference" in frame.columns:
        out["reference"] = _unescaped(_text(frame, "reference"))
    if "std" in frame.columns:
        out["std"] = _optional_number(frame, "std", path, minimum=POSITIVE_FLOOR)
        _check_magnitude(frame, out["std"].fillna(0.0), "std", LIMITS["range_m"], "", path)

    def fail(i: int, message: str) -> None:
        raise InputError(f"{path}: line {int(out['line'].iloc[i])}, {message}")

    declared = kinds()
    if (i := _first(~out["kind"].isin(declared))) is not None:
        fail(i, f"column 'kind': {frame['kind'].iloc[i]!r} is not one of {', '.join(declared)}")
    _check_magnitude(frame, out["time"], "time", LIMITS["time_s"], "s", path)
    if not_detected is not None:
        if not np.isfinite(not_detected):
            raise InputError(f"not_detected: must be a finite number, got {not_detected!r}")
        absent = ((out["kind"] == "rss") & (out["value"] == float(not_detected))).to_numpy()
        if absent.any():
            warnings.warn(f"{path}: {int(absent.sum())} rss row(s) equal to the not-detected "
                          f"value {float(not_detected):g} left out (stations not received)",
                          stacklevel=2)
            out = out[~absent].reset_index(drop=True)
    is_range = (out["kind"] == "range").to_numpy()
    is_rss = (out["kind"] == "rss").to_numpy()
    value = out["value"].to_numpy()
    std = out["std"].to_numpy(float) if "std" in out.columns else 0.0
    floor = np.broadcast_to(range_floor_m(std), value.shape)       # the library's rule
    if (i := _first(is_range & (value < floor))) is not None:
        fail(i, f"column 'value': negative range {value[i]:g}" + (
            f" (below {-floor[i]:g} m: {NEGATIVE_RANGE_SIGMAS:g} times the row's std)"
            if floor[i] < 0 else " (a range is a distance >= 0; a row's std allows a noisy "
            f"range down to -{NEGATIVE_RANGE_SIGMAS:g} std)"))
    if np.any(noisy := is_range & (value < 0)):       # accepted: a noisy short range, read as 0
        out.loc[noisy, "value"] = 0.0
        value = out["value"].to_numpy()
    limit = out["kind"].map({n: k.limit for n, k in declared.items()}).to_numpy(dtype=float)
    if (i := _first(np.abs(value) > limit)) is not None:       # NaN: a kind without a limit
        fail(i, f"column 'value': {_beyond(declared[out['kind'].iloc[i]], value[i])}")
    if (i := _first(is_rss & (value > LIMITS["rss_max_dbm"]))) is not None:
        sentinel = (" (+100 dBm is the 'not detected' marker of WiFi fingerprint data sets: "
                    "drop those rows or read them with -o not_detected=100)"
                    if value[i] == RSS_NOT_DETECTED_DBM else "")
        fail(i, f"column 'value': rss {value[i]:g} dBm is above the plausible maximum of "
                f"{LIMITS['rss_max_dbm']:g} dBm{sentinel}")
    if (i := _first(is_rss & (value < LIMITS["rss_min_dbm"]))) is not None:
        fail(i, f"column 'value': rss {value[i]:g} dBm is below the plausible minimum of "
                f"{LIMITS['rss_min_dbm']:g} dBm")
    ref = out["reference"] if "reference" in out.columns else pd.Series([""] * len(out))
    needs = out["kind"].isin([n for n, k in declared.items() if k.reference]).to_numpy()
    if (i := _first(needs & (ref == "").to_numpy())) is not None:
        fail(i, f"column 'reference': a {out['kind'].iloc[i]} row needs its reference anchor")
    if (i := _first(~needs & (ref != "").to_numpy())) is not None:
        fail(i, f"column 'reference': {ref.iloc[i]!r} on a {out['kind'].iloc[i]} row; only a "
                "row of a kind with a reference anchor (tdoa) has one (leave the cell empty)")
    is_motion = out["kind"].isin(MOTION_KINDS).to_numpy()
    if is_motion.any():
        _check_odometry(out, is_motion, fail)
    is_motion = out["kind"].isin([n for n, k in declared.items() if k.self_measured]).to_numpy()
    if (i := _first((out["node"] == out["peer"]).to_numpy() & ~is_motion)) is not None:
        raise InputError(f"{path}: line {int(out['line'].iloc[i])}: node {out['node'].iloc[i]!r}"
                         " measured itself")
    if anchors is not None:
        known = set(anchors["id"]) | set(out["node"].unique())
        unknown = ~out["peer"].isin(known).to_numpy() & ~is_motion
        if unknown_peers is not None:
            for i in np.flatnonzero(unknown):
                unknown_peers.setdefault(out["peer"].iloc[i], int(out["line"].iloc[i]))
            unknown[:] = False
        if (i := _first(unknown)) is not None:
            refuse_unknown_peer(path, int(out["line"].iloc[i]), out["peer"].iloc[i])
        if (i := _first(out["node"].isin(set(anchors["id"])))) is not None:
            fail(i, f"column 'node': {out['node'].iloc[i]!r} is an anchor id; anchors do not "
                    "need locating")
    return out


def refuse_unknown_peer(path: Path | str, line: int, peer: str) -> None:
    """Raise the :class:`InputError` of a row whose peer is neither an anchor nor a node."""
    raise InputError(f"{path}: line {line}, column 'peer': unknown anchor or node {peer!r} "
                     "(not in the anchors file nor a node)")


def _beyond(kind, value: float) -> str:
    """Why ``value`` is refused: beyond its kind's :attr:`~radioloc.core.kinds.Kind.limit`."""
    if kind.unit == "rad":
        limit = "2 pi" if np.isclose(kind.limit, 2 * np.pi) else f"{kind.limit:g}"
        return f"angle {value:g} is beyond {limit}: {kind.name} is in radians (degrees?)"
    return (f"{kind.name} {value:g} {kind.unit} is beyond the limit of {kind.limit:g} "
            f"{kind.unit}")


def _check_odometry(out: pd.DataFrame, is_motion: np.ndarray, fail) -> None:
    """Odometry rows: ``dx`` and ``dy`` in pairs (one of each per node and time)."""
    rows = out[is_motion]
    twice = rows.duplicated(["time", "node", "kind"])
    if twice.any():
        i = int(np.flatnonzero(is_motion)[np.flatnonzero(twice.to_numpy())[0]])
        fail(i, f"column 'kind': a second {out['kind'].iloc[i]!r} row of node "
                f"{out['node'].iloc[i]!r} at time {out['time'].iloc[i]!r}")
    count = rows.groupby(["time", "node"])["kind"].transform("size").to_numpy()
    if (j := _first(count != 2)) is not None:
        i = int(np.flatnonzero(is_motion)[j])
        other = "odometry_dy" if out["kind"].iloc[i] == "odometry_dx" else "odometry_dx"
        fail(i, f"column 'kind': {out['kind'].iloc[i]!r} of node {out['node'].iloc[i]!r} at "
                f"time {out['time'].iloc[i]!r} has no {other!r} row at the same time "
                "(odometry rows come in dx, dy pairs)")


def subtract_anchor_bias(measurements: pd.DataFrame, anchors: pd.DataFrame | None) -> pd.DataFrame:
    """Ranges corrected by the anchors' ``bias_m`` (a calibrated anchors file): each range to
    an anchor minus that anchor's bias, floored at 0. Unchanged when there is no ``bias_m``.
    A corrected range below 0 by more than the negative-range rule allows
    (:func:`~radioloc.core.validation.check_ranges`, with the row's ``std`` and the
    anchor's ``bias_std_m`` as its noise) is refused, naming the line.

    Parameters
    ----------
    measurements, anchors : DataFrame
        As read by :func:`read_measurements` and :func:`read_anchors`.

    Returns
    -------
    DataFrame
    """
    if anchors is None or "bias_m" not in anchors.columns:
        return measurements
    peer = measurements["peer"]
    ranges = (measurements["kind"] == "range").to_numpy()
    bias = np.where(ranges, peer.map(dict(zip(anchors["id"], anchors["bias_m"]))).to_numpy(float),
                    np.nan)
    bias_sd = (peer.map(dict(zip(anchors["id"], anchors["bias_std_m"]))).to_numpy(float)
               if "bias_std_m" in anchors.columns else np.zeros(len(peer)))
    std = (measurements["std"].to_numpy(float) if "std" in measurements.columns
           else np.zeros(len(peer)))
    lines = measurements["line"].to_numpy() if "line" in measurements else None
    out = measurements.copy()
    out["value"] = corrected_ranges(measurements["value"].to_numpy(float), std, bias, bias_sd,
                                    peer.to_numpy(),
                                    lambda i: "" if lines is None else f"line {int(lines[i])}, ")
    return out


def corrected_ranges(value: np.ndarray, std: np.ndarray, bias: np.ndarray, bias_std: np.ndarray,
                     peer: np.ndarray, where) -> np.ndarray:
    """Values minus their anchor's ``bias_m`` (NaN: a row without one, kept), floored at 0
    (the rule of :func:`subtract_anchor_bias`, on arrays).

    Parameters
    ----------
    value, std, bias, bias_std : ndarray, shape (N,)
        The rows' values and stds, their anchors' ``bias_m`` and ``bias_std_m`` (NaN: none).
    peer : ndarray, shape (N,)
        The rows' anchors, for the message.
    where : callable
        Row index to the row's name in the message (``"line 7, "``, or ``""``).

    Returns
    -------
    ndarray, shape (N,)

    Raises
    ------
    InputError
        A corrected range below 0 beyond the negative-range rule, naming the row.
    """
    # the negative-range rule on the corrected range: the row's std and the bias's own
    # standard deviation (bias_std_m of a calibrated file) set how far below 0 it may go
    var = np.nan_to_num(std) ** 2 + np.nan_to_num(bias_std) ** 2
    floor = range_floor_m(np.sqrt(var), np.nan_to_num(bias))
    has = np.isfinite(bias)
    if (i := _first(has & (value < floor))) is not None:
        raise InputError(
            f"measurements: {where(i)}column 'value': range {value[i]:g} m to anchor "
            f"{peer[i]!r} is below that anchor's bias_m {bias[i]:g} m "
            f"(corrected, a negative range beyond {NEGATIVE_RANGE_SIGMAS:g} standard "
            "deviations of the row's std and the anchor's bias_std_m): bias_m in another "
            "unit, or the wrong anchors file?")
    return np.where(has, np.maximum(value - np.nan_to_num(bias), 0.0), value)


def check_kinds(measurements: pd.DataFrame, used: Iterable[str], method: str) -> None:
    """Refuse rows of a kind that ``method`` does not use (they would be dropped silently).

    Parameters
    ----------
    measurements : DataFrame
        As returned by :func:`read_measurements`.
    used : iterable of str
        The kinds the method uses.
    method : str
        Its name, for the message.

    Returns
    -------
    None

    Raises
    ------
    InputError
        Naming the unused kind, how many rows have it and the first line.
    """
    used = tuple(used)
    other = ~measurements["kind"].isin(used)
    if other.any():
        rows = measurements[other]
        kind = rows["kind"].iloc[0]
        n = int((rows["kind"] == kind).sum())
        raise InputError(f"method {method}: uses only {', '.join(repr(k) for k in used)} rows; "
                         f"the measurements hold {n} {kind!r} row(s) (first at line "
                         f"{int(rows['line'].iloc[0])}): remove them or choose a method that "
                         "uses them")


def write_estimates(frame: pd.DataFrame, path: Path | str | None) -> None:
    """Write ``time, node, x, y[, ...]`` estimates as CSV, or Parquet for a ``*.parquet``
    path (stdout, as CSV, if ``path`` is None or '-').

    Parameters
    ----------
    frame : DataFrame
        The estimates.
    path : path or None
        The output file, written atomically (temporary name, then renamed); a device such
        as ``/dev/stdout`` is written in place.

    Returns
    -------
    None

    Raises
    ------
    OutputError
        The file cannot be written (a folder, no permission, a full device, ...).

    Notes
    -----
    Floats are written in their shortest exact decimal form, so that reading the file back
    gives the same numbers bit for bit (distinct time stamps stay distinct). A CSV text
    cell that a spreadsheet would run as a formula is escaped (:func:`spreadsheet_cell`).
    """
    def write_csv(f) -> None:
        write_csv_rows(frame, f)

    if path is None or str(path) == "-":
        write_csv(sys.stdout)
    elif Path(path).suffix.lower() == ".parquet":
        from radioloc.io.datasets import _need_pyarrow

        _need_pyarrow()
        atomic_write_with(path, lambda f: frame.to_parquet(f, index=False), binary=True)
    else:
        atomic_write_with(path, write_csv)


def write_csv_rows(frame: pd.DataFrame, f, header: bool = True) -> None:
    """Write ``frame`` as CSV rows to the open text file ``f`` as :func:`write_estimates`
    writes them (with the header line, or without it: the rows that follow earlier ones).

    Parameters
    ----------
    frame : DataFrame
    f : text file
    header : bool

    Returns
    -------
    None
    """
    safe = _spreadsheet_safe(frame)
    chunks = csv_chunks(safe)
    if chunks is None:
        safe.to_csv(f, index=False, header=header)
        return
    if not header:
        next(chunks)
    for text in chunks:
        f.write(text)


#: Characters that make the CSV writer quote a cell.
_QUOTED = (",", '"', "\r", "\n")


def csv_chunks(frame: pd.DataFrame, rows: int = 50_000) -> Iterator[str] | None:
    """The text ``frame.to_csv(index=False)`` writes, in pieces of ``rows`` rows (built a
    column at a time), or None for a frame this does not cover: a text cell that needs
    quoting or is missing, a column that is not float64, integer, boolean or text, a single
    column.

    Floats in their shortest exact form (``repr``), a missing float as an empty cell.

    Parameters
    ----------
    frame : DataFrame
    rows : int

    Returns
    -------
    iterator of str, or None
        The header line first.
    """
    names = [str(c) for c in frame.columns]
    if len(names) < 2 or any(q in c for c in names for q in _QUOTED):
        return None
    kinds = []
    for name in frame.columns:
        col = frame[name]
        if col.dtype == np.float64:
            kinds.append("float")
        elif col.dtype.kind in "iub":
            kinds.append("int")
        elif isinstance(col.dtype, pd.StringDtype) or (
                col.dtype.kind in "OU" and not isinstance(col.dtype, pd.CategoricalDtype)):
            if col.isna().any() or not all(isinstance(v, str) and not any(q in v for q in _QUOTED)
                                           for v in col.unique()):
                return None
            kinds.append("text")
        else:
            return None
    end = os.linesep

    def cells(values: list, kind: str) -> list[str]:
        if kind == "float":
            return [repr(v) if v == v else "" for v in values]
        return [str(v) for v in values] if kind == "int" else values

    def pieces() -> Iterator[str]:
        yield ",".join(names) + end
        for start in range(0, len(frame), rows):
            part = frame.iloc[start:start + rows]
            columns = [cells(part[c].tolist(), kind) for c, kind in zip(frame.columns, kinds)]
            yield end.join(map(",".join, zip(*columns))) + end

    return pieces()


def read_reference(path: Path | str) -> pd.DataFrame:
    """Read a reference trajectory CSV (``time[, node], x, y[, z]``), e.g. the
    ``reference.csv`` written by ``radioloc datasets export``.

    Parameters
    ----------
    path : path
        The file.

    Returns
    -------
    DataFrame
        ``time``, ``node`` (str; absent when the file has none: the reference of every
        node), ``x``, ``y`` and ``z`` if present, ``frame`` if present (the frame of the
        coordinates, :mod:`radioloc.locate.frames`), sorted by node and time.

    Raises
    ------
    InputError
        Missing column, a cell that is not a finite number, a repeated ``(time, node)``.
    """
    frame = _read_csv(path, "reference")
    _require_columns(frame, ("time", "x", "y"), path)
    out = pd.DataFrame({"time": _numeric(frame, "time", path)})
    if "node" in frame.columns:
        out["node"] = _ids(frame, "node", path)
    for c in ("x", "y", "z"):
        if c in frame.columns:
            out[c] = _numeric(frame, c, path)
    if "frame" in frame.columns:                 # its coordinates' frame (locate.frames)
        out["frame"] = _text(frame, "frame")
    keys = ["node", "time"] if "node" in out else ["time"]
    twice = out.duplicated(keys)
    if twice.any():
        i = int(np.flatnonzero(twice.to_numpy())[0])
        raise InputError(f"{path}: line {_line(frame, i)}: a second reference position for "
                         f"the same {' and '.join(keys)}")
    return out.sort_values(keys, kind="stable").reset_index(drop=True)
