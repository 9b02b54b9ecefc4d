"""Ranges of a whole network from ray-traced channels, RTS/ACK hand-shakes and GSIC.

Every node in turn is the master; the other ``K - 1`` nodes answer its RTS at once. The
channels of the ``K (K - 1) / 2`` links are traced once (cached) and are reciprocal. For
each ACK set the responder ``j`` of master ``k`` starts its ACK ``turnaround_s`` plus a
Gaussian jitter after the first path of the RTS reaches it, so its ACK reaches the master
at ``tau_first(k, j) + jitter + tau_p(j, k)`` after the turnaround; the master's round-trip
estimate is the first arrival ``t``, its range ``c t / 2``. A responder with no path to
the master never hears the RTS and sends nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radioloc.channel.cdma import CDMAConfig, gold_codes, received_acks
from radioloc.channel.gsic import GSICConfig, gsic_toa, matched_filter_toa
from radioloc.channel.raytrace import C_LIGHT, LinkChannels, TraceConfig, trace_links_cached
from radioloc.channel.scene import Scene
from radioloc.core.errors import InputError
from radioloc.core.validation import as_positions


@dataclass(frozen=True)
class NetworkRanges:
    """Ranges measured in ``S`` hand-shake rounds of ``K`` nodes.

    gsic_m, matched_filter_m: (S, K, K) range measured at master ``k`` (axis 1) to node ``i``
        (axis 2) in round ``s``; NaN on the diagonal and where nothing was detected.
    true_m: (K, K) distances. los: (K, K) line of sight. n_paths: (K, K) traced paths.
    first_path_m: (K, K) length of the earliest traced path (NaN without a path): the range
        a perfect first-arrival detector would report, NLOS excess included.
    """

    gsic_m: np.ndarray
    matched_filter_m: np.ndarray
    true_m: np.ndarray
    los: np.ndarray
    n_paths: np.ndarray
    first_path_m: np.ndarray


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
                   gsic: GSICConfig | None = None, cache_dir: Path | str | None = None,
                   channels: LinkChannels | None = None) -> NetworkRanges:
    """Simulate ``rounds`` ACK sets at every master and estimate ranges (GSIC and matched filter).

    Parameters
    ----------
    scene : Scene
    positions : ndarray (K, 2)
        True node positions (outside buildings). Node ``k`` uses Gold code ``k``.
    rounds : int
        ACK sets per master (paper: 28).
    rng : numpy Generator
        Jitter, path phases and noise.
    trace, cdma, gsic : configs, optional
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
    jitter = rng.normal(0.0, cdma.turnaround_jitter_s, size=shape) if cdma.turnaround_jitter_s > 0 \
        else np.zeros(shape)
    arr = first[None, :, :, None] + jitter[..., None] + delays[None]              # (S, K, K-1, P)
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
    for est in (gsic_toa, matched_filter_toa):
        toa = est(y, code_idx, codes, cdma, gsic).toa_s.reshape(S, K, K - 1)
        r = np.full((S, K, K), np.nan)
        r[:, np.arange(K)[:, None], resp] = 0.5 * C_LIGHT * toa
        out.append(r)
    true = np.linalg.norm(positions[:, None] - positions[None], axis=-1)
    los = np.zeros((K, K), bool)
    npaths = np.zeros((K, K), int)
    i, j = np.triu_indices(K, 1)
    los[i, j] = los[j, i] = ch.los
    npaths[i, j] = npaths[j, i] = ch.n_paths
    first_m = np.full((K, K), np.nan)
    first_m[i, j] = first_m[j, i] = ch.first_delay() * C_LIGHT
    return NetworkRanges(out[0], out[1], true, los, npaths, first_m)
