"""`reproduce -o key=value`: config fields overridden by name, read as the field's type."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from radioloc.cli import app
from radioloc.core.errors import ConfigError
from radioloc.experiments.base import get_experiment

EXP = "p000-montecarlo"


def _config():
    exp = get_experiment(EXP)
    return exp, exp.config(False)


def test_fields_read_as_their_types():
    exp, cfg = _config()
    new = exp.with_options(cfg, {"iterations": "7", "side_m": "250.5",
                                 "range_var_m2": "1, 4", "forgetting": "0.9"})
    assert new.iterations == 7 and isinstance(new.iterations, int)
    assert new.side_m == 250.5
    assert new.range_var_m2 == (1.0, 4.0)
    assert new.forgetting == 0.9
    assert exp.with_options(cfg, None) is cfg


@pytest.mark.parametrize("opts, words", [
    ({"bogus": "1"}, ["bogus", "known", "iterations"]),
    ({"runs": "3"}, ["--runs"]),
    ({"iterations": "many"}, ["iterations", "many"]),
    ({"iterations": "0"}, ["iterations", "> 0"]),
    ({"side_m": "inf"}, ["side_m", "finite"]),
    ({"range_var_m2": "1, -4"}, ["range_var_m2", "> 0"]),
])
def test_bad_options_name_the_field(opts, words):
    exp, cfg = _config()
    with pytest.raises(ConfigError) as err:
        exp.with_options(cfg, opts)
    for w in words:
        assert w in str(err.value)


def test_cli_records_the_override(tmp_path):
    res = CliRunner().invoke(app, ["reproduce", EXP, "--runs", "20", "-o", "iterations=5",
                                   "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    summary = json.loads((tmp_path / EXP / "summary.json").read_text())
    assert summary["config"]["iterations"] == 5


def test_every_node_assisted_runs_with_finite_metrics_and_no_empty_class(tmp_path):
    res = CliRunner().invoke(app, ["reproduce", EXP, "--runs", "20", "-o", "iterations=5",
                                   "-o", "assisted=6", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "warning" not in res.output
    metrics = json.loads((tmp_path / EXP / "summary.json").read_text())["metrics"]
    values = {m["name"]: m["value"] for m in metrics}
    assert values and all(v is not None and v == v for v in values.values())
    assert not any("_unassisted_" in name for name in values)
    assert any("_assisted_" in name for name in values)


def test_cli_refuses_options_for_all_and_unknown_keys(tmp_path):
    res = CliRunner().invoke(app, ["reproduce", "all", "-o", "iterations=5", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "name the experiment" in res.output
    res = CliRunner().invoke(app, ["reproduce", EXP, "-o", "iteration=5", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "no such option" in res.output
    assert not (tmp_path / EXP).exists()


def test_config_command_lists_fields():
    res = CliRunner().invoke(app, ["config", EXP])
    assert res.exit_code == 0 and "iterations" in res.output


def test_nested_config_fields_are_set_by_dotted_names():
    exp = get_experiment("p000-urban")
    cfg = exp.config(False)
    new = exp.with_options(cfg, {"trace.max_order": "2", "provider": "sionna"})
    assert new.trace.max_order == 2 and new.provider == "sionna"
    assert cfg.trace.max_order != 2 or cfg.provider != "sionna"   # the original is untouched
    with pytest.raises(ConfigError, match="trace.FIELD"):
        exp.with_options(cfg, {"trace": "3"})
    with pytest.raises(ConfigError, match="max_ordr"):
        exp.with_options(cfg, {"trace.max_ordr": "3"})
    with pytest.raises(ConfigError, match="provider"):
        exp.with_options(cfg, {"provider": "nonsense"})       # the config's own validation


def test_an_optional_number_reads_none_and_positive_numbers_only():
    from radioloc.experiments.p001_highway import HighwayExperiment
    e = HighwayExperiment()
    for full in (False, True):
        c = e.config(full)
        assert e.with_options(c, {"variant_runs": "3"}).variant_runs == 3
        assert e.with_options(c, {"variant_runs": "none"}).variant_runs is None
        for bad in ("0", "-2", "x"):
            with pytest.raises(ConfigError, match="-o variant_runs"):
                e.with_options(c, {"variant_runs": bad})


@pytest.mark.parametrize("text, want", [("()", ()), (" ( ) ", ()),
                                        ("(cells_1m, avg10)", ("cells_1m", "avg10")),
                                        ("cells_1m", ("cells_1m",))])
def test_tuple_options_accept_parentheses_and_the_empty_tuple(text, want):
    exp = get_experiment("p003-tether")
    cfg = exp.with_options(exp.config(False), {"ablations": text})
    assert cfg.ablations == want


def test_an_empty_number_tuple_reads_as_empty_and_a_bare_comma_is_refused():
    exp, cfg = _config()
    new = exp.with_options(cfg, {"range_var_m2": "()"})
    assert new.range_var_m2 == ()
    with pytest.raises(ConfigError, match="range_var_m2"):
        exp.with_options(cfg, {"range_var_m2": ","})
