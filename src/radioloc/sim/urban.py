"""Paper 000's complete radiolocation scenario: a synthetic city, nodes on its streets, the
ray-traced channels of every link and the ranges of repeated RTS/ACK hand-shakes.

:func:`simulate_urban_network` draws everything from named child streams of the
experiment seed (:func:`radioloc.core.rng.stream`): ``"scene"`` (the city layout),
``"placement/<i>"`` (the street points of scenario ``i``) and ``"channel/<i>"``
(hand-shake jitter, path phases and receiver noise), so ``--seed`` changes the whole
scenario and every block of runs sees the same one. Ray tracing is cached on disk by
provider, scene, end points and trace settings. The channel provider is chosen by the
trace configuration's type: :class:`radioloc.channel.raytrace.TraceConfig` (the 2-D
tracer) or :class:`radioloc.channel.sionna_rt.SionnaConfig` (Sionna RT).

Nothing here imports an estimator.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import pandas as pd

from radioloc.channel.cdma import CDMAConfig
from radioloc.channel.gsic import OMPSICConfig
from radioloc.channel.ranging import NetworkRanges, network_ranges, trace_network
from radioloc.channel.raytrace import TraceConfig, trace_links_cached
from radioloc.channel.scene import Scene, city_grid, street_positions
from radioloc.core.errors import GeometryError, InputError
from radioloc.core.rng import stream

__all__ = ["UrbanNetwork", "place_nodes", "simulate_urban_network", "ack_set_ranges",
           "range_table", "building_table"]


@dataclass(frozen=True)
class UrbanNetwork:
    """One simulated urban network.

    Attributes
    ----------
    scene : Scene
        The buildings.
    positions : ndarray, shape (K, 2)
        True node positions, metres.
    ranges : NetworkRanges
        Ranges of every ACK set at every master (OMP-SIC and matched filter).
    """

    scene: Scene
    positions: np.ndarray
    ranges: NetworkRanges


def place_nodes(scene: Scene, nodes: int, rng: np.random.Generator, *, candidates: int,
                half_width_m: float, trace: TraceConfig | None = None,
                cache_dir: str | None = None, attempts: int = 20,
                require_paths: bool = False) -> np.ndarray:
    """``nodes`` random street positions (optionally with a traced path on every link).

    By default the first ``nodes`` of ``candidates`` random street points in
    ``[-half_width_m, half_width_m]^2`` are kept, whatever their links. With
    ``require_paths`` (a labelled variant: it selects easy geometries) the candidates are
    traced pairwise with the 2-D tracer (reflection order 1) and a randomised depth-first
    search looks for a ``nodes``-clique of the connectivity graph; without one, a fresh
    candidate set is drawn (at most ``attempts`` times).

    Parameters
    ----------
    scene : Scene
    nodes : int
        ``K``.
    rng : Generator
        Candidate points and search order.
    candidates : int
        Street points per attempt.
    half_width_m : float
        Half side of the placement square, centred on the origin.
    trace : TraceConfig, optional
        Its ``max_excess_m``, carrier and wall permittivity are used (order 1).
    cache_dir : str, optional
        Ray-tracing cache.
    attempts : int
        Candidate sets tried.
    require_paths : bool
        Keep only node sets in which every pair has a traced path.

    Returns
    -------
    ndarray, shape (K, 2)

    Raises
    ------
    GeometryError
        No candidate set of any attempt holds a connected node set.
    """
    if nodes < 2 or candidates < nodes:
        raise InputError(f"candidates: need at least nodes = {nodes} >= 2 candidates, "
                         f"got {candidates}")
    if not require_paths:
        cand = street_positions(scene, candidates, rng, half_width_m=half_width_m,
                                clearance_m=3.0)
        return cand[:nodes]
    t = trace if isinstance(trace, TraceConfig) else TraceConfig()
    quick = TraceConfig(max_order=1, max_excess_m=t.max_excess_m, carrier_hz=t.carrier_hz,
                        wall_permittivity=t.wall_permittivity)
    for _ in range(int(attempts)):
        cand = street_positions(scene, candidates, rng, half_width_m=half_width_m,
                                clearance_m=3.0)
        i, j = np.triu_indices(len(cand), 1)
        ch = trace_links_cached(scene, cand[i], cand[j], quick, cache_dir)
        ok = np.zeros((len(cand), len(cand)), bool)
        ok[i, j] = ok[j, i] = ch.n_paths > 0
        order = rng.permutation(len(cand))

        def grow(chosen: list[int], rest: list[int]) -> list[int] | None:
            if len(chosen) == nodes:
                return chosen
            for n, c in enumerate(rest):            # search of a small graph, not a batch
                if all(ok[c, p] for p in chosen):
                    found = grow(chosen + [c], rest[n + 1:])
                    if found:
                        return found
            return None

        found = grow([], list(order))
        if found is not None:
            return cand[np.array(found)]
    raise GeometryError(f"no set of {nodes} street points with a traced path on every link in "
                        f"{attempts} candidate sets; change the seed or the placement area")


@lru_cache(maxsize=16)
def simulate_urban_network(seed: int, *, scenario: int = 0, nodes: int = 6, rounds: int = 28,
                           city_size_m: float = 1000.0, half_width_m: float = 300.0,
                           candidates: int = 24, trace=None,
                           cdma: CDMAConfig | None = None, sic: OMPSICConfig | None = None,
                           cache_dir: str | None = None,
                           require_paths: bool = False) -> UrbanNetwork:
    """The scene, the node positions and the ranges of every ACK set (cached per arguments).

    Parameters
    ----------
    seed : int
        Experiment seed; the draws come from its ``"scene"``, ``"placement/<scenario>"`` and
        ``"channel/<scenario>"`` streams.
    scenario : int
        Index of the node placement in the same city.
    nodes : int
        ``K``; node ``k`` uses Gold code ``k``.
    rounds : int
        ACK sets collected by every master (paper: 28).
    city_size_m : float
        Side of the synthetic city (:func:`radioloc.channel.scene.city_grid`).
    half_width_m, candidates : float, int
        Node placement (:func:`place_nodes`).
    trace : TraceConfig or SionnaConfig, optional
        Channel provider and its settings (default: the 2-D tracer, ``TraceConfig()``).
    cdma, sic : configs, optional
        Physical-layer and detector settings.
    cache_dir : str, optional
        Ray-tracing cache (default ``~/.cache/radioloc/channels`` or ``$RADIOLOC_CACHE``).
    require_paths : bool
        Placement keeps only node sets with a traced path on every link (variant).

    Returns
    -------
    UrbanNetwork
    """
    scene = city_grid(stream(seed, "scene"), size_m=city_size_m)
    pos = place_nodes(scene, nodes, stream(seed, f"placement/{scenario}"), candidates=candidates,
                      half_width_m=half_width_m, trace=trace, cache_dir=cache_dir,
                      require_paths=require_paths)
    ch = trace_network(scene, pos, trace, cache_dir)
    ranges = network_ranges(scene, pos, rounds, stream(seed, f"channel/{scenario}"), cdma=cdma,
                            sic=sic, channels=ch)
    return UrbanNetwork(scene, pos, ranges)


def ack_set_ranges(ranges: np.ndarray, order: np.ndarray, min_ranges: int = 3) -> np.ndarray:
    """The ranges each run feeds its estimators, packet by packet.

    Parameters
    ----------
    ranges : ndarray, shape (S, K, K) or (R, S, K, K)
        Range at master ``k`` to node ``i`` in ACK set ``s`` (NaN: not detected), shared
        by every run or one set per run.
    order : ndarray of int, shape (R, K, S)
        Order of the ACK sets of every master in every run (a permutation of ``0..S-1``).
    min_ranges : int
        A master with fewer detected ranges in an ACK set sends no packet (the RLS needs
        pairs of ranges).

    Returns
    -------
    ndarray, shape (R, S, K, K)
        ``out[r, n, k, i]``: range at master ``k`` to node ``i`` in packet ``n`` of run
        ``r``; NaN where missing (the diagonal included).
    """
    S, K = ranges.shape[-3:-1]
    kk = np.arange(K)
    if ranges.ndim == 3:
        rho = ranges[order.transpose(0, 2, 1), kk[None, None, :], :]      # (R, S, K, K)
    else:
        rr = np.arange(len(order))[:, None, None]
        rho = ranges[rr, order.transpose(0, 2, 1), kk[None, None, :], :]
    rho = np.where(kk[:, None] == kk[None, :], np.nan, rho)
    sends = np.isfinite(rho).sum(axis=-1) >= min_ranges
    return np.where(sends[..., None], rho, np.nan)


def range_table(r: NetworkRanges) -> pd.DataFrame:
    """Tidy range errors: one row per (round, master, node, detector).

    Parameters
    ----------
    r : NetworkRanges

    Returns
    -------
    DataFrame
        Columns ``round, master, node, detector`` (``"omp_sic"`` or ``"matched_filter"``),
        ``range_m, true_m, los, first_path_m, n_paths, rts_error_m, error_m``
        (``range_m - true_m``; NaN where nothing was detected).
    """
    S, K, _ = r.sic_m.shape
    s, k, i = np.meshgrid(np.arange(S), np.arange(K), np.arange(K), indexing="ij")
    off = k != i
    frames = []
    for name, arr in (("omp_sic", r.sic_m), ("matched_filter", r.matched_filter_m)):
        frames.append(pd.DataFrame({
            "round": s[off], "master": k[off], "node": i[off], "detector": name,
            "range_m": arr[off], "true_m": np.broadcast_to(r.true_m, arr.shape)[off],
            "los": np.broadcast_to(r.los, arr.shape)[off],
            "first_path_m": np.broadcast_to(r.first_path_m, arr.shape)[off],
            "n_paths": np.broadcast_to(r.n_paths, arr.shape)[off],
            "rts_error_m": r.rts_error_m[off]}))
    df = pd.concat(frames, ignore_index=True)
    df["error_m"] = df["range_m"] - df["true_m"]
    return df


def building_table(scene: Scene) -> pd.DataFrame:
    """The building footprints as rows ``building, vertex, x, y`` (closed rings).

    Parameters
    ----------
    scene : Scene

    Returns
    -------
    DataFrame
    """
    frames = []
    for b, p in enumerate(scene.polygons):
        xy = np.asarray(p.exterior.coords)
        frames.append(pd.DataFrame({"building": b, "vertex": np.arange(len(xy)),
                                    "x": xy[:, 0], "y": xy[:, 1]}))
    if not frames:
        return pd.DataFrame(columns=["building", "vertex", "x", "y"])
    return pd.concat(frames, ignore_index=True)
