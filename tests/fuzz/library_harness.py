"""Cases, mutations and the outcome classifier of the LIBRARY fuzz (estimators and models).

Every estimator of :data:`radioloc.estimators.ESTIMATORS` has a small valid problem
(:data:`CASES`): constructor settings, call arguments, and a description of each field (may
it hold NaN (a missing measurement), negative values, zeros). A generated case mutates one
field of one problem (:func:`mutate`: a NaN, an infinity, a huge or tiny magnitude, a
negative or zero entry, a shape that does not broadcast, an empty array, text instead of
numbers, an enormous size) or replaces the geometry (collinear, coplanar, duplicate or
coincident anchors with exact ranges), calls the library and is classified
(:func:`classify_call`) as

- ``error``: a toolkit error (``RadiolocError``) on one line that names the mutated field;
- ``success``: a result whose positions and covariances are finite, without a
  RuntimeWarning, and within tolerance of the truth where the case has an exact answer;
- a failure otherwise: ``traceback`` (any other exception), ``memory`` (MemoryError),
  ``hang`` (no answer within :data:`TIME_LIMIT_S`), ``runtime warning``, ``non-finite
  output``, ``accepted invalid input`` (success on an input the contract refuses: an
  infinity, a NaN where no measurement can be missing, a negative variance, a shape that
  does not broadcast, ...), ``wrong answer`` (far from a known answer), ``error naming the
  wrong field``, ``multi-line error``.
"""

from __future__ import annotations

import contextlib
import math
import os
import resource
import signal
import traceback
import warnings
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from hypothesis import strategies as st

from radioloc.core.errors import GeometryError, RadiolocError
from radioloc.core.results import Estimate, Track
from radioloc.estimators import (
    ESTIMATORS,
    GENERIC_ESTIMATORS,
    BatchSmoother,
    ClosedFormTracker,
    ExtendedKalmanFilter,
    GridFilter,
    GridGeometry,
    LeastSquares,
    LocalML,
    MixtureLocalizer,
    MixtureTracker,
    Multilateration,
    NetworkEKF,
    NetworkRLS,
    NewtonTracker,
    P2PParticleFilter,
    ParticleFilter,
    RangeEKF,
    Ransac,
)
from radioloc.models import (
    BearingModel,
    ConstantAcceleration,
    ConstantVelocity,
    DiagMixture,
    GaussianRange,
    InputDriven,
    LogDistanceGaussian,
    LosNlosRange,
    RandomWalk,
    RangeModel,
    StickyLinkChain,
    TrapezoidModel,
    UniformDisk,
    WhiteAccelerationCV,
)
from radioloc.estimators.anchor_calibration import calibrate_anchors
from radioloc.models.measurement import Context, Observation
from radioloc.models.tdoa import TdoaModel

TALLY: Counter = Counter()
#: seconds a library call may take before it counts as a hang
TIME_LIMIT_S = 120.0
#: address-space limit while a case runs: an allocation the library should have refused
#: ends in MemoryError (a failure) instead of swapping the machine
ADDRESS_LIMIT_BYTES = 8 * 2**30

B = 2
ANCHORS = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 20.0], [30.0, 20.0]])


@dataclass(frozen=True)
class Field:
    """How the contract treats a field: may it hold NaN (a missing measurement), negative
    values, zeros; ``setting`` for a constructor scalar; ``names``: the words an error
    about it may use (default: its own name)."""

    nan_ok: bool = False
    neg_ok: bool = True
    zero_ok: bool = True
    setting: bool = False
    integer: bool = False
    names: tuple[str, ...] = ()
    shape_free: bool = False       # no shape to break (a scalar argument)
    none_ok: bool = False          # None is a valid setting (its default)
    extra_ok: bool = False         # one more coordinate (3-D) is a valid input
    drop_ok: bool = False          # without its first batch row it still broadcasts (valid)


@dataclass
class Case:
    """A valid problem: ``settings`` (constructor), ``args`` (call), ``fields`` (the
    mutable ones), ``solve(settings, args)`` runs it; ``truth`` (optional) the exact answer
    of the unmutated problem, compared at ``tol_m``."""

    name: str
    settings: dict[str, Any]
    args: dict[str, Any]
    fields: dict[str, Field]
    solve: Callable[[dict, dict], Any]
    truth: np.ndarray | None = None
    tol_m: float = 1e-3


# ---- the valid problems ----------------------------------------------------------------

def _rng(seed):
    return np.random.default_rng(seed)


def case_multilateration() -> Case:
    truth = np.array([[7.0, 12.0], [21.0, 4.0]])
    r = np.linalg.norm(truth[:, None] - ANCHORS, axis=-1)
    return Case("Multilateration", {"std_m": 0.01},
                {"ranges": r, "anchors": ANCHORS.copy(), "weights": np.ones(r.shape),
                 "initial": truth + 1.5},
                {"std_m": Field(setting=True, neg_ok=False, zero_ok=False, none_ok=True),
                 "max_iter": Field(setting=True, integer=True, neg_ok=False, zero_ok=False),
                 "ranges": Field(nan_ok=True, neg_ok=False), "anchors": Field(extra_ok=True),
                 "weights": Field(neg_ok=False), "initial": Field(drop_ok=True)},
                lambda s, a: Multilateration(**s).locate(**a), truth)


def _network(seed=1, K=4, N=3):
    rng = _rng(seed)
    truth = rng.uniform(0, 30, (B, K, 2))
    d = np.linalg.norm(truth[:, :, None] - truth[:, None], axis=-1)
    ranges = np.broadcast_to(d[:, None], (B, N, K, K)).copy()
    ranges[..., np.arange(K), np.arange(K)] = np.nan      # a node's range to itself: unused
    prior = truth + rng.normal(0, 1.0, truth.shape)
    return ranges, prior


