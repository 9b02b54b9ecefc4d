"""Tethering simulation of paper 003 (Sect. IV, Algorithm 4; Sect. V), batched over runs.

A tracker robot localizes and follows a trackee on a 2-D office floor whose walls attenuate
the RSS (:mod:`radioloc.channel.indoor_rss`). Both are point robots that start at random
global poses; each keeps odometry in its own local frame (origin and heading at its start),
so the two frames differ by an unknown rotation and translation. The tracker's grid lives in
the tracker's local frame. Every step of ``dt_s`` runs Algorithm 4 once for all runs:

1. the trackee moves (only once the tracker has localized it, as in Sect. V) and reports
   its odometry pose ``s_b``;
2. frames synchronised: ShiftGrid by the trackee's odometry step rotated into the tracker's
   frame with the compass headings, then BlurGrid(gamma); otherwise BlurGrid(|step| + gamma);
3. GetLocation / GetUncertainty; below ``v`` the tracker drives toward the estimate (and, with
   a compass, synchronises the frames once within ``delta``), otherwise ExploreGrid;
4. ProbabilityUpdate with a new RSSI reading.

Choices the paper leaves open (all in :class:`TetherParams`): the channel, robot speeds,
odometry noise model, the exploration pattern (random waypoints around the tracker's origin),
the trackee's motion (random waypoints on the floor), the tracker's stand-off distance, and
that after synchronisation the compass keeps giving both headings (noisy) every step.
Robots pass through walls (walls only attenuate); positions are clipped to the floor.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from radioloc.channel.indoor_rss import IndoorChannel, office_walls
from radioloc.estimators.grid import (
    GridGeometry, blur_grid, get_location, get_uncertainty, probability_update, shift_grid)
from radioloc.models.rssi_trapezoid import TrapezoidModel


@dataclass(frozen=True)
class TetherParams:
    """World, robots and filter settings.

    floor_m, rooms: square floor split into rooms x rooms rooms with door gaps.
    start_range_m: initial tracker-trackee distance drawn uniformly in this interval.
    speed_tracker, speed_trackee: m/s. standoff_m: DriveToward stops this close to the estimate.
    explore_radius_m: ExploreGrid visits random waypoints within this radius of the origin.
    roam_radius_m: the trackee walks between random waypoints within this radius of its start.
    odo_scale_std: relative std of each odometry step length error.
    odo_heading_std: heading drift, rad per sqrt(metre) driven.
    compass_std_deg: std of each compass heading.
    grid_cells, cell_m: the tracker's grid (square, centred on its local origin).
    epsilon: minimum cell probability (Algorithm 1). gamma_m: odometry blur (Algorithm 4).
    v_m: uncertainty threshold for "localized". delta_m: sync distance.
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
    grid_cells: int = 40
    cell_m: float = 1.0
    epsilon: float = 1e-6
    gamma_m: float = 0.3
    v_m: float = 3.0
    delta_m: float = 2.0
    channel: IndoorChannel = field(default_factory=IndoorChannel)

    @property
    def grid(self) -> GridGeometry:
        return GridGeometry.centred(self.grid_cells, self.grid_cells, self.cell_m)

    def walls(self) -> np.ndarray:
        return office_walls(self.floor_m, self.rooms)


@dataclass
class TetherTrace:
    """Per-step records, arrays of shape ``(B, T)`` (``grids``: step -> ``(B, h, w)`` at the recorded steps)."""

    time_s: np.ndarray
    error_m: np.ndarray
    true_distance_m: np.ndarray
    uncertainty_m: np.ndarray
    localized: np.ndarray
    synced: np.ndarray
    grids: dict = field(default_factory=dict)
    snapshots: dict = field(default_factory=dict)


def _rot(theta: np.ndarray, v: np.ndarray) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]], axis=-1)


def _step_toward(pos, target, speed, stop):
    """Displacement of at most ``speed`` from ``pos`` toward ``target``, stopping ``stop`` short."""
    d = target - pos
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    go = np.clip(n - stop, 0.0, speed)
    return np.where(n > 1e-12, d / np.where(n > 1e-12, n, 1.0) * go, 0.0)


def calibration_pairs(params: TetherParams, n: int, rng: np.random.Generator):
    """(RSSI, distance) pairs from random node placements on the floor (Sect. III-B)."""
    f = params.floor_m
    a = rng.uniform(0.5, f - 0.5, (n, 2))
    b = rng.uniform(0.5, f - 0.5, (n, 2))
    return params.channel.sample_rssi(a, b, params.walls(), rng), np.linalg.norm(a - b, axis=-1)


