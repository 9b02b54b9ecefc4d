"""Small simulated problems for every measurement model, for the generic contract and
metamorphic tests (a helper module, not a test).

Each :class:`ModelCase` is a scene: anchors, a batch of ``B`` straight tracks of ``T``
steps (``(x, y[, z])`` with ``x != y``), and one or more observation parts (a model and the
anchors of its rows). :meth:`ModelCase.problem` draws the measurements once, in the scene's
own frame, and returns them for the scene moved by a rotation about the vertical, a
translation, a relabelling of the anchors and a scaling of time:

- every model here depends on the geometry through distances and angles measured in the
  anchor's frame, so the values ``z`` of a rigidly moved scene are those of the original
  (a bearing anchor's yaw turns with the scene); :func:`check_invariance` checks that the
  models agree;
- relabelling the anchor table by ``perm`` (new row ``j`` holds old anchor ``perm[j]``)
  reorders the rows of every part by their new anchor index (``Context.index``,
  ``reference_index``, per-anchor yaws and biases follow);
- scaling time by ``s`` leaves positions where they were, divides velocities by ``s`` (the
  prior's mean by ``s``, its variance by ``s^2``) and the white-acceleration density by
  ``s^3``, which maps the motion model onto itself: ``Q'(s dt) = S Q(dt) S`` with
  ``S = diag(1, 1/s)``.

``PRIOR`` fixes the prior of the state's extra components: a receiver clock offset of
``CLOCK_M`` metres and per-anchor biases are estimated from a prior centred on 0.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from radioloc.models import (
    BearingModel,
    Context,
    DiagMixture,
    FingerprintMixture,
    FingerprintScanModel,
    HeadingModel,
    LogDistanceGaussian,
    LosNlosRange,
    MeasurementModel,
    MixtureRssModel,
    Observation,
    PseudorangeModel,
    RangeModel,
    StateLayout,
    WhiteAccelerationCV,
)
from radioloc.models.rss_model import RssModel, TrapezoidRssModel
from radioloc.models.rssi_trapezoid import TrapezoidModel
from radioloc.models.tdoa import TdoaModel

B = 3                       # problems per batch
T = 8                       # steps of a track
DT_S = 0.5                  # seconds between steps
Q_M2_PER_S3 = 0.05          # white-acceleration density of the motion model
CLOCK_M = 2.0               # receiver clock offset (pseudorange), metres
CLOCK_PRIOR_STD_M = 3.0
BIAS_PRIOR_STD_M = 0.5
VELOCITY = np.array([0.6, 0.2])
ANCHORS_2D = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 20.0], [30.0, 20.0], [12.0, 27.0]])
HEIGHTS_M = np.array([0.5, 4.0, 2.5, 5.0, 1.0])
TAG_HEIGHT_M = 1.5
#: trapezoids of paper 003's form: reading ``k`` <-> distance ``30 - 0.3 k`` metres
TRAPEZOIDS = TrapezoidModel(mu=np.clip(30.0 - 0.3 * np.arange(101.0), 0.3, None),
                            tau=np.full(101, 0.3), sigma=np.full(101, 0.6), count=np.ones(101))


class MinimalBearing(MeasurementModel):
    """Angle of the node seen from each point, ``atan2(y - y_a, x - x_a)`` in radians, with
    only ``predict`` and ``std``: the Jacobian is the base class's numerical one and the
    wrapped Gaussian ``logpdf`` the base class's (a model as small as a user may write)."""

    kind = "aoa"
    angular = True

    def __init__(self, std_rad: float) -> None:
        self.std_rad = std_rad

    def predict(self, state, context):
        d = state["position"][..., None, :] - context.points
        return np.arctan2(d[..., 1], d[..., 0])

    def std(self, context):
        return self.row_std(self.std_rad, context)


