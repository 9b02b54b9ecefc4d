"""``radioloc locate --method ekf-track``: track each node from its measurements to anchors
with the generic extended Kalman filter (:class:`radioloc.estimators.ExtendedKalmanFilter`).

Every kind the filter has a model for is used (:data:`TRACKER_KINDS`: every kind
:mod:`radioloc.core.kinds` declares, ranges, time differences, angles of arrival,
pseudoranges, ...; :func:`radioloc.locate.adapter.default_models` builds the
model each declares; RSS with a log-distance model per anchor from the anchors file,
:mod:`radioloc.locate.path_loss`), and ``-o anchor_bias=1`` adds a range bias per anchor to the state
(WiFi RTT offsets, antenna delays), learnt online from a common offset fitted at the start.
Measurements are processed as they arrive: the rows of a node that share one time stamp are
one update, whatever anchors they reach (one anchor at a time is fine); a time with no
measurement to a known anchor is not a step. Ranges whose peer is another node (tag-to-tag)
are used with ``-o cooperative=1`` only (:mod:`radioloc.locate.cooperative`: the peer's
estimate as a moving anchor); otherwise they are left out.

Divergence (:func:`radioloc.locate.health.divergence`: innovations far outside their band,
or a track far outside the anchors' box while refusing its measurements) is recorded in the
summary (``innovations``, with the noise options in force: a stated noise too small for the
log makes the filter refuse the measurements and coast on its motion model) and warned by
the health check with its other findings. When the values of
one kind, mapped back from a known slip (:func:`radioloc.locate.slips.slips`: tdoa or aoa
of the wrong sign, pseudoranges in km or ns, odometry in mm or negated), make every track
consistent, the log is refused instead, by an error naming the kind and the slip. A unit
slip (a map that scales the values) is named only when the log does not fit with every
sigma :data:`NOISE_SLACK` times larger either: scaling the values scales their errors, so
a log with too small a stated noise (NLOS excess on metre pseudoranges) would otherwise be
blamed on its unit.

A gap longer than ``max_gap_s`` between a node's ranges starts a new track (the motion
model alone cannot bridge it; one update from a prior metres wide linearises badly).

The start: the node is assumed to stay within ``prior_std_m`` of one place during its first
``init_s`` seconds; the median range to each anchor over that window is fitted by a coarse
then fine grid search over the horizontal plane (at the tag height, or at the anchors' mean
height in 3-D), which finds the global least-squares minimum rather than a mirror basin. A
log without ranges to three anchors starts from a robust least-squares fit of the window's
medians of every kind (an angle's median taken on the circle), and the window's angles far
from their medians are left out as reflections (:func:`start_screened`). The
filter starts there with position standard deviation ``prior_std_m`` and velocity standard
deviation ``PRIOR_SPEED_STD`` m/s.

Motion models for asynchronous rows are continuous-time: ``cv`` is a constant velocity
driven by white acceleration of spectral density ``q`` (m^2/s^3), so the process noise of an
interval does not depend on how the interval is split (:class:`WhiteAccelerationCV`);
``rw`` is a random walk of diffusion ``q`` (m^2/s).

Odometry rows (``odometry_dx``, ``odometry_dy``) replace that motion model: the state is
the position, moved at each step by the odometry's displacement over the step (the
control input) with a random walk of diffusion ``odometry_std_m^2`` about it
(:mod:`radioloc.locate.odometry`); options ``motion`` and ``q`` do not apply then. The
odometry rows are not steps: the steps stay the times of the measurements to anchors.

Heading rows (a phone's compass azimuth turned into the anchors' frame) measure the
direction of the velocity (:class:`~radioloc.models.heading.HeadingModel`, ``heading_std_rad``):
an update of the constant-velocity state like any other row, so a time with a heading
alone is a step too (not with ``rw`` or odometry; a node with heading rows only has no
start).
"""

from __future__ import annotations

import warnings
from types import SimpleNamespace
from dataclasses import replace

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError, GeometryError, InputError, RadiolocError
from radioloc.core.kinds import kinds as declared_kinds
from radioloc.core.kinds import model_kinds
from radioloc.core.plausibility import value_checks
from radioloc.estimators.extended_kalman import ExtendedKalmanFilter
from radioloc.estimators.least_squares import LeastSquares
from radioloc.io.measurements import Measurements
from radioloc.locate.adapter import (anchor_positions, default_models, frame_settings,
                                     given_sigmas, log_observations, sigma_options)
from radioloc.locate.cooperative import cooperative_batch, peer_ranges
from radioloc.locate.base import MAX_GAP_S, LocateRequest, Option, locate_method
from radioloc.locate.path_loss import anchor_rss_model
from radioloc.locate.odometry import (ODOMETRY_OPTIONS, ODOMETRY_STD_M,
                                      has_odometry, odometry_controls, odometry_motion)
from radioloc.locate.progress import progress
from radioloc.locate.self_tuning import (learn_nodes, not_learnable, offsets_taken_off,
                                         tuned_observations)
from radioloc.locate.health import divergence, noise_in_force, snapshot_scale
from radioloc.locate.slips import likely_slip
from radioloc.locate.table import covariance_columns
from radioloc.models.measurement import (Context, Observation, StateLayout, check_motion,
                                         wrap_angle)
from radioloc.models.motion import RandomWalk, WhiteAccelerationCV, WhiteJerkCA
from radioloc.models.ranging import RangeModel

#: The measurement kinds the trackers read: every declared kind (:mod:`radioloc.core.kinds`;
#: rss with a path-loss model per anchor, odometry as the control input of the motion).
TRACKER_KINDS = tuple(declared_kinds())

#: Range sigma of the trackers when ``range_std_m`` is not given, m.
RANGE_STD_M = 0.15
#: An angle of the start window this many robust standard deviations from its column's
#: median is a reflection (:func:`start_screened`).
START_SIGMAS = 4.0
#: Standard deviation of the start velocity, m/s.
PRIOR_SPEED_STD = 3.0
#: Prior standard deviation of a receiver clock's drift (times c), m/s: 1 ppm, the
#: frequency error of a temperature-compensated crystal oscillator.
CLOCK_DRIFT_PRIOR_STD = 300.0
#: Factor on every sigma with which a diverged log is tried again before a slip is named
#: (:func:`looser_noise`).
NOISE_SLACK = 3.0


def motion_model(kind: str, q: float, dim: int):
    """The motion model of option ``motion``.

    Parameters
    ----------
    kind : {"cv", "ca", "rw"}
        Constant velocity (white acceleration), constant acceleration (white jerk) or random
        walk.
    q : float
        Acceleration spectral density (m^2/s^3, ``cv``), jerk spectral density (m^2/s^5,
        ``ca``) or diffusion (m^2/s, ``rw``).
    dim : int
        Position coordinates.

    Returns
    -------
    WhiteAccelerationCV, WhiteJerkCA or RandomWalk
    """
    if kind == "ca":
        return WhiteJerkCA(q, dim)
    return WhiteAccelerationCV(q, dim) if kind == "cv" else RandomWalk(q, dim)