def simulate_tether(params: TetherParams, model: TrapezoidModel, batch: int, steps: int,
                    rng: np.random.Generator, *, compass: bool,
                    record_steps: tuple[int, ...] = ()) -> TetherTrace:
    """Run Algorithm 4 for ``batch`` independent runs for ``steps`` steps."""
    B, T, P = int(batch), int(steps), params
    geom = P.grid
    walls = P.walls()
    lo, hi = 0.5, P.floor_m - 0.5
    # global initial poses: frame origins and headings
    g_a = rng.uniform(lo + 5, hi - 5, (B, 2))
    ang = rng.uniform(0, 2 * np.pi, B)
    g_b = np.clip(g_a + rng.uniform(*P.start_range_m, B)[:, None]
                  * np.stack([np.cos(ang), np.sin(ang)], -1), lo, hi)
    th_a = rng.uniform(-np.pi, np.pi, B)        # heading of each local frame in the global one
    th_b = rng.uniform(-np.pi, np.pi, B)
    g0_a = g_a.copy()
    frame0_a = th_a.copy()
    s_a = np.zeros((B, 2))                      # tracker odometry (local frame)
    s_b = np.zeros((B, 2))                      # trackee odometry (its local frame)
    p = geom.uniform(B)
    synced = np.zeros(B, bool)
    localized = np.zeros(B, bool)
    wp_a = rng.uniform(-P.explore_radius_m, P.explore_radius_m, (B, 2))
    home_b = g_b.copy()

    def roam():
        return np.clip(home_b + rng.uniform(-P.roam_radius_m, P.roam_radius_m, (B, 2)), lo, hi)

    wp_b = roam()
    comp = np.deg2rad(P.compass_std_deg)
    out = {k: np.zeros((B, T)) for k in ("err", "dist", "unc", "loc", "syn")}
    grids, snaps = {}, {}
    for t in range(T):
        # 1. trackee motion (stationary until localized) and its odometry report
        step_b = np.where(localized[:, None], _step_toward(g_b, wp_b, P.speed_trackee * P.dt_s, 0.0), 0.0)
        new_wp = np.linalg.norm(g_b + step_b - wp_b, axis=-1) < 0.2
        wp_b = np.where(new_wp[:, None], roam(), wp_b)
        g_b = np.clip(g_b + step_b, lo, hi)
        length = np.linalg.norm(step_b, axis=-1)
        odo_b = _rot(-th_b, step_b) * (1 + rng.normal(0, P.odo_scale_std, B))[:, None]
        th_b = th_b + rng.normal(0, P.odo_heading_std, B) * np.sqrt(length)
        s_b_prev, s_b = s_b, s_b + odo_b
        # 2. motion model of the grid
        d_b = s_b - s_b_prev
        rel = (th_b + rng.normal(0, comp, B)) - (th_a + rng.normal(0, comp, B))
        shifted = shift_grid(p, geom, np.where(synced[:, None], _rot(rel, d_b), 0.0), P.epsilon)
        p = np.where(synced[:, None, None], shifted, p)
        p = blur_grid(p, geom, np.where(synced, 0.0, np.linalg.norm(d_b, axis=-1)) + P.gamma_m, P.epsilon)
        # 3. behaviour
        loc = get_location(p, geom)
        unc = get_uncertainty(p, geom)
        good = unc < P.v_m
        localized |= good
        reached = np.linalg.norm(s_a - wp_a, axis=-1) < 0.3
        wp_a = np.where(reached[:, None], rng.uniform(-P.explore_radius_m, P.explore_radius_m, (B, 2)), wp_a)
        target = np.where(good[:, None], loc, wp_a)
        u = _step_toward(s_a, target, P.speed_tracker * P.dt_s, np.where(good, P.standoff_m, 0.0)[:, None])
        if compass:
            synced |= good & (np.linalg.norm(s_a - loc, axis=-1) < P.delta_m)
        s_a = s_a + u
        ulen = np.linalg.norm(u, axis=-1)
        g_a = np.clip(g_a + _rot(th_a, u) * (1 + rng.normal(0, P.odo_scale_std, B))[:, None], lo, hi)
        th_a = th_a + rng.normal(0, P.odo_heading_std, B) * np.sqrt(ulen)
        # 4. measurement update
        rssi = P.channel.sample_rssi(g_a, g_b, walls, rng)
        p = probability_update(p, geom, s_a, rssi, model, P.epsilon)
        est = get_location(p, geom)
        truth_local = _rot(-frame0_a, g_b - g0_a)
        out["err"][:, t] = np.linalg.norm(est - truth_local, axis=-1)
        out["dist"][:, t] = np.linalg.norm(g_a - g_b, axis=-1)
        out["unc"][:, t] = get_uncertainty(p, geom)
        out["loc"][:, t] = localized
        out["syn"][:, t] = synced
        if t in record_steps:
            grids[t] = p.copy()
            snaps[t] = {"tracker": s_a.copy(), "trackee": truth_local, "estimate": est}
    time = (np.arange(T) + 1) * P.dt_s
    return TetherTrace(np.broadcast_to(time, (B, T)), out["err"], out["dist"], out["unc"],
                       out["loc"].astype(bool), out["syn"].astype(bool), grids, snaps)
