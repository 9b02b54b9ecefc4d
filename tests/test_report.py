"""The HTML report: scoreboard, gap colours, captions, folded tables; no backend switch."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from radioloc.report.html import (claims_score, figure_caption, gap_class, headline_metrics,
                                  render, scoreboard, write_index)


def fake_record(eid: str, paper: str = "001", holds=(True, False), skipped: str | None = None,
                n_metrics: int = 6) -> dict:
    metrics = [{"name": f"metric_{k}", "value": 1.0 + 0.2 * k, "paper": 1.0 if k % 2 == 0 else None,
                "unit": "m", "note": f"note {k} " + "word " * 30} for k in range(n_metrics)]
    return {"experiment": eid, "paper": paper, "seed": 0, "runs": 10, "full": False,
            "elapsed_s": 1.5, "metrics": [] if skipped else metrics,
            "claims": [] if skipped else [{"claim": f"claim {i}", "holds": h}
                                          for i, h in enumerate(holds)],
            "notes": ["a note"], "skipped": skipped, "config": None}


def write_fake_report(out: Path) -> Path:
    """A small report: three experiments (one skipped) with figures of several sizes; beta's
    figure is written without a caption (a folder from before captions were recorded)."""
    from radioloc.report.style import figure, save

    records = [fake_record("alpha", "000", (True, True, True)),
               fake_record("beta", "001", (True, False)),
               fake_record("gamma", "004", skipped="data set 'x' not found (looked in: /a, /b)")]
    for r in records:
        (out / r["experiment"]).mkdir(parents=True, exist_ok=True)
        (out / r["experiment"] / "summary.json").write_text(json.dumps(r))
    for name, width in (("fig3_map", 6.4), ("fig4a_error_cdf", 11.0), ("extra_view", 14.0)):
        fig, ax = figure(width=width, height=3.5)
        ax.plot([0, 1, 2], [0, 1, 0.5], label="ours")
        ax.legend()
        save(fig, out / "alpha" / f"{name}.png", caption=f"What {name} shows, in words.")
    fig, ax = figure()
    ax.plot([0, 1], [1, 0])
    fig.savefig(out / "beta" / "fig1_rmse.png")
    return write_index(out, {"alpha": "First experiment.", "beta": "Second."})


def test_gap_classes():
    assert gap_class(1.05, 1.0) == "good"
    assert gap_class(0.8, 1.0) == "fair"
    assert gap_class(2.0, 1.0) == "poor"
    assert gap_class(1.0, None) == "" and gap_class(None, 1.0) == "" and gap_class(1.0, 0.0) == ""


def test_claims_score_and_headlines():
    r = fake_record("a", holds=(True, False, True))
    assert claims_score(r) == (2, 3)
    assert [m["name"] for m in headline_metrics(r)] == ["metric_0", "metric_2", "metric_4"]


def test_scoreboard_shows_a_gap_only_within_a_factor_and_a_headline_on_every_row():
    far = fake_record("far", n_metrics=0)
    far["metrics"] = [{"name": "err_m", "value": 451562.0, "paper": 20.0, "unit": "m",
                       "note": "", "ci_low": 1.0e5, "ci_high": 8.0e5}]
    none = fake_record("none", n_metrics=0)
    none["metrics"] = [{"name": "count", "value": 7.0, "paper": None, "unit": "", "note": ""},
                       {"name": "other", "value": 1.0, "paper": None, "unit": "", "note": ""}]
    near = fake_record("near", n_metrics=0)
    near["metrics"] = [{"name": "rmse_m", "value": 1.2, "paper": 1.0, "unit": "m", "note": ""}]
    board = scoreboard([far, none, near])
    assert "%" not in board.split("far")[-1].split("</tr>")[0]      # no +2257710%
    assert "4.52e+05" in board and "paper 20" in board and "[1e+05, 8e+05]" in board
    assert [m["name"] for m in headline_metrics(none)] == ["count"]  # a number on every row
    assert "no number with a published value" not in board
    assert "+20%" in board
    assert gap_class(451562.0, 20.0) == "poor" and gap_class(-1.0, 1.0) == "poor"


def test_a_departure_the_paper_predicts_is_marked_apart_from_our_gap(tmp_path):
    from radioloc.report.tables import PREDICTED

    r = fake_record("pred", n_metrics=0)
    r["metrics"] = [{"name": "plain", "value": 1.0, "paper": None, "unit": "", "note": ""},
                    {"name": "newton_diverged", "value": 0.3, "paper": 0.0, "unit": "",
                     "note": "", "predicted": "Sect. I: Newton's method may diverge"},
                    {"name": "rmse_m", "value": 3.0, "paper": 1.0, "unit": "m", "note": ""}]
    board = scoreboard([r])
    row = board.split("</thead>")[1]
    assert PREDICTED in row and 'class="expected"' in row and "+200%" in row
    assert [m["name"] for m in headline_metrics(r)] == ["newton_diverged", "rmse_m"]
    page = render([r], tmp_path)
    assert page.count(PREDICTED) >= 3            # legend, scoreboard row, metric table


def test_captions_name_the_paper_figure():
    assert figure_caption("fig4a_error_cdf", "001") == "Error cdf. Reproduces Fig. 4(a) of paper 001."
    assert figure_caption("fig3_map", "000") == "Map. Reproduces Fig. 3 of paper 000."
    assert figure_caption("track", "004") == "Track."


def test_scoreboard_rows_link_to_sections():
    html = scoreboard([fake_record("alpha", holds=(True, True)), fake_record("beta", holds=(False,)),
                       fake_record("gamma", skipped="absent")])
    assert html.count("<tr>") == 4
    for eid in ("alpha", "beta", "gamma"):
        assert f'href="#{eid}"' in html
    assert 'pill good">2 of 2' in html and 'pill poor">0 of 1' in html and "skipped" in html


def test_page_leads_with_the_scoreboard_and_folds_tables(tmp_path):
    index = write_fake_report(tmp_path)
    page = index.read_text()
    assert page.index('class="scoreboard"') < page.index('<section id="alpha">')
    assert page.count("<details>") >= 2 and "All 6 metrics" in page
    assert "What fig4a_error_cdf shows, in words." in page
    assert "Rmse. Reproduces Fig. 1 of paper 001." in page        # no captions.json
    # figures in paper order, then the others
    assert page.index("fig3_map.png") < page.index("fig4a_error_cdf.png") < page.index("extra_view.png")
    assert "4 of 5 claims" in page and "2 of 3 experiments ran" in page


def test_render_escapes_text(tmp_path):
    r = fake_record("alpha")
    r["claims"][0]["claim"] = "<script>x</script>"
    assert "<script>x" not in render([r], tmp_path)


def test_import_does_not_switch_the_backend():
    code = ("import matplotlib, sys; matplotlib.use('svg'); "
            "import radioloc.report.style, radioloc.report.html, radioloc.cli; "
            "from radioloc.report.style import figure; figure(); "
            "assert matplotlib.get_backend().lower() == 'svg', matplotlib.get_backend(); "
            "assert 'matplotlib.pyplot' not in sys.modules")
    src = str(Path(__file__).resolve().parents[1] / "src")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PYTHONPATH": src, "PATH": "/usr/bin:/bin", "MPLBACKEND": "",
                              "HOME": "/nonexistent"})
    assert res.returncode == 0, res.stderr


def test_claims_show_verdict_and_interval_and_metrics_their_interval(tmp_path):
    """An undecided claim reads 'undecided at this size' with its interval, counts as not
    holding in the score, and a metric's interval shows in the table."""
    from radioloc.report.tables import claim_evidence, interval, verdict

    r = fake_record("delta", holds=(True,))
    r["claims"] = [{"claim": "A beats B", "holds": None, "verdict": "undecided at this size",
                    "estimate": 0.2, "ci_low": -0.1, "ci_high": 0.5, "level": 0.95, "n": 16,
                    "unit": "m", "what": "mean paired difference"},
                   {"claim": "C beats D", "holds": True}]
    r["metrics"][0].update(ci_low=0.9, ci_high=1.1)
    assert claims_score(r) == (1, 2)
    assert verdict(r["claims"][1]) == "holds" and claim_evidence(r["claims"][1]) == ""
    assert claim_evidence(r["claims"][0]) == ("mean paired difference 0.2 m, 95% CI [-0.1, 0.5], "
                                              "n = 16")
    assert interval(0.9, 1.1) == "[0.9, 1.1]" and interval(None, 1.0) == ""
    page = render([r], tmp_path)
    assert "undecided at this size" in page and "95% CI [-0.1, 0.5]" in page
    assert "<td class=\"num\">[0.9, 1.1]</td>" in page and "95% CI</th>" in page


