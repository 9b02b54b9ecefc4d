"""The measurement-kind registry (:mod:`radioloc.core.kinds`): what it generates (schema,
value checks, sigma options, method kinds, the docs' tables), a kind registered by a package
outside radioloc through the ``radioloc.kinds`` entry points and run through ``locate``, and
the one-line refusal of a model that reads velocity with a motion model without it."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.kinds import kinds, markdown_table, model_kinds
from radioloc.io.logs import read_measurements
from radioloc.locate.adapter import sigma_options
from radioloc.locate.base import methods

ROOT = Path(__file__).resolve().parents[1]
ANCHORS = pd.DataFrame({"id": ["A", "B", "C", "D"], "x": [0.0, 20.0, 20.0, 0.0],
                        "y": [0.0, 0.0, 15.0, 15.0]})


def _hooks():
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "hooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("page", ["your-own-log/index.md", "architecture.md"])
def test_the_docs_kinds_tables_are_the_registry(page):
    hooks = _hooks()
    text = (ROOT / "docs" / page).read_text(encoding="utf-8")
    assert text.count(hooks.KINDS_MARKER) == 1
    built = hooks.on_page_markdown(text)
    rows = [ln for ln in built.splitlines() if ln.startswith("| `") and "` | " in ln
            and ln.split("`")[1] in kinds()]
    assert [ln.split("`")[1] for ln in rows[-len(kinds()):]] == list(kinds())
    assert markdown_table().strip() in built
    for name, k in kinds().items():
        row = next(ln for ln in markdown_table().splitlines() if ln.startswith(f"| `{name}` |"))
        assert f"| {k.unit} |" in row
        if k.sigma_option:
            assert f"`{k.sigma_option}` ({k.sigma_default:g})" in row


def test_schema_options_and_methods_come_from_the_declarations(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("time,node,peer,kind,value\n0,t,A,sonar,3\n")
    with pytest.raises(InputError, match="is not one of " + ", ".join(kinds())):
        read_measurements(path)
    # each kind's limit refuses a row, naming the line
    for name, k in kinds().items():
        if k.limit is None or k.self_measured or k.reference:
            continue
        path.write_text(f"time,node,peer,kind,value\n0,t,A,{name},{2 * k.limit!r}\n")
        with pytest.raises(InputError, match=f"line 2, column 'value': .*{name}"):
            read_measurements(path)
    options = sigma_options()
    assert {k.sigma_option for k in model_kinds().values()} == set(options)
    for k in model_kinds().values():
        assert f"(default {k.sigma_default:g})" in options[k.sigma_option].help
    readers = methods()
    for method in ("ekf-track", "smoother", "lsq", "pf"):
        assert set(model_kinds()) <= set(readers[method].kinds), method
        own = set(options) - ({"range_std_m"} if method == "pf" else set())  # pf: los_std_m
        assert own <= set(readers[method].options), method


PLUGIN = '''
import numpy as np

from radioloc.core.kinds import Kind
from radioloc.models.measurement import MeasurementModel
from radioloc.models.ranging import range_geometry


class CentimetreRange(MeasurementModel):
    """A range reported in centimetres."""

    kind = "range_cm"

    def __init__(self, std_cm):
        self.std_cm = std_cm

    def predict(self, state, context):
        return 100.0 * range_geometry(state["position"], context.points, context.height_m)[0]

    def jacobian(self, state, context):
        return {"position": 100.0 * range_geometry(state["position"], context.points,
                                                   context.height_m)[1]}

    def std(self, context):
        return self.row_std(self.std_cm, context)


KIND = Kind("range_cm", "cm", "distance to `peer`, centimetres", model=CentimetreRange,
            sigma_option="range_cm_std", sigma_default=30.0, limit=1e9)
TWICE = Kind("range", "m", "a second range", limit=1.0)
'''


def _plugin(tmp_path: Path, target: str) -> Path:
    """A package ``kindplug`` outside src/ with one ``radioloc.kinds`` entry point."""
    site = tmp_path / "site"
    (site / "kindplug").mkdir(parents=True)
    (site / "kindplug" / "__init__.py").write_text(textwrap.dedent(PLUGIN))
    info = site / "kindplug-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: kindplug\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[radioloc.kinds]\nrange_cm = {target}\n")
    return site


def _radioloc(site: Path, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(site), COLUMNS="400")
    return subprocess.run([sys.executable, "-m", "radioloc.cli", *args], env=env,
                          capture_output=True, text=True, timeout=300)


def test_a_kind_from_another_package_runs_through_locate(tmp_path):
    site = _plugin(tmp_path, "kindplug:KIND")
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 20.0, 0.5)
    xy = np.stack([10 + 5 * np.cos(0.2 * t), 7 + 4 * np.sin(0.2 * t)], -1)
    cm = 100 * np.linalg.norm(xy[:, None] - ANCHORS[["x", "y"]].to_numpy(), axis=-1)
    log = pd.DataFrame({"time": np.repeat(t, 4), "node": "tag",
                        "peer": np.tile(ANCHORS["id"], t.size), "kind": "range_cm",
                        "value": (cm + 10 * rng.standard_normal(cm.shape)).ravel()})
    log.to_csv(tmp_path / "m.csv", index=False)
    ANCHORS.to_csv(tmp_path / "a.csv", index=False)
    for method in ("lsq", "ekf-track"):
        out = tmp_path / f"{method}.csv"
        res = _radioloc(site, "locate", str(tmp_path / "m.csv"), "--anchors",
                        str(tmp_path / "a.csv"), "--method", method, "-o", "range_cm_std=10",
                        "--out", str(out))
        assert res.returncode == 0, res.stderr
        est = pd.read_csv(out)
        err = np.linalg.norm(est[["x", "y"]].to_numpy() - xy, axis=1)
        assert len(est) == t.size and np.median(err) < 0.3, (method, err)
    listing = _radioloc(site, "methods")
    assert "range_cm_std" in listing.stdout and "range_cm" in listing.stdout


def test_a_kind_declared_twice_is_named_and_a_broken_entry_point_warns(tmp_path):
    site = _plugin(tmp_path, "kindplug:TWICE")
    res = _radioloc(site, "methods")
    assert res.returncode != 0
    assert "kind 'range' declared twice: by radioloc.models.ranging and by entry point" \
        in res.stderr + res.stdout
    assert "Traceback" not in res.stderr + res.stdout
    broken = _plugin(tmp_path / "b", "kindplug:MISSING")
    res = _radioloc(broken, "methods")
    assert res.returncode == 0 and "radioloc.kinds: entry point range_cm" in res.stderr


def _heading_log():
    from radioloc.models.heading import HeadingModel
    from radioloc.models.measurement import Context, Observation

    z = np.full((6, 1), 0.3)
    return Observation(HeadingModel(std_rad=0.1), z, Context(points=np.zeros((1, 2))))


@pytest.mark.parametrize("estimator", ["ekf", "smoother", "pf"])
def test_a_velocity_model_with_a_random_walk_is_refused_naming_both(estimator):
    from radioloc.estimators.batch_smoother import BatchSmoother
    from radioloc.estimators.extended_kalman import ExtendedKalmanFilter
    from radioloc.estimators.particle_filter import ParticleFilter
    from radioloc.models.motion import RandomWalk

    motion = RandomWalk(1.0, 2)
    est = {"ekf": lambda: ExtendedKalmanFilter(motion), "smoother": lambda: BatchSmoother(motion),
           "pf": lambda: ParticleFilter(motion, n_particles=50)}[estimator]()
    layout = est.layout_for if estimator == "pf" else est.state_layout
    with pytest.raises(ConfigError) as err:
        layout([_heading_log()])
    message = str(err.value)
    assert "\n" not in message
    assert "HeadingModel (kind heading) reads velocity" in message and "RandomWalk" in message


def test_anchor_columns_the_kinds_read_are_read_and_carried_per_row(tmp_path):
    from radioloc.io.logs import read_anchors
    from radioloc.models.measurement import Context

    columns = list(dict.fromkeys(c for k in kinds().values() for c in k.anchor_columns))
    assert columns
    values = {c: [float(i + 1), ""] for i, c in enumerate(columns)}
    table = pd.DataFrame({"id": ["A", "B"], "x": [0.0, 5.0], "y": [0.0, 0.0], **values})
    table.to_csv(tmp_path / "a.csv", index=False)
    read = read_anchors(tmp_path / "a.csv")
    for i, c in enumerate(columns):
        assert read[c].iloc[0] == i + 1 and np.isnan(read[c].iloc[1]), c
    ctx = Context(points=np.zeros((3, 2)), columns={"vx": [1.0, 2.0, 3.0]})
    assert ctx.take(np.array([2, 0])).columns["vx"].tolist() == [3.0, 1.0]
    with pytest.raises(InputError, match=r"columns\['vx'\]: expected 3 values"):
        Context(points=np.zeros((3, 2)), columns={"vx": [1.0, 2.0]})
