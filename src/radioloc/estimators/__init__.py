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
- ``GridFilter`` (recursive): paper 003;
- ``MixtureLocalizer`` (snapshot), ``MixtureTracker`` (recursive): paper 004;
- ``LeastSquares`` (snapshot), ``BatchSmoother`` (whole trajectory): any measurement model,
  robust and max-mixture LOS/NLOS losses.

The cores they share are here too: :func:`kalman_predict` / :func:`kalman_update` /
:func:`rts_smooth` (the one Kalman filter and smoother), :func:`solve_nlls` (the one
nonlinear least-squares driver).
"""

from radioloc.estimators.base import RecursiveEstimator, SnapshotEstimator
from radioloc.estimators.batch_smoother import BatchSmoother
from radioloc.estimators.closed_form import ClosedFormTracker
from radioloc.estimators.ekf import NetworkEKF
from radioloc.estimators.ekf_tracker import RangeEKF
from radioloc.estimators.extended_kalman import ExtendedKalmanFilter
from radioloc.estimators.grid import GridFilter, GridGeometry
from radioloc.estimators.kalman import GaussianState, kalman_predict, kalman_update, rts_smooth
from radioloc.estimators.least_squares import LeastSquares
from radioloc.estimators.los_nlos_em import fit_los_nlos
from radioloc.estimators.mixture_localization import (
    MixtureLocalizer,
    MixtureTracker,
    posterior_mixture,
)
from radioloc.estimators.multilateration import Multilateration
from radioloc.estimators.nlls import NLLSResult, solve_nlls
from radioloc.estimators.nlls_newton import NewtonTracker
from radioloc.estimators.p2p_particle import OnlineEM, P2PParticleFilter
from radioloc.estimators.particle_filter import ParticleFilter
from radioloc.estimators.pf_smoother import backward_simulation
from radioloc.estimators.rls import NetworkRLS
from radioloc.estimators.snapshot_baselines import LocalML, Ransac

#: the estimators over any measurement model (``tags.generic``; ``Observation`` inputs)
GENERIC_ESTIMATORS = (ExtendedKalmanFilter, ParticleFilter, LeastSquares, BatchSmoother)

#: every estimator class of the toolkit (the contract tests run each: the paper
#: estimators on their own arrays, the generic ones on every model their tags accept)
ESTIMATORS = (Multilateration, NetworkRLS, NetworkEKF, RangeEKF, P2PParticleFilter, LocalML,
              Ransac, ClosedFormTracker, NewtonTracker, GridFilter, MixtureLocalizer,
              MixtureTracker) + GENERIC_ESTIMATORS

__all__ = [
    "Multilateration", "NetworkRLS", "NetworkEKF", "RangeEKF", "P2PParticleFilter", "LocalML",
    "Ransac", "ClosedFormTracker", "NewtonTracker", "GridFilter", "MixtureLocalizer",
    "MixtureTracker", "ParticleFilter", "LeastSquares", "BatchSmoother",
    "GridGeometry", "posterior_mixture", "fit_los_nlos", "OnlineEM", "backward_simulation",
    "SnapshotEstimator", "RecursiveEstimator", "ESTIMATORS", "GENERIC_ESTIMATORS",
    "ExtendedKalmanFilter",
    "GaussianState", "kalman_predict", "kalman_update", "rts_smooth", "NLLSResult", "solve_nlls",
]