def case_network_rls() -> Case:
    ranges, prior = _network()
    return Case("NetworkRLS", {"forgetting": 0.7},
                {"ranges": ranges, "prior_mean": prior, "prior_var": np.full(prior.shape, 1.0)},
                {"forgetting": Field(setting=True, neg_ok=False, zero_ok=False),
                 "std_m": Field(setting=True, neg_ok=False, zero_ok=False, none_ok=True),
                 # no range noise given: every negative range is refused (check_ranges)
                 "ranges": Field(nan_ok=True, neg_ok=False), "prior_mean": Field(),
                 "prior_var": Field(neg_ok=False)},
                lambda s, a: NetworkRLS(**s).run(**a))


def case_network_ekf() -> Case:
    ranges, prior = _network(2)
    return Case("NetworkEKF", {"std_m": 0.1},
                {"ranges": ranges, "prior_mean": prior, "prior_var": np.full(prior.shape, 1.0)},
                {"std_m": Field(setting=True, neg_ok=False, zero_ok=False),
                 # a range below -6 noise sigmas (0.6 m here) is refused (check_ranges)
                 "ranges": Field(nan_ok=True, neg_ok=False), "prior_mean": Field(),
                 "prior_var": Field(neg_ok=False)},
                lambda s, a: NetworkEKF(**s).run(**a))


def _walk(seed=3, T=12, dt=0.5):
    rng = _rng(seed)
    t = np.arange(T) * dt
    start = np.c_[rng.uniform(4, 26, B), rng.uniform(3, 9, B)]
    truth = start[:, None, :] + np.stack([0.6 * t, 0.2 * t], -1)
    r = np.linalg.norm(truth[..., None, :] - ANCHORS, axis=-1)
    return t, truth, r, start


def case_range_ekf() -> Case:
    t, truth, r, start = _walk()
    settings = {"motion": ConstantVelocity(0.05), "measurement": GaussianRange(0.05),
                "anchors": ANCHORS.copy()}
    return Case("RangeEKF", settings,
                {"ranges": r, "time": t, "prior_mean": np.c_[start, np.zeros((B, 2))],
                 "prior_cov": np.eye(4)},
                {"anchors": Field(setting=True), "range_bias_m": Field(setting=True),
                 "gate": Field(setting=True, neg_ok=False, zero_ok=False, none_ok=True),
                 # slightly negative (within 6 sigmas): taken; the mutation's -r-1: refused
                 "ranges": Field(nan_ok=True, neg_ok=False), "time": Field(),
                 "prior_mean": Field(), "prior_cov": Field(neg_ok=False)},
                lambda s, a: RangeEKF(**s).run(a["ranges"], a["time"], prior_mean=a["prior_mean"],
                                               prior_cov=a["prior_cov"]))


def case_particle_filter() -> Case:
    t, truth, r, start = _walk(seed=4, T=8)
    ranges = np.concatenate([np.full((B, 1, 8, 1), np.nan), r[:, None]], axis=-1)
    steps = np.diff(np.concatenate([start[:, None], truth], axis=1), axis=1)[:, None]
    settings = {"motion": InputDriven(0.02), "measurement": LosNlosRange(0.05, 5.0, 0.95),
                "particles": 64, "init_std": 0.3, "reset_std_m": 0.1}
    return Case("P2PParticleFilter", settings,
                {"ranges": ranges, "initial": start[:, None], "anchors": ANCHORS.copy(),
                 "controls": steps},
                {"particles": Field(setting=True, integer=True, neg_ok=False, zero_ok=False),
                 "init_std": Field(setting=True, neg_ok=False),
                 "reset_std_m": Field(setting=True, neg_ok=False, zero_ok=False),
                 # LOS ranges are Gaussian: below -6 LOS sigmas a range is refused
                 "ranges": Field(nan_ok=True, neg_ok=False), "initial": Field(),
                 "anchors": Field(), "controls": Field()},
                lambda s, a: P2PParticleFilter(**s).run(
                    a["ranges"], a["initial"], np.random.default_rng(5), anchors=a["anchors"],
                    controls=a["controls"]))


def _links(seed):
    rng = _rng(seed)
    truth = np.c_[rng.uniform(4, 26, B), rng.uniform(3, 9, B)]
    centres = np.broadcast_to(np.r_[ANCHORS, [[15.0, -5.0]]], (B, 5, 2)).copy()
    r = np.linalg.norm(truth[:, None] - centres, axis=-1)
    return truth, centres, r


def case_local_ml() -> Case:
    truth, centres, r = _links(6)
    return Case("LocalML", {"measurement": LosNlosRange(0.02, 5.0, 0.9), "radius_m": 40.0},
                {"ranges": r, "centres": centres},
                {"radius_m": Field(setting=True, neg_ok=False, zero_ok=False, none_ok=True),
                 "coarse_points": Field(setting=True, integer=True, neg_ok=False, zero_ok=False,
                                        none_ok=True),
                 "ranges": Field(nan_ok=True, neg_ok=False), "centres": Field()},
                lambda s, a: LocalML(**s).locate(**a), truth, 0.1)