def test_save_records_the_caption_and_refuses_a_file_name(tmp_path):
    """The caption goes to captions.json beside the PNG (and into the report); an empty
    caption or one that repeats the file name is refused before any file is written."""
    from radioloc.core.errors import ConfigError
    from radioloc.report.captions import is_file_name, read_captions
    from radioloc.report.style import figure, save

    for bad, name in (("", "a.png"), ("  ", "a.png"), ("Error CDF.", "error_cdf.png"),
                      ("error-cdf", "fig4a_error_cdf.png"), ("Fig4a error cdf", "fig4a_error_cdf.png")):
        fig, ax = figure()
        with pytest.raises(ConfigError, match=name.replace(".", "[.]")):
            save(fig, tmp_path / name, caption=bad)
        assert not (tmp_path / name).exists()
    assert not (tmp_path / "captions.json").exists()
    assert not is_file_name("CDF of the position error of two methods.", "error_cdf")
    fig, ax = figure()
    save(fig, tmp_path / "one.png", caption="First  figure,\n one line.")
    save(fig, tmp_path / "two.png", caption="Second figure.")
    save(fig, tmp_path / "one.png", caption="First figure, again.")
    assert read_captions(tmp_path) == {"one": "First figure, again.", "two": "Second figure."}
    (tmp_path / "captions.json").write_text("not json")
    assert read_captions(tmp_path) == {}


def test_a_legend_outside_the_axes_is_kept_in_the_png(tmp_path):
    """A legend placed right of the axes widens the PNG instead of being cut at the
    figure's edge; with a constrained layout the figure legend fits inside."""
    from matplotlib.image import imread

    from radioloc.report.style import figure, save

    widths = {}
    for name, outside in (("inside", False), ("outside", True)):
        fig, ax = figure(width=4.0, height=3.0)
        ax.plot([0, 1], [0, 1], label="a long label of the curve that would be clipped")
        if outside:
            ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0))
        widths[name] = imread(save(fig, tmp_path / f"{name}.png", caption=f"Legend {name}.")).shape[1]
    assert widths["outside"] > widths["inside"] + 100
    fig, ax = figure(width=4.0, height=3.0, layout="constrained")
    ax.plot([0, 1], [0, 1], label="a label")
    legend = fig.legend(loc="outside right upper")
    save(fig, tmp_path / "constrained.png", caption="Figure legend outside the axes.")
    box = legend.get_window_extent()
    assert box.x1 <= fig.bbox.x1 + 1 and box.x0 >= fig.bbox.x0 - 1
    assert not ax.get_window_extent().overlaps(box)
