"""The public data sets the toolkit reads: where they are, how to fetch them, how to export them.

Every data set has an entry in :data:`DATASETS`: its folder name, its origin (repository and
commit), its license, and a pinned list of files with their checksums (``registry/<name>.txt``
beside this module). Three questions are answered here:

* **Where is it?** :func:`data_roots` lists the folders searched, in order: ``$RADIOLOC_DATA``
  when it is set (then nothing else), otherwise the platform cache
  (``pooch.os_cache("radioloc")``, e.g. ``~/.cache/radioloc``) and the ``shared/data`` folder
  next to the repository checkout this package runs from. :func:`find` returns the first
  folder that holds the set; :func:`require` raises
  :class:`~radioloc.core.errors.DataUnavailable` saying where it looked and how to fetch it.
* **How do I get it?** :func:`fetch` downloads every file of the set from its pinned origin
  with pooch and checks its checksum (``radioloc datasets fetch NAME``).
* **How do I use it with my own tools?** :func:`export` writes a run in the ``radioloc
  locate`` schema (measurements and anchors, see :mod:`radioloc.io.logs`) or a fingerprint
  calibration file (see :mod:`radioloc.locate.gmm`), as CSV or Parquet.

The checksums are the SHA-256 of the reference copy of each set, which its ``SOURCE.md``
states was copied unchanged from the pinned commit (UJIIndoorLoc: the zip's git blob id and
the SHA-256 of the two CSVs, as its ``SOURCE.md`` gives them).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import urllib.parse
import urllib.request
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError, DataUnavailable, InputError

_REGISTRY_DIR = Path(__file__).with_name("registry")


@dataclass(frozen=True)
class DataSet:
    """One public data set.

    Attributes
    ----------
    name : str
        Folder name below a data root, e.g. ``"hanyang-uwb-outdoor"``.
    title : str
        One line saying what it is.
    origin : str
        Repository (or archive) the files come from.
    commit : str
        Pinned commit of ``origin``.
    base_url : str
        URL that a file's relative path is appended to.
    license : str
        License of the data, as its ``SOURCE.md`` states it.
    aliases : tuple of str
        Short names accepted by the command line (e.g. ``"hanyang"``).
    exports : str
        What :func:`export` writes for it (empty when it writes nothing).
    files : tuple of (str, str or None)
        ``(relative path, checksum)``; the checksum is ``"sha256:<hex>"``,
        ``"gitblob:<hex>"`` or ``None`` (unknown). Empty: read ``registry/<name>.txt``.
    archive : tuple of (str, str, dict) or None
        ``(relative path of a zip, its checksum, {member: (target path, sha256)})`` for a
        set that is published as an archive.
    note : str
        Caveat shown by ``radioloc datasets list`` (e.g. a missing license).
    """

    name: str
    title: str
    origin: str
    commit: str
    base_url: str
    license: str
    aliases: tuple[str, ...] = ()
    exports: str = ""
    files: tuple[tuple[str, str | None], ...] = ()
    archive: tuple[str, str | None, dict[str, tuple[str, str]]] | None = None
    note: str = ""

    def entries(self) -> list[tuple[str, str | None]]:
        """The pinned files ``(relative path, checksum or None)``."""
        if self.files:
            return list(self.files)
        path = _REGISTRY_DIR / f"{self.name}.txt"
        if not path.is_file():
            return []
        out = []
        for line in path.read_text().splitlines():
            line = line.strip()
            if line and not line.startswith("#"):
                rel, _, digest = line.rpartition(" ")
                out.append((rel, digest or None))
        return out

    @property
    def checksums_known(self) -> bool:
        """Whether every file (or the archive) has a pinned checksum."""
        if self.archive is not None:
            return self.archive[1] is not None
        entries = self.entries()
        return bool(entries) and all(d is not None for _, d in entries)

    @property
    def marker(self) -> str:
        """A file whose presence says the set is there (the first pinned file)."""
        if self.archive is not None:
            return next(iter(self.archive[2].values()))[0]
        entries = self.entries()
        return entries[0][0] if entries else ""


def _github(owner_repo: str, commit: str) -> tuple[str, str]:
    return (f"https://github.com/{owner_repo}",
            f"https://raw.githubusercontent.com/{owner_repo}/{commit}/")


_UJI_ORIGIN, _UJI_BASE = _github("andrejvysny/ujiindoorloc-capstone",
                                 "54a38ccc8b28494afa6ce7a2c7ce71db93c3deda")
_HY_ORIGIN, _HY_BASE = _github("cucudasluv/UWB-dataset", "c12599812e556324eadc763e409ea8f51098dda6")
_HE_ORIGIN, _HE_BASE = _github("theheraldproject/herald-analysis",
                               "fb668bec0fdf6a9c3f1fa99f6ff8e29eff8c2108")
_KO_ORIGIN, _KO_BASE = _github("marckolak/ble-rss-fingerprints-calib2021",
                               "0a69aaa7006909d3f8f9f3a14fcba9405d404fa5")
_RTT_ORIGIN, _RTT_BASE = _github("haiyaoyu/RTT-Indoor-localization-data-set",
                                 "2b19c6c0db0e54f07800802fdf261ea3835ca478")
_UC_ORIGIN, _UC_BASE = _github("ShuningZhao/Character-Trajectories",
                               "0c9bfa477542c4f885370a6af05a99b45764f3af")
_SL_ORIGIN, _SL_BASE = _github("TUC-ProAut/libRSF", "d54801a232af02c0cda6012dabd3dea6c5fd77c5")

#: Every data set the toolkit reads, by folder name.
DATASETS: dict[str, DataSet] = {d.name: d for d in (
    DataSet("hanyang-uwb-outdoor",
            "Outdoor UWB two-way ranging (DW1000): static LOS/NLOS ranges at known distances; "
            "a moving tag with 4 anchors and RTK-GNSS truth (trajectory A)",
            _HY_ORIGIN, "c12599812e556324eadc763e409ea8f51098dda6", _HY_BASE,
            "Apache-2.0", aliases=("hanyang",),
            exports="locate run: measurements (ranges), anchors, reference, the set's LS/ESKF "
                    "estimates"),
    DataSet("gnss-smartloc-berlin",
            "GPS and GLONASS pseudoranges (satellite ECEF positions per epoch), car odometry and "
            "reference of a 283 s urban drive through Potsdamer Platz, Berlin (smartLoc)",
            _SL_ORIGIN, "d54801a232af02c0cda6012dabd3dea6c5fd77c5",
            _SL_BASE + "datasets/smartLoc/",
            "CC-BY-SA-4.0 (cite Reisdorf, Pfeifer, Bressler, Bauer, Weissig, Lange, TU Chemnitz)",
            aliases=("smartloc", "berlin"),
            exports="locate run: measurements (pseudoranges), anchors (satellite tracks, ECEF, "
                    "one group per constellation), reference (ECEF), odometry"),
    DataSet("herald-ble-rssi-distance",
            "BLE phone-to-phone RSSI at known distances (cable car, 0-3.4 m), two Android sessions",
            _HE_ORIGIN, "fb668bec0fdf6a9c3f1fa99f6ff8e29eff8c2108", _HE_BASE,
            "Apache-2.0", aliases=("herald",)),
    DataSet("kolakowski-ble-fingerprints-2021",
            "BLE RSS fingerprints from 6 anchors in a flat: 4,104 calibration points and a "
            "robot test run with LiDAR-SLAM truth",
            _KO_ORIGIN, "0a69aaa7006909d3f8f9f3a14fcba9405d404fa5", _KO_BASE,
            "CC-BY-4.0", aliases=("kolakowski",),
            exports="fingerprint calibration CSV + locate run (rss) of the robot test, reference"),
    DataSet("uci-character-trajectories",
            "Pen-tip velocity trajectories (200 Hz), 1,429 labelled samples of 20 letters",
            _UC_ORIGIN, "0c9bfa477542c4f885370a6af05a99b45764f3af", _UC_BASE,
            "none stated (UCI lists the original under CC-BY-4.0)",
            aliases=("uci-characters", "characters"),
            note="this repackaging carries no license: use for local validation only"),
    DataSet("ujiindoorloc",
            "WiFi RSS fingerprints (UJIIndoorLoc, UCI 310): 3 buildings, 19,937 training and "
            "1,111 validation fingerprints, 520 access points",
            _UJI_ORIGIN, "54a38ccc8b28494afa6ce7a2c7ce71db93c3deda", _UJI_BASE,
            "CC-BY-4.0 (cite Torres-Sospedra et al., IPIN 2014)", aliases=("uji",),
            exports="fingerprint calibration CSV (training, one building floor) + locate run "
                    "(rss) of the validation fingerprints, reference",
            archive=("data/ujiindoorloc.zip", "gitblob:36971c13e67e5f9ca6854f861c6df48fee93f074", {
                "UJIndoorLoc/trainingData.csv": (
                    "trainingData.csv",
                    "sha256:45ca0128bd12019c976bb4793e407c979c82995d7a5940ab7288620247905168"),
                "UJIndoorLoc/validationData.csv": (
                    "validationData.csv",
                    "sha256:5f90c536648cd657b2c516d20c4e0968d4003279ea6bd5d5d5322d3f1e8905c0"),
            })),
    DataSet("wifi-rtt-haiyaoyu",
            "WiFi RTT (802.11mc) ranges, RSS and IMU of two phones walking loops in 3 venues "
            "(6-8 access points), with ground truth",
            _RTT_ORIGIN, "2b19c6c0db0e54f07800802fdf261ea3835ca478", _RTT_BASE, "MIT",
            aliases=("wifi-rtt", "rtt"),
            exports="locate run per circle: both phones' RTT ranges (with the phone's std) and "
                    "RSS, anchors, reference"),
)}


def get(name: str) -> DataSet:
    """The data set called ``name`` (folder name or alias).

    Parameters
    ----------
    name : str
        Folder name (``"hanyang-uwb-outdoor"``) or alias (``"hanyang"``).

    Returns
    -------
    DataSet

    Raises
    ------
    ConfigError
        Unknown name (the message lists the known ones).
    """
    key = name.strip().lower()
    for d in DATASETS.values():
        if key == d.name or key in d.aliases:
            return d
    raise ConfigError(f"unknown data set {name!r}; known: {', '.join(DATASETS)}")


# ---- where the data sets are ----------------------------------------------------------

def repository_root() -> Path | None:
    """The root of the source checkout this package runs from.

    Returns
    -------
    Path or None
        ``None`` when the package is installed elsewhere (no ``pyproject.toml`` and
        ``src/radioloc`` two levels above the package).
    """
    root = Path(__file__).resolve().parents[3]
    return root if (root / "pyproject.toml").is_file() and (root / "src" / "radioloc").is_dir() \
        else None


def platform_cache() -> Path:
    """The platform's cache folder for radioloc.

    Returns
    -------
    Path
        ``pooch.os_cache("radioloc")``, e.g. ``~/.cache/radioloc`` on Linux.
    """
    try:
        import pooch
    except ImportError:  # pragma: no cover - pooch is a dependency
        base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        return Path(base) / "radioloc"
    return Path(pooch.os_cache("radioloc"))


def data_roots() -> list[Path]:
    """Folders searched for data sets, in order.

    Returns
    -------
    list of Path
        ``[$RADIOLOC_DATA]`` when that variable is set; otherwise the platform cache and,
        for a source checkout, ``<checkout>/../shared/data``.
    """
    env = os.environ.get("RADIOLOC_DATA")
    if env:
        return [Path(env).expanduser()]
    roots = [platform_cache()]
    repo = repository_root()
    if repo is not None:
        roots.append(repo.parent / "shared" / "data")
    return roots


def download_root() -> Path:
    """Where :func:`fetch` writes.

    Returns
    -------
    Path
        ``$RADIOLOC_DATA`` if set, else the platform cache.
    """
    return data_roots()[0]


def find(name: str) -> Path | None:
    """The folder of data set ``name`` in the first data root that holds it, or ``None``.

    Parameters
    ----------
    name : str
        Data set folder name or alias. A folder name that is not in :data:`DATASETS`
        is looked up as a plain folder.

    Returns
    -------
    Path or None
    """
    folder = get(name).name if _known(name) else name
    for root in data_roots():
        if (root / folder).is_dir():
            return root / folder
    return None


def _known(name: str) -> bool:
    try:
        get(name)
    except ConfigError:
        return False
    return True


def missing_message(name: str) -> str:
    """One sentence: data set ``name`` is absent, where it was looked for, how to fetch it.

    Parameters
    ----------
    name : str
        Data set folder name or alias (or any folder name).

    Returns
    -------
    str
    """
    folder = get(name).name if _known(name) else name
    where = ", ".join(str(r) for r in data_roots())
    how = (f"fetch it with `radioloc datasets fetch {folder}`" if _known(name)
           else "copy it there")
    return (f"data set folder '{folder}' is absent (looked in: {where}); {how}, or set RADIOLOC_DATA "
            f"to the folder that holds '{folder}'")


def require(name: str) -> Path:
    """The folder of data set ``name``.

    Parameters
    ----------
    name : str
        Data set folder name or alias.

    Returns
    -------
    Path

    Raises
    ------
    DataUnavailable
        The set is in no data root; the message says where it looked and how to fetch it.
    """
    path = find(name)
    if path is None:
        raise DataUnavailable(missing_message(name))
    return path


def status() -> pd.DataFrame:
    """Which data sets are present.

    Returns
    -------
    DataFrame
        One row per data set: ``name, present, path, license, checksums, exports, title,
        note``.
    """
    rows = []
    for d in DATASETS.values():
        path = find(d.name)
        rows.append({"name": d.name, "present": path is not None,
                     "path": "" if path is None else str(path), "license": d.license,
                     "checksums": "pinned" if d.checksums_known else "unknown",
                     "exports": d.exports, "title": d.title, "note": d.note})
    return pd.DataFrame(rows)


# ---- fetching ---------------------------------------------------------------------------

def file_digest(path: Path | str, kind: str = "sha256") -> str:
    """``sha256`` of a file, or its git blob id (``kind="gitblob"``), as hex.

    Parameters
    ----------
    path : path
    kind : {"sha256", "gitblob"}

    Returns
    -------
    str
    """
    path = Path(path)
    if kind == "sha256":
        h = hashlib.sha256()
    elif kind == "gitblob":
        h = hashlib.sha1()
        h.update(f"blob {path.stat().st_size}\0".encode())
    else:
        raise ConfigError(f"checksum kind {kind!r} is not sha256 or gitblob")
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def matches_checksum(path: Path, checksum: str | None) -> bool:
    """Whether the file at ``path`` exists and has ``checksum`` (``"kind:hexdigest"``, the
    registry's form; ``kind`` as :func:`file_digest` takes it). False when ``checksum`` is None."""
    if checksum is None or not path.is_file():
        return False
    kind, _, digest = checksum.partition(":")
    return file_digest(path, kind) == digest.lower()


def _file_downloader(url: str, output_file, pooch_obj=None) -> None:
    """pooch downloader for ``file://`` URLs (local mirrors and tests)."""
    src = Path(urllib.request.url2pathname(urllib.parse.urlparse(url).path))
    if not src.is_file():
        raise DataUnavailable(f"{url}: not found")
    if hasattr(output_file, "write"):
        output_file.write(src.read_bytes())
    else:
        shutil.copyfile(src, output_file)


def _download(url: str, target: Path, checksum: str | None, verify: bool) -> None:
    import pooch

    kind = (checksum or "").partition(":")[0]
    known = checksum if (verify and kind == "sha256") else None
    downloader: Callable | None = _file_downloader if url.startswith("file:") else None
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        pooch.retrieve(url, known_hash=known, fname=target.name, path=target.parent,
                       downloader=downloader, progressbar=False)
    except ValueError as exc:  # pooch: hash mismatch
        target.unlink(missing_ok=True)
        raise DataUnavailable(f"{url}: checksum mismatch ({exc}); the origin changed or the "
                              "download is corrupt (--no-verify accepts it unchecked)") from None
    except OSError as exc:
        raise DataUnavailable(f"{url}: download failed ({exc})") from None
    if verify and kind == "gitblob" and not matches_checksum(target, checksum):
        target.unlink(missing_ok=True)
        raise DataUnavailable(f"{url}: checksum mismatch (expected {checksum}); --no-verify "
                              "accepts it unchecked")


def fetch(name: str, *, dest: Path | str | None = None, verify: bool = True,
          base_url: str | None = None, log: Callable[[str], None] | None = None) -> Path:
    """Download data set ``name`` from its pinned origin and check every file.

    Files already present with the right checksum are not downloaded again.

    Parameters
    ----------
    name : str
        Data set folder name or alias.
    dest : path, optional
        Data root to write into (the set goes to ``dest/<name>``); default
        :func:`download_root`.
    verify : bool
        Check the pinned checksums (default). A set without pinned checksums is refused
        unless ``verify=False``.
    base_url : str, optional
        Replace the origin's base URL (a mirror, or a ``file://`` folder).
    log : callable, optional
        Called with one line per file.

    Returns
    -------
    Path
        The data set folder.

    Raises
    ------
    DataUnavailable
        A download failed or a checksum did not match.
    ConfigError
        ``verify`` is on and the set has no pinned checksum.
    """
    ds = get(name)
    if verify and not ds.checksums_known:
        raise ConfigError(f"{ds.name}: the checksum of the origin's files is unknown, so the "
                          "download cannot be verified; rerun with --no-verify to accept it "
                          "unchecked")
    base = (base_url or ds.base_url).rstrip("/") + "/"
    folder = Path(dest).expanduser() / ds.name if dest is not None else download_root() / ds.name
    say = log or (lambda _msg: None)
    if ds.archive is not None:
        rel, checksum, members = ds.archive
        if all(matches_checksum(folder / t, h) for t, h in members.values()) and verify:
            say(f"{ds.name}: present and verified")
        else:
            zpath = folder / ".download" / Path(rel).name
            if not (zpath.is_file() and (not verify or matches_checksum(zpath, checksum))):
                say(f"download {base + rel}")
                _download(base + urllib.parse.quote(rel), zpath, checksum, verify)
            with zipfile.ZipFile(zpath) as zf:
                for member, (target, digest) in members.items():
                    out = folder / target
                    out.parent.mkdir(parents=True, exist_ok=True)
                    with zf.open(member) as src, out.open("wb") as dst:
                        shutil.copyfileobj(src, dst)
                    if verify and not matches_checksum(out, digest):
                        out.unlink()
                        raise DataUnavailable(f"{ds.name}: {member} in {rel} does not match "
                                              f"{digest}")
                    say(f"extracted {target}")
            shutil.rmtree(folder / ".download", ignore_errors=True)
    else:
        for rel, checksum in ds.entries():
            target = folder / rel
            if verify and matches_checksum(target, checksum):
                continue
            say(f"download {rel}")
            _download(base + urllib.parse.quote(rel), target, checksum, verify)
    (folder / "FETCHED.md").write_text(
        f"# {ds.name}\n\n{ds.title}\n\n- origin: {ds.origin} (commit {ds.commit})\n"
        f"- license: {ds.license}\n- checksums: {'verified' if verify else 'NOT verified'}\n"
        + (f"- note: {ds.note}\n" if ds.note else ""))
    return folder


# ---- Parquet and CSV tables -------------------------------------------------------------

def _need_pyarrow() -> None:
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        raise ConfigError("Parquet needs pyarrow: pip install 'radioloc[parquet]'") from None


def read_table_text(path: Path | str) -> pd.DataFrame:
    """Read a CSV or Parquet table with every cell as text, as the ``locate`` readers expect.

    Parameters
    ----------
    path : path
        ``*.parquet`` is read with pyarrow; anything else as CSV.

    Returns
    -------
    DataFrame
        Columns as in the file, cells as ``str`` (missing cells as ``""``).
    """
    path = Path(path)
    if path.suffix.lower() != ".parquet":
        return pd.read_csv(path, dtype=str, skipinitialspace=True, keep_default_na=False)
    _need_pyarrow()
    try:
        frame = pd.read_parquet(path)
    except Exception as exc:  # pyarrow raises its own error types
        raise InputError(f"{path}: not a readable Parquet file ({str(exc).strip()})") from None
    return _text_cells(frame)


def _text_cells(frame: pd.DataFrame) -> pd.DataFrame:
    """Every cell of ``frame`` as ``str`` (missing cells as ``""``)."""
    return frame.apply(lambda c: c.map(lambda v: "" if v is None or (isinstance(v, float)
                                                                     and np.isnan(v)) else str(v)))


def parquet_text_blocks(path: Path | str, rows: int) -> Iterator[pd.DataFrame]:
    """The rows of the Parquet file ``path`` as :func:`read_table_text` gives them, read
    ``rows`` at a time (one batch at a time): a DataFrame of text cells each."""
    _need_pyarrow()
    import pyarrow as pa
    import pyarrow.parquet as pq

    for batch in pq.ParquetFile(path).iter_batches(batch_size=rows):
        yield _text_cells(pa.Table.from_batches([batch]).to_pandas())


def write_table(frame: pd.DataFrame, path: Path | str) -> Path:
    """Write ``frame`` as Parquet (``*.parquet``) or CSV (anything else), without the index.

    Parameters
    ----------
    frame : DataFrame
    path : path

    Returns
    -------
    Path
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".parquet":
        _need_pyarrow()
        frame.to_parquet(path, index=False)
    else:
        frame.to_csv(path, index=False, float_format="%.6f")
    return path


# ---- exporting --------------------------------------------------------------------------

def hanyang_runs(root: Path | str) -> list[str]:
    """Run names of the Hanyang dynamic runs present.

    Parameters
    ----------
    root : path
        The data set folder.

    Returns
    -------
    list of str
        E.g. ``["LOS/A/1", "LOS/A/2", ...]``.
    """
    from radioloc.io.hanyang import dynamic_runs

    return [f"{p.parts[-3]}/{p.parts[-2].split('_')[-1]}/{p.parts[-1].split('_')[-1]}"
            for p in dynamic_runs(root)]


def _hanyang_folder(root: Path, run: str) -> Path:
    parts = run.replace("_", "/").split("/")
    parts = [p for p in parts if p and p.lower() not in ("trajectory", "case")]
    if len(parts) != 3:
        raise ConfigError(f"run: expected CONDITION/TRAJECTORY/CASE such as 'LOS/A/1', got {run!r}")
    folder = (root / "Dynamic_measurements" / parts[0].upper() / f"Trajectory_{parts[1].upper()}"
              / f"Case_{parts[2]}")
    if not folder.is_dir():
        raise ConfigError(f"run {run!r}: {folder} is absent; present: "
                          f"{', '.join(hanyang_runs(root))}")
    return folder


def export_hanyang(out: Path | str, *, run: str = "LOS/A/1", root: Path | str | None = None,
                   epoch_s: float = 0.0, tag_height_m: float | None = None,
                   fmt: str = "csv") -> dict[str, Path]:
    """Write one Hanyang dynamic run in the ``radioloc locate`` schema.

    By default every range is written at its own time stamp, one anchor per row, as the
    anchors answer: the log as it is, for the trackers (``ekf-track``, ``pf``). With
    ``epoch_s > 0`` each anchor's ranges are sampled on a common epoch grid instead: at
    each epoch, an anchor's latest range of the last ``epoch_s`` seconds (sample and hold);
    epochs where some anchor has no fresh range are dropped, so every epoch has all
    anchors (what per-epoch multilateration, ``gn``, needs).

    Parameters
    ----------
    out : path
        Output folder.
    run : str
        ``CONDITION/TRAJECTORY/CASE``, e.g. ``"LOS/A/1"`` (see :func:`hanyang_runs`).
    root : path, optional
        The data set folder (default :func:`require`).
    epoch_s : float
        Epoch length in seconds; 0 (default) writes every range at its own time stamp
        (one anchor per row, as the anchors answer), for the trackers (``ekf-track``,
        ``pf``); e.g. 0.1 for ``gn``.
    tag_height_m : float, optional
        If given, ranges are projected to the horizontal plane with the tag at this height
        (``sqrt(r^2 - (h - z_a)^2)``, 0 when negative) and anchors are written in 2-D;
        otherwise anchors keep ``z`` and ranges are the measured 3-D ones.
    fmt : {"csv", "parquet"}
        File format of the tables.

    Returns
    -------
    dict of str to Path
        ``measurements``, ``anchors``, ``reference`` (RTK truth, tag at ``z + 1 m`` as the
        authors' code assumes), ``ls`` and ``eskf`` (the set's own estimates, where present).
    """
    from radioloc.io.hanyang import load_dynamic

    if not epoch_s >= 0:
        raise ConfigError(f"epoch_s: must be >= 0 (0: the raw rows), got {epoch_s}")
    ext = _ext(fmt)
    root = Path(root) if root is not None else require("hanyang-uwb-outdoor")
    dyn = load_dynamic(_hanyang_folder(root, run))
    if epoch_s == 0:                                  # the rows as they arrive, unsampled
        from radioloc.io.hanyang import measurement_rows

        meas, anchors = measurement_rows(dyn)
        if tag_height_m is not None:
            dz = float(tag_height_m) - meas["peer"].map(dict(zip(anchors["id"], anchors["z"])))
            meas["value"] = np.sqrt(np.maximum(meas["value"] ** 2 - dz ** 2, 0.0))
            anchors = anchors[["id", "x", "y"]]
        return _write_hanyang(Path(out), ext, meas, anchors, dyn)
    ids = dyn.anchors["id"].to_numpy()
    start = float(dyn.ranges.time_s.min()) + epoch_s
    t = np.arange(start, float(dyn.ranges.time_s.max()) + 1e-9, epoch_s)
    value = np.full((t.size, ids.size), np.nan)
    for j, aid in enumerate(ids):                     # loop over the anchor files
        g = dyn.ranges[dyn.ranges.anchor == aid].sort_values("time_s")
        ts, r = g.time_s.to_numpy(), g.range_m.to_numpy()
        k = np.searchsorted(ts, t, side="right") - 1
        ok = (k >= 0) & (t - ts[np.maximum(k, 0)] < epoch_s)
        value[ok, j] = r[k[ok]]
    keep = np.isfinite(value).all(axis=1)
    t, value = t[keep], value[keep]
    anchors = dyn.anchors.assign(id=[f"A{a}" for a in ids])
    if tag_height_m is not None:
        dz = float(tag_height_m) - anchors["z"].to_numpy()
        value = np.sqrt(np.maximum(value ** 2 - dz ** 2, 0.0))
        anchors = anchors[["id", "x", "y"]]
    n_t, n_a = value.shape
    meas = pd.DataFrame({"time": np.repeat(np.round(t, 6), n_a), "node": "tag",
                         "peer": np.tile(anchors["id"].to_numpy(), n_t), "kind": "range",
                         "value": value.ravel()})
    return _write_hanyang(Path(out), ext, meas, anchors, dyn)


def _write_hanyang(out: Path, ext: str, meas, anchors, dyn) -> dict[str, Path]:
    from radioloc.io.hanyang import TAG_HEIGHT_OFFSET_M

    ref = dyn.reference.rename(columns={"time_s": "time"})
    ref = ref.assign(z=ref["z"] + TAG_HEIGHT_OFFSET_M)
    paths = {"measurements": write_table(meas, out / f"measurements{ext}"),
             "anchors": write_table(anchors, out / f"anchors{ext}"),
             "reference": write_table(ref, out / f"reference{ext}")}
    for key, frame in dyn.estimates.items():
        paths[key] = write_table(frame.rename(columns={"time_s": "time"}), out / f"{key}{ext}")
    return paths


def export_kolakowski(out: Path | str, *, root: Path | str | None = None,
                      fmt: str = "csv") -> dict[str, Path]:
    """Write the Kolakowski BLE set as a fingerprint calibration file and a ``locate`` run.

    Parameters
    ----------
    out : path
        Output folder.
    root : path, optional
        The data set folder (default :func:`require`).
    fmt : {"csv", "parquet"}
        File format of the measurement and reference tables (the calibration file is
        always CSV, the format ``radioloc locate --method gmm --calibration`` reads).

    Returns
    -------
    dict of str to Path
        ``calibration`` (``x, y`` and one column per anchor id, dBm, empty = not
        received), ``measurements`` (``rss`` rows of the robot test run, node ``robot``),
        ``anchors`` and ``reference`` (``time, x, y`` of the robot, LiDAR SLAM).
    """
    from radioloc.io.kolakowski import load_anchors, load_fingerprints

    ext = _ext(fmt)
    root = Path(root) if root is not None else require("kolakowski-ble-fingerprints-2021")
    cal = load_fingerprints(root, "calibration")
    test = load_fingerprints(root, "robot")
    ids = [str(a) for a in cal.anchor_ids]
    out = Path(out)
    calib = pd.DataFrame(cal.position, columns=["x", "y"])
    calib[ids] = cal.rss
    paths = {"calibration": write_table(calib, out / "calibration.csv")}
    paths.update(_rss_run(out, ext, test.time_s, "robot", [str(a) for a in test.anchor_ids],
                          test.rss, pd.DataFrame({"time": np.round(test.time_s, 6),
                                                  "x": test.position[:, 0],
                                                  "y": test.position[:, 1]})))
    anchors = load_anchors(root)
    paths["anchors"] = write_table(anchors.assign(id=anchors["id"].astype(str)), out / f"anchors{ext}")
    return paths


def _rss_run(out: Path, ext: str, time: np.ndarray, node: str, ids: list[str],
             rss: np.ndarray, reference: pd.DataFrame) -> dict[str, Path]:
    """``rss`` rows (one per received station) and the reference table."""
    n, s = rss.shape
    rows = pd.DataFrame({"time": np.repeat(np.round(time, 6), s), "node": node,
                         "peer": np.tile(ids, n), "kind": "rss", "value": rss.ravel()})
    rows = rows[np.isfinite(rows["value"].to_numpy())]
    return {"measurements": write_table(rows, out / f"measurements{ext}"),
            "reference": write_table(reference, out / f"reference{ext}")}


def export_wifi_rtt(out: Path | str, *, venue: str = "Canteen", circle: str | int = 1,
                    rss: bool = False, phone_std: bool = False, heading: bool = False,
                    root: Path | str | None = None, fmt: str = "csv") -> dict[str, Path]:
    """Write one circle of the WiFi RTT set in the ``radioloc locate`` schema.

    Both phones go in one log, as nodes ``M1`` and ``M2`` (their clocks start at 0 together).
    Each sample gives one ``range`` row per AP measured and, with ``rss``, one ``rss`` row.
    The standard deviation the phone reports with a range is the spread within its burst of
    exchanges, far below the range's error (biases of 1-7 m, multipath outliers), so it is
    written (as the ``std`` column) only with ``phone_std``. The truth columns
    (true distances, ground truth) are never written as measurements; the ground truth goes
    to ``reference``. An AP written as 0 (not measured) has no row. The phone-to-phone
    ranges are not written: their clock is not aligned with the phones' logs. With
    ``heading``, each sample's ``Azimuth`` (the phone's orientation, an IMU input) becomes a
    ``heading`` row (peer ``imu``): negated, as the compass turns clockwise and the map's
    angles counter-clockwise, so the row is the map heading plus an unknown offset (the
    rotation between magnetic north and the map's x axis) to remove before tracking
    (:func:`radioloc.locate.heading_offset.estimate_heading_offset`).

    Parameters
    ----------
    out : path
        Output folder.
    venue : str
        A venue folder of the set's ``raw_data`` (:func:`radioloc.io.wifi_rtt.venues`).
    circle : str or int
        A circle folder of the venue.
    rss : bool
        Also write the RSS rows (for methods that use ``rss``).
    phone_std : bool
        Write the phone's reported standard deviation as the ``std`` column.
    heading : bool
        Also write the phone's azimuth as ``heading`` rows (sensor frame).
    root : path, optional
        The data set folder (default :func:`require`).
    fmt : {"csv", "parquet"}

    Returns
    -------
    dict of str to Path
        ``measurements``, ``anchors``, ``reference`` (``time, node, x, y``).
    """
    from radioloc.io.wifi_rtt import PHONES, load_anchors, load_run

    ext = _ext(fmt)
    root = Path(root) if root is not None else require("wifi-rtt-haiyaoyu")
    rows, refs = [], []
    for phone in PHONES:
        run = load_run(root, venue, circle, phone)
        n, a = run.range_m.shape
        t = np.repeat(np.round(run.time_s, 6), a)
        kinds = [("range", run.range_m, run.range_std_m)]
        if rss:
            kinds.append(("rss", run.rss_dbm, np.full_like(run.rss_dbm, np.nan)))
        for kind, value, std in kinds:
            rows.append(pd.DataFrame({"time": t, "node": phone, "peer": np.tile(run.ap_ids, n),
                                      "kind": kind, "value": value.ravel(), "std": std.ravel()}))
        if heading:
            azimuth = run.imu["Azimuth"].to_numpy(dtype=float)
            rows.append(pd.DataFrame({"time": np.round(run.time_s, 6), "node": phone,
                                      "peer": "imu", "kind": "heading",
                                      "value": np.angle(np.exp(-1j * azimuth)),
                                      "std": np.nan}))
        refs.append(pd.DataFrame({"time": np.round(run.time_s, 6), "node": phone,
                                  "x": run.truth_xy[:, 0], "y": run.truth_xy[:, 1]}))
    meas = pd.concat(rows, ignore_index=True)
    if not phone_std:
        meas = meas.drop(columns="std")
    meas = meas[np.isfinite(meas["value"].to_numpy())].sort_values(["time", "node", "kind"],
                                                                    kind="stable")
    out = Path(out)
    return {"measurements": write_table(meas, out / f"measurements{ext}"),
            "anchors": write_table(load_anchors(root, venue), out / f"anchors{ext}"),
            "reference": write_table(pd.concat(refs, ignore_index=True).sort_values(
                ["time", "node"], kind="stable"), out / f"reference{ext}")}


#: How ``export_smartloc`` writes the ``std`` of a pseudorange.
SMARTLOC_WEIGHTS = ("variance", "elevation", "cn0")


def export_smartloc(out: Path | str, *, weights: str = "variance", root: Path | str | None = None,
                    fmt: str = "csv") -> dict[str, Path]:
    """Write the smartLoc Berlin drive in the ``radioloc locate`` schema.

    Each pseudorange is a ``pseudorange`` row of node ``car`` to its satellite (``G12``,
    ``R20``); the satellites are moving anchors in ECEF (``frame`` column ``ecef``), one row
    per epoch where the satellite was tracked, each with its constellation as ``group``
    (``GPS``, ``GLONASS``: one receiver clock per group). The receiver's position is never
    written to the measurements: the reference goes to ``reference`` (ECEF, ``frame``
    ``ecef``). The car's body-frame speed, vertical speed and yaw rate go to ``odometry``
    and, as ``speed``, ``vertical_speed`` and ``yaw_rate`` rows with their standard
    deviations, beside the pseudoranges
    in ``measurements_odometry`` (for ``ekf-track`` and ``smoother``).

    Parameters
    ----------
    out : path
        Output folder.
    weights : {"variance", "elevation", "cn0"}
        The ``std`` column: the square root of the file's variance, or a model of the
        elevation (:func:`radioloc.core.gnss.elevation_std_m`) or of the C/N0
        (:func:`radioloc.core.gnss.cn0_std_m`) at their default constants.
    root : path, optional
        The data set folder (default :func:`require`).
    fmt : {"csv", "parquet"}

    Returns
    -------
    dict of str to Path
        ``measurements`` (the pseudoranges), ``measurements_odometry`` (the pseudoranges
        and the odometry as ``speed``, ``vertical_speed`` and ``yaw_rate`` rows of sensor
        ``odometry``, for the trackers), ``anchors``, ``reference`` and ``odometry``
        (``time, speed_mps, vertical_mps, yaw_rate_rps, speed_var, vertical_var,
        yaw_rate_var``).
    """
    from radioloc.io.smartloc import load
    from radioloc.core.gnss import cn0_std_m, elevation_std_m

    if weights not in SMARTLOC_WEIGHTS:
        raise ConfigError(f"weights: {weights!r} is not one of {', '.join(SMARTLOC_WEIGHTS)}")
    ext = _ext(fmt)
    root = Path(root) if root is not None else require("gnss-smartloc-berlin")
    drive = load(root)
    pr = drive.pseudoranges.assign(time=np.round(drive.pseudoranges["time"].to_numpy(), 6))
    std = {"variance": lambda: np.sqrt(pr["variance"].to_numpy()),
           "elevation": lambda: elevation_std_m(pr["elevation_deg"].to_numpy()),
           "cn0": lambda: cn0_std_m(pr["cn0_dbhz"].to_numpy())}[weights]()
    meas = pd.DataFrame({"time": pr["time"], "node": "car", "peer": pr["satellite"],
                         "kind": "pseudorange", "value": pr["value"], "std": std})
    anchors = pd.DataFrame({"id": pr["satellite"], "time": pr["time"], "x": pr["x"],
                            "y": pr["y"], "z": pr["z"], "group": pr["system"], "frame": "ecef"})
    anchors = anchors.sort_values(["id", "time"], kind="stable")
    ref = drive.reference.assign(time=np.round(drive.reference["time"].to_numpy(), 6),
                                 frame="ecef")
    odo = drive.odometry.assign(time=np.round(drive.odometry["time"].to_numpy(), 6))
    rates = pd.concat([pd.DataFrame({"time": odo["time"], "node": "car", "peer": "odometry",
                                     "kind": kind, "value": odo[value],
                                     "std": np.sqrt(odo[var].to_numpy())})
                       for kind, value, var in (("speed", "speed_mps", "speed_var"),
                                                ("vertical_speed", "vertical_mps", "vertical_var"),
                                                ("yaw_rate", "yaw_rate_rps", "yaw_rate_var"))])
    with_odometry = pd.concat([meas, rates]).sort_values("time", kind="stable")
    out = Path(out)
    return {"measurements": _write_exact(meas, out / f"measurements{ext}"),
            "measurements_odometry": _write_exact(with_odometry,
                                                  out / f"measurements_odometry{ext}"),
            "anchors": _write_exact(anchors, out / f"anchors{ext}"),
            "reference": _write_exact(ref, out / f"reference{ext}"),
            "odometry": _write_exact(odo, out / f"odometry{ext}")}


def _write_exact(frame: pd.DataFrame, path: Path) -> Path:
    """:func:`write_table` with every float in its shortest exact form (satellite
    coordinates need more than the micrometres of ``write_table``'s CSV)."""
    if path.suffix.lower() == ".parquet":
        return write_table(frame, path)
    from radioloc.io.logs import write_estimates

    path.parent.mkdir(parents=True, exist_ok=True)
    write_estimates(frame, path)
    return path


#: UJIIndoorLoc's value for "access point not detected".
UJI_NOT_DETECTED = 100


def export_ujiindoorloc(out: Path | str, *, building: int = 0, floor: int = 0,
                        min_detections: int = 20, root: Path | str | None = None,
                        fmt: str = "csv") -> dict[str, Path]:
    """Write one building floor of UJIIndoorLoc as a fingerprint calibration file (training
    fingerprints) and a ``locate`` run (validation fingerprints).

    Coordinates are the file's (EPSG:3857 "metres", 0.766 ground metres each, see the set's
    SOURCE.md) minus the origin of the floor's training fingerprints (``floor(min x)``,
    ``floor(min y)``), written to ``origin.csv``. RSS 100 (not detected) becomes an empty
    cell; only access points detected at least ``min_detections`` times in the floor's
    training fingerprints are kept. Validation fingerprints are independent snapshots by
    another user months later, so ``time`` is the fingerprint's row number, not a clock.

    Parameters
    ----------
    out : path
        Output folder.
    building, floor : int
        ``BUILDINGID`` (0-2) and ``FLOOR`` (0-4) to export.
    min_detections : int
        Keep access points detected at least this often in the training fingerprints.
    root : path, optional
        The data set folder (default :func:`require`).
    fmt : {"csv", "parquet"}
        File format of the measurement and reference tables (calibration: CSV).

    Returns
    -------
    dict of str to Path
        ``calibration``, ``measurements`` (node ``phone``), ``reference`` (``time, x, y,
        timestamp, phone``) and ``origin``.
    """
    ext = _ext(fmt)
    root = Path(root) if root is not None else require("ujiindoorloc")
    train = _uji_read(root / "trainingData.csv", building, floor)
    valid = _uji_read(root / "validationData.csv", building, floor)
    waps = [c for c in train.columns if c.startswith("WAP")]
    detected = (train[waps] != UJI_NOT_DETECTED).sum()
    keep = [w for w in waps if detected[w] >= min_detections]
    if not keep:
        raise ConfigError(f"min_detections={min_detections}: no access point is detected that "
                          f"often on building {building} floor {floor}")
    origin = np.floor(train[["LONGITUDE", "LATITUDE"]].min().to_numpy(float))
    out = Path(out)

    def pos(frame):
        return frame[["LONGITUDE", "LATITUDE"]].to_numpy(float) - origin

    def rss(frame):
        v = frame[keep].to_numpy(float)
        return np.where(v == UJI_NOT_DETECTED, np.nan, v)

    calib = pd.DataFrame(pos(train), columns=["x", "y"])
    calib[keep] = rss(train)
    paths = {"calibration": write_table(calib, out / "calibration.csv")}
    vpos = pos(valid)
    time = np.arange(len(valid), dtype=float)
    paths.update(_rss_run(out, ext, time, "phone", keep, rss(valid), pd.DataFrame(
        {"time": time, "x": vpos[:, 0], "y": vpos[:, 1],
         "timestamp": valid["TIMESTAMP"].to_numpy(), "phone": valid["PHONEID"].to_numpy()})))
    paths["origin"] = write_table(pd.DataFrame({"x0": [origin[0]], "y0": [origin[1]],
                                                "unit": ["EPSG:3857 m"]}), out / "origin.csv")
    return paths


def _uji_read(path: Path, building: int, floor: int) -> pd.DataFrame:
    if not path.is_file():
        raise DataUnavailable(f"{path}: not found")
    frame = pd.read_csv(path)
    need = {"LONGITUDE", "LATITUDE", "FLOOR", "BUILDINGID", "TIMESTAMP", "PHONEID"}
    if need - set(frame.columns):
        raise InputError(f"{path}: missing column(s) {', '.join(sorted(need - set(frame.columns)))}")
    sel = frame[(frame["BUILDINGID"] == building) & (frame["FLOOR"] == floor)]
    if sel.empty:
        raise ConfigError(f"{path}: no fingerprint on building {building} floor {floor}")
    return sel.reset_index(drop=True)


def _ext(fmt: str) -> str:
    fmt = fmt.lower().lstrip(".")
    if fmt not in ("csv", "parquet"):
        raise ConfigError(f"format: {fmt!r} is not csv or parquet")
    if fmt == "parquet":
        _need_pyarrow()
    return "." + fmt


#: Export functions by data set folder name.
EXPORTERS: dict[str, Callable[..., dict[str, Path]]] = {
    "gnss-smartloc-berlin": export_smartloc,
    "hanyang-uwb-outdoor": export_hanyang,
    "kolakowski-ble-fingerprints-2021": export_kolakowski,
    "ujiindoorloc": export_ujiindoorloc,
    "wifi-rtt-haiyaoyu": export_wifi_rtt,
}


def export(name: str, out: Path | str, **options) -> dict[str, Path]:
    """Export data set ``name`` to ``out`` (see :func:`export_hanyang`,
    :func:`export_kolakowski`, :func:`export_ujiindoorloc` for the options).

    Parameters
    ----------
    name : str
        Data set folder name or alias.
    out : path
        Output folder.
    **options
        Passed to the set's exporter.

    Returns
    -------
    dict of str to Path
        The files written, by role.

    Raises
    ------
    ConfigError
        The set has no exporter.
    """
    ds = get(name)
    if ds.name not in EXPORTERS:
        raise ConfigError(f"{ds.name}: nothing to export (it holds no locate run nor "
                          f"fingerprints); exportable: {', '.join(EXPORTERS)}")
    return EXPORTERS[ds.name](out, **options)


__all__ = ["DATASETS", "DataSet", "data_roots", "download_root", "export", "export_hanyang",
           "export_kolakowski", "export_smartloc", "export_ujiindoorloc", "export_wifi_rtt", "fetch", "find", "get", "hanyang_runs",
           "missing_message", "read_table_text", "require", "status", "write_table"]