def case_ransac() -> Case:
    truth, centres, r = _links(7)
    return Case("Ransac", {"threshold_m": 0.5, "radius_m": 40.0},
                {"ranges": r, "centres": centres},
                {"threshold_m": Field(setting=True, neg_ok=False, zero_ok=False),
                 "radius_m": Field(setting=True, neg_ok=False, zero_ok=False),
                 "max_iter": Field(setting=True, integer=True, neg_ok=False),
                 # the inlier threshold is Ransac's noise scale: below -6 of it, refused
                 "ranges": Field(nan_ok=True, neg_ok=False), "centres": Field()},
                lambda s, a: Ransac(**s).locate(**a), truth, 0.01)


def _single_sensor(seed, n=10, T=0.5):
    rng = _rng(seed)
    k = np.arange(n)
    sensor = np.c_[20 * np.cos(1.3 * k), 20 * np.sin(1.3 * k)]
    start = np.c_[rng.uniform(4, 26, B), rng.uniform(3, 9, B)]
    vel = np.array([0.8, 0.3])
    track = start[:, None] + (k * T)[:, None] * vel
    r = np.linalg.norm(track - sensor, axis=-1)
    return sensor, track[:, -1], r, T, np.c_[track[:, -1], np.broadcast_to(vel, (B, 2))]


def case_closed_form() -> Case:
    sensor, truth, r, T, _ = _single_sensor(8)
    return Case("ClosedFormTracker", {"accel_var": 1e-6, "std_m": 0.01},
                {"ranges": r, "sensor_path": sensor, "sample_period_s": T},
                {"accel_var": Field(setting=True, neg_ok=False),
                 # None is the default: no noise (or give measurement=)
                 "std_m": Field(setting=True, neg_ok=False, none_ok=True),
                 "max_iter": Field(setting=True, integer=True, neg_ok=False),
                 "ranges": Field(nan_ok=True, neg_ok=False), "sensor_path": Field(extra_ok=True),
                 "sample_period_s": Field(neg_ok=False, zero_ok=False, shape_free=True)},
                lambda s, a: ClosedFormTracker(**s).locate(**a), truth, 0.05)


def case_newton() -> Case:
    sensor, truth, r, T, state = _single_sensor(9)
    return Case("NewtonTracker", {},
                {"ranges": r, "sensor_path": sensor, "sample_period_s": T,
                 "initial_state": state + 0.3},
                {"max_iter": Field(setting=True, integer=True, neg_ok=False),
                 "ranges": Field(nan_ok=True, neg_ok=False), "sensor_path": Field(),
                 "sample_period_s": Field(neg_ok=False, zero_ok=False, shape_free=True),
                 "initial_state": Field()},
                lambda s, a: NewtonTracker(**s).locate(
                    a["ranges"], a["sensor_path"], a["sample_period_s"],
                    initial_state=a["initial_state"]), truth, 0.05)


LOGD = LogDistanceGaussian(a=60.0, n=2.0, s=2.0, d_ref_m=0.1)


def case_grid() -> Case:
    rng = _rng(10)
    truth = np.array([[20.0, 4.0], [8.0, 9.0]])
    xy = rng.uniform([6, 0], [24, 12], (B, 10, 2))
    rssi = LOGD.mean(np.linalg.norm(xy - truth[:, None], axis=-1))
    return Case("GridFilter", {"geometry": GridGeometry.centred(30, 16, 1.0, centre=(15.0, 6.0)),
                               "model": LOGD, "epsilon": 1e-12},
                {"tracker_xy": xy, "rssi": rssi},
                {"epsilon": Field(setting=True, neg_ok=False, none_ok=True),   # None: its default
                 "blur_m": Field(setting=True, neg_ok=False),
                 "tracker_xy": Field(nan_ok=True), "rssi": Field(nan_ok=True)},
                lambda s, a: GridFilter(**s).run(a["tracker_xy"], a["rssi"]))


STATIONS = np.array([[0.0, 0.0], [12.0, 0.0], [0.0, 6.0], [12.0, 6.0]])


def _mean_rss(p):
    d = np.linalg.norm(np.asarray(p, float)[..., None, :] - STATIONS, axis=-1)
    return -40.0 - 20.0 * np.log10(np.maximum(d, 0.5))


def mixture_models(step=2.0) -> DiagMixture:
    gx, gy = np.meshgrid(np.arange(0.0, 12.1, step), np.arange(0.0, 6.1, step))
    grid = np.c_[gx.ravel(), gy.ravel()]
    m = _mean_rss(grid)
    k, s = m.shape
    means = np.concatenate([np.broadcast_to(grid, (s, k, 2)), m.T[..., None]], axis=-1)
    return DiagMixture.create(np.ones((s, k)), means,
                              np.broadcast_to([0.5, 0.5, 0.5], (s, k, 3)).copy())


def case_mixture_localizer() -> Case:
    truth = np.array([[8.0, 2.0], [3.0, 5.0]])
    return Case("MixtureLocalizer", {"models": mixture_models(), "max_components": 6},
                {"rss": _mean_rss(truth)},
                {"max_components": Field(setting=True, integer=True, neg_ok=False,
                                         zero_ok=False),
                 "rss": Field(nan_ok=True)},
                lambda s, a: MixtureLocalizer(**s).locate(**a))


def case_mixture_tracker() -> Case:
    time = 0.5 * np.arange(5)
    starts = np.array([[2.0, 1.0], [3.0, 4.5]])
    truth = starts[:, None] + np.c_[1.0 * time, 0.3 * time]
    return Case("MixtureTracker", {"models": mixture_models(), "motion": UniformDisk(1.5),
                                   "max_components": 6},
                {"rss": _mean_rss(truth), "time": time},
                {"max_components": Field(setting=True, integer=True, neg_ok=False,
                                         zero_ok=False),
                 "rss": Field(nan_ok=True), "time": Field()},
                lambda s, a: MixtureTracker(**s).run(**a))