def rotation(theta: float, dim: int) -> np.ndarray:
    """Rotation by ``theta`` about the vertical, ``(dim, dim)``."""
    c, s = np.cos(theta), np.sin(theta)
    R = np.eye(dim)
    R[:2, :2] = [[c, -s], [s, c]]
    return R


@dataclass(frozen=True)
class Part:
    """The rows of one observation: a model (``make(theta, perm, shift)`` builds it for a
    scene rotated by ``theta``, then translated by ``shift``, with its anchor table
    relabelled by ``perm``), the anchor-table row of each measurement row, and of its
    reference (time differences)."""

    make: Callable[[float, np.ndarray, np.ndarray], object]
    rows: np.ndarray
    reference: np.ndarray | None = None


@dataclass
class Problem:
    """One scene, ready for an estimator.

    Attributes
    ----------
    observations : list of Observation
        ``z`` ``(B, T, m)`` each.
    truth : ndarray, shape (B, T, D)
    time : ndarray, shape (T,)
    motion : WhiteAccelerationCV
    layout : StateLayout
        Position, velocity and what the models read.
    prior_mean : ndarray, shape (B, n)
    prior_cov : ndarray, shape (n, n)
    time_scale : float
        The factor time was scaled by (rates in ``RATE_SETTINGS`` are divided by it).
    """

    observations: list
    truth: np.ndarray
    time: np.ndarray
    motion: object
    layout: StateLayout
    prior_mean: np.ndarray
    prior_cov: np.ndarray
    time_scale: float = 1.0

    def snapshot(self, step: int = 0) -> list:
        """The observations of one step, ``z`` ``(B, m)`` (for a snapshot estimator)."""
        return [replace(o, z=o.z[:, step]) for o in self.observations]

    def with_values(self, z: list) -> Problem:
        """The same problem with other values (one array per observation)."""
        return replace(self, observations=[replace(o, z=v) for o, v in zip(self.observations, z)])

    def take(self, runs: slice) -> Problem:
        """The problems ``runs`` of the batch."""
        return replace(self, observations=[replace(o, z=o.z[runs]) for o in self.observations],
                       truth=self.truth[runs], prior_mean=self.prior_mean[runs])


