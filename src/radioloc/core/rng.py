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


#: Spawn keys of named streams start here; block keys are small integers below it.
_NAMED_KEY = 2**32


def stream_seed(seed: int, name: str) -> np.random.SeedSequence:
    """The seed sequence of the named child stream ``name`` of ``SeedSequence(seed)``.

    Named streams hold an experiment's draws that are not per-run (a calibration set, a
    scene, the example shown in a figure): they change with ``--seed`` like every other
    draw, and never coincide with a block's stream.
    """
    import zlib

    return np.random.SeedSequence(entropy=int(seed),
                                  spawn_key=(_NAMED_KEY + zlib.crc32(name.encode()),))


def experiment_seed(rng: np.random.Generator) -> int:
    """The experiment seed behind a block generator made by :func:`block_generator`."""
    seq = getattr(rng.bit_generator, "seed_seq", None)
    if (not isinstance(seq, np.random.SeedSequence) or not isinstance(seq.entropy, int)
            or len(seq.spawn_key) != 1 or seq.spawn_key[0] >= _NAMED_KEY):
        from radioloc.core.errors import ConfigError

        raise ConfigError("experiment_seed: the generator was not made by block_generator")
    return int(seq.entropy)


def stream(seed: int | np.random.Generator, name: str) -> np.random.Generator:
    """A generator for the named child stream ``name`` of the experiment's seed.

    ``seed`` is the experiment seed or any block generator of the experiment (whose seed
    is then recovered with :func:`experiment_seed`), so that ``run_block`` can draw a
    per-experiment calibration without knowing the seed: every block draws the same one.
    """
    s = experiment_seed(seed) if isinstance(seed, np.random.Generator) else int(seed)
    return np.random.default_rng(stream_seed(s, name))