# ---- the generic estimators: Observation inputs (a model, values, a context) -------------

def _observations(a: dict, model) -> Observation:
    return Observation(model, a["z"], Context(points=a["points"], std=a.get("context_std")),
                       a.get("std"))


def _generic_fields(track: bool) -> dict[str, Field]:
    # z: below -6 sigmas of its noise a range is refused (check_ranges); NaN: missing
    out = {"z": Field(nan_ok=True, neg_ok=False), "points": Field(extra_ok=True),
           "std": Field(nan_ok=True, neg_ok=False, zero_ok=False, drop_ok=True),
           "context_std": Field(nan_ok=True, neg_ok=False, zero_ok=False, names=("std",))}
    if track:
        out.update({"time": Field(), "prior_mean": Field(), "prior_cov": Field(neg_ok=False)})
    return out


def _least_squares(settings: dict, a: dict, model):
    """LeastSquares flags a fit it cannot bound (``diagnostics['degenerate']``, a NaN
    covariance, ``converged`` False) instead of raising: the flag counts as its refusal."""
    est = LeastSquares(**settings).locate(_observations(a, model))
    if np.any(est.diagnostics["degenerate"]):
        raise GeometryError("problem flagged degenerate by LeastSquares")
    return est


def case_least_squares() -> Case:
    truth = np.array([7.0, 12.0])
    z = np.linalg.norm(ANCHORS - truth, axis=-1)
    return Case("LeastSquares", {"loss_scale": 1.0, "max_iterations": 50},
                {"z": z, "points": ANCHORS.copy(), "std": np.full(4, 0.05),
                 "context_std": np.full(4, 0.05)},
                {**_generic_fields(False),
                 "loss_scale": Field(setting=True, neg_ok=False, zero_ok=False),
                 # 0 iterations is documented: the start is returned
                 "max_iterations": Field(setting=True, integer=True, neg_ok=False)},
                lambda s, a: _least_squares(s, a, RangeModel(std_m=0.05)),
                truth, 1e-3)


def _generic_walk():
    t, truth, r, start = _walk(seed=5, T=10)
    return t, truth[0], r[0], start[0]


def _track_case(name, make, settings, extra_fields, model=None, **kw) -> Case:
    t, truth, r, start = _generic_walk()
    args = {"z": r, "points": ANCHORS.copy(), "std": np.full(r.shape, 0.05),
            "context_std": np.full(4, 0.05), "time": t,
            "prior_mean": np.r_[start, 0.0, 0.0], "prior_cov": np.eye(4)}

    def solve(s, a):
        return make(**s).run(_observations(a, model or RangeModel(std_m=0.05)), a["time"],
                             prior_mean=a["prior_mean"], prior_cov=a["prior_cov"], **kw)
    return Case(name, settings, args, {**_generic_fields(True), **extra_fields}, solve)


def case_extended_kalman() -> Case:
    counts = Field(setting=True, integer=True, neg_ok=False, zero_ok=False)
    return _track_case("ExtendedKalmanFilter",
                       lambda **s: ExtendedKalmanFilter(WhiteAccelerationCV(0.05, 2), **s),
                       {"gate": 16.0},
                       {"gate": Field(setting=True, neg_ok=False, zero_ok=False, none_ok=True),
                        "iterations": counts, "gate_patience": counts})


def case_generic_particle() -> Case:
    return _track_case("ParticleFilter",
                       lambda **s: ParticleFilter(WhiteAccelerationCV(0.05, 2), **s),
                       {"n_particles": 200, "seed": 1},
                       {"n_particles": Field(setting=True, integer=True, neg_ok=False,
                                             zero_ok=False),
                        "seed": Field(setting=True, integer=True, neg_ok=False),
                        "ess_threshold": Field(setting=True, neg_ok=False)})


def case_batch_smoother() -> Case:
    return _track_case("BatchSmoother",
                       lambda **s: BatchSmoother(WhiteAccelerationCV(0.05, 2), **s),
                       {"max_iterations": 30},
                       {"max_iterations": Field(setting=True, integer=True, neg_ok=False,
                                                zero_ok=False)})


def case_generic_mixture() -> Case:
    """The mixture tracker on range observations (its Gaussian-sum step)."""
    return _track_case("MixtureTracker/range",
                       lambda **s: MixtureTracker(motion=WhiteAccelerationCV(0.05, 2), **s),
                       {"max_components": 8},
                       {"max_components": Field(setting=True, integer=True, neg_ok=False,
                                                zero_ok=False)})


def case_bearing_least_squares() -> Case:
    """The generic least squares on angles of arrival (a model other than ranges)."""
    truth = np.array([7.0, 12.0])
    d = truth - ANCHORS
    z = np.arctan2(d[:, 1], d[:, 0])
    return Case("LeastSquares/aoa", {},
                {"z": z, "points": ANCHORS.copy(), "std": np.full(4, 0.01),
                 "context_std": np.full(4, 0.01)},
                {**_generic_fields(False), "z": Field(nan_ok=True)},     # angles: any sign
                lambda s, a: _least_squares(s, a, BearingModel(std_rad=0.01)),
                truth, 1e-3)


