"""The shortcuts of the particle-link kernel (pf_kernels.link_weights) give the values of its
full path bit for bit.

A link of a chunk skips ``erfcx`` when every particle has ``u = e / s - lam s >= 8.5`` and
also skips the ``E_1`` exponential and the division when every particle has ``-z^2 / 2 <
-745.2`` (``E_1 = 0``). The per-particle outputs (log weight, new link posterior, online-EM
sums) of one particle do not depend on the other particles, so appending one particle far
from every range (``u`` very negative on every link) forces the full path on every link and
must leave the outputs of the others unchanged, bit for bit. The inputs place the particle
cloud so that each link is in one class: erfcx skipped, NLOS-only, general, log domain.
"""

import numpy as np
import pytest

from radioloc.estimators import pf_kernels as K
from radioloc.estimators.p2p_particle import CHUNK, _link_update, _link_update_numpy

S_LOS, NLOS_MEAN = 0.05, 5.0          # lam s = 0.01


def _cloud(seed, k=300):
    """One filter: a particle cloud of radius 0.3 m and links whose ranges put every
    particle's residual ``e`` in a chosen interval (m)."""
    rng = np.random.default_rng(seed)
    particles = rng.uniform(-0.3, 0.3, (1, k, 2)) + [10.0, 5.0]
    node_xy = np.array([[[40.0, 5.0], [10.0, 30.0], [-20.0, 0.0], [10.0, -25.0],
                         [30.0, 30.0], [0.0, 0.0], [-10.0, 20.0]]])
    d = np.linalg.norm(particles[0, :, None, :] - node_xy[0], axis=-1)       # (k, L)
    th = np.array([[d[:, 0].max() + 0.45,      # e in [0.45, 1.1]: u >= 8.5, z < 38.6
                    d[:, 1].max() + 2.5,       # e >= 2.5: z >= 50, E_1 = 0 (NLOS only)
                    d[:, 2].mean(),            # e both signs: the general path
                    d[:, 3].min() - 1.5,       # e <= -1.5: z <= -30, log domain
                    d[:, 4].max() + 0.45,      # as link 0, but a new neighbour
                    0.0,                       # padding
                    d[:, 6].max() + 0.16]])    # u from 3.2 up: erfcx needed
    valid = np.array([[True, True, True, True, True, False, True]])
    where_prev = np.array([[2, 0, 1, 3, -1, -1, 0]])
    prev_q = rng.random((1, k, 4))
    prev_q[0, ::5] = 0.0
    prev_q[0, 1::7] = 1.0
    params = np.array([[S_LOS, NLOS_MEAN, 0.3]])
    return particles, node_xy, th, valid, where_prev, prev_q, params


def _with_far_particle(args):
    particles, node_xy, th, valid, where_prev, prev_q, params = args
    far = np.concatenate([particles, [[[1000.0, 1000.0]]]], axis=1)
    q = np.concatenate([prev_q, np.full((1, 1, prev_q.shape[-1]), 0.5)], axis=1)
    return far, node_xy, th, valid, where_prev, q, params


def test_residual_classes_of_the_inputs():
    particles, node_xy, th, valid, *_ = _cloud(0)
    e = th[0] - np.linalg.norm(particles[0, :, None, :] - node_xy[0], axis=-1)
    z = e / S_LOS
    u = z - S_LOS / NLOS_MEAN
    assert np.all(u[:, 0] >= 8.5) and np.any(-0.5 * z[:, 0] ** 2 >= -745.2)
    assert np.all(-0.5 * z[:, 1] ** 2 < -745.2)
    assert np.any(u[:, 2] < 0) and np.any(u[:, 2] > 0)
    assert np.all(z[:, 3] < -26)
    assert np.all(u[:, 6] > 3) and np.any(u[:, 6] < 8.5)


def test_vexp_floor_is_exactly_zero():
    # the NLOS-only loop sets E_1 = 0 where -z^2 / 2 < -745.2: vexp clamps its argument
    # there and must return exactly 0
    f = K.njit(lambda x: K.vexp(x))
    assert f(K._EXP_LO) == 0.0
    assert f(-1e4) == 0.0
    assert f(-745.1) > 0.0


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("em", [False, True])
def test_shortcut_links_equal_the_full_path_bit_for_bit(seed, em):
    args = _cloud(seed)
    k = args[0].shape[1]
    assert k + 1 <= CHUNK                      # one chunk: the far particle forces every link
    fast = _link_update(*args, "numba", em)
    full = _link_update(*_with_far_particle(args), "numba", em)
    np.testing.assert_array_equal(fast[0], full[0][..., :k])           # log w
    np.testing.assert_array_equal(fast[1], full[1][..., :k, :])        # new posteriors
    if em:
        np.testing.assert_array_equal(fast[3], full[3][..., :k, :])
    # the classes did their work: link 1 NLOS only (posterior exactly 0), link 3 in the
    # log domain (posterior from exp(A1 - lse): strictly between 0 and 1 or 0)
    assert np.all(fast[1][0, :, 1] == 0.0)
    assert np.all(fast[1][0, :, 5] == 0.0)


@pytest.mark.parametrize("seed", [0, 1])
def test_shortcut_links_equal_the_numpy_reference(seed):
    # same tolerance as tests/test_pf_kernels_reference.py (log domain vs linear domain
    # with vexp/verfcx: about 1e-13 relative per link)
    args = _cloud(seed)
    ref = _link_update_numpy(*args)
    fast = _link_update(*args, "numba", True)
    valid = args[3]
    np.testing.assert_allclose(fast[0], ref[0], rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(fast[1], np.where(valid[..., None, :], ref[1], 0), rtol=1e-9,
                               atol=1e-12)
    np.testing.assert_allclose(fast[3], ref[3], rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(fast[2][..., 1] > fast[2][..., 0],
                                  ref[2][..., 1] > ref[2][..., 0])