@dataclass
class ModelCase:
    """A scene for one model class (see the module docstring).

    Attributes
    ----------
    name : str
    dim : int
        Position dimension.
    parts : list of Part
    tol_m : float
        Accuracy expected of a Gaussian (Jacobian) estimator at the final step / snapshot.
    snapshot : bool
        Whether one epoch fixes the state (False: per-anchor biases need a prior).
    extra : dict
        ``{"clock_offset": CLOCK_M, "anchor_bias": (A,)}`` truth of the extra components.
    seed : int
        Of the measurement draws.
    snapshot_tol_m : float, optional
        Accuracy of a snapshot fit of the first epoch (default ``tol_m``).
    """

    name: str
    dim: int
    parts: list
    tol_m: float
    snapshot: bool = True
    extra: dict = field(default_factory=dict)
    seed: int = 0
    snapshot_tol_m: float | None = None

    @property
    def anchors(self) -> np.ndarray:
        return ANCHORS_2D if self.dim == 2 else np.c_[ANCHORS_2D, HEIGHTS_M]

    @property
    def models(self) -> list:
        return [p.make(0.0, np.arange(len(ANCHORS_2D)), np.zeros(self.dim)) for p in self.parts]

    def _truth(self) -> np.ndarray:
        rng = np.random.default_rng(100 + self.seed)
        start = np.c_[rng.uniform(6, 24, B), rng.uniform(3, 9, B)]
        t = np.arange(T) * DT_S
        track = start[:, None, :] + t[:, None] * VELOCITY
        if self.dim == 3:
            track = np.concatenate([track, np.full((B, T, 1), TAG_HEIGHT_M)], axis=-1)
        return track

    def _layout(self, models) -> StateLayout:
        layout = StateLayout(dim=self.dim, order=1)
        for m in models:
            layout = layout.with_model(m, len(ANCHORS_2D))
        return layout

    def _contexts(self, anchors: np.ndarray, new_of_old: np.ndarray):
        """Per part: the row order and the context in a relabelled anchor table."""
        out = []
        for p in self.parts:
            order = np.argsort(new_of_old[p.rows], kind="stable")
            idx = new_of_old[p.rows[order]]
            ref_idx = None if p.reference is None else new_of_old[p.reference[order]]
            ctx = Context(points=anchors[idx], index=idx,
                          reference=None if ref_idx is None else anchors[ref_idx],
                          reference_index=ref_idx)
            out.append((order, ctx))
        return out

    def values(self) -> list:
        """The measurements of the original scene, ``(B, T, m)`` per part (drawn once)."""
        rng = np.random.default_rng(self.seed)
        models = self.models
        layout = self._layout(models)
        truth = self._truth()
        comps = {"position": truth}
        if layout.clock:
            comps["clock_offset"] = np.full((B, T), self.extra.get("clock_offset", 0.0))
        if layout.n_bias:
            comps["anchor_bias"] = np.broadcast_to(self.extra["anchor_bias"], (B, T, layout.n_bias))
        comps["velocity"] = np.broadcast_to(np.r_[VELOCITY, [0.0] * (self.dim - 2)], truth.shape)
        state = {k: np.asarray(v, float) for k, v in comps.items()}
        ident = np.arange(len(ANCHORS_2D))
        out = []
        for m, (_, ctx) in zip(models, self._contexts(self.anchors, ident)):
            if isinstance(m, TrapezoidRssModel):     # readings: the trapezoids' centre, quantised
                d = np.linalg.norm(truth[..., None, :] - ctx.points, axis=-1)
                d = d + 0.1 * rng.standard_normal(d.shape)
                out.append(np.clip(np.round((30.0 - d) / 0.3), 0, 100))
            else:
                out.append(m.sample(state, ctx, rng))
        return out

    def problem(self, theta: float = 0.0, shift=None, perm=None, time_scale: float = 1.0,
                z: list | None = None) -> Problem:
        """The scene rotated by ``theta`` (about the vertical), then translated by ``shift``,
        its anchor table relabelled by ``perm`` and its time scaled by ``time_scale``.

        Parameters
        ----------
        theta : float
            Radians.
        shift : array_like, shape (D,), optional
        perm : array_like of int, shape (A,), optional
            New anchor row ``j`` is old anchor ``perm[j]``.
        time_scale : float
        z : list of ndarray, optional
            Values of the original scene (default :meth:`values`).

        Returns
        -------
        Problem
        """
        A = len(ANCHORS_2D)
        perm = np.arange(A) if perm is None else np.asarray(perm)
        new_of_old = np.argsort(perm)
        R = rotation(theta, self.dim)
        t = np.zeros(self.dim) if shift is None else np.asarray(shift, float)
        anchors = (self.anchors @ R.T + t)[perm]
        z = self.values() if z is None else z
        models = [p.make(theta, perm, t) for p in self.parts]
        obs = []
        for m, v, (order, ctx) in zip(models, z, self._contexts(anchors, new_of_old)):
            obs.append(Observation(model=m, z=v[..., order], context=ctx))
        truth = self._truth() @ R.T + t
        s = float(time_scale)
        time = np.arange(T) * DT_S * s
        layout = self._layout(models)
        D, n = self.dim, layout.size
        vel = np.r_[VELOCITY, [0.0] * (D - 2)] @ R.T / s
        start = self._truth()[:, 0] + np.r_[0.3, -0.2, [0.1] * (D - 2)]
        mean = np.zeros((B, n))
        mean[:, :D] = start @ R.T + t
        mean[:, D:2 * D] = vel
        var = np.r_[np.full(D, 1.0), np.full(D, 0.25 / s**2)]
        if layout.clock:
            var = np.r_[var, [CLOCK_PRIOR_STD_M**2] * layout.clock]
        if layout.n_bias:
            var = np.r_[var, np.full(layout.n_bias, BIAS_PRIOR_STD_M**2)]
        return Problem(obs, truth, time, WhiteAccelerationCV(Q_M2_PER_S3 / s**3, dim=D),
                       layout, mean, np.diag(var), s)


