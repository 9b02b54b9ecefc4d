"""Scenarios: geometry, trajectories, who hears whom and measurement draws, one module
per setting. Simulations take a ``numpy.random.Generator``; they never import an estimator
(a tracker under test is injected, as in :func:`simulate_tether`)."""

from radioloc.sim.corridor import Corridor
from radioloc.sim.highway import HighwayScenario, anchor_coverage, anchor_layout, reflect
from radioloc.sim.highway import simulate as simulate_highway
from radioloc.sim.measurements import clock_trajectory, observe, simulate_aoa, simulate_tdoa
from radioloc.sim.network import draw_network
from radioloc.sim.single_sensor import circular_sensor_path, random_tracks
from radioloc.sim.tether import TetherParams, simulate_tether
from radioloc.sim.urban import simulate_urban_network

__all__ = ["Corridor", "HighwayScenario", "anchor_layout", "anchor_coverage", "reflect", "simulate_highway", "draw_network",
           "circular_sensor_path", "random_tracks", "TetherParams", "simulate_tether",
           "simulate_urban_network", "observe", "clock_trajectory", "simulate_tdoa", "simulate_aoa"]
