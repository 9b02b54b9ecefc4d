"""Estimators: one contract for every algorithm (see ``docs/architecture.md``).

Snapshot estimators locate from one epoch: ``Estimator(settings).locate(...) -> Estimate``.
Recursive estimators filter a series: ``init``, ``step``, ``estimate`` and
``run(...) -> Track``. Models (motion, measurement) are constructor arguments.

- ``Multilateration`` (snapshot): ranges to anchors, the toolkit baseline;
- ``NetworkRLS``, ``NetworkEKF`` (recursive): paper 000, distributed RLS and sequential EKF;
- ``ExtendedKalmanFilter`` (recursive, generic): any motion model and any measurement model
  (``Observation`` inputs), optionally iterated, with the RTS smoother;
- ``RangeEKF`` (recursive): a configuration of it on ranges (papers 001 and 002 baselines);
- ``P2PParticleFilter`` (recursive), ``LocalML``, ``Ransac`` (snapshot): paper 001;
- ``ParticleFilter`` (recursive): any motion model and any measurement models
  (``Observation`` inputs), with the discrete row states of paper 001 summed out exactly;
- ``ClosedFormTracker``, ``NewtonTracker`` (snapshot): paper 002;
- ``GridFilter`` (recursive): paper 003, and any model with a log-likelihood on 2-D
  positions (``Observation`` inputs);
- ``MixtureLocalizer`` (snapshot), ``MixtureTracker`` (recursive): paper 004;
- ``LeastSquares`` (snapshot), ``BatchSmoother`` (whole trajectory): any measurement model,
  robust and max-mixture LOS/NLOS losses.

The cores they share are here too: :func:`kalman_predict` / :func:`kalman_update` /
:func:`rts_smooth` (the one Kalman filter and smoother), :func:`solve_nlls` (the one
nonlinear least-squares driver).
"""

from radioloc.core.lazy import lazy_exports

#: public name -> the submodule defining it (imported on first access)
_WHERE = {
    "RecursiveEstimator": "base",
    "SnapshotEstimator": "base",
    "BatchSmoother": "batch_smoother",
    "ClosedFormTracker": "closed_form",
    "NetworkEKF": "ekf",
    "RangeEKF": "ekf_tracker",
    "ExtendedKalmanFilter": "extended_kalman",
    "GridFilter": "grid",
    "GridGeometry": "grid",
    "GaussianState": "kalman",
    "kalman_predict": "kalman",
    "kalman_update": "kalman",
    "rts_smooth": "kalman",
    "LeastSquares": "least_squares",
    "fit_los_nlos": "los_nlos_em",
    "MixtureLocalizer": "mixture_localization",
    "MixtureTracker": "mixture_localization",
    "posterior_mixture": "mixture_localization",
    "Multilateration": "multilateration",
    "NLLSResult": "nlls",
    "solve_nlls": "nlls",
    "NewtonTracker": "nlls_newton",
    "OnlineEM": "p2p_particle",
    "P2PParticleFilter": "p2p_particle",
    "ParticleFilter": "particle_filter",
    "backward_simulation": "pf_smoother",
    "NetworkRLS": "rls",
    "LocalML": "snapshot_baselines",
    "Ransac": "snapshot_baselines",
}
_getattr, _dir = lazy_exports(__name__, _WHERE)

#: the estimators over any measurement model (``tags.generic``; ``Observation`` inputs)
_GENERIC = ("ExtendedKalmanFilter", "ParticleFilter", "LeastSquares", "BatchSmoother")

#: every estimator class of the toolkit (the contract tests run each: the paper
#: estimators on their own arrays, the generic ones on every model their tags accept)
_ALL = ("Multilateration", "NetworkRLS", "NetworkEKF", "RangeEKF", "P2PParticleFilter",
        "LocalML", "Ransac", "ClosedFormTracker", "NewtonTracker", "GridFilter",
        "MixtureLocalizer", "MixtureTracker") + _GENERIC


def __getattr__(name: str) -> object:
    """``GENERIC_ESTIMATORS`` and ``ESTIMATORS`` (tuples of classes), or a lazy export."""
    if name == "GENERIC_ESTIMATORS":
        return tuple(c for c in (_getattr(n) for n in _ALL) if c.tags.generic)
    if name == "ESTIMATORS":
        return tuple(_getattr(n) for n in _ALL)
    return _getattr(name)


def __dir__() -> list[str]:
    return sorted(set(_dir()) | {"ESTIMATORS", "GENERIC_ESTIMATORS"})


__all__ = [
    "Multilateration", "NetworkRLS", "NetworkEKF", "RangeEKF", "P2PParticleFilter", "LocalML",
    "Ransac", "ClosedFormTracker", "NewtonTracker", "GridFilter", "MixtureLocalizer",
    "MixtureTracker", "ParticleFilter", "LeastSquares", "BatchSmoother",
    "GridGeometry", "posterior_mixture", "fit_los_nlos", "OnlineEM", "backward_simulation",
    "SnapshotEstimator", "RecursiveEstimator", "ESTIMATORS", "GENERIC_ESTIMATORS",
    "ExtendedKalmanFilter",
    "GaussianState", "kalman_predict", "kalman_update", "rts_smooth", "NLLSResult", "solve_nlls",
]
