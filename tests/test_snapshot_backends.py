"""The snapshot baselines of paper 001 (LocalML, Ransac): the compiled candidate scores
against the array expressions that define them, through the public API, for every LOS
fraction regime of the mixture and both search readings; invariants of both backends."""

import numpy as np
import pytest

from radioloc.core.errors import ConfigError
from radioloc.estimators.snapshot_baselines import LocalML, Ransac
from radioloc.models.los_nlos import LosNlosRange

TOL = 1e-10


def _scene(rng, batch=(3, 7), nodes=13, los_only=False):
    truth = rng.uniform(0, 30, batch + (2,))
    cen = rng.uniform(0, 30, batch + (nodes, 2))
    d = np.linalg.norm(truth[..., None, :] - cen, axis=-1)
    r = d + rng.normal(0, 0.05, d.shape)
    if not los_only:
        r += (rng.random(d.shape) < 0.5) * rng.exponential(5, d.shape)
        r[rng.random(r.shape) < 0.3] = np.nan
    return truth, cen, r


def _close(a, b):
    np.testing.assert_allclose(a, b, rtol=TOL, atol=TOL * np.abs(b).max())


@pytest.mark.parametrize("alpha", [0.0, 1e-9, 0.3, 1.0])
@pytest.mark.parametrize("local", [False, True])
def test_local_ml_backends_agree(alpha, local):
    rng = np.random.default_rng(int(alpha * 1000) + local)
    truth, cen, r = _scene(rng)
    model = LosNlosRange(0.05, 5.0, alpha)
    kw = {"search_radius_m": 2.0} if local else {}
    centre = truth + rng.normal(0, 1, truth.shape) if local else None
    got, ref = (LocalML(model, 10.0, backend=b, **kw).locate(r, cen, centre)
                for b in ("numba", "numpy"))
    _close(got.position, ref.position)
    _close(got.diagnostics["log_likelihood"], ref.diagnostics["log_likelihood"])


def test_ransac_backends_agree():
    _, cen, r = _scene(np.random.default_rng(5), batch=(11,))
    got, ref = (Ransac(0.15, 10.0, backend=b).locate(r, cen) for b in ("numba", "numpy"))
    _close(got.position, ref.position)
    np.testing.assert_array_equal(got.diagnostics["inliers"], ref.diagnostics["inliers"])


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_single_snapshot_equals_its_row_of_the_batch_and_los_ranges_find_the_truth(backend):
    truth, cen, r = _scene(np.random.default_rng(6), batch=(4,), los_only=True)
    model = LosNlosRange(0.05, 5.0, 0.9)
    for est in (LocalML(model, 40.0, backend=backend), Ransac(0.2, 40.0, backend=backend)):
        batch = est.locate(r, cen).position
        np.testing.assert_allclose(est.locate(r[2], cen[2]).position, batch[2], rtol=1e-12)
        np.testing.assert_allclose(batch, truth, atol=0.1)


def test_bad_backend_name_raises():
    with pytest.raises(ConfigError, match="backend"):
        LocalML(LosNlosRange(), 10.0, backend="fortran")
    with pytest.raises(ConfigError, match="backend"):
        Ransac(0.15, 10.0, backend="fortran")
