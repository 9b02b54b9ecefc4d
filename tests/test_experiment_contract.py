"""Every registered experiment honours the runner's contract.

``run_block`` is a pure function of (config, run indices, generator): the same block with
the same seed gives the same frame (no hidden global state, so results cannot depend on
which process or worker ran the block), and the frame has a ``run`` column holding exactly
the block's run indices. Columns the experiment declares as timings (CPU seconds) are
measurements of the machine and are left out of the comparison. Every figure ``summarize``
writes has a caption in ``captions.json`` that says more than the file name.
"""

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import DataUnavailable
from radioloc.core.rng import block_generator
from radioloc.experiments.base import registry
from radioloc.report.captions import is_file_name, read_captions

EXPERIMENTS = sorted(registry())


def _forbid(*args, **kwargs):
    raise _Forbidden("summarize() may only read the results table: it simulated or estimated")


class _Forbidden(AssertionError):
    pass


@pytest.mark.parametrize("exp_id", EXPERIMENTS)
def test_run_block_is_deterministic_and_summarize_only_reads_the_table(exp_id, tmp_path,
                                                                         monkeypatch):
    """The same block with the same seed gives the same tidy frame; then ``summarize()`` on
    that frame runs with every simulation, random draw and estimator entry point replaced
    by a function that fails: every metric and claim comes from the rows the blocks wrote.
    Every claim reads holds / does not hold / undecided at this size, and a decided claim
    with an interval has finite ends (a claim is never decided on a missing interval).
    (One test, so that the table is computed twice rather than three times.)"""
    import sys
    import warnings

    import radioloc.core.rng as rng_mod
    from radioloc.estimators import ESTIMATORS

    exp = registry()[exp_id]
    try:
        exp.check_available()
    except DataUnavailable as exc:
        pytest.skip(str(exc))
    cfg = exp.config(False)
    assert isinstance(cfg.runs, int) and cfg.runs >= 1
    assert isinstance(cfg.block_size, int) and cfg.block_size >= 1
    n = min(2, cfg.runs, cfg.block_size)
    cfg = dataclasses.replace(cfg, runs=n)
    runs = np.arange(n)
    a = exp.run_block(cfg, runs, block_generator(3, 0))
    b = exp.run_block(cfg, runs, block_generator(3, 0))
    assert isinstance(a, pd.DataFrame) and len(a) > 0
    assert "run" in a.columns
    assert set(a["run"].unique()) == set(runs.tolist())
    timing = list(exp.timing_columns)
    pd.testing.assert_frame_equal(a.drop(columns=timing), b.drop(columns=timing))

    originals = {id(np.random.default_rng), id(rng_mod.stream), id(rng_mod.block_generator)}
    for mod in [m for name, m in list(sys.modules.items())
                if name.startswith("radioloc") and m is not None] + [np.random, rng_mod]:
        for attr, value in list(vars(mod).items()):
            if id(value) in originals:
                monkeypatch.setattr(mod, attr, _forbid)
    for cls in ESTIMATORS:
        for name in ("run", "locate", "step", "init"):
            if name in vars(cls):
                monkeypatch.setattr(cls, name, _forbid)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # tiny tables: empty means are expected
        summary = exp.summarize(cfg, a, tmp_path)
    assert summary.metrics
    for c in summary.claims:          # three verdicts; an interval only with its verdict's evidence
        d = json.loads(json.dumps(c.as_dict()))
        assert d["verdict"] in ("holds", "does not hold", "undecided at this size"), c.claim
        assert (d["holds"] is None) == (d["verdict"] == "undecided at this size"), c.claim
        if d["holds"] is not None and c.ci is not None:
            assert d["ci_low"] is not None and d["ci_low"] <= d["ci_high"], c.claim
    for m in summary.metrics:
        d = json.loads(json.dumps(m.as_dict()))
        if d["ci_low"] is not None:
            assert d["ci_low"] <= d["ci_high"], m.name
    figures = sorted(tmp_path.glob("*.png"))          # every figure has a caption saying more
    captions = read_captions(tmp_path)                # than its file name
    assert figures, "summarize() wrote no figure"
    for f in figures:
        assert f.stem in captions, f"{f.name}: no caption in captions.json"
        assert not is_file_name(captions[f.stem], f.stem), f"{f.name}: {captions[f.stem]!r}"