def case_tdoa_least_squares() -> Case:
    """The generic least squares on time differences: the reference anchor of each row is
    the second point of its context."""
    truth = np.array([7.0, 12.0])
    peers, ref = ANCHORS[1:], np.tile(ANCHORS[0], (3, 1))
    z = np.linalg.norm(peers - truth, axis=-1) - np.linalg.norm(ref - truth, axis=-1)

    def solve(s, a):
        est = LeastSquares(**s).locate(Observation(
            TdoaModel(std_m=0.05), a["z"], Context(points=a["points"], reference=a["reference"])))
        if np.any(est.diagnostics["degenerate"]):
            raise GeometryError("problem flagged degenerate by LeastSquares")
        return est
    return Case("LeastSquares/tdoa", {}, {"z": z, "points": peers.copy(), "reference": ref},
                # a tdoa unit slip may be blamed on the values or on the anchors
                {"z": Field(nan_ok=True, names=("z", "tdoa")),
                 "points": Field(names=("points", "tdoa")),
                 "reference": Field(names=("reference", "tdoa"))}, solve,
                truth, 1e-3)


def case_calibrate_anchors() -> Case:
    """Anchor self-calibration (a function): one rough anchor among surveyed ones, exact
    anchor-to-anchor ranges."""
    anchors = np.array([[0.0, 0.0], [20.0, 0.0], [0.0, 15.0], [20.0, 15.0], [8.0, -4.0]])
    pairs = [(i, j) for i in range(5) for j in range(i + 1, 5)]
    ranges = np.array([(i, j, np.linalg.norm(anchors[i] - anchors[j])) for i, j in pairs])
    prior = anchors + np.r_[[0.0] * 8, 0.4, -0.3].reshape(5, 2)

    def solve(s, a):
        fit = calibrate_anchors(a["prior_position"], a["prior_std_m"],
                                anchor_ranges=a["anchor_ranges"], **s)
        return Estimate(position=fit.position, covariance=fit.covariance)
    return Case("calibrate_anchors", {"std_m": 0.01},
                {"prior_position": prior, "prior_std_m": np.r_[0.0, 0.0, 0.0, 0.0, 1.0],
                 "anchor_ranges": ranges},
                # a tiny prior std leaves the information ill-conditioned: refused by the
                # rough anchors it names
                {"prior_position": Field(extra_ok=True),
                 "prior_std_m": Field(neg_ok=False, names=("prior_std_m", "rough anchors")),
                 "anchor_ranges": Field(neg_ok=False),
                 "std_m": Field(setting=True, neg_ok=False, zero_ok=False)},
                solve, anchors, 0.05)


CASES: dict[str, Callable[[], Case]] = {
    "Multilateration": case_multilateration, "NetworkRLS": case_network_rls,
    "NetworkEKF": case_network_ekf, "RangeEKF": case_range_ekf,
    "P2PParticleFilter": case_particle_filter, "LocalML": case_local_ml, "Ransac": case_ransac,
    "ClosedFormTracker": case_closed_form, "NewtonTracker": case_newton,
    "GridFilter": case_grid, "MixtureLocalizer": case_mixture_localizer,
    "MixtureTracker": case_mixture_tracker,
    "LeastSquares": case_least_squares, "ExtendedKalmanFilter": case_extended_kalman,
    "ParticleFilter": case_generic_particle, "BatchSmoother": case_batch_smoother,
    "LeastSquares/aoa": case_bearing_least_squares, "MixtureTracker/range": case_generic_mixture,
    "LeastSquares/tdoa": case_tdoa_least_squares, "calibrate_anchors": case_calibrate_anchors,
}
assert {c.__name__ for c in ESTIMATORS} | {c.__name__ for c in GENERIC_ESTIMATORS} \
    <= {k.split("/")[0] for k in CASES}, "a new estimator needs a fuzz case"


# ---- mutations -------------------------------------------------------------------------

ARRAY_MUTATIONS = ["nan", "inf", "-inf", "huge", "tiny", "negative", "zero", "scale_huge",
                   "scale_tiny", "extra_column", "leading_axis", "drop_axis", "empty", "text",
                   "max_float", "subnormal", "complex", "bool", "object"]
SETTING_VALUES = [math.nan, math.inf, -math.inf, -1.0, 0.0, 1e300, 1e-300, 1.7976931348623157e308,
                  5e-324, 10**12, 10**9, True, "abc", None, -5, 0.5, 2.0, complex(2.0, 0.0),
                  np.complex128(2.0), np.bool_(True)]

#: mutations the contract refuses whatever the field (besides the field's own rules)
ALWAYS_INVALID = {"inf", "-inf", "extra_column", "drop_axis", "empty", "text", "complex",
                  "bool", "object"}
#: shape mutations: an error about them may name any array argument of the call (in a
#: mismatch between two arguments either can be the one at fault)
SHAPE_MUTATIONS = {"extra_column", "leading_axis", "drop_axis", "empty"}


@dataclass
class Mutation:
    field: str
    kind: str
    value: Any = None
    invalid: bool = False     # the contract must refuse it
    exact: bool = False       # the truth of the case still holds (compare the answer)
    description: str = ""
    names: tuple[str, ...] = ()   # words an error may use (default: the field's own)


def _set_one(arr, index, value):
    out = np.array(arr, dtype=float, copy=True)
    out[index] = value
    return out


def invalid_setting(spec: Field, value) -> bool:
    if value is None:
        return not spec.none_ok
    if isinstance(value, (str, complex, np.complexfloating)):
        return True
    if isinstance(value, np.bool_):
        return True
    if isinstance(value, bool):
        return spec.integer
    v = float(value)
    if not math.isfinite(v):
        return True
    if v < 0 and not spec.neg_ok:
        return True
    if v == 0 and not spec.zero_ok:
        return True
    if spec.integer and v != int(v):
        return True
    return False


