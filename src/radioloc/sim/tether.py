"""Tethering world of paper 003 (Sect. IV, Algorithm 4; Sect. V), batched over runs.

A tracker robot localizes and follows a trackee on a 2-D office floor whose walls attenuate
the RSS (:mod:`radioloc.channel.indoor_rss`). Both are point robots that start at random
global poses; each keeps odometry in its own local frame (origin and heading at its start),
so the two frames differ by an unknown rotation and translation. The tracker's estimator is
*injected*: any object with the :class:`Tracker` interface (the experiment passes
the grid filter ``GridFilter`` of the estimators layer); its frame is the tracker's local frame. Every
step of ``dt_s`` runs Algorithm 4 once for all runs:

1. the trackee moves (only once the tracker has localized it, as in Sect. V) and reports
   its odometry pose ``s_b``;
2. prediction: frames synchronised: the trackee's odometry step rotated into the tracker's
   frame with the compass headings is a known shift (ShiftGrid), plus the tracker's own
   blur ``gamma``; otherwise an extra blur of ``|step|`` (BlurGrid(|step| + gamma));
3. the tracker's estimate (GetLocation / GetUncertainty): below ``v`` the tracker drives
   toward it (and, with a compass, synchronises the frames once within ``delta``),
   otherwise ExploreGrid;
4. update with a new RSSI reading (ProbabilityUpdate).

The radio: the channel gives the received power in dBm; the tracker's radio reports it on
the paper's 0..100 RSSI scale (:func:`read_rssi`, the sensor quantiser
:func:`radioloc.models.rssi_trapezoid.dbm_to_rssi100`).

Inter-robot information sharing. The paper's (Sect. IV, Algorithm 4's ReceiveTrackeePose):
the trackee sends its odometry pose every step, which sets the blur before the frames are
synchronised and the shift after; ``TetherParams.share_odometry = False`` is the world
without it (the tracker knows only the trackee's top speed and blurs by
``speed_trackee dt`` every step). Beyond the paper (its conclusion names more than two nodes
as future work): ``trackers = M > 1`` robots track the same trackee as a team. They start
in a known formation (tracker ``j`` uniform within ``team_start_m`` of tracker 0, random
heading; the relative initial poses are known to the team) and, with ``share_readings``,
each tracker also applies every team-mate's RSSI reading of the step (ProbabilityUpdate
centred on the team-mate's odometry position carried into its own frame through the known
initial poses): the team-mates' likelihood grids multiplied into its own, each reading
counted once. Sharing whole posteriors instead would multiply in the same readings again
at every step. The trackee starts moving once any tracker has localized it.

Choices the paper leaves open (all in :class:`TetherParams`): the channel, robot speeds,
odometry noise model, the exploration pattern (random waypoints around the tracker's origin),
the trackee's motion (random waypoints on the floor), the tracker's stand-off distance, and
that after synchronisation the compass keeps giving both headings (noisy) every step.
Robots pass through walls (walls only attenuate); positions are clipped to the floor.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from radioloc.channel.indoor_rss import IndoorChannel, office_walls
from radioloc.core.errors import ConfigError
from radioloc.core.results import Estimate, Track, track_from_steps
from radioloc.models.rssi_trapezoid import dbm_to_rssi100


class Tracker(Protocol):
    """What the tethering world needs from the tracker's estimator (injected).

    The grid filter ``GridFilter`` (estimators layer) has this interface. The world calls, every
    step, ``predict``, then ``estimate`` (the behaviour acts on the predicted belief), then
    ``update`` with the new reading, then ``estimate`` again (recorded). A plain ``step``
    (predict and update at once) would not do: Algorithm 4 acts between the two.

    Attributes
    ----------
    (none required; any object with the four methods below)
    """

    def init(self, batch: int) -> Any:
        """State of ``batch`` runs before any reading.

        Parameters
        ----------
        batch : int
            Number of runs B.

        Returns
        -------
        object
            The tracker's state (opaque to the world).
        """

    def predict(self, state: Any, *, dt: float, shift_m: np.ndarray,
                extra_blur_m: np.ndarray) -> Any:
        """Predict over ``dt``.

        Parameters
        ----------
        state : object
            Current state.
        dt : float
            Step length, seconds.
        shift_m : ndarray, shape (B, 2)
            Known displacement of the trackee in the tracker's frame, metres.
        extra_blur_m : ndarray, shape (B,)
            Radius of an unknown displacement of the trackee, metres.

        Returns
        -------
        object
            The predicted state.
        """

    def update(self, state: Any, tracker_xy: np.ndarray, rssi: np.ndarray) -> Any:
        """Update with one RSSI reading per run.

        Parameters
        ----------
        state : object
            Current state.
        tracker_xy : ndarray, shape (B, 2)
            The tracker's odometry position, metres.
        rssi : ndarray, shape (B,)
            Readings on the 0..100 scale.

        Returns
        -------
        object
            The posterior state.
        """

    def estimate(self, state: Any) -> Estimate:
        """The trackee's position in the tracker's frame.

        Parameters
        ----------
        state : object
            A state.

        Returns
        -------
        Estimate
            ``position`` ``(B, 2)``; its spread is read from ``diagnostics['uncertainty_m']``
            (else ``Estimate.uncertainty_m``).
        """


@dataclass(frozen=True)
class TetherParams:
    """World, robots and behaviour settings (the tracker's estimator is injected).

    Parameters
    ----------
    dt_s : float
        Step length, seconds.
    floor_m, rooms : float, int
        Square floor of side ``floor_m`` split into ``rooms x rooms`` rooms with door gaps.
    start_range_m : tuple of float
        Initial tracker-trackee distance, uniform in this interval, metres.
    speed_tracker, speed_trackee : float
        Speeds, m/s.
    standoff_m : float
        DriveToward stops this close to the estimate, metres.
    explore_radius_m : float
        ExploreGrid visits random waypoints within this radius of the tracker's origin.
    roam_radius_m : float
        The trackee walks between random waypoints within this radius of its start.
    odo_scale_std : float
        Relative standard deviation of each odometry step length.
    odo_heading_std : float
        Heading drift, rad per sqrt(metre) driven.
    compass_std_deg : float
        Standard deviation of each compass heading, degrees.
    v_m : float
        Uncertainty threshold for "localized" (Algorithm 4's ``v``), metres.
    delta_m : float
        Frames are synchronised once the tracker is this close to the estimate, metres.
    channel : IndoorChannel
        The radio channel.
    share_odometry : bool
        The trackee sends its odometry pose every step (the paper's inter-robot sharing);
        False: the tracker blurs by ``speed_trackee * dt_s`` every step and never shifts.
    team_start_m : float
        With several trackers: tracker ``j >= 1`` starts uniformly within this distance of
        tracker 0 (known relative initial poses), metres.
    """

    dt_s: float = 1.0
    floor_m: float = 40.0
    rooms: int = 4
    start_range_m: tuple[float, float] = (4.0, 12.0)
    speed_tracker: float = 0.6
    speed_trackee: float = 0.3
    standoff_m: float = 1.0
    explore_radius_m: float = 8.0
    roam_radius_m: float = 6.0
    odo_scale_std: float = 0.05
    odo_heading_std: float = 0.03
    compass_std_deg: float = 3.0
    v_m: float = 3.0
    delta_m: float = 2.0
    channel: IndoorChannel = field(default_factory=IndoorChannel)
    share_odometry: bool = True
    team_start_m: float = 4.0

    def walls(self) -> np.ndarray:
        """The floor's wall segments.

        Returns
        -------
        ndarray, shape (M, 4)
            Rows ``x1, y1, x2, y2``.
        """
        return office_walls(self.floor_m, self.rooms)


@dataclass
class TetherTrace:
    """What the world recorded, per run and step.

    Attributes
    ----------
    time_s, error_m, true_distance_m, uncertainty_m : ndarray, shape (B, T)
        Step time; tracker's estimation error in its initial frame; tracker-trackee
        distance; the tracker's reported spread.
    localized, synced : ndarray of bool, shape (B, T)
        Localized (spread once below ``v``) and frames synchronised.
    trackee_xy, tracker_xy : ndarray, shape (B, T, 2)
        The trackee's true position and the tracker's odometry position, both in the
        tracker's initial frame.
    track : Track
        The tracker's estimates after each update.
    states : dict
        Step -> the tracker's state after that step's update, at ``record_steps``.
    error_odom_m : ndarray, shape (B, T)
        The same error scored in the tracker's current odometry frame (the trackee's true
        position relative to the tracker's true pose, placed at its odometry pose): the
        tracker's own odometry drift is not counted.
    driving : ndarray of bool, shape (B, T)
        The tracker drove toward its estimate in this step (the predicted belief's spread
        was below ``v``); otherwise it explored (ExploreGrid).
    """

    time_s: np.ndarray
    error_m: np.ndarray
    true_distance_m: np.ndarray
    uncertainty_m: np.ndarray
    localized: np.ndarray
    synced: np.ndarray
    trackee_xy: np.ndarray
    tracker_xy: np.ndarray
    track: Track
    states: dict = field(default_factory=dict)
    error_odom_m: np.ndarray | None = None
    driving: np.ndarray | None = None


def read_rssi(channel: IndoorChannel, a, b, walls, rng: np.random.Generator) -> np.ndarray:
    """One reading of the tracker's radio: channel power in dBm quantised to 0..100.

    Parameters
    ----------
    channel : IndoorChannel
        The channel.
    a, b : array_like, shape (..., 2)
        End points of the links, metres.
    walls : array_like, shape (M, 4)
        Wall segments.
    rng : numpy.random.Generator
        Source of the channel's shadowing and fading.

    Returns
    -------
    ndarray of int, shape (...)
        RSSI on the 0..100 scale (``dbm_to_rssi100``, i.e. ``dBm + 110`` clipped).
    """
    return dbm_to_rssi100(channel.sample_dbm(a, b, walls, rng))


def _spread(est: Estimate) -> np.ndarray:
    u = est.diagnostics.get("uncertainty_m")
    return np.asarray(est.uncertainty_m if u is None else u)


def _rot(theta: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 2) by angles ``theta`` (...)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


def _step_toward(pos, target, speed, stop):
    """Displacement of at most ``speed`` from ``pos`` toward ``target``, stopping ``stop`` short."""
    d = target - pos
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    go = np.clip(n - stop, 0.0, speed)
    return np.where(n > 1e-12, d / np.where(n > 1e-12, n, 1.0) * go, 0.0)


def calibration_pairs(params: TetherParams, n: int, rng: np.random.Generator):
    """(RSSI, distance) pairs from random node placements on the floor (Sect. III-B).

    Parameters
    ----------
    params : TetherParams
        Floor and channel.
    n : int
        Number of pairs.
    rng : numpy.random.Generator
        Source of the placements and readings.

    Returns
    -------
    rssi : ndarray of int, shape (n,)
        Readings on the 0..100 scale.
    dist : ndarray, shape (n,)
        True distances, metres.
    """
    f = params.floor_m
    a = rng.uniform(0.5, f - 0.5, (n, 2))
    b = rng.uniform(0.5, f - 0.5, (n, 2))
    return read_rssi(params.channel, a, b, params.walls(), rng), np.linalg.norm(a - b, axis=-1)


def simulate_tether(params: TetherParams, tracker: Tracker, batch: int, steps: int,
                    rng: np.random.Generator, *, compass: bool,
                    record_steps: tuple[int, ...] = (), trackers: int = 1,
                    share_readings: bool = False) -> TetherTrace:
    """Run Algorithm 4 for ``batch`` independent runs for ``steps`` steps.

    Parameters
    ----------
    params : TetherParams
        World, robots and behaviour.
    tracker : Tracker
        The tracker's estimator (e.g. the grid filter ``GridFilter``); with ``trackers = M``
        it holds ``batch * M`` states, one per tracker of each run.
    batch, steps : int
        Runs B and steps T.
    rng : numpy.random.Generator
        Source of every draw of the world (poses, waypoints, odometry, compass, channel).
    compass : bool
        Whether the robots have a compass (frames can be synchronised).
    record_steps : tuple of int
        Steps whose tracker state is kept in :attr:`TetherTrace.states`.
    trackers : int
        Robots M tracking the same trackee (1: the paper's two-node problem). With one
        tracker the draws are those of the single-tracker world.
    share_readings : bool
        With ``M > 1``: each tracker also applies its team-mates' readings of the step
        (see the module docstring); False: each tracks alone.

    Returns
    -------
    TetherTrace
        With ``M > 1`` every per-run array has ``B * M`` rows: tracker ``i`` of run ``b``
        at row ``b * M + i``, each scored in its own frames.
    """
    B, T, P, M = int(batch), int(steps), params, int(trackers)
    if M < 1:
        raise ConfigError(f"trackers: expected at least 1, got {trackers!r}")
    walls = P.walls()
    lo, hi = 0.5, P.floor_m - 0.5
    # global initial poses: frame origins and headings (tracker 0 first)
    g_a = rng.uniform(lo + 5, hi - 5, (B, 2))
    ang = rng.uniform(0, 2 * np.pi, B)
    g_b = np.clip(g_a + rng.uniform(*P.start_range_m, B)[:, None]
                  * np.stack([np.cos(ang), np.sin(ang)], -1), lo, hi)
    th_a = rng.uniform(-np.pi, np.pi, B)        # heading of each local frame in the global one
    th_b = rng.uniform(-np.pi, np.pi, B)
    g_a, th_a = g_a[:, None], th_a[:, None]     # (B, M, 2), (B, M)
    if M > 1:                                   # team-mates: a known start formation
        rad = P.team_start_m * np.sqrt(rng.uniform(0, 1, (B, M - 1)))
        phi = rng.uniform(0, 2 * np.pi, (B, M - 1))
        mates = g_a + rad[..., None] * np.stack([np.cos(phi), np.sin(phi)], -1)
        g_a = np.concatenate([g_a, np.clip(mates, lo + 1, hi - 1)], axis=1)
        th_a = np.concatenate([th_a, rng.uniform(-np.pi, np.pi, (B, M - 1))], axis=1)
    g0_a = g_a.copy()
    frame0_a = th_a.copy()
    s_a = np.zeros((B, M, 2))                   # tracker odometry (each its local frame)
    s_b = np.zeros((B, 2))                      # trackee odometry (its local frame)
    state = tracker.init(B * M)
    synced = np.zeros((B, M), bool)
    localized = np.zeros((B, M), bool)
    wp_a = rng.uniform(-P.explore_radius_m, P.explore_radius_m, (B, M, 2))
    home_b = g_b.copy()

    def roam():
        return np.clip(home_b + rng.uniform(-P.roam_radius_m, P.roam_radius_m, (B, 2)), lo, hi)

    def flat(x):
        return x.reshape(B * M, *x.shape[2:])

    def mate_in_own_frame(x, o):
        """Team-mate ``(i + o) % M``'s odometry position in tracker ``i``'s frame."""
        j = (np.arange(M) + o) % M
        return (_rot(-frame0_a, g0_a[:, j] - g0_a)
                + _rot(frame0_a[:, j] - frame0_a, x[:, j]))

    wp_b = roam()
    comp = np.deg2rad(P.compass_std_deg)
    out = {k: np.zeros((B, M, T)) for k in ("err", "dist", "unc", "loc", "syn", "odom",
                                                 "drv")}
    truth_xy, own_xy = np.zeros((B, M, T, 2)), np.zeros((B, M, T, 2))
    states, estimates = {}, []
    for t in range(T):
        # 1. trackee motion (stationary until localized) and its odometry report
        moving = localized.any(axis=1)
        step_b = np.where(moving[:, None], _step_toward(g_b, wp_b, P.speed_trackee * P.dt_s, 0.0), 0.0)
        new_wp = np.linalg.norm(g_b + step_b - wp_b, axis=-1) < 0.2
        wp_b = np.where(new_wp[:, None], roam(), wp_b)
        g_b = np.clip(g_b + step_b, lo, hi)
        length = np.linalg.norm(step_b, axis=-1)
        odo_b = _rot(-th_b, step_b) * (1 + rng.normal(0, P.odo_scale_std, B))[:, None]
        th_b = th_b + rng.normal(0, P.odo_heading_std, B) * np.sqrt(length)
        s_b_prev, s_b = s_b, s_b + odo_b
        # 2. prediction: a known shift once the frames are synchronised, else a wider blur
        d_b = (s_b - s_b_prev)[:, None]
        rel = (th_b + rng.normal(0, comp, B))[:, None] - (th_a + rng.normal(0, comp, (B, M)))
        if P.share_odometry:
            shift = np.where(synced[..., None], _rot(rel, d_b), 0.0)
            blur = np.where(synced, 0.0, np.linalg.norm(d_b, axis=-1))
        else:                                   # no report: the trackee's top speed
            shift = np.zeros((B, M, 2))
            blur = np.full((B, M), P.speed_trackee * P.dt_s)
        state = tracker.predict(state, dt=P.dt_s, shift_m=flat(shift), extra_blur_m=flat(blur))
        # 3. behaviour on the predicted belief
        belief = tracker.estimate(state)
        loc = belief.position.reshape(B, M, 2)
        good = _spread(belief).reshape(B, M) < P.v_m
        localized |= good
        reached = np.linalg.norm(s_a - wp_a, axis=-1) < 0.3
        wp_a = np.where(reached[..., None],
                        rng.uniform(-P.explore_radius_m, P.explore_radius_m, (B, M, 2)), wp_a)
        target = np.where(good[..., None], loc, wp_a)
        u = _step_toward(s_a, target, P.speed_tracker * P.dt_s, np.where(good, P.standoff_m, 0.0)[..., None])
        if compass:
            synced |= good & (np.linalg.norm(s_a - loc, axis=-1) < P.delta_m)
        s_a = s_a + u
        ulen = np.linalg.norm(u, axis=-1)
        g_a = np.clip(g_a + _rot(th_a, u) * (1 + rng.normal(0, P.odo_scale_std, (B, M)))[..., None], lo, hi)
        th_a = th_a + rng.normal(0, P.odo_heading_std, (B, M)) * np.sqrt(ulen)
        # 4. measurement update (own reading, then the team-mates' when shared)
        rssi = read_rssi(P.channel, g_a, g_b[:, None], walls, rng)
        state = tracker.update(state, flat(s_a), flat(rssi))
        if share_readings:
            for o in range(1, M):
                j = (np.arange(M) + o) % M
                state = tracker.update(state, flat(mate_in_own_frame(s_a, o)), flat(rssi[:, j]))
        est = tracker.estimate(state)
        estimates.append(est)
        pos = est.position.reshape(B, M, 2)
        truth_local = _rot(-frame0_a, g_b[:, None] - g0_a)
        out["err"][..., t] = np.linalg.norm(pos - truth_local, axis=-1)
        truth_odom = s_a + _rot(-th_a, g_b[:, None] - g_a)
        out["odom"][..., t] = np.linalg.norm(pos - truth_odom, axis=-1)
        out["dist"][..., t] = np.linalg.norm(g_a - g_b[:, None], axis=-1)
        out["unc"][..., t] = _spread(est).reshape(B, M)
        out["loc"][..., t] = localized
        out["syn"][..., t] = synced
        out["drv"][..., t] = good
        truth_xy[:, :, t], own_xy[:, :, t] = truth_local, s_a
        if t in record_steps:
            states[t] = state
    time = (np.arange(T) + 1) * P.dt_s
    o = {k: flat(v) for k, v in out.items()}
    return TetherTrace(np.broadcast_to(time, (B * M, T)), o["err"], o["dist"], o["unc"],
                       o["loc"].astype(bool), o["syn"].astype(bool), flat(truth_xy), flat(own_xy),
                       track_from_steps(estimates, time=time), states, o["odom"],
                       o["drv"].astype(bool))
