"""Cooperative-network scenarios of paper 000: random node constellations with GPS-assisted
and unassisted priors, and the noisy pairwise ranges of repeated iterations.

Every function takes the generator it draws from; nothing here imports an estimator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.geometry import pairwise_distances
from radioloc.core.renamed import Renamed, renamed_keywords
from radioloc.core.validation import check_positive

__all__ = ["NetworkDraw", "draw_network", "iteration_ranges", "prior_variances"]


@dataclass(frozen=True)
class NetworkDraw:
    """A batch of random networks with their priors.

    Attributes
    ----------
    truth : ndarray, shape (R, K, 2)
        True node positions, metres.
    prior_mean : ndarray, shape (R, K, 2)
        Prior means: the truth plus Gaussian errors of the prior variances.
    prior_var : ndarray, shape (R, K, 2)
        Per-axis prior variances, m^2.
    assisted : ndarray of bool, shape (K,)
        Which nodes are GPS-assisted (the first ones).
    """

    truth: np.ndarray
    prior_mean: np.ndarray
    prior_var: np.ndarray
    assisted: np.ndarray


def prior_variances(runs: int, nodes: int, assisted: int, var_assisted_m2: float,
                    var_unassisted_m2: float) -> np.ndarray:
    """Per-axis prior variances: the first ``assisted`` nodes get ``var_assisted_m2``.

    Parameters
    ----------
    runs, nodes, assisted : int
        ``R``, ``K`` and the number of GPS-assisted nodes.
    var_assisted_m2, var_unassisted_m2 : float
        Per-axis prior variances of the two classes, m^2.

    Returns
    -------
    ndarray, shape (R, K, 2)
    """
    if not 0 <= assisted <= nodes:
        raise InputError(f"assisted: must lie in 0..{nodes}, got {assisted}")
    check_positive(var_assisted_m2, "var_assisted_m2")
    check_positive(var_unassisted_m2, "var_unassisted_m2")
    var = np.where(np.arange(nodes) < assisted, var_assisted_m2, var_unassisted_m2)
    return np.broadcast_to(var[None, :, None], (runs, nodes, 2)).astype(float)


def draw_network(rng: np.random.Generator, runs: int, nodes: int, assisted: int, *,
                 side_m: float, var_assisted_m2: float, var_unassisted_m2: float
                 ) -> NetworkDraw:
    """``runs`` networks of ``nodes`` nodes uniform in a square, with Gaussian priors.

    Draw order (kept for reproducibility): the positions ``(R, K, 2)``, then the prior
    errors ``(R, K, 2)``.

    Parameters
    ----------
    rng : Generator
    runs, nodes, assisted : int
        ``R``, ``K`` and the number of GPS-assisted nodes (the first ones).
    side_m : float
        Side of the square ``[0, side_m]^2``.
    var_assisted_m2, var_unassisted_m2 : float
        Per-axis prior variances, m^2.

    Returns
    -------
    NetworkDraw
    """
    check_positive(side_m, "side_m")
    var = prior_variances(runs, nodes, assisted, var_assisted_m2, var_unassisted_m2)
    truth = rng.uniform(0.0, side_m, size=(runs, nodes, 2))
    prior = truth + rng.normal(size=truth.shape) * np.sqrt(var)
    return NetworkDraw(truth, prior, var, np.arange(nodes) < assisted)


@renamed_keywords({"range_var_m2": Renamed("std_m", variance=True)},
                  positional=("range_var_m2", "rng"))
def iteration_ranges(truth: np.ndarray, iterations: int, *, std_m: float,
                     rng: np.random.Generator) -> np.ndarray:
    """Noisy ranges of every ordered pair (master ``k``, node ``i``) at every iteration.

    Each entry gets an independent Gaussian error of standard deviation ``std_m``; ranges
    are not clipped at 0. The errors are drawn in the order ``(N, R, K, K)``.

    Parameters
    ----------
    truth : ndarray, shape (R, K, 2)
        True positions, metres.
    iterations : int
        ``N``.
    std_m : float
        Range noise standard deviation, metres (the paper's ``sigma_v^2 = 900 m^2`` is
        ``std_m=30``). The old third argument ``range_var_m2`` (m^2) still works with a
        ``FutureWarning``.
    rng : Generator

    Returns
    -------
    ndarray, shape (R, N, K, K)
        ``ranges[r, n, k, i]``: range at master ``k`` to node ``i`` in iteration ``n``.
    """
    check_positive(std_m, "std_m", allow_zero=True)
    D = pairwise_distances(truth)                                    # (R, K, K)
    R, K = D.shape[:2]
    noise = rng.normal(size=(int(iterations), R, K, K)) * std_m
    return D[:, None] + noise.transpose(1, 0, 2, 3)