@st.composite
def mutations(draw, case: Case) -> tuple[Case, Mutation]:
    """One mutation of one field of ``case`` (a new Case; the original is untouched)."""
    name = draw(st.sampled_from(sorted(case.fields)))
    spec = case.fields[name]
    settings, args = dict(case.settings), dict(case.args)
    if spec.setting:
        value = draw(st.sampled_from(SETTING_VALUES))
        if spec.integer and isinstance(value, float) and math.isfinite(value) and value > 1e6:
            value = int(min(value, 10**15))
        settings[name] = value
        m = Mutation(name, "setting", value, invalid_setting(spec, value),
                     description=f"{name}={value!r}")
        return Case(case.name, settings, args, case.fields, case.solve), m
    target = args
    arr = np.asarray(target[name], dtype=float)
    kind = draw(st.sampled_from(ARRAY_MUTATIONS))
    if spec.shape_free and kind in ("extra_column", "leading_axis", "drop_axis", "empty"):
        kind = "nan"
    index = tuple(draw(st.integers(0, n - 1)) for n in arr.shape) if arr.ndim else ()
    invalid = kind in ALWAYS_INVALID
    if kind == "nan":
        new = _set_one(arr, index, np.nan)
        invalid = not spec.nan_ok
    elif kind == "inf":
        new = _set_one(arr, index, np.inf)
    elif kind == "-inf":
        new = _set_one(arr, index, -np.inf)
    elif kind == "huge":
        new = _set_one(arr, index, draw(st.sampled_from([1e300, -1e300, 1e20, 1e154])))
        invalid = new[index] < 0 and not spec.neg_ok
    elif kind == "max_float":
        new = _set_one(arr, index, 1.7976931348623157e308)
    elif kind == "tiny":
        new = _set_one(arr, index, draw(st.sampled_from([1e-300, 1e-12, 5e-324])))
    elif kind == "subnormal":
        new = arr * 5e-324 if arr.ndim else np.float64(5e-324)
    elif kind == "negative":
        new = _set_one(arr, index, -abs(float(arr[index])) - 1.0)
        invalid = not spec.neg_ok and bool(np.isfinite(new[index]))   # NaN stays missing
    elif kind == "zero":
        new = _set_one(arr, index, 0.0)
        invalid = not spec.zero_ok
    elif kind == "scale_huge":
        new = arr * 1e150
    elif kind == "scale_tiny":
        new = arr * 1e-150
    elif kind == "extra_column":
        new = np.concatenate([arr, arr[..., :1]], axis=-1) if arr.ndim else np.ones(3)
        invalid = not spec.extra_ok
    elif kind == "leading_axis":
        new = np.broadcast_to(arr, (3,) + arr.shape).copy()
    elif kind == "drop_axis":
        if spec.drop_ok and arr.ndim >= 1:
            new = arr[0]                 # one row (or value) for the whole batch: valid
            invalid = False
        else:
            new = arr[..., 0] if arr.ndim else np.zeros((2, 2, 2))
    elif kind == "empty":
        new = arr[:0] if arr.ndim else np.zeros(0)
    elif kind == "complex":        # the imaginary part must not be dropped without a word
        new = arr + 0j if arr.ndim else complex(float(arr), 0.0)
    elif kind == "bool":           # True must not be read as 1
        new = arr > np.median(arr) if arr.ndim else np.bool_(True)
    elif kind == "object":         # numbers hidden in an object array (a list with None...)
        new = arr.astype(object)
    elif kind == "text":
        new = np.full(arr.shape, "abc", dtype=object) if arr.ndim else "abc"
    else:  # pragma: no cover
        raise AssertionError(kind)
    target[name] = new
    m = Mutation(name, kind, None, invalid, description=f"{name}: {kind} at {index}")
    if kind in SHAPE_MUTATIONS:
        m.names = tuple(k for k, f in case.fields.items() if not f.setting)
    return Case(case.name, settings, args, case.fields, case.solve), m


# ---- geometry: degenerate anchors with exact ranges -------------------------------------

@st.composite
def anchor_geometry(draw, n_min=3, n_max=6):
    """``(shape, anchors (n, 2), truth (2,))``: general, collinear, near-collinear,
    duplicate or coincident anchors; coordinates on a 1 mm grid."""
    n = draw(st.integers(n_min, n_max))
    coord = st.floats(-100, 100, allow_nan=False).map(lambda v: round(v, 3))
    shape = draw(st.sampled_from(["general", "collinear", "near-collinear", "duplicate",
                                  "coincident", "far-offset"]))
    if shape in ("general", "duplicate", "far-offset"):
        anchors = np.array([(draw(coord), draw(coord)) for _ in range(n)])
        if shape == "duplicate":
            anchors[1] = anchors[0]
        if shape == "far-offset":
            anchors = anchors + draw(st.sampled_from([1e6, -1e7, 3e5]))
    elif shape == "coincident":
        anchors = np.tile([draw(coord), draw(coord)], (n, 1))
    else:
        y0, slope = draw(coord), draw(st.floats(-2, 2).map(lambda v: round(v, 3)))
        xs = draw(st.lists(coord, min_size=n, max_size=n, unique=True))
        anchors = np.array([(x, y0 + slope * x) for x in xs])
        if shape == "near-collinear":
            anchors[1, 1] += draw(st.sampled_from([1e-6, 1e-4, 1e-2, 0.3]))
        if draw(st.booleans()):
            # a node 1 cm .. 10 m from the anchors' line: the two mirror fixes nearly tie
            h = draw(st.sampled_from([0.01, 0.05, 0.28, 1.0, 3.0, 10.0, -0.05, -1.0]))
            x = draw(coord)
            return (f"{shape}, node {h} m off the line", anchors,
                    np.array([x, y0 + slope * x]) + h * np.array([-slope, 1.0]) / math.hypot(1, slope))
    truth = np.array([draw(coord), draw(coord)]) + (anchors.mean(0) if shape == "far-offset"
                                                     else 0.0)
    return shape, anchors, truth