def _predicted(xy: np.ndarray, anchors: np.ndarray, height: float | None) -> np.ndarray:
    """Ranges from horizontal positions (..., 2) to anchors (M, 2|3) at a node height."""
    d2 = np.sum((xy[..., None, :] - anchors[:, :2]) ** 2, axis=-1)
    if anchors.shape[1] == 3:
        d2 = d2 + (height - anchors[:, 2]) ** 2
    return np.sqrt(d2)


def column_medians(values: np.ndarray, angular: bool = False) -> np.ndarray:
    """Median of each column of ``values`` ``(T, S)`` over its finite entries (NaN for a
    column with none).

    With ``angular`` the values are angles (radians): the median of their differences from
    the column's circular mean, wrapped to ``(-pi, pi]``, so angles on both sides of
    ``+-pi`` have a median between them (not near 0), and a reflection far off the others
    does not move it.
    """
    med = np.full(values.shape[1], np.nan)
    heard = np.isfinite(values).any(axis=0)
    v = values[:, heard]
    if angular:
        centre = np.angle(np.nanmean(np.exp(1j * v), axis=0))
        med[heard] = wrap_angle(np.nanmedian(wrap_angle(v - centre), axis=0) + centre)
    else:
        med[heard] = np.nanmedian(v, axis=0)
    return med


def start_position(times: np.ndarray, R: np.ndarray, anchors: np.ndarray, height: float | None,
                   bias: float, init_s: float, common_offset: bool = False):
    """Horizontal start position from the median ranges of the first ``init_s`` seconds.

    Two grid searches (coarse over a square covering every anchor and the largest range,
    then fine around the best cell) minimise the sum of squared range residuals; with at
    least three anchors not on one line this is the global minimum, not a mirror basin.

    With ``common_offset``, every range is taken to carry one unknown offset ``b >= 0``
    (per-anchor biases, of which this is the mean): each cell's residuals are taken about
    their median, and the search stays within the anchors' bounding box grown by a quarter
    of its size and 2 m (far outside it, a common offset explains any ranges equally well).

    Parameters
    ----------
    times : ndarray, shape (T,)
    R : ndarray, shape (T, M)
        Ranges (NaN: absent).
    anchors : ndarray, shape (M, 2) or (M, 3)
    height : float or None
        Node height when anchors are 3-D (None: the anchors' mean height).
    bias : float
        Range bias subtracted from the ranges.
    init_s : float
        Window length, seconds.

    common_offset : bool
        Estimate a common range offset too.

    Returns
    -------
    ndarray, shape (2,)
        With ``common_offset``: ``(position (2,), offset_m)``.

    Raises
    ------
    GeometryError
        Fewer than three anchors heard in the window (and in the whole log).
    """
    med = column_medians(R[times <= times[0] + init_s])
    heard = np.isfinite(med)
    if heard.sum() < 3:   # widen to the whole log rather than give up
        med = column_medians(R)
        heard = np.isfinite(med)
    if heard.sum() < 3:
        raise GeometryError(f"ranges to {int(heard.sum())} anchor(s) only; the start position "
                            "needs three")
    r = med[heard] - bias
    a = anchors[heard]
    h = None if a.shape[1] == 2 else (float(np.mean(anchors[:, 2])) if height is None else height)
    # the same window is started again and again when the settings are learned: one
    # search per window (a pure function of these inputs)
    key = (r.tobytes(), a.tobytes(), anchors.tobytes(), h, common_offset)
    found = _STARTS.get(key)
    if found is None:
        found = _grid_start(r, a, anchors, h, common_offset)
        if len(_STARTS) >= 256:
            _STARTS.clear()
        _STARTS[key] = found
    best, offset = found
    return (best.copy(), offset) if common_offset else best.copy()


#: Start positions found, by their search's inputs (:func:`start_position`).
_STARTS: dict = {}


def _grid_start(r, a, anchors, h, common_offset):
    """:func:`start_position`'s two grid searches: ``(position (2,), offset_m)``."""
    lo, hi = anchors[:, :2].min(axis=0), anchors[:, :2].max(axis=0)
    centre = (lo + hi) / 2 if common_offset else anchors[:, :2].mean(axis=0)
    half = (float(np.max((hi - lo) * 0.75 + 2.0)) if common_offset else
            float(np.max(np.abs(anchors[:, :2] - centre)) + np.max(r) + 1.0))
    best, offset = centre, 0.0
    for _ in range(3):   # coarse, finer, finest: 201 x 201 cells each
        g = np.linspace(-half, half, 201)
        gx, gy = np.meshgrid(best[0] + g, best[1] + g, indexing="ij")
        xy = np.stack([gx.ravel(), gy.ravel()], axis=-1)
        res = r - _predicted(xy, a, h)
        b = np.maximum(np.median(res, axis=-1), 0.0) if common_offset else np.zeros(len(xy))
        k = int(np.argmin(np.sum((res - b[:, None]) ** 2, axis=-1)))
        best, offset = xy[k], float(b[k])
        half = half / 20
    return best, offset