def _fixed(model) -> Callable:
    return lambda theta, perm, shift: model


def _bearing(component: str):
    yaw = np.linspace(-0.4, 0.5, len(ANCHORS_2D))          # one frame per anchor

    def make(theta, perm, shift):
        return BearingModel(std_rad=0.004, component=component,
                            orientation_rad=(yaw + theta)[perm])
    return make


def _heading(theta, perm, shift):
    """The direction of the velocity: the sensor's frame stays put when the scene turns, so
    its offset turns the other way."""
    return HeadingModel(std_rad=0.02, offset_rad=-theta, min_speed_mps=0.1)


#: calibration places of the fingerprint mixture (every 3 m over the tracks' area)
PLACES = np.stack(np.meshgrid(np.arange(3.0, 28.0, 3.0), np.arange(0.0, 13.0, 3.0)),
                  -1).reshape(-1, 2)


def _fingerprint(theta, perm, shift):
    """Paper 004's per-station mixtures on the places, the signal mean falling with the
    distance to the station's anchor; isotropic position variances, so that the rotated
    places are the rotated model."""
    d = np.linalg.norm(PLACES[None] - ANCHORS_2D[:, None], axis=-1)           # (A, K)
    nu = -40.0 - 20.0 * np.log10(np.maximum(d, 0.5))
    pos = PLACES @ rotation(theta, 2).T + np.asarray(shift, float)[:2]
    means = np.concatenate([np.broadcast_to(pos, d.shape + (2,)), nu[..., None]], -1)
    mix = DiagMixture.create(np.ones(d.shape), means, np.full(d.shape + (3,), 1.5))
    return MixtureRssModel(mix[np.asarray(perm)])


def _scan(theta, perm, shift):
    """A shared-place fingerprint model on the same places: access point ``k`` at the
    anchor, detected with a probability falling with the distance, its reading the same
    log-distance mean (4 dB^2)."""
    d = np.linalg.norm(PLACES[:, None] - ANCHORS_2D, axis=-1)                # (K, A)
    pos = PLACES @ rotation(theta, 2).T + np.asarray(shift, float)[:2]
    k = len(PLACES)
    fm = FingerprintMixture(pos, np.full((k, 2), 1.5), np.full(k, -np.log(k)),
                            np.clip(1.2 - d / 30.0, 0.05, 0.95)[:, perm],
                            (-40.0 - 20.0 * np.log10(np.maximum(d, 0.5)))[:, perm],
                            np.full(d.shape, 4.0), np.ones(d.shape[1], bool),
                            np.zeros((k, 0), np.int64))
    return FingerprintScanModel(fm)


ALL = np.arange(len(ANCHORS_2D))
OTHERS = ALL[1:]

