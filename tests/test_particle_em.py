import os
from pathlib import Path

import numpy as np
import pytest

from radioloc.core.errors import InputError
from radioloc.estimators.los_nlos_em import fit_los_nlos
from radioloc.models.los_nlos import LosNlosRange

DATA = Path(os.environ.get("RADIOLOC_DATA", "/work/shared/data")) / "hanyang-uwb-outdoor"


@pytest.mark.parametrize("alpha,bias", [(0.3, 0.0), (0.6, 0.2)])
def test_em_recovers_known_parameters(alpha, bias):
    rng = np.random.default_rng(7)
    n = 4000
    truth = LosNlosRange(0.1, 3.0, alpha)
    e = truth.sample(np.zeros(n), rng.random(n) < alpha, rng) + bias
    fit = fit_los_nlos(e)
    assert fit.model.alpha == pytest.approx(alpha, abs=0.04)
    assert fit.model.los_std_m == pytest.approx(0.1, rel=0.1)
    assert fit.model.nlos_mean_m == pytest.approx(3.0, rel=0.1)
    assert fit.bias_m == pytest.approx(bias, abs=0.02)
    # generalised EM: the log-likelihood never decreases
    assert np.all(np.diff(fit.loglik) > -1e-9)


def test_em_bad_input():
    with pytest.raises(InputError, match="errors"):
        fit_los_nlos(np.ones(3))
    with pytest.raises(InputError, match="errors"):
        fit_los_nlos(np.array([np.nan] * 20))


@pytest.mark.skipif(not DATA.is_dir(), reason="hanyang-uwb-outdoor data set absent")
def test_hanyang_loader():
    from radioloc.io.hanyang import dynamic_runs, load_dynamic, load_static
    s = load_static(DATA)
    assert set(s.condition) == {"LOS", "NLOS"} and np.all(np.isfinite(s.error_m))
    assert s.error_m.abs().median() < 1.0
    run = load_dynamic(dynamic_runs(DATA)[0])
    assert len(run.anchors) == 4 and {"ls", "eskf"} <= set(run.estimates)
    assert run.ranges.range_m.between(0, 100).all()


def test_hanyang_missing_folder_raises(tmp_path):
    from radioloc.core.errors import DataUnavailable
    from radioloc.io.hanyang import dynamic_runs, load_static
    with pytest.raises(DataUnavailable):
        load_static(tmp_path)
    with pytest.raises(DataUnavailable):
        dynamic_runs(tmp_path)
