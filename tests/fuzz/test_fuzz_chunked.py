"""Fuzz of ``radioloc locate --chunk-rows``: a log read in chunks of a drawn size, against the
whole log at once (``--chunk-rows 0``), for the chunked methods on their scenarios' logs,
mutated (malformed cells, dropped, repeated or reordered rows) or as they are. Each case must
end as the whole run ends: the same error line, or the same rows (times and nodes exactly,
positions to 1e-9; the covariances too where neither run's health check inflated one: a
chunk's few rows are judged on their own). Profile: RADIOLOC_FUZZ_PROFILE."""

from __future__ import annotations

import json

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from fuzz_harness import FUZZ, TALLY, mutated_rows, read_output, render, run

#: (scenario, method, options)
CASES = [("gn", "gn", {}), ("gn3", "gn", {"on_degenerate": "skip"}), ("gn", "lsq", {}),
         ("ekf-track", "ekf-track", {"tune": "0"})]


def _outcome(args: list[str], out):
    res = run(args + ["--out", str(out)])
    if res.exit_code != 0:
        lines = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
        return "error", lines, None
    summary = json.loads(out.with_name(out.stem + ".summary.json").read_text())
    return "success", read_output(out.read_text()), summary


def _inflated(summary: dict) -> bool:
    return any(v > 1.0 for v in summary.get("health", {}).get("covariance_inflation", {}).values())


@FUZZ
@given(data=st.data(), case=st.sampled_from(CASES), mutate=st.booleans())
def test_fuzz_chunked_equals_whole(scenarios, workdir, data, case, mutate):
    name, method, options = case
    sc = scenarios[name]
    rows = data.draw(mutated_rows(sc.rows)) if mutate else sc.rows
    meas = workdir / "chunked-meas.csv"
    meas.write_text(render(rows, quoted=False))
    chunk = data.draw(st.integers(1, max(1, len(rows))))
    args = ["locate", str(meas), "--method", method, "-q"]
    for k, p in sc.files.items():
        args += [f"--{k}", str(p)]
    for k, v in {**sc.options, **options}.items():
        args += ["-o", f"{k}={v}"]
    whole = _outcome(args + ["--chunk-rows", "0"], workdir / "whole.csv")
    chunked = _outcome(args + ["--chunk-rows", str(chunk)], workdir / "chunked.csv")
    assert chunked[0] == whole[0], (chunked[:2], whole[:2])
    if whole[0] == "error":
        assert chunked[1] == whole[1]
        TALLY["chunked: error as whole"] += 1
        return
    a, b = whole[1], chunked[1]
    assert list(b.columns) == list(a.columns) and len(b) == len(a)
    assert (b["node"].to_numpy() == a["node"].to_numpy()).all()
    assert np.array_equal(b["time"].to_numpy(), a["time"].to_numpy())
    same = ["x", "y", "z"] if _inflated(whole[2]) or _inflated(chunked[2]) else [
        c for c in a.columns if c not in ("time", "node")]
    for c in same:
        if c in a.columns:
            np.testing.assert_allclose(b[c].to_numpy(float), a[c].to_numpy(float), rtol=1e-9,
                                       atol=1e-9, err_msg=c)
    TALLY["chunked: success as whole"] += 1