OPTIONS = {
    "motion": Option("'cv' constant velocity (white acceleration, default), 'ca' constant "
                     "acceleration (white jerk; default with yaw_rate rows) or 'rw' random "
                     "walk", str, choices=("cv", "ca", "rw")),
    "q": Option("process noise: acceleration spectral density m^2/s^3 (cv, default 1), jerk "
                "spectral density m^2/s^5 (ca) or diffusion m^2/s (rw, default 1)", float,
                min=0, max=1e6),
    "range_bias_m": Option("constant offset of every range (antenna delay), m; subtracted "
                           "(default 0)", float, min=-1e3, max=1e3),
    "anchor_bias": Option("1: estimate a range bias per anchor online (WiFi RTT offsets, "
                          "antenna delays), starting from a common offset fitted to the first "
                          "init_s seconds", bool),
    "bias_prior_std_m": Option("prior standard deviation of each anchor's bias about that "
                               "common offset, m (default 3)", float, min=0, min_exclusive=True,
                               max=1e3),
    **sigma_options(),
    "clock_offset_std_m_per_sqrt_s": Option("pseudoranges: white frequency noise of the "
                                            "receiver clock offset (times c), m/sqrt(s) "
                                            "(default 1)", float, min=0, max=1e6),
    "clock_drift_std_m_per_s_per_sqrt_s": Option("pseudoranges: random walk of the clock "
                                                 "drift (times c), m/s/sqrt(s) (default 1)",
                                                 float, min=0, max=1e6),
    "earth_rotation": Option("pseudoranges: 1 adds the Earth-rotation (Sagnac) term (default: "
                             "1 when the anchors are in ecef or wgs84 or --origin is given)",
                             bool),
    "tag_height_m": Option("known node height: track in 2-D (x, y) with 3-D anchors (default: "
                           "3-D tracking when the anchors have z)", float, min=-1e4, max=1e4),
    "gate": Option("drop a range whose squared innovation exceeds gate x its predicted "
                   "variance (default 16, i.e. 4 sigma; 0: no gating)", float, min=0, max=1e9),
    "smooth": Option("1: Rauch-Tung-Striebel smoothed track (offline; uses later ranges)",
                     bool),
    "prior_std_m": Option("standard deviation of the start position, m (default 2)", float,
                          min=0, min_exclusive=True, max=1e6),
    "init_s": Option("seconds of ranges whose medians fix the start position (default 2)",
                     float, min=0, max=1e6),
    "max_gap_s": Option("a gap longer than this between a node's ranges restarts its track "
                        "from a new start fix (default 5 s)", float, min=0, min_exclusive=True,
                        max=1e9),
    "tune": Option("1 (default): learn the noise of each kind, each anchor's range offset and "
                   "how its error wanders, and the process noise from the log, per node "
                   "(radioloc.locate.self_tuning; an option given is used as given); 0: the "
                   "fixed defaults", bool),
    "cooperative": Option("1: use ranges between nodes, each peer's latest estimate as a "
                          "moving anchor, its uncertainty along the line of sight added to the "
                          "range variance (default 0: such rows are left out)", bool),
    **ODOMETRY_OPTIONS,
}


def segments(times: np.ndarray, max_gap_s: float) -> list[slice]:
    """Slices of ``times`` split where consecutive times are more than ``max_gap_s`` apart.

    Parameters
    ----------
    times : ndarray, shape (T,)
        Sorted times.
    max_gap_s : float

    Returns
    -------
    list of slice
    """
    cuts = np.flatnonzero(np.diff(times) > max_gap_s) + 1
    edges = np.concatenate([[0], cuts, [times.size]])
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def tracker_settings(request: LocateRequest, anchors: np.ndarray) -> dict:
    """Options common to the trackers, with defaults, checked against the anchors.

    Parameters
    ----------
    request : LocateRequest
    anchors : ndarray, shape (M, 2) or (M, 3)

    Returns
    -------
    dict
        ``motion, q, height, dim, bias, smooth, prior_std, init_s, max_gap_s`` and
        ``odometry_std`` (None: the log has no odometry rows).

    Raises
    ------
    ConfigError
        ``motion`` or ``q`` given with odometry rows, ``odometry_std_m`` without them.
    """
    odometry = has_odometry(request.measurements)
    if odometry:
        for key in ("motion", "q"):
            if key in request.parsed or key in request.options:
                raise ConfigError(f"option {key}: the log holds odometry rows, which drive "
                                  "the motion (tune odometry_std_m instead)")
    elif "odometry_std_m" in request.parsed or "odometry_std_m" in request.options:
        raise ConfigError("option odometry_std_m: the log holds no odometry rows")
    yaw = bool((request.measurements["kind"] == "yaw_rate").any())
    kind = request.option("motion", "ca" if yaw else "cv", str)
    height = request.option("tag_height_m")
    if height is not None and anchors.shape[1] != 3:
        raise InputError("option tag_height_m: needs anchors with a z column")
    dim = 2 if (height is not None or anchors.shape[1] == 2) else 3
    return {"motion": kind, "q": request.option("q", 1.0),
            "height": height, "dim": dim, "bias": request.option("range_bias_m", 0.0),
            "smooth": bool(request.option("smooth", False, bool)),
            "prior_std": request.option("prior_std_m", 2.0),
            "init_s": request.option("init_s", 2.0),
            "max_gap_s": request.option("max_gap_s", MAX_GAP_S),
            "clock_offset_q": request.option("clock_offset_std_m_per_sqrt_s", 1.0),
            "clock_drift_q": request.option("clock_drift_std_m_per_s_per_sqrt_s", 1.0),
            "odometry_std": (request.option("odometry_std_m", ODOMETRY_STD_M) if odometry
                             else None)}


#: Settings of the start fit's :class:`LeastSquares`: a micrometre is close enough for a
#: start, and the Huber loss converges linearly once rows cross its corner (a pseudorange
#: log's start, its clock offset far from the initial 0, took up to 146 iterations).
START_FIT = {"tol": 1e-6, "max_iterations": 1000}


def start_state(times: np.ndarray, observations: list, anchors: np.ndarray, s: dict,
                anchor_bias: bool = False) -> tuple[np.ndarray, float]:
    """Start position (and common range offset) of a track.

    From the ranges when there are ranges to three anchors (:func:`start_position`, a
    global grid search); otherwise a robust least-squares fit
    (:class:`~radioloc.estimators.LeastSquares`, Huber loss) of every observation's median
    over the first ``init_s`` seconds.

    Parameters
    ----------
    times : ndarray, shape (T,)
    observations : list of Observation
    anchors : ndarray, shape (M, 2|3)
    s : dict
        From :func:`tracker_settings`.
    anchor_bias : bool
        Fit a common range offset too (the start of the per-anchor biases).

    Returns
    -------
    position : ndarray, shape (D,)
    offset_m : float
        The common range offset (``anchor_bias``) or the receiver clock offset (models
        that read ``clock_offset``), metres; 0 otherwise.
    """
    dim = s["dim"]
    ranges = [o for o in observations if o.model.kind == "range"]
    if ranges and (np.isfinite(ranges[0].z).any(axis=0).sum() >= 3 or len(observations) == 1):
        R = np.full((times.size, len(anchors)), np.nan)
        R[:, ranges[0].context.index] = ranges[0].z
        fit = start_position(times, R, anchors, s["height"], s["bias"], s["init_s"],
                             common_offset=anchor_bias)
        xy, offset = fit if anchor_bias else (fit, 0.0)
        pos = np.zeros(dim)
        pos[:2] = xy
        if dim == 3:
            pos[2] = float(np.mean(anchors[:, 2]))
        return pos, offset
    window = times <= times[0] + s["init_s"]
    own = {n for n, k in declared_kinds().items() if k.self_measured}
    observations = [o for o in observations if o.model.kind not in own]
    moving = any(o.moving for o in observations)
    if moving:                              # moving anchors: the fullest epoch of the window
        rows = sum(np.isfinite(o.z[window]).sum(axis=-1) for o in observations)
        k = int(np.argmax(rows))
        medians = [Observation(o.model, *o.at(k), no_check=o.no_check) for o in observations]
    else:
        medians = [replace(o, z=column_medians(o.z[window], o.model.angular), std=None) for o in observations]
    # one epoch's rows of moving anchors (satellites far away): plain least squares, which
    # converges from the Earth's centre where the Huber loss's reweighting can stall
    fit = LeastSquares(loss="linear" if moving else "huber", **START_FIT).locate(medians)
    if not bool(np.all(fit.converged)) or not np.all(np.isfinite(fit.position)):
        raise GeometryError("the measurements of the first init_s seconds do not fix a start "
                            "position (give -o init_s=SECONDS longer)")
    clock = 0.0
    if any("clock_offset" in o.model.reads for o in observations):
        clock = float(np.asarray(fit.diagnostics["state"])[..., dim])   # after the position
    return np.asarray(fit.position, dtype=float), clock