#: one case per model class (and per noise of the range model)
CASES = {c.name: c for c in [
    ModelCase("range-gaussian", 2, [Part(_fixed(RangeModel(std_m=0.05)), ALL)], 0.15),
    ModelCase("range-los-nlos", 2, [Part(_fixed(RangeModel(noise=LosNlosRange(0.05, 1.0, 0.9))),
                                         ALL)], 1.2, seed=1,
              # NLOS links (1 m mean excess, 10 %) fitted by the mixture's moments: the
              # ungated smoother ends 0.76 m off on one run, one epoch 1.5 m
              snapshot_tol_m=2.0),
    ModelCase("range-anchor-bias", 2,
              [Part(_fixed(RangeModel(std_m=0.05, anchor_bias=True)), ALL)], 0.6,
              snapshot=False, extra={"anchor_bias": np.array([0.3, -0.2, 0.1, 0.0, 0.25])},
              seed=2),
    ModelCase("tdoa", 2, [Part(_fixed(TdoaModel(std_m=0.05)), OTHERS, np.zeros(4, int))], 0.3,
              seed=3),
    ModelCase("bearing-azimuth", 2, [Part(_bearing("azimuth"), ALL)], 0.3, seed=4),
    ModelCase("bearing-3d", 3, [Part(_bearing("azimuth"), ALL), Part(_bearing("elevation"), ALL)],
              0.4, seed=5),
    ModelCase("pseudorange", 2, [Part(_fixed(PseudorangeModel(std_m=0.05)), ALL)], 0.4,
              extra={"clock_offset": CLOCK_M}, seed=6),
    ModelCase("rss", 2, [Part(_fixed(RssModel(LogDistanceGaussian(a=-40.0, n=2.5, s=0.2,
                                                                  d_ref_m=0.5))), ALL)], 0.8,
              seed=7),
    ModelCase("rss-trapezoid", 2, [Part(_fixed(TrapezoidRssModel(TRAPEZOIDS)), ALL)], 1.0, seed=8),
    ModelCase("rss-fingerprint", 2, [Part(_fingerprint, ALL)], 1.0, seed=9),
    # one scan does not fix the position: beyond the places the place weights saturate, so
    # the likelihood stays at its value on the edge place (run 0's maximum is a strip
    # running from y = 12 m to any distance), and inside them a single scan's maximum lies
    # 4.7 m from run 2's truth (1.6 nats above the truth's)
    ModelCase("rss-scan", 2, [Part(_scan, ALL)], 1.2, snapshot=False, seed=10),
    # a heading fixes no position: with ranges, and no snapshot (the speed is unobserved)
    ModelCase("range-heading", 2, [Part(_fixed(RangeModel(std_m=0.05)), ALL),
                                   Part(_heading, ALL[:1])], 0.15, snapshot=False, seed=11),
]}


def check_invariance(case: ModelCase, problem: Problem, atol: float = 1e-7) -> None:
    """Assert that the moved scene's models predict, at the moved truth, what the original's
    predict at the original truth (the premise of the metamorphic tests)."""
    base = case.problem()
    for o0, o1 in zip(base.observations, problem.observations):
        if not getattr(o0.model, "gaussian", True):
            continue
        for step in (0, T - 1):
            comps0 = _components(base, step)
            comps1 = _components(problem, step)
            h0 = o0.model.predict(comps0, o0.context)
            h1 = o1.model.predict(comps1, o1.context)
            # compare row by row by physical anchor: sort both by the rows' points' distance
            np.testing.assert_allclose(np.sort(h0, -1), np.sort(h1, -1), atol=atol, rtol=0)


def _components(p: Problem, step: int) -> dict:
    D = p.truth.shape[-1]
    comps = {"position": p.truth[:, step], "velocity": p.prior_mean[:, D:2 * D]}
    if p.layout.clock:
        comps["clock_offset"] = np.full(B, CLOCK_M)
    if p.layout.n_bias:
        comps["anchor_bias"] = np.zeros((B, p.layout.n_bias))
    return comps


# ---- the generic estimators over the cases ----------------------------------------------
#: settings of the small runs (a constructor parameter of that name gets this value)
SMALL_SETTINGS = {"n_particles": 500, "cell_m": 0.25, "max_components": 8}
#: settings that are rates, with the power of time in their unit (intensities per second,
#: the clock drift's per second cubed): divided by the problem's time scale to that power, so
#: that a scaled problem is the same model (the batch smoother's clock and bias random walks)
RATE_SETTINGS = {"extra_q": (1e-6, 1), "drift_q": (1e-6, 3)}
SEEDS = np.arange(11, 11 + B)


def generic_estimators() -> list:
    """Every class of ``radioloc.estimators.ESTIMATORS`` whose tags say ``generic``."""
    from radioloc.estimators import ESTIMATORS
    return [c for c in ESTIMATORS if c.tags.generic]


