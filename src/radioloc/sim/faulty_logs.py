"""Simulated measurement logs with known faults, in the ``radioloc locate`` formats.

A tag walks a circle among six anchors; :func:`walk_log` writes its ranges, time differences
or angles to every anchor at every step, with Gaussian noise of a stated standard deviation,
and then applies one fault of :data:`FAULTS` (the slips and gross errors that real logs
carry). The truth is returned beside the log, for scoring only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

__all__ = ["ANCHORS", "FAULTS", "KIND_OF_FAULT", "STATED_STD", "SimulatedLog", "walk_log"]

#: Anchor positions (m).
ANCHORS = {"A0": (0.0, 0.0), "A1": (20.0, 0.0), "A2": (20.0, 15.0), "A3": (0.0, 15.0),
           "A4": (10.0, -3.0), "A5": (23.0, 7.0)}
#: The stated noise standard deviation of each kind (m, or rad for angles).
STATED_STD = {"range": 0.1, "tdoa": 0.1, "aoa": 0.02}
#: The faults :func:`walk_log` applies: none, an anchor with x and y swapped in the anchors
#: table, noise 3 times the stated one, 20 % of ranges 5 m long (NLOS), angles as compass
#: bearings, time differences of the wrong sign, anchors in millimetres, gross errors (8 % of
#: rows: ranges 40-250 m long, time differences off by 25-100 m).
FAULTS = ("clean", "swapped_anchor", "noise_3x", "nlos", "compass", "tdoa_sign",
          "anchors_mm", "spikes")
#: The kind a fault needs (others: ranges, or any kind given).
KIND_OF_FAULT = {"compass": "aoa", "tdoa_sign": "tdoa"}


@dataclass(frozen=True)
class SimulatedLog:
    """A log, its anchors, the truth, and what was stated about it."""

    measurements: pd.DataFrame
    anchors: pd.DataFrame
    reference: pd.DataFrame
    kind: str
    options: dict[str, str]


def _path(steps: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
    t = dt * np.arange(steps)
    angle = t / 5.0                           # 1 m/s on a circle of radius 5 m
    return t, np.column_stack([11.0 + 5.0 * np.cos(angle), 7.0 + 5.0 * np.sin(angle)])


def walk_log(fault: str = "clean", seed: int = 0, *, kind: str | None = None,
             steps: int = 120, dt: float = 0.25, node: str = "tag") -> SimulatedLog:
    """One simulated log with ``fault`` applied.

    Parameters
    ----------
    fault : str
        One of :data:`FAULTS`.
    seed : int
        Seed of the noise and of the faulty rows.
    kind : {"range", "tdoa", "aoa"}, optional
        Default: :data:`KIND_OF_FAULT`'s, else ``"range"``.
    steps, dt : int, float
        Time steps and their length (s).
    node : str

    Returns
    -------
    SimulatedLog
        ``options``: the stated noise (``range_std_m``, ``tdoa_std_m`` or ``aoa_std_rad``).
    """
    if fault not in FAULTS:
        raise ValueError(f"fault: one of {FAULTS}, got {fault!r}")
    kind = kind or KIND_OF_FAULT.get(fault, "range")
    rng = np.random.default_rng(seed)
    ids = list(ANCHORS)
    xy = np.array([ANCHORS[a] for a in ids])
    t, pos = _path(steps, dt)
    sigma = STATED_STD[kind] * (3.0 if fault == "noise_3x" else 1.0)
    dist = np.linalg.norm(pos[:, None, :] - xy[None], axis=-1)          # (T, A)
    reference = None
    if kind == "range":
        true = dist
    elif kind == "tdoa":
        true, ids_used, reference = dist[:, 1:] - dist[:, :1], ids[1:], ids[0]
    elif kind == "aoa":
        true = np.arctan2(pos[:, None, 1] - xy[None, :, 1], pos[:, None, 0] - xy[None, :, 0])
    else:
        raise ValueError(f"kind: range, tdoa or aoa, got {kind!r}")
    peers = ids if kind != "tdoa" else ids_used
    value = true + sigma * rng.standard_normal(true.shape)
    if fault == "nlos" and kind == "range":
        value = value + 5.0 * (rng.random(value.shape) < 0.2)
    if fault == "spikes":
        hit = rng.random(value.shape) < 0.08
        if kind == "range":
            value = value + hit * rng.uniform(40.0, 250.0, value.shape)
        else:
            step = rng.uniform(25.0, 100.0, value.shape) * rng.choice([-1.0, 1.0], value.shape)
            value = value + hit * step * (1.0 if kind == "tdoa" else 0.0)
    if fault == "compass":
        value = (math.pi / 2 - value + math.pi) % (2 * math.pi) - math.pi
    if fault == "tdoa_sign":
        value = -value
    if kind == "aoa":
        value = (value + math.pi) % (2 * math.pi) - math.pi
    frame = pd.DataFrame({"time": np.repeat(t, len(peers)), "node": node,
                          "peer": np.tile(peers, steps), "kind": kind,
                          "value": value.ravel()})
    if reference is not None:
        frame["reference"] = reference
    anchors = pd.DataFrame({"id": ids, "x": xy[:, 0], "y": xy[:, 1]})
    if fault == "swapped_anchor":
        anchors.loc[4, ["x", "y"]] = anchors.loc[4, ["y", "x"]].to_numpy(copy=True)
    if fault == "anchors_mm":
        anchors[["x", "y"]] *= 1000.0
    truth = pd.DataFrame({"time": t, "node": node, "x": pos[:, 0], "y": pos[:, 1]})
    option = {"range": "range_std_m", "tdoa": "tdoa_std_m", "aoa": "aoa_std_rad"}[kind]
    return SimulatedLog(frame, anchors, truth, kind, {option: f"{STATED_STD[kind]:g}"})