def tracker_motion(s: dict):
    """The motion model of a track: the odometry's (``s["odometry_std"]`` set) or option
    ``motion``'s.

    Parameters
    ----------
    s : dict
        From :func:`tracker_settings`.

    Returns
    -------
    motion model
    """
    if s.get("odometry_std") is not None:
        return odometry_motion(s["odometry_std"], s["dim"])
    return motion_model(s["motion"], s["q"], s["dim"])


def tracker_filter(anchors: np.ndarray, s: dict, gate: float | None, anchor_bias: bool = False,
                   bias_prior_std_m: float = 3.0, clock: bool = False,
                   bias_std_m_per_sqrt_s=0.0, bias_time_constant_s=None,
                   bias_terms: int = 1) -> ExtendedKalmanFilter:
    """The generic :class:`ExtendedKalmanFilter` the trackers run (motion model of ``s``).

    Parameters
    ----------
    anchors : ndarray, shape (M, 2|3)
    s : dict
        From :func:`tracker_settings`.
    gate : float or None
    anchor_bias : bool
        A range bias per anchor in the state.
    bias_prior_std_m : float
    clock : bool
        The receiver's clock offset and drift in the state (pseudoranges).
    bias_std_m_per_sqrt_s, bias_time_constant_s : float or ndarray, optional
        How the anchor biases wander (:class:`ExtendedKalmanFilter`; default constant).
    bias_terms : {1, 2}
        Bias states per anchor (:class:`~radioloc.models.ranging.RangeModel`).

    Returns
    -------
    ExtendedKalmanFilter
    """
    dim = s["dim"]
    motion = tracker_motion(s)
    return ExtendedKalmanFilter(motion, gate=gate, bias_prior_std_m=bias_prior_std_m,
                                bias_std_m_per_sqrt_s=bias_std_m_per_sqrt_s,
                                bias_time_constant_s=bias_time_constant_s,
                                layout=StateLayout(dim=dim, order=motion.state_dim // dim - 1,
                                                   clock=2 if clock else 0,
                                                   n_bias=len(anchors) * bias_terms
                                                   if anchor_bias else 0),
                                clock_drift_prior_std_m_per_s=CLOCK_DRIFT_PRIOR_STD,
                                clock_offset_std_m_per_sqrt_s=s.get("clock_offset_q", 1.0),
                                clock_drift_std_m_per_s_per_sqrt_s=s.get("clock_drift_q", 1.0))


def reads_clock(observations: list) -> bool:
    """Whether a model of ``observations`` reads the receiver clock offset."""
    return any("clock_offset" in o.model.reads for o in observations)


def track_prior(ekf: ExtendedKalmanFilter, times: np.ndarray, observations: list,
                anchors: np.ndarray, s: dict, anchor_bias: bool = False
                ) -> tuple[np.ndarray, np.ndarray]:
    """Prior mean and variances of one track (see the module docstring for the start).

    Parameters
    ----------
    ekf : ExtendedKalmanFilter
        From :func:`tracker_filter`.
    times : ndarray, shape (T,)
    observations : list of Observation
    anchors : ndarray, shape (M, 2|3)
    s : dict
        From :func:`tracker_settings`.
    anchor_bias : bool

    Returns
    -------
    mean, var : ndarray, shape (n,)
        Over the filter's state layout for ``observations``.
    """
    dim = s["dim"]
    pos, offset = start_state(times, observations, anchors, s, anchor_bias)
    layout = ekf.state_layout(observations)
    mean = np.zeros(layout.size)
    var = np.full(layout.size, PRIOR_SPEED_STD ** 2)
    mean[:dim] = pos
    var[:dim] = s["prior_std"] ** 2
    extra = slice(layout.motion_size, layout.size)
    var[extra] = ekf.init(np.zeros(layout.motion_size), np.eye(layout.motion_size),
                          observations=observations).covariance.diagonal()[extra]
    if "anchor_bias" in layout.slices:
        mean[layout.slices["anchor_bias"]] = offset
    elif "clock_offset" in layout.slices:          # a pseudorange receiver's clock
        mean[layout.slices["clock_offset"]] = offset
    return mean, var


