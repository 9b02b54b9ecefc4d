"""Randomness: generators are passed in, never global.

Monte Carlo runs are grouped in fixed-size *blocks*. Block ``b`` of an experiment with
seed ``s`` always draws from ``SeedSequence(s).spawn(...)[b]``, whatever the number of
runs requested, the number of workers or the engine, so results never depend on how the
work is scheduled.
"""

from __future__ import annotations

import numpy as np


def block_seed(seed: int, block: int) -> np.random.SeedSequence:
    """The seed sequence of block ``block``: the ``block``-th child of ``SeedSequence(seed)``.

    Equal to ``np.random.SeedSequence(seed).spawn(block + 1)[block]``.
    """
    return np.random.SeedSequence(entropy=seed, spawn_key=(block,))


def block_generator(seed: int, block: int) -> np.random.Generator:
    """A PCG64 generator for one block of runs."""
    return np.random.default_rng(block_seed(seed, block))


def as_generator(rng: np.random.Generator | int | None) -> np.random.Generator:
    """Accept a Generator, an integer seed or None (fresh entropy)."""
    if isinstance(rng, np.random.Generator):
        return rng
    return np.random.default_rng(rng)
