"""Ranges of a whole network from ray-traced channels, RTS/ACK hand-shakes and OMP-SIC.

Every node in turn is the master; the other ``K - 1`` nodes answer its RTS at once. The
channels of the ``K (K - 1) / 2`` links are traced once (cached) and are reciprocal.

RTS: the master ``k`` sends its Gold code ``k``; each responder ``j`` receives it over the
link's paths (own random path phases) plus receiver noise and detects its first arrival
``t_rts(k, j)`` with the same OMP-SIC detector the master uses for the ACKs (one user). A
responder that detects nothing sends no ACK. With ``CDMAConfig.rts_sync == "ideal"`` (a
labelled variant) the responder knows the true first arrival ``tau_first(k, j)`` instead.

ACK: responder ``j`` starts its ACK ``turnaround_s`` plus a Gaussian clock jitter after
``t_rts(k, j)``, so its paths reach the master at ``t_rts(k, j) + jitter + tau_p(j, k)``
after the turnaround; the master's round-trip estimate is the first arrival ``t`` of the
user in the ACK set, its range ``c t / 2``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radioloc.channel.cdma import CDMAConfig, gold_codes, received_acks
from radioloc.channel.gsic import OMPSICConfig, matched_filter_toa, omp_sic_toa
from radioloc.channel.raytrace import C_LIGHT, LinkChannels, TraceConfig, trace_links_cached
from radioloc.channel.scene import Scene
from radioloc.core.errors import InputError
from radioloc.core.validation import as_positions


@dataclass(frozen=True)
class NetworkRanges:
    """Ranges measured in ``S`` hand-shake rounds of ``K`` nodes.

    sic_m, matched_filter_m: (S, K, K) range measured at master ``k`` (axis 1) to node ``i``
        (axis 2) in round ``s`` by OMP-SIC and by the matched filter; NaN on the diagonal and
        where nothing was detected.
    true_m: (K, K) distances. los: (K, K) line of sight. n_paths: (K, K) traced paths.
    first_path_m: (K, K) length of the earliest traced path (NaN without a path): the range
        a perfect first-arrival detector would report, NLOS excess included.
    rts_error_m: (S, K, K) the responder ``i``'s RTS first-arrival error towards master
        ``k``, as a length (``c (t_rts - tau_first)``); NaN where the responder did not
        detect the RTS (it then sends no ACK); 0 with ideal synchronisation.
    """

    sic_m: np.ndarray
    matched_filter_m: np.ndarray
    true_m: np.ndarray
    los: np.ndarray
    n_paths: np.ndarray
    first_path_m: np.ndarray
    rts_error_m: np.ndarray


def link_index(K: int) -> np.ndarray:
    """Index of the link ``{i, j}`` in the ``np.triu_indices(K, 1)`` order.

    Parameters
    ----------
    K : int
        Number of nodes.

    Returns
    -------
    ndarray of int, shape (K, K)
        Link index of every ordered pair; -1 on the diagonal.
    """
    idx = -np.ones((K, K), int)
    i, j = np.triu_indices(K, 1)
    idx[i, j] = np.arange(i.size)
    idx[j, i] = np.arange(i.size)
    return idx


def trace_network(scene: Scene, positions: np.ndarray, config: TraceConfig | None = None,
                  cache_dir: Path | str | None = None) -> LinkChannels:
    """Channels of every pair ``i < j`` (``np.triu_indices`` order), cached.

    Parameters
    ----------
    scene : Scene
    positions : ndarray (K, 2)
        Node positions, metres.
    config : TraceConfig, optional
    cache_dir : path, optional
        Ray-tracing cache.

    Returns
    -------
    LinkChannels
        ``K (K - 1) / 2`` links.
    """
    positions = as_positions(positions, "positions", dims=(2,))
    i, j = np.triu_indices(len(positions), 1)
    return trace_links_cached(scene, positions[i], positions[j], config, cache_dir)


def network_ranges(scene: Scene, positions: np.ndarray, rounds: int, rng: np.random.Generator,
                   *, trace: TraceConfig | None = None, cdma: CDMAConfig | None = None,
                   sic: OMPSICConfig | None = None, cache_dir: Path | str | None = None,
                   channels: LinkChannels | None = None) -> NetworkRanges:
    """Simulate ``rounds`` RTS/ACK hand-shakes at every master and estimate ranges.

    The ACK sets go through OMP-SIC and through the matched filter (both with the same
    RTS detections and ACK windows).

    Parameters
    ----------
    scene : Scene
    positions : ndarray (K, 2)
        True node positions (outside buildings). Node ``k`` uses Gold code ``k``.
    rounds : int
        ACK sets per master (paper: 28).
    rng : numpy Generator
        Jitter, path phases and noise (RTS and ACK).
    trace : TraceConfig or SionnaConfig, optional
        Channel provider and settings (used when ``channels`` is not given).
    cdma, sic : configs, optional
    cache_dir : path, optional
        Ray-tracing cache (default :func:`radioloc.channel.raytrace.default_cache_dir`).
    channels : LinkChannels, optional
        Already traced channels of the pairs (skips tracing).

    Returns
    -------
    NetworkRanges
    """
    positions = as_positions(positions, "positions", dims=(2,))
    if positions.ndim != 2 or len(positions) < 2:
        raise InputError(f"positions: expected (K >= 2, 2), got {positions.shape}")
    if int(rounds) != rounds or rounds < 1:
        raise InputError(f"rounds: expected a positive integer, got {rounds}")
    cdma = cdma or CDMAConfig()
    K = len(positions)
    codes = gold_codes(cdma.code_degree)
    if K > len(codes):
        raise InputError(f"positions: {K} nodes but only {len(codes)} Gold codes of degree {cdma.code_degree}")
    ch = channels if channels is not None else trace_network(scene, positions, trace, cache_dir)
    idx = link_index(K)
    # responders of master k: all j != k, in increasing order
    col = np.arange(K - 1)[None, :]
    resp = col + (col >= np.arange(K)[:, None])                                   # (K, K-1)
    links = idx[np.arange(K)[:, None], resp]                                      # (K, K-1)
    first = ch.first_delay()[links]                                               # (K, K-1)
    delays = ch.delays[links]                                                     # (K, K-1, P)
    gains = ch.gains[links]
    S = int(rounds)
    shape = (S, K, K - 1)
    P = delays.shape[-1]
    if cdma.rts_sync == "ideal":
        t_rts = np.broadcast_to(first, shape).copy()
    else:
        # the RTS of master k (code k) at every responder: one single-user window each
        if cdma.random_path_phases:
            g_rts = np.abs(gains)[None] * np.exp(2j * np.pi * rng.uniform(size=(S,) + gains.shape))
        else:
            g_rts = gains[None] * np.exp(2j * np.pi * rng.uniform(size=shape))[..., None]
        d_rts = np.broadcast_to(delays[None], g_rts.shape)
        g_rts = np.where(np.isfinite(d_rts), g_rts, 0.0)
        rts_code = np.broadcast_to(np.arange(K)[None, :, None], shape).reshape(-1, 1)
        y_rts = received_acks(d_rts.reshape(-1, 1, P), g_rts.reshape(-1, 1, P), rts_code, cdma,
                              rng, codes)
        t_rts = omp_sic_toa(y_rts, rts_code, codes, cdma, sic).toa_s.reshape(shape)
    jitter = rng.normal(0.0, cdma.turnaround_jitter_s, size=shape) if cdma.turnaround_jitter_s > 0 \
        else np.zeros(shape)
    arr = t_rts[..., None] + jitter[..., None] + delays[None]                     # (S, K, K-1, P)
    if cdma.random_path_phases:
        phase = rng.uniform(0, 2 * np.pi, size=arr.shape)
        g = np.abs(gains)[None] * np.exp(1j * phase)
    else:
        g = gains[None] * np.exp(2j * np.pi * rng.uniform(size=shape))[..., None]
    arr = np.where(np.isfinite(arr), np.maximum(arr, 0.0), np.nan)
    g = np.where(np.isfinite(arr), g, 0.0)
    B = S * K
    code_idx = np.broadcast_to(resp, (S, K, K - 1)).reshape(B, K - 1)
    y = received_acks(arr.reshape(B, K - 1, -1), g.reshape(B, K - 1, -1), code_idx, cdma, rng, codes)
    out = []
    for est in (omp_sic_toa, matched_filter_toa):
        toa = est(y, code_idx, codes, cdma, sic).toa_s.reshape(S, K, K - 1)
        r = np.full((S, K, K), np.nan)
        r[:, np.arange(K)[:, None], resp] = 0.5 * C_LIGHT * toa
        out.append(r)
    rts_err = np.full((S, K, K), np.nan)
    rts_err[:, np.arange(K)[:, None], resp] = C_LIGHT * (t_rts - first[None])
    true = np.linalg.norm(positions[:, None] - positions[None], axis=-1)
    los = np.zeros((K, K), bool)
    npaths = np.zeros((K, K), int)
    i, j = np.triu_indices(K, 1)
    los[i, j] = los[j, i] = ch.los
    npaths[i, j] = npaths[j, i] = ch.n_paths
    first_m = np.full((K, K), np.nan)
    first_m[i, j] = first_m[j, i] = ch.first_delay() * C_LIGHT
    return NetworkRanges(out[0], out[1], true, los, npaths, first_m, rts_err)
