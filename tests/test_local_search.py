"""The snapshot search's coarse lattice: per-problem spacings and sizes in one batch, scored
in blocks of any size, give each problem the best point of its own lattice (the first of
equal scores), as the lattice listed out and scored at once does."""

from __future__ import annotations

import numpy as np
import pytest

from radioloc.estimators.local_search import best_candidate, best_on_lattice, local_grid

CENTRE = np.array([[2.0, -1.0], [50.0, 30.0], [0.0, 0.0]])
SPACING = np.array([1.0, 2.5, 0.5])
HALF_POINTS = np.array([3, 6, 1])
PEAK = np.array([[4.2, 0.9], [41.0, 37.6], [9.0, 9.0]])      # the last outside its lattice


def bowl(x, peak):
    """A bowl around ``peak``, flat (tied) beyond 6 m of it."""
    return -np.minimum(np.linalg.norm(x - peak, axis=-1), 6.0)


def objective(x):
    return bowl(x, PEAK[:, None, :])


def listed_out(b):
    """Problem ``b``'s lattice as explicit candidates, ``local_grid`` order."""
    n = HALF_POINTS[b]
    return CENTRE[b] + local_grid(n * SPACING[b], 2 * n + 1)


@pytest.mark.parametrize("block", [1, 7, 2**18])
def test_blocks_of_any_size_give_each_problem_the_best_of_its_own_lattice(block):
    best, score = best_on_lattice(objective, CENTRE, SPACING, HALF_POINTS, block=block)
    for b in range(3):
        cand = listed_out(b)
        want = best_candidate(lambda x, p=PEAK[b]: bowl(x, p), cand, np.ones(len(cand), dtype=bool))
        np.testing.assert_allclose(best[b], want, rtol=0, atol=1e-12)
        assert score[b] == bowl(cand, PEAK[b]).max()
    # known answers: the lattice point nearest each peak; the third problem's lattice lies
    # more than 6 m from its peak, every point ties, and the first one wins
    np.testing.assert_allclose(best[0], [4.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(best[1], [40.0, 37.5], atol=1e-12)
    np.testing.assert_allclose(best[2], [-0.5, -0.5], atol=1e-12)