@st.composite
def anchor_geometry3(draw, n_min=4, n_max=6):
    """``(shape, anchors (n, 3), truth (3,))``: general, coplanar, nearly coplanar (one
    anchor 1e-6 .. 0.1 m off the plane) or collinear anchors; a node sometimes close to
    their plane."""
    n = draw(st.integers(n_min, n_max))
    coord = st.floats(-60, 60, allow_nan=False).map(lambda v: round(v, 3))
    shape = draw(st.sampled_from(["general", "coplanar", "near-coplanar", "collinear"]))
    pts = np.array([(draw(coord), draw(coord), draw(coord)) for _ in range(n)])
    if shape == "collinear":
        pts = pts[:1] + np.linspace(-1.0, 1.0, n)[:, None] * (pts[1] - pts[0])
    elif shape != "general":
        normal = np.array([draw(st.floats(-1, 1)), draw(st.floats(-1, 1)), 1.0])
        normal /= np.linalg.norm(normal)
        pts = pts - np.outer((pts - pts[0]) @ normal, normal)
        if shape == "near-coplanar":
            pts[1] += draw(st.sampled_from([1e-6, 1e-3, 0.1])) * normal
        if draw(st.booleans()):
            h = draw(st.sampled_from([0.02, 0.3, 2.0, -0.3]))
            return (f"{shape}, node {h} m off the plane", pts,
                    pts.mean(0) + np.array([draw(coord), draw(coord), 0.0]) @ (
                        np.eye(3) - np.outer(normal, normal)) + h * normal)
    return shape, pts, np.array([draw(coord), draw(coord), draw(coord)])


def conditioning(anchors, truth) -> float:
    """Smallest singular value of the unit line-of-sight matrix (0: no unique fix)."""
    d = np.asarray(anchors) - np.asarray(truth)
    r = np.linalg.norm(d, axis=1, keepdims=True)
    if np.any(r < 1e-6):
        return 0.0
    return float(np.linalg.svd(d / r, compute_uv=False)[-1])


# ---- running and classifying -----------------------------------------------------------

class Hang(BaseException):
    """A library call ran longer than :data:`TIME_LIMIT_S`."""


@contextlib.contextmanager
def guarded():
    """Time limit (SIGALRM) and address-space limit around one call."""
    def on_alarm(signum, frame):
        raise Hang()
    old_handler = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, TIME_LIMIT_S)
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    limit = ADDRESS_LIMIT_BYTES if hard == resource.RLIM_INFINITY else min(hard, ADDRESS_LIMIT_BYTES)
    with contextlib.suppress(ValueError, OSError):
        resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old_handler)
        with contextlib.suppress(ValueError, OSError):
            resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def _arrays(result) -> list[np.ndarray]:
    if isinstance(result, (Estimate, Track)):
        out = [np.asarray(result.position)]
        if result.covariance is not None:
            out.append(np.asarray(result.covariance))
        return out
    if isinstance(result, DiagMixture):
        return [result.weights, result.means, result.variances]
    if isinstance(result, np.ndarray):
        return [result]
    if isinstance(result, tuple):
        return [a for r in result for a in _arrays(r)]
    return []


