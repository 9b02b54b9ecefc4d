"""Data sets: lookup, fetch (from a local file:// mirror, never the network), export."""

from __future__ import annotations

import os
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from radioloc.cli_datasets import datasets_app
from radioloc.core.errors import ConfigError, DataUnavailable
from radioloc.io import datasets as ds
from radioloc.io.logs import read_anchors, read_measurements

TEST_DATA = Path(__file__).parent / "data"
SHARED = Path(os.environ.get("RADIOLOC_DATA", "/work/shared/data"))
runner = CliRunner()


@pytest.fixture
def test_root(monkeypatch):
    monkeypatch.setenv("RADIOLOC_DATA", str(TEST_DATA))
    return TEST_DATA


def _mirror_dataset(name: str, src: Path, checksums: bool = True) -> ds.DataSet:
    files = tuple((str(p.relative_to(src)), f"sha256:{ds.file_digest(p)}" if checksums else None)
                  for p in sorted(src.rglob("*.csv")))
    return ds.DataSet(name, "test set", "local", "0" * 40, src.as_uri() + "/", "CC0",
                      aliases=("mirror",), files=files)


# ---- lookup -----------------------------------------------------------------------------

def test_env_var_is_the_only_root(monkeypatch, tmp_path):
    monkeypatch.setenv("RADIOLOC_DATA", str(tmp_path))
    assert ds.data_roots() == [tmp_path]
    assert ds.download_root() == tmp_path