def accepted(cls, case: ModelCase) -> bool:
    """Whether ``cls``'s tags take every model of ``case`` and its dimension."""
    return case.dim in cls.tags.dims and all(cls.tags.accepts(m) for m in case.models)


def applicable(cls, case: ModelCase) -> bool:
    """Accepted, and a snapshot estimator only on a case one epoch determines."""
    return accepted(cls, case) and (cls.tags.recursive or case.snapshot)


def pairs() -> list:
    """``(estimator class, case name)`` for every applicable combination."""
    return [(cls, name) for cls in generic_estimators() for name, case in CASES.items()
            if applicable(cls, case)]


def make_estimator(cls, problem: Problem, runs: slice = slice(None)):
    """``cls`` with the small settings: the problem's motion model (its ``motion``
    parameter) for a recursive estimator, a seed per run where it takes ``seed`` (so a run
    draws the same alone as in a batch), rates scaled with time."""
    import inspect
    params = inspect.signature(cls).parameters
    kw = {k: v for k, v in SMALL_SETTINGS.items() if k in params}
    kw.update({k: v / problem.time_scale ** power for k, (v, power) in RATE_SETTINGS.items()
               if k in params})
    if "seed" in params:
        kw["seed"] = SEEDS[runs]
    if cls.tags.recursive:
        kw["motion"] = problem.motion
    return cls(**kw)


def solve(cls, problem: Problem, runs: slice = slice(None)):
    """Run ``cls`` on the problems ``runs``: a ``Track`` (recursive) or an ``Estimate`` of
    the first step (snapshot)."""
    p = problem.take(runs)
    est = make_estimator(cls, p, runs)
    if cls.tags.recursive:
        mean, cov = p.prior_mean, p.prior_cov
        grow = getattr(est, "layout_for", None) or getattr(est, "state_layout", None)
        layout = p.layout if grow is None else grow(p.observations)
        if layout.clock == 2 and p.layout.clock == 1:
            mean, cov = with_drift(layout, mean, cov, p.time_scale)
        return est.run(p.observations, p.time, prior_mean=mean, prior_cov=cov)
    return est.locate(p.snapshot())


def with_drift(layout: StateLayout, mean: np.ndarray, cov: np.ndarray, time_scale: float = 1.0
               ) -> tuple[np.ndarray, np.ndarray]:
    """A prior over a state with the clock offset alone, carried onto ``layout``, which also
    holds the clock's drift (the filters' default: ``radioloc.models.clock.drifting``):
    the drift starts at 0 m/s, standard deviation 1 m/s (in the problem's unit of time)."""
    d = layout.slices["clock_drift"].start
    mean = np.insert(mean, d, 0.0, axis=-1)
    cov = np.insert(np.insert(cov, d, 0.0, axis=-1), d, 0.0, axis=-2)
    cov[..., d, d] = 1.0 / time_scale ** 2
    return mean, cov


def final(result) -> np.ndarray:
    """The position per problem at the last step (a track) or the estimate, ``(B, D)``."""
    from radioloc.core.results import Track
    return result.position[..., -1, :] if isinstance(result, Track) else result.position


def truth_of(cls, problem: Problem) -> np.ndarray:
    """The truth ``final`` is compared with, ``(B, D)``."""
    return problem.truth[:, -1] if cls.tags.recursive else problem.truth[:, 0]


#: accuracy factor of an estimator that samples (particles: Monte Carlo error of 500
#: particles in a 4- to 6-dimensional state)
SAMPLING_FACTOR = 2.5


def tolerance_m(cls, case: ModelCase) -> float:
    """Accuracy expected of ``cls`` on ``case`` at low noise, metres."""
    tol = case.tol_m if cls.tags.recursive else (case.snapshot_tol_m or case.tol_m)
    return tol * (SAMPLING_FACTOR if cls.tags.uses == "logpdf" else 1.0)