def call(fn: Callable[[], Any]):
    """``(result, exception, warnings)`` of ``fn()`` under :func:`guarded`."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            with guarded():
                return fn(), None, list(caught)
        except Hang as exc:
            return None, exc, list(caught)
        except Exception as exc:  # noqa: BLE001 - classified
            return None, exc, list(caught)


def classify_call(fn: Callable[[], Any], *, names: tuple[str, ...] = (), invalid: bool = False,
                  truth: np.ndarray | None = None, tol_m: float = 1e-3,
                  position=lambda r: getattr(r, "position", None)) -> tuple[str, str]:
    """``(outcome, detail)`` of one library call: ``error``, ``success`` or a failure class.

    Parameters
    ----------
    fn : callable
        The call.
    names : tuple of str
        Words of which an error message must contain one (the mutated field).
    invalid : bool
        The input is one the contract refuses: success is a failure.
    truth : ndarray, optional
        The exact answer: a success farther than ``tol_m`` is a wrong answer.
    """
    result, exc, caught = call(fn)
    runtime = [w for w in caught if issubclass(w.category, RuntimeWarning)]
    if isinstance(exc, Hang):
        return "hang", f"no answer within {TIME_LIMIT_S:g} s"
    if isinstance(exc, MemoryError):
        return "memory", f"MemoryError: {exc}"
    if exc is not None and not isinstance(exc, RadiolocError):
        tb = "".join(traceback.format_exception(exc)[-4:])
        return "traceback", f"{type(exc).__name__}: {exc} | {tb}"
    if runtime:
        w = runtime[0]
        return "runtime warning", f"{w.category.__name__}: {w.message} ({w.filename}:{w.lineno})"
    if exc is not None:
        msg = str(exc)
        if "\n" in msg.strip():
            return "multi-line error", msg
        # a geometry error names the problem (row, run, node) whose geometry fails
        place = isinstance(exc, GeometryError) and any(
            w in msg for w in ("problem", "run ", "node", "nodes"))
        if names and not place and not any(n in msg for n in names):
            return "error naming the wrong field", f"expected one of {names}: {msg}"
        return "error", f"{type(exc).__name__}: {msg}"
    arrays = _arrays(result)
    if not arrays:
        return "bad success", f"no array in the result {type(result).__name__}"
    for a in arrays:
        if not np.all(np.isfinite(a)):
            return "non-finite output", f"NaN/inf in an output of shape {a.shape}"
    if invalid:
        return "accepted invalid input", "the call succeeded"
    if truth is not None:
        pos = np.asarray(position(result))
        pos = pos[..., -1, :] if isinstance(result, Track) else pos
        err = float(np.max(np.linalg.norm(pos - truth, axis=-1)))
        if err > tol_m:
            return "wrong answer", f"{err:.3g} m from the truth (tolerance {tol_m:g} m)"
    return "success", ""


def record(outcome: str, detail: str, context: str) -> str:
    """Tally an outcome; raise AssertionError on a failure (or collect it, see
    ``RADIOLOC_FUZZ_COLLECT``)."""
    if outcome in ("error", "success"):
        TALLY[f"library {outcome}"] += 1
        return outcome
    TALLY["library FAILURE"] += 1
    collect = os.environ.get("RADIOLOC_FUZZ_COLLECT")
    if collect:
        import json
        with open(collect, "a") as fh:
            fh.write(json.dumps({"library": True, "outcome": outcome, "detail": detail[:3000],
                                 "context": context[:3000]}) + "\n")
        return "collected"
    raise AssertionError(f"{outcome}: {detail}\ncase: {context}")


# ---- models: constructors with hostile scalars, then a method call ---------------------

def _motion_check(m):
    return (m.F(0.5), m.Q(0.5))


def _range_check(m):
    return m.logpdf(np.array([10.0, 11.0]), np.array([10.0, 10.0]))


MODELS: dict[str, tuple[Callable, dict[str, Field], dict[str, Any], Callable]] = {
    "RandomWalk": (RandomWalk, {"q_m2_per_s": Field(neg_ok=False)}, {"q_m2_per_s": 0.1},
                   _motion_check),
    "ConstantVelocity": (ConstantVelocity, {"accel_var": Field(neg_ok=False)},
                         {"accel_var": 0.1}, _motion_check),
    "WhiteAccelerationCV": (WhiteAccelerationCV, {"q": Field(neg_ok=False)}, {"q": 0.1},
                            _motion_check),
    "ConstantAcceleration": (ConstantAcceleration, {"jerk_var": Field(neg_ok=False)},
                             {"jerk_var": 0.1}, _motion_check),
    "InputDriven": (InputDriven, {"std_m": Field(neg_ok=False)}, {"std_m": 0.1},
                    lambda m: m.Q(0.5)),
    "UniformDisk": (UniformDisk, {"v_max_m_per_s": Field(neg_ok=False)},
                    {"v_max_m_per_s": 1.5}, lambda m: m.Q(0.5)),
    "GaussianRange": (GaussianRange, {"std_m": Field(neg_ok=False, zero_ok=False)},
                      {"std_m": 0.1}, _range_check),
    "LosNlosRange": (LosNlosRange, {"los_std_m": Field(neg_ok=False, zero_ok=False),
                                    "nlos_mean_m": Field(neg_ok=False),
                                    "alpha": Field(neg_ok=False)},
                     {"los_std_m": 0.05, "nlos_mean_m": 5.0, "alpha": 0.3}, _range_check),
    "StickyLinkChain": (StickyLinkChain, {"alpha": Field(neg_ok=False)}, {"alpha": 0.9},
                        lambda m: np.asarray(m.alpha, float)),
    "LogDistanceGaussian": (LogDistanceGaussian,
                            {"a": Field(), "n": Field(), "s": Field(neg_ok=False, zero_ok=False),
                             "d_ref_m": Field(neg_ok=False, zero_ok=False)},
                            {"a": 60.0, "n": 2.0, "s": 2.0, "d_ref_m": 0.1},
                            lambda m: m.likelihood(np.array([1.0, 5.0, 20.0]), np.array(50.0))),
}


def trapezoid_arrays():
    """Valid arrays of a :class:`TrapezoidModel` (RSSI 0..100 per distance bin)."""
    mu = np.linspace(40.0, 0.5, 101)
    return {"mu": mu, "tau": np.full(101, 1.0), "sigma": np.full(101, 2.0),
            "count": np.full(101, 100.0)}


def mixture_arrays():
    """Valid arrays of a :class:`DiagMixture` (two components in 2-D)."""
    return {"weights": np.array([0.4, 0.6]), "means": np.array([[0.0, 1.0], [2.0, 3.0]]),
            "variances": np.array([[1.0, 0.5], [0.2, 2.0]])}


ARRAY_MODELS: dict[str, tuple[Callable, dict[str, Field], Callable[[], dict], Callable]] = {
    "TrapezoidModel": (TrapezoidModel,
                       {"mu": Field(), "tau": Field(neg_ok=False), "sigma": Field(neg_ok=False),
                        "count": Field(neg_ok=False)},
                       trapezoid_arrays,
                       lambda m: m.likelihood(np.array([1.0, 5.0, 20.0]), np.array(50.0))),
    "DiagMixture.create": (DiagMixture.create,
                           {"weights": Field(neg_ok=False), "means": Field(),
                            "variances": Field(neg_ok=False, zero_ok=False)},
                           mixture_arrays,
                           lambda m: (m.moments(), m.logpdf(np.array([[1.0, 1.0]])))),
}