def track_priors(ekf: ExtendedKalmanFilter, tracks: list[tuple[str | None, np.ndarray, list]],
                 anchors: np.ndarray, s: dict, anchor_bias: bool = False
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Stacked priors of several tracks (:func:`track_prior` of each), for one batch.

    Parameters
    ----------
    ekf : ExtendedKalmanFilter
    tracks : list of (label, times (T_b,), observations)
        ``label`` leads the message of a start that fails (``None``: the error as raised).
    anchors : ndarray, shape (M, 2|3)
    s : dict
        From :func:`tracker_settings`.
    anchor_bias : bool

    Returns
    -------
    prior_mean : ndarray, shape (B, n)
    prior_cov : ndarray, shape (B, n, n)

    Raises
    ------
    GeometryError
        The start window of a track does not fix a start position.
    """
    means, variances = [], []
    for label, times, obs in tracks:
        try:
            mean, var = track_prior(ekf, times, obs, anchors, s, anchor_bias)
        except GeometryError as exc:
            if label is None:
                raise
            raise GeometryError(f"{label}: {exc}") from None
        means.append(mean)
        variances.append(var)
    return np.stack(means), np.stack([np.diag(v) for v in variances])


def run_tracker(times: np.ndarray, observations: list, anchors: np.ndarray, s: dict,
                gate: float | None, smooth: bool, anchor_bias: bool = False,
                bias_prior_std_m: float = 3.0, controls: np.ndarray | None = None):
    """One node's track by the generic :class:`ExtendedKalmanFilter` over its observations
    (any kinds; see the module docstring for the start).

    Parameters
    ----------
    times : ndarray, shape (T,)
    observations : list of Observation
        ``z`` of shape ``(T, S)``.
    anchors : ndarray, shape (M, 2|3)
    s : dict
        From :func:`tracker_settings`.
    gate : float or None
    smooth : bool
    anchor_bias : bool
        Estimate a per-anchor range bias (the range model must read ``anchor_bias``).
    bias_prior_std_m : float
    controls : ndarray, shape (T, D), optional
        Odometry displacement over each step (row 0 zero), with ``s["odometry_std"]``.

    Returns
    -------
    Track
    """
    ekf = tracker_filter(anchors, s, gate, anchor_bias, bias_prior_std_m, reads_clock(observations))
    mean, var = track_prior(ekf, times, observations, anchors, s, anchor_bias)
    return ekf.run(observations, times, prior_mean=mean, prior_cov=np.diag(var),
                   controls=controls, smooth=smooth)


def stack_tracks(times: list[np.ndarray], observations: list[list[Observation]]
                 ) -> tuple[np.ndarray, list[Observation]]:
    """Tracks as one batch for :meth:`ExtendedKalmanFilter.run`, aligned by step index.

    Each track keeps its own times (the batch's time array is ``(B, T)``); a shorter track
    is padded at its end with its last time (a step of zero length) and absent rows, which
    leave its state unchanged. The rows of each kind are the union of the tracks' slots
    (anchor, reference anchor); a slot a track does not have is absent (NaN) in it, which
    the update skips. A slot keeps its anchor-file columns (``Context.columns``). Rows of a
    step are independent and the kinds come in the order of their names (as each track's
    own observations come), so each track's result equals its own run.

    Parameters
    ----------
    times : list of ndarray, shape (T_b,)
    observations : list of list of Observation
        Per track, ``z`` of shape ``(T_b, S)``; the same model for a kind in every track.

    Returns
    -------
    times : ndarray, shape (B, T)
        ``T = max T_b``.
    observations : list of Observation
        One per kind, ``z`` and ``std`` of shape ``(B, T, S)``.
    """
    B, T = len(times), max(t.size for t in times)
    t = np.empty((B, T))
    for b, tb in enumerate(times):
        t[b, :tb.size], t[b, tb.size:] = tb, tb[-1]
    kinds: dict[str, list] = {}
    for b, obs in enumerate(observations):
        for o in obs:
            kinds.setdefault(o.model.kind, []).append((b, o))
    out = []
    for _, members in sorted(kinds.items()):
        slots: dict[tuple[int, int], int] = {}
        for _, o in members:
            ctx = o.context
            ref = (ctx.reference_index if ctx.reference_index is not None
                   else np.full(ctx.rows, -1))
            for key in zip(ctx.index.tolist(), ref.tolist()):
                slots.setdefault(key, len(slots))
        z = np.full((B, T, len(slots)), np.nan)
        std = np.full_like(z, np.nan) if any(o.std is not None for _, o in members) else None
        moving = any(o.moving for _, o in members)   # points (B, T, S, P): per track and step
        points = np.zeros(((B, T) if moving else ()) + (len(slots),)
                          + members[0][1].context.points.shape[-1:])
        reference = None if members[0][1].context.reference is None else np.zeros_like(points)
        group = None if members[0][1].context.group is None else np.zeros(len(slots), dtype=int)
        columns = {c: np.full(len(slots), np.nan) for c in members[0][1].context.columns or {}}
        for b, o in members:
            ctx = o.context
            ref = (ctx.reference_index if ctx.reference_index is not None
                   else np.full(ctx.rows, -1))
            cols = np.array([slots[k] for k in zip(ctx.index.tolist(), ref.tolist())], dtype=int)
            z[b, :o.steps, cols] = o.z.T
            if o.std is not None:
                std[b, :o.steps, cols] = o.std.T
            for whole, part in ((points, ctx.points), (reference, ctx.reference)):
                if whole is None:
                    continue
                if not moving:
                    whole[cols] = part
                    continue
                track = np.broadcast_to(part, (o.steps,) + part.shape[-2:])
                whole[b, :o.steps, cols] = np.swapaxes(track, 0, 1)
                whole[b, o.steps:] = whole[b, o.steps - 1]      # padded steps: the last
            if group is not None:
                group[cols] = ctx.group
            for c, v in columns.items():
                v[cols] = ctx.columns[c]
        first = members[0][1].context
        keys = np.array(list(slots), dtype=int).reshape(-1, 2)
        ctx = Context(points=points, index=keys[:, 0],
                      reference=reference,
                      reference_index=None if first.reference_index is None else keys[:, 1],
                      height_m=first.height_m, columns=columns or None, group=group)
        out.append(Observation(members[0][1].model, z, ctx, std,
                               no_check=members[0][1].no_check))
    return t, out


def run_ekf(times, R, anchors, s: dict, range_std: float, gate: float | None, smooth: bool):
    """One node's range-only track (:func:`run_tracker` on a ``(T, M)`` range array).

    Parameters
    ----------
    times : ndarray, shape (T,)
    R : ndarray, shape (T, M)
    anchors : ndarray, shape (M, 2|3)
    s : dict
        From :func:`tracker_settings`.
    range_std : float
    gate : float or None
    smooth : bool

    Returns
    -------
    Track
    """
    obs = Observation(RangeModel(std_m=range_std), np.asarray(R, dtype=float) - s["bias"],
                      Context(points=anchors, index=np.arange(len(anchors)), height_m=s["height"]))
    return run_tracker(times, [obs], anchors, dict(s, bias=0.0, odometry_std=None), gate, smooth)


def observation_window(obs: Observation, seg: slice) -> Observation:
    """The steps ``seg`` of one node's observation (``z`` ``(T, S)``; moving anchors'
    points ``(T, S, D)`` are cut to the same steps; its other fields kept)."""
    ctx = obs.context

    def cut(a):
        return a if a is None or a.ndim < 3 else a[seg]
    if cut(ctx.points) is not ctx.points or cut(ctx.reference) is not ctx.reference:
        ctx = replace(ctx, points=cut(ctx.points), reference=cut(ctx.reference))
    return replace(obs, z=obs.z[seg], context=ctx, std=None if obs.std is None else obs.std[seg])


def start_screened(times: np.ndarray, obs: Observation, init_s: float) -> Observation:
    """``obs`` without the angles of its start window that are reflections.

    A track's first update comes from a prior ``prior_std_m`` wide, so the innovation gate
    of an angle is wide there too (a radian and more at a few metres), and a reflection (an
    angle anywhere on the circle) at the first steps can pass it and throw the track metres
    off. In the first ``init_s`` seconds an angle further than ``START_SIGMAS`` times its
    column's spread (1.4826 times the median absolute deviation from the column's circular
    median, at least the model's sigma) from that median is left out (absent, like a
    missing row). Other kinds, whose errors are bounded by the prior's spread, are kept.

    Parameters
    ----------
    times : ndarray, shape (T,)
    obs : Observation
        ``z`` of shape ``(T, S)``.
    init_s : float

    Returns
    -------
    Observation
    """
    if not obs.model.angular:
        return obs
    window = times <= times[0] + init_s
    w = obs.z[window]
    heard = np.isfinite(w).any(axis=0)
    dev = np.full_like(w, np.nan)
    dev[:, heard] = np.abs(wrap_angle(w[:, heard] - column_medians(w[:, heard], angular=True)))
    spread = np.full(w.shape[1], np.inf)
    spread[heard] = np.maximum(1.4826 * np.nanmedian(dev[:, heard], axis=0),
                               obs.model.std(obs.context)[heard])
    far = np.zeros(obs.z.shape, dtype=bool)
    far[window] = dev > START_SIGMAS * spread
    if not far.any():
        return obs
    return replace(obs, z=np.where(far, np.nan, obs.z))


def track_window(times: np.ndarray, observations: list, seg: slice, init_s: float) -> list:
    """The observations of one track: the steps ``seg`` (:func:`observation_window`), the
    reflections of the start window left out (:func:`start_screened`)."""
    return [start_screened(times[seg], observation_window(o, seg), init_s)
            for o in observations]


def segment_tracks(parts, s: dict) -> list[tuple[str, np.ndarray, list]]:
    """``(node, times, observations)`` of every segment (:func:`segments`) of every node of
    ``parts`` (``(node, times, observations)`` each), each as :func:`track_window` gives it:
    the tracks the settings are learned from.

    Parameters
    ----------
    parts : iterable of (node, times (T,), observations)
    s : dict
        From :func:`tracker_settings`.

    Returns
    -------
    list of (node, times, observations)
    """
    return [(node, times[seg], track_window(times, obs, seg, s["init_s"]))
            for node, times, obs in parts for seg in segments(times, s["max_gap_s"])]


def track_table(node, times, track, restart: bool = False) -> pd.DataFrame:
    """Rows ``time, node, x, y[, z], uncertainty_m, cov_*`` and flags of one node's track.

    Parameters
    ----------
    node : str
    times : ndarray, shape (T,)
    track : Track
        With ``diagnostics["gated"]`` (ranges refused by the gate at each step) and
        ``diagnostics["p_nlos"]`` when the tracker has them.
    restart : bool
        The track starts again after a gap (flag ``restart`` on its first row).

    Returns
    -------
    DataFrame
        Flags: ``gated`` (int), ``restart`` (0/1), ``p_nlos`` where known.
    """
    return pd.DataFrame(track_columns(node, times, track, restart))


def track_columns(node, times, track, restart: bool = False) -> dict[str, np.ndarray]:
    """The columns of :func:`track_table`, in order (without building the table)."""
    out = {"time": times, "node": node}
    for k, c in enumerate("xyz"[: track.position.shape[-1]]):
        out[c] = track.position[:, k]
    out.update(covariance_columns(track.covariance))
    if "gated" in track.diagnostics:
        out["gated"] = np.asarray(track.diagnostics["gated"], dtype=np.int64)
    flag = np.zeros(len(times), dtype=np.int64)
    flag[:1] = int(restart)
    out["restart"] = flag
    if "p_nlos" in track.diagnostics:
        out["p_nlos"] = np.asarray(track.diagnostics["p_nlos"], dtype=float)
    return out


def track_summary(tables: list[pd.DataFrame], per_node: list, **extra) -> dict:
    """Counts of a tracker's run for ``summary.json``.

    Parameters
    ----------
    tables : list of DataFrame
        From :func:`track_table`.
    per_node : list of (node, times, ranges)
        From :func:`radioloc.locate.adapter.anchor_ranges`.
    **extra
        Further entries.

    Returns
    -------
    dict
        ``nodes``, ``ranges`` (to anchors, after averaging duplicates), ``ranges_used``,
        ``ranges_gated``, ``steps``, ``restarts`` and ``extra``.
    """
    frame = pd.concat(tables, ignore_index=True)
    ranges = int(sum(np.isfinite(R).sum() for _, _, R in per_node))
    gated = int(frame["gated"].sum()) if "gated" in frame else 0
    return {"nodes": len(per_node), "ranges": ranges, "ranges_used": ranges - gated,
            "ranges_gated": gated, "steps": len(frame),
            "restarts": int(frame["restart"].sum()), **extra}


@locate_method("ekf-track", "Extended Kalman filter tracking each node from its measurements "
                            "to anchors as they arrive: every kind with a model (ranges "
                            "optionally with a bias per anchor), RSS (a "
                            "path-loss model per anchor in the anchors file), ranges between "
                            "nodes with -o cooperative=1 (constant velocity or random walk, "
                            "or driven by odometry rows; RTS smoother with -o smooth=1)",
               options=OPTIONS, kinds=TRACKER_KINDS, inputs=("anchors",), moving_anchors=True)
def locate_ekf_track(request: LocateRequest) -> pd.DataFrame:
    """Track every node with the generic :class:`ExtendedKalmanFilter` over its rows.

    Each kind present gets its model (:func:`radioloc.locate.adapter.default_models`);
    ``-o anchor_bias=1`` adds a range bias per anchor to the state.

    Parameters
    ----------
    request : LocateRequest
        Measurements, anchors, ``-o`` options (see :data:`OPTIONS`).

    Returns
    -------
    DataFrame
        ``time, node, x, y[, z], uncertainty_m``, covariance columns, flags ``gated``
        (measurements refused by the gate) and ``restart`` (first row after a gap): one row
        per time stamp at which the node has a measurement (the filtered state, or the
        smoothed one with ``smooth=1``).
    """
    out, diverged, n_tracks, noise = track_log(request, request.measurements)
    if diverged:
        skipped = request.parsed.get("no_check")     # None: check_log did not run
        bounded = () if skipped is None else [k for k, name in value_checks().items()
                                              if name not in skipped]
        # a unit is blamed only when looser sigmas do not make the log fit either
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                loose = looser_noise(request)
                noisy = not track_log(loose, loose.measurements)[1]
        except RadiolocError:
            noisy = False
        slip = likely_slip(request.measurements,
                           lambda log: not track_log(request, log)[1], bounded=bounded,
                           scales=not noisy,
                           fit_scale=lambda log, kinds: snapshot_scale(request, log, kinds))
        if slip is not None:
            kinds, how, question = slip
            raise InputError(f"method ekf-track: the {kinds} rows fit no track ({len(diverged)} "
                             f"of {n_tracks} diverged) but do once {how}: {question}")
        stated = noise_in_force(request.measurements, noise)
        given = [k for k in noise if request.option(k) is not None]
        cause = ({"cause": "rows the noise learned from the log (summary 'learned') does not "
                           "describe: NLOS? (a LOS/NLOS model: --method smoother or pf)"}
                 if "learned" in out.attrs["summary"] and not given else {})
        out.attrs["summary"]["innovations"] = [   # warned by the health check (base.run_method)
            {"node": node, "start": t0, "noise": stated, **cause, **sign}
            for node, t0, sign in diverged]
    return out


def looser_noise(request: LocateRequest) -> LocateRequest:
    """The request with every sigma in force (given or default, of each kind the log holds,
    and the odometry's, and each row's own ``std``) times :data:`NOISE_SLACK`: a log that
    fits no track with the stated noise but does with this one may have diverged by its
    noise, and no unit slip is named (a sign or a convention still is)."""
    kinds = set(request.measurements["kind"].unique())
    looser = {}
    for kind in kinds & set(model_kinds()):
        k = model_kinds()[kind]
        looser[k.sigma_option] = NOISE_SLACK * float(request.option(k.sigma_option,
                                                                    k.sigma_default))
    if has_odometry(request.measurements):
        looser["odometry_std_m"] = NOISE_SLACK * request.option("odometry_std_m", ODOMETRY_STD_M)
    meas = request.measurements
    if "std" in meas.columns:
        meas = meas.assign(std=NOISE_SLACK * meas["std"])
    return replace(request, measurements=meas, parsed={**request.parsed, **looser})


def log_models(request: LocateRequest, meas: pd.DataFrame, table: pd.DataFrame, s: dict,
               anchor_bias: bool = False) -> tuple[Measurements, dict, dict]:
    """The log, the noise options in force and the measurement model of each kind it holds
    (:func:`radioloc.locate.adapter.default_models`; RSS with a path-loss model per anchor
    from the anchors file), for the trackers.

    Parameters
    ----------
    request : LocateRequest
    meas : DataFrame
        The measurements.
    table : DataFrame
        The anchors table.
    s : dict
        From :func:`tracker_settings`.
    anchor_bias : bool
        Range models with a bias per anchor.

    Returns
    -------
    log : Measurements
    noise : dict
        The sigma options in force (``range_std_m`` at least).
    models : dict
        Kind to model.

    Raises
    ------
    ConfigError
        A model that reads velocity (heading rows) with a motion model that has none
        (``motion=rw``, odometry), naming both.
    """
    log = Measurements(meas)
    opts = given_sigmas(request)
    opts.setdefault("range_std_m", RANGE_STD_M)
    models = default_models(log.kinds, opts, anchor_bias=anchor_bias,
                            settings=frame_settings(request))
    motion = tracker_motion(s)
    for model in models.values():
        check_motion(model, motion)
    if "rss" in log.kinds:   # one path-loss model per anchor, from the anchors file
        models["rss"] = anchor_rss_model(table, meas.loc[meas["kind"] == "rss", "peer"])
    return log, opts, models


def _log_tracks(request: LocateRequest, meas: pd.DataFrame) -> SimpleNamespace:
    """The tracks of the log ``meas`` and the settings they run with (the first part of
    :func:`track_log`): ``table``, ``anchors``, ``s`` (:func:`tracker_settings`), ``gate``,
    ``anchor_bias``, ``given``, ``tune`` (the settings are learned), ``short`` (why not,
    where the log cannot teach them), ``meas`` (less ``range_bias_m``), ``opts`` (the noise
    in force), ``parts`` (per node) and ``tracks`` ``(node, times, observations, restart,
    controls)``."""
    table = request.require_anchors("ekf-track")
    anchors = anchor_positions(table)
    s = tracker_settings(request, anchors)
    given = given_sigmas(request)
    tune = (request.option("tune", True, bool) and s["odometry_std"] is None
            and not request.option("cooperative", False, bool))
    short = not_learnable(meas, given) if tune else None
    tune = tune and short is None
    if s["bias"]:
        meas = meas.assign(value=np.where(meas["kind"] == "range", meas["value"] - s["bias"],
                                          meas["value"]))
    anchor_bias = bool(request.option("anchor_bias", False, bool))
    log, opts, models = log_models(request, meas, table, s, anchor_bias or (
        tune and "range_std_m" not in given and bool((meas["kind"] == "range").any())))
    parts = [(node, times, obs, segments(times, s["max_gap_s"])) for node, times, obs
             in log_observations(log, table, models, "ekf-track", s["height"])]
    tracks = []
    for node, times, obs, segs in parts:
        for n, seg in enumerate(segs):
            controls = (None if s["odometry_std"] is None else
                        odometry_controls(meas, node, times[seg], s["dim"]))
            tracks.append((node, times[seg], track_window(times, obs, seg, s["init_s"]), n > 0,
                           controls))
    return SimpleNamespace(table=table, anchors=anchors, s=s, gate=request.option("gate", 16.0)
                           or None, anchor_bias=anchor_bias, given=given, tune=tune,
                           short=short, meas=meas, opts=opts, parts=parts, tracks=tracks)


def learn_log(request: LocateRequest) -> tuple[dict, str | None]:
    """The settings ``ekf-track`` learns from the log of ``request`` (as :func:`track_log`
    learns them; for a run that tracks in chunks, :mod:`radioloc.locate.chunked`).

    Returns
    -------
    learned : dict of node to Learned
        Empty where nothing is learned.
    short : str or None
        Why the log cannot teach them (None: it can, or ``tune=0``).
    """
    k = _log_tracks(request, request.measurements)
    if not k.tune:
        return {}, k.short
    return learn_tracks(request, [tr[:3] for tr in k.tracks], k.table, k.s, k.gate,
                        k.given), None


def track_log(request: LocateRequest, meas: pd.DataFrame):
    """Every node's track from the log ``meas`` (the body of ``locate --method ekf-track``).

    Parameters
    ----------
    request : LocateRequest
        Anchors and options.
    meas : DataFrame
        The measurements (the request's, or a copy with one kind's values mapped).

    Returns
    -------
    out : DataFrame
        The tracks' rows, with ``attrs["summary"]``.
    diverged : list of (node, start time, dict)
        The tracks :func:`divergence` flags.
    n_tracks : int
    noise : dict
        The noise options in force.
    """
    k = _log_tracks(request, meas)
    table, anchors, s, gate, anchor_bias = k.table, k.anchors, k.s, k.gate, k.anchor_bias
    meas, opts, parts, tracks, short = k.meas, k.opts, k.parts, k.tracks, k.short
    clock = any(reads_clock(tr[2]) for tr in tracks)
    bias_prior = request.option("bias_prior_std_m", 3.0)
    peers = (peer_ranges(meas, table["id"]) if request.option("cooperative", False, bool)
             else None)
    learned = {}
    if k.tune:               # each node's settings from its own rows (locate.self_tuning)
        learned = learn_tracks(request, [tr[:3] for tr in tracks], table, s, gate, k.given)
        tracks = [(node, t, tuned_observations(o, learned[node]), r, c)
                  for node, t, o, r, c in tracks]
    # one filter per form of state: the learned settings differ per node, each batch member
    # (a track) takes its node's (process noise, anchor-bias wander and start; the learned
    # range offsets come off its ranges, so that one range model serves the batch)
    wander = [b for b, tr in enumerate(tracks)
              if tr[0] in learned and learned[tr[0]].offset_m is not None]
    groups = [g for g in (wander, [b for b in range(len(tracks)) if b not in set(wander)]) if g]
    rows = sum(int(np.isfinite(o.z).sum()) for tr in tracks for o in tr[2])
    results: dict[int, object] = {}
    with progress(rows + (len(peers) if peers is not None else 0), "ekf-track") as bar:
        for group in groups:
            mine = [tracks[b] for b in group]
            lrs = [learned.get(tr[0]) for tr in mine]
            q = np.array([s["q"] if lr is None else lr.q for lr in lrs])[:, None]   # (B, steps)
            if group is wander:
                bias = [lr.bias_settings() for lr in lrs]
                ekf = tracker_filter(anchors, dict(s, q=q), gate, True, bias_prior, clock,
                                     np.stack([b[0] for b in bias])[:, None, :],
                                     np.stack([b[1] for b in bias])[:, None, :], bias_terms=2)
                priors = [tuned_prior(ekf, tr[1], tr[2], anchors, s, b[2])
                          for tr, b in zip(mine, bias)]
                prior_mean = np.stack([p[0] for p in priors])
                prior_cov = np.stack([p[1] for p in priors])
                mine = [(node, t, offsets_taken_off(o), r, c) for node, t, o, r, c in mine]
            else:
                ekf = tracker_filter(anchors, dict(s, q=q), gate, anchor_bias, bias_prior, clock)
                prior_mean, prior_cov = track_priors(   # ranges already without range_bias_m
                    ekf, [(f"method ekf-track: node {node!r} from time {float(times[0])!r}",
                           times, obs) for node, times, obs, _, _ in mine], anchors,
                    dict(s, bias=0.0), anchor_bias)
            coop = None
            if peers is not None and len(peers):
                if s["odometry_std"] is not None:
                    raise ConfigError("option cooperative: not with odometry rows")
                coop = cooperative_batch([tr[:3] for tr in mine], peers,
                                         RangeModel(std_m=opts["range_std_m"]), s["dim"])
                t, batch = coop.time, coop.observations
            else:
                t, batch = stack_tracks([tr[1] for tr in mine], [tr[2] for tr in mine])
            controls = None
            if s["odometry_std"] is not None:   # padded steps: zero length, no displacement
                controls = np.zeros(t.shape + (s["dim"],))
                for b, tr in enumerate(mine):
                    controls[b, : tr[1].size] = tr[4]
            track = ekf.run(batch, t, prior_mean=prior_mean, prior_cov=prior_cov,
                            controls=controls, smooth=s["smooth"],
                            coupling=None if coop is None else coop.coupling,
                            on_step=bar.advance)
            for k, b in enumerate(group):
                results[b] = (track[k, :tracks[b][1].size] if coop is None
                              else coop.track_of(track, k))
    tables, diverged = [], []
    for b, (node, times, _, restart, _) in enumerate(tracks):
        one = results[b]
        tables.append(track_table(node, times, one, restart=restart))
        sign = divergence(one, anchors, gate)
        if sign is not None:
            diverged.append((node, float(times[0]), sign))
    out = pd.concat(tables, ignore_index=True).sort_values(["time", "node"], kind="stable")
    out = out.reset_index(drop=True)
    counts: dict[str, int] = {}
    for _, _, obs, _ in parts:
        for o in obs:
            counts[o.model.kind] = counts.get(o.model.kind, 0) + int(np.isfinite(o.z).sum())
    out.attrs["summary"] = {
        "nodes": len(parts), "ranges": counts.get("range", 0), "measurements": counts,
        "measurements_gated": int(out["gated"].sum()) if "gated" in out else 0,
        "steps": len(out), "restarts": int(out["restart"].sum()),
        "range_std_m": opts["range_std_m"], "gate": gate or 0.0, "anchor_bias": anchor_bias,
        "odometry_std_m": s["odometry_std"], "tracks_diverged": len(diverged)}
    if learned:
        out.attrs["summary"]["learned"] = {str(n): lr.report for n, lr in learned.items()}
    if short:
        out.attrs["summary"]["tune"] = short
    return out, diverged, len(tables), opts


def learn_tracks(request: LocateRequest, tracks: list, table: pd.DataFrame, s: dict,
                 gate: float | None, given: dict) -> dict:
    """Each node's settings learned from its own tracks (:func:`learn_nodes`, with the
    trackers' filter and start; every node's runs in one batch).

    Parameters
    ----------
    request : LocateRequest
    tracks : list of (node, times (T,), observations)
    table : DataFrame
        The anchors table.
    s : dict
        From :func:`tracker_settings`.
    gate : float or None
    given : dict
        The sigma options given.

    Returns
    -------
    dict of node to Learned
    """
    anchors = anchor_positions(table)
    ids = [str(a) for a in table["id"]]
    clock = any(reads_clock(tr[2]) for tr in tracks)
    bias_prior = request.option("bias_prior_std_m", 3.0)
    nodes: dict = {}
    for node, times, obs in tracks:
        nodes.setdefault(node, []).append((times, obs))
    return learn_nodes(
        nodes,
        lambda q, bs, tau, terms: tracker_filter(anchors, dict(s, q=q), gate, terms > 0,
                                                 bias_prior, clock, bs, tau, terms),
        lambda ekf, t, o, bv: tuned_prior(ekf, t, o, anchors, s, bv), gate, given,
        s["q"], ids, s["dim"], q_given=request.option("q") is not None)


def tuned_prior(ekf, times, observations, anchors, s, bias_cov):
    """:func:`track_prior` of a self-tuned track, with its covariance: ``bias_cov`` None, the
    anchor biases about a common offset (the start's fit); else about 0 (the learned offsets
    are in the range model) with covariance ``bias_cov``."""
    sl = ekf.state_layout(observations).slices.get("anchor_bias")
    mean, var = track_prior(ekf, times, observations, anchors, dict(s, bias=0.0),
                            sl is not None)
    cov = np.diag(var)
    if bias_cov is not None and sl is not None:
        mean[sl] = 0.0
        cov[sl, sl] = bias_cov
    return mean, cov