def test_default_roots_do_not_depend_on_the_working_directory(monkeypatch, tmp_path):
    monkeypatch.delenv("RADIOLOC_DATA", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    roots = ds.data_roots()
    monkeypatch.chdir(tmp_path)
    assert ds.data_roots() == roots
    assert roots[0] == ds.platform_cache()
    assert all(r.is_absolute() for r in roots)
    repo = ds.repository_root()
    if repo is not None:
        assert roots[1] == repo.parent / "shared" / "data"


def test_missing_set_says_where_it_looked_and_how_to_fetch(monkeypatch, tmp_path):
    monkeypatch.setenv("RADIOLOC_DATA", str(tmp_path / "none"))
    with pytest.raises(DataUnavailable) as err:
        ds.require("hanyang")
    msg = str(err.value)
    assert str(tmp_path / "none") in msg
    assert "radioloc datasets fetch hanyang-uwb-outdoor" in msg


def test_experiment_skip_message_names_the_folders_once(monkeypatch, tmp_path):
    from radioloc.experiments.base import get_experiment

    monkeypatch.setenv("RADIOLOC_DATA", str(tmp_path / "none"))
    with pytest.raises(DataUnavailable) as err:
        get_experiment("real-uwb-hanyang").check_available()
    msg = str(err.value)
    assert msg.count("looked in") == 1 and msg.count(str(tmp_path / "none")) == 1
    assert "datasets fetch" in msg


def test_find_and_data_root(test_root):
    from radioloc.experiments.base import data_root

    assert ds.find("kolakowski") == test_root / "kolakowski-ble-fingerprints-2021"
    assert ds.find("herald") is None
    assert data_root("ujiindoorloc") == test_root


def test_unknown_name_lists_the_known_ones():
    with pytest.raises(ConfigError, match="hanyang-uwb-outdoor"):
        ds.get("nope")


# ---- registry ---------------------------------------------------------------------------

def test_every_set_has_pinned_checksums():
    for d in ds.DATASETS.values():
        assert d.checksums_known, d.name
        assert d.base_url.startswith("https://") and d.commit in d.base_url


@pytest.mark.parametrize("name", [n for n in ds.DATASETS if n != "ujiindoorloc"])
def test_registry_matches_the_reference_copy(name):
    folder = SHARED / name
    if not folder.is_dir():
        pytest.skip(f"reference copy {folder} absent")
    for rel, checksum in ds.get(name).entries():
        assert ds.matches_checksum(folder / rel, checksum), rel


def test_uji_members_match_the_reference_copy():
    folder = SHARED / "ujiindoorloc"
    if not folder.is_dir():
        pytest.skip(f"reference copy {folder} absent")
    for target, checksum in ds.get("ujiindoorloc").archive[2].values():
        assert ds.matches_checksum(folder / target, checksum)


# ---- fetch from a local mirror -----------------------------------------------------------

def test_fetch_from_file_url_verifies_and_skips_present_files(monkeypatch, tmp_path):
    src = TEST_DATA / "kolakowski-ble-fingerprints-2021"
    entry = _mirror_dataset("mirror-set", src)
    monkeypatch.setitem(ds.DATASETS, entry.name, entry)
    lines = []
    folder = ds.fetch("mirror", dest=tmp_path, log=lines.append)
    assert folder == tmp_path / "mirror-set"
    for rel, _ in entry.entries():
        assert (folder / rel).read_bytes() == (src / rel).read_bytes()
    assert len(lines) == len(entry.entries())
    assert "verified" in (folder / "FETCHED.md").read_text()
    lines.clear()
    ds.fetch("mirror", dest=tmp_path, log=lines.append)   # all present: nothing downloaded
    assert lines == []


def test_fetch_refuses_a_changed_file(monkeypatch, tmp_path):
    src = tmp_path / "origin"
    shutil.copytree(TEST_DATA / "kolakowski-ble-fingerprints-2021", src)
    entry = _mirror_dataset("mirror-set", src)
    (src / "anchors.csv").write_text("id,x,y\n1,0,0\n")     # the origin changed
    monkeypatch.setitem(ds.DATASETS, entry.name, entry)
    with pytest.raises(DataUnavailable, match="checksum mismatch"):
        ds.fetch("mirror-set", dest=tmp_path / "dest")
    assert not (tmp_path / "dest" / "mirror-set" / "anchors.csv").exists()
    folder = ds.fetch("mirror-set", dest=tmp_path / "dest", verify=False)
    assert (folder / "anchors.csv").read_text() == "id,x,y\n1,0,0\n"
    assert "NOT verified" in (folder / "FETCHED.md").read_text()


def test_fetch_without_known_checksum_needs_no_verify(monkeypatch, tmp_path):
    entry = _mirror_dataset("mirror-set", TEST_DATA / "ujiindoorloc", checksums=False)
    monkeypatch.setitem(ds.DATASETS, entry.name, entry)
    with pytest.raises(ConfigError, match="--no-verify"):
        ds.fetch("mirror-set", dest=tmp_path)
    assert not (tmp_path / "mirror-set").exists()
    res = runner.invoke(datasets_app, ["fetch", "mirror-set", "--dest", str(tmp_path), "--no-verify"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "mirror-set" / "trainingData.csv").is_file()


def test_fetch_archive_checks_the_zip_and_its_members(monkeypatch, tmp_path):
    origin = tmp_path / "origin"
    (origin / "data").mkdir(parents=True)
    zpath = origin / "data" / "set.zip"
    with zipfile.ZipFile(zpath, "w") as zf:
        for f in ("trainingData.csv", "validationData.csv"):
            zf.write(TEST_DATA / "ujiindoorloc" / f, f"UJ/{f}")
    members = {f"UJ/{f}": (f, f"sha256:{ds.file_digest(TEST_DATA / 'ujiindoorloc' / f)}")
               for f in ("trainingData.csv", "validationData.csv")}
    entry = ds.DataSet("zip-set", "t", "local", "0" * 40, origin.as_uri(), "CC0",
                       archive=("data/set.zip", f"gitblob:{ds.file_digest(zpath, 'gitblob')}",
                                members))
    monkeypatch.setitem(ds.DATASETS, entry.name, entry)
    folder = ds.fetch("zip-set", dest=tmp_path / "dest")
    assert (folder / "validationData.csv").read_bytes() == \
        (TEST_DATA / "ujiindoorloc" / "validationData.csv").read_bytes()
    assert not (folder / ".download").exists()
    bad = ds.DataSet("zip-bad", "t", "local", "0" * 40, origin.as_uri(), "CC0",
                     archive=("data/set.zip", "gitblob:" + "0" * 40, members))
    monkeypatch.setitem(ds.DATASETS, bad.name, bad)
    with pytest.raises(DataUnavailable, match="checksum mismatch"):
        ds.fetch("zip-bad", dest=tmp_path / "dest2")


def test_git_blob_id_is_gits():
    import hashlib

    data = (TEST_DATA / "ujiindoorloc" / "validationData.csv").read_bytes()
    want = hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()
    assert ds.file_digest(TEST_DATA / "ujiindoorloc" / "validationData.csv", "gitblob") == want


# ---- export -----------------------------------------------------------------------------

def test_export_hanyang_is_the_locate_schema(test_root, tmp_path):
    paths = ds.export("hanyang", tmp_path, run="LOS/A/1", epoch_s=0.1)
    anchors = read_anchors(paths["anchors"])
    meas = read_measurements(paths["measurements"], anchors=anchors)
    assert list(anchors["id"]) == ["A3", "A5", "A9", "A12"] and "z" in anchors
    assert (meas.groupby("time")["peer"].nunique() == 4).all()     # complete epochs only
    ref = pd.read_csv(paths["reference"])
    assert set(paths) == {"measurements", "anchors", "reference", "ls", "eskf"}
    # ranges are the distance to the tag at reference z + 1 m (within the made-up noise)
    m = meas.merge(anchors, left_on="peer", right_on="id")
    tag = np.stack([np.interp(m.time, ref.time, ref[c]) for c in ("x", "y", "z")], -1)
    dist = np.linalg.norm(tag - m[["x", "y", "z"]].to_numpy(), axis=-1)
    assert np.max(np.abs(dist - m["value"])) < 0.25


def test_export_hanyang_2d_then_locate_end_to_end(test_root, tmp_path):
    from radioloc.cli import app

    res = runner.invoke(app, ["datasets", "export", "hanyang", "--out", str(tmp_path),
                              "--tag-height", "1.1", "--epoch-s", "0.1"])
    assert res.exit_code == 0, res.output
    assert list(read_anchors(tmp_path / "anchors.csv").columns)[:3] == ["id", "x", "y"]
    res = runner.invoke(app, ["locate", str(tmp_path / "measurements.csv"), "--anchors",
                              str(tmp_path / "anchors.csv"), "--out", str(tmp_path / "est.csv")])
    assert res.exit_code == 0, res.output
    est, ref = pd.read_csv(tmp_path / "est.csv"), pd.read_csv(tmp_path / "reference.csv")
    err = np.hypot(est.x - np.interp(est.time, ref.time, ref.x),
                   est.y - np.interp(est.time, ref.time, ref.y))
    assert len(est) > 30 and np.median(err) < 0.3


def test_export_hanyang_unknown_run(test_root, tmp_path):
    with pytest.raises(ConfigError, match="LOS/A/1"):
        ds.export("hanyang", tmp_path, run="NLOS/B/4")


def test_export_kolakowski_calibration_and_run(test_root, tmp_path):
    paths = ds.export("kolakowski", tmp_path)
    cal = pd.read_csv(paths["calibration"])
    assert list(cal.columns) == ["x", "y", "1", "2", "3"] and len(cal) == 24
    assert cal["3"].isna().sum() == 5                          # not received stays empty
    meas = read_measurements(paths["measurements"])
    assert set(meas["kind"]) == {"rss"} and set(meas["peer"]) <= {"1", "2", "3"}
    assert len(meas) == 8 * 3 - 2                              # two readings were missing
    res = runner.invoke(__import__("radioloc.cli", fromlist=["app"]).app,
                        ["locate", str(paths["measurements"]), "--method", "gmm", "--calibration",
                         str(paths["calibration"]), "-o", "components=2",
                         "--out", str(tmp_path / "est.csv")])
    assert res.exit_code == 0, res.output
    assert len(pd.read_csv(tmp_path / "est.csv")) == 8


def test_export_ujiindoorloc_one_floor(test_root, tmp_path):
    paths = ds.export("uji", tmp_path, building=0, floor=0, min_detections=3)
    cal = pd.read_csv(paths["calibration"])
    origin = pd.read_csv(paths["origin"])
    assert (origin.x0[0], origin.y0[0]) == (-7610.0, 4864880.0)
    assert cal.x.min() == 0 and cal.y.min() == 0 and len(cal) == 20
    waps = [c for c in cal.columns if c.startswith("WAP")]
    assert "WAP005" not in waps                                # never detected on this floor
    assert not (cal[waps] == 100).any().any()                  # 100 = not detected -> empty
    ref = pd.read_csv(paths["reference"])
    assert list(ref.time) == [0.0, 1.0, 2.0]
    meas = read_measurements(paths["measurements"])
    assert set(meas["peer"]) <= set(waps)


def test_export_hanyang_default_is_the_raw_rows_for_the_trackers(test_root, tmp_path):
    paths = ds.export("hanyang", tmp_path, run="LOS/A/1")
    meas = pd.read_csv(paths["measurements"])
    # one anchor per row, at the time it answered: no time stamp carries all anchors
    assert meas.groupby("time")["peer"].nunique().max() == 1
    assert meas["time"].is_monotonic_increasing


def test_export_parquet_reads_like_csv(test_root, tmp_path):
    pytest.importorskip("pyarrow")
    a = ds.export("hanyang", tmp_path / "csv")
    b = ds.export("hanyang", tmp_path / "pq", fmt="parquet")
    assert b["measurements"].suffix == ".parquet"
    csv = pd.read_csv(a["measurements"])
    pq = pd.read_parquet(b["measurements"])
    assert list(pq.columns) == list(csv.columns)
    np.testing.assert_allclose(pq["value"], csv["value"], atol=1e-6)
    text = ds.read_table_text(b["anchors"])
    assert list(text["id"]) == ["A3", "A5", "A9", "A12"] and isinstance(text["x"][0], str)


def test_export_bad_options(test_root, tmp_path):
    with pytest.raises(ConfigError, match="nothing to export"):
        ds.export("herald", tmp_path)
    with pytest.raises(ConfigError, match="csv or parquet"):
        ds.export("hanyang", tmp_path, fmt="xlsx")
    with pytest.raises(ConfigError, match="building 2 floor 0"):
        ds.export("uji", tmp_path, building=2)


# ---- command line -------------------------------------------------------------------------

def test_cli_list_says_which_sets_are_present(test_root):
    res = runner.invoke(datasets_app, ["list"], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    lines = {ln.split()[1]: ln for ln in res.output.splitlines()
             if ln.startswith("│ ") and len(ln.split()) > 3 and "-" in ln.split()[1]}
    assert "yes" in lines["hanyang-uwb-outdoor"] and "no" in lines["herald-ble-rssi-distance"]
    assert str(test_root) in res.output


def test_cli_errors_are_one_line(test_root, tmp_path):
    res = runner.invoke(datasets_app, ["export", "herald", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "nothing to export" in res.output


def test_locate_reads_and_writes_parquet(test_root, tmp_path):
    """`radioloc locate` on an exported Parquet log gives what it gives on the CSV log."""
    pytest.importorskip("pyarrow")
    from radioloc.cli import app

    paths = ds.export("hanyang", tmp_path / "pq", fmt="parquet", tag_height_m=1.1, epoch_s=0.1)
    assert list(read_anchors(paths["anchors"]).columns)[:3] == ["id", "x", "y"]
    ds.export("hanyang", tmp_path / "csv", tag_height_m=1.1, epoch_s=0.1)
    for kind, ext in (("csv", "csv"), ("pq", "parquet")):
        res = runner.invoke(app, ["locate", str(tmp_path / kind / f"measurements.{ext}"),
                                  "--anchors", str(tmp_path / kind / f"anchors.{ext}"),
                                  "--out", str(tmp_path / f"est_{kind}.{ext}")])
        assert res.exit_code == 0, res.output
    a = pd.read_csv(tmp_path / "est_csv.csv")
    b = pd.read_parquet(tmp_path / "est_pq.parquet")
    np.testing.assert_allclose(b[["x", "y"]].to_numpy(), a[["x", "y"]].to_numpy(), atol=1e-5)


CONVERTED = [
    # (data set, export options, method, locate options): every method that fits each format
    ("hanyang", {"epoch_s": 0.1, "tag_height_m": 1.1}, "gn", ["-o", "on_degenerate=skip"]),
    ("hanyang", {"tag_height_m": 1.1}, "ekf-track", []),
    ("hanyang", {"tag_height_m": 1.1}, "ekf-track", ["--smooth"]),
    ("hanyang", {"tag_height_m": 1.1}, "pf", ["-o", "particles=200", "-o", "seed=1"]),
    ("kolakowski", {}, "gmm", ["-o", "components=2"]),
    ("uji", {"building": 0, "floor": 0, "min_detections": 1}, "gmm", ["-o", "components=2"]),
    ("uji", {"building": 0, "floor": 0, "min_detections": 1}, "gmm", ["-o", "model=places"]),
]


@pytest.mark.parametrize("name, export_opts, method, opts", CONVERTED,
                         ids=[f"{c[0]}-{c[2]}{'-' + c[3][0] if c[3] else ''}" for c in CONVERTED])
def test_every_converted_log_runs_through_locate(test_root, tmp_path, name, export_opts,
                                                 method, opts):
    from radioloc.cli import app

    paths = ds.export(name, tmp_path, **export_opts)
    args = ["locate", str(paths["measurements"]), "--method", method, *opts,
            "--out", str(tmp_path / "est.csv")]
    if "calibration" in paths:
        args += ["--calibration", str(paths["calibration"])]
    elif "anchors" in paths:
        args += ["--anchors", str(paths["anchors"])]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    est = pd.read_csv(tmp_path / "est.csv")
    assert len(est) > 0 and np.isfinite(est[["x", "y"]].to_numpy()).all()
    assert {"time", "node", "x", "y"} <= set(est.columns)
