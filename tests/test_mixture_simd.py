"""The West/Runnalls reduction on SIMD lanes (``models.mixture._west_lanes``: groups of
``_LANES`` 2-D mixtures with the same component count): the same results bit for bit as the
NumPy reference and as the one-mixture kernel (a batch of one never takes the lanes), in
full groups, a part group padded with copies, groups with lanes whose lowest weights tie
(such a lane finishes alone; the lanes stop when fewer than half are left), candidates the
cost bound cannot exclude (that merge on a copy), and mixed component counts (no lanes)."""

import numpy as np

from radioloc.models.mixture import _LANES, DiagMixture, product, reduce, reduce_reference


def _assert_same(a, b):
    np.testing.assert_array_equal(a.weights, b.weights)
    np.testing.assert_array_equal(a.means, b.means)
    np.testing.assert_array_equal(a.variances, b.variances)


def _batch(rng, n, k=8, spread=3.0):
    a = DiagMixture.create(rng.uniform(0.1, 1, (n, k)), rng.normal(0, spread, (n, k, 2)),
                           rng.uniform(0.5, 2, (n, k, 2)))
    b = DiagMixture.create(rng.uniform(0.1, 1, (n, k)), rng.normal(0, spread, (n, k, 2)),
                           rng.uniform(0.5, 2, (n, k, 2)))
    return a, b


def _one_by_one(mix, kmax):
    """The one-mixture kernel per row (a batch of one is reduced without lanes), padded to
    the batch's component count."""
    outs = [reduce(mix[i:i + 1], kmax) for i in range(mix.batch_shape[0])]
    kk = max(o.n_components for o in outs)
    w = np.zeros((len(outs), kk))
    m = np.zeros((len(outs), kk, 2))
    v = np.ones((len(outs), kk, 2))
    for i, o in enumerate(outs):
        n = o.n_components
        w[i, :n], m[i, :n], v[i, :n] = o.weights[0], o.means[0], o.variances[0]
    return DiagMixture(w, m, v)


def test_lanes_equal_reference_and_one_by_one():
    rng = np.random.default_rng(41)
    a, b = _batch(rng, 2 * _LANES - 5)                    # a full group, a padded part group
    mix = product(a, b)
    for kmax in (8, 1):
        fast = reduce(mix, kmax)
        _assert_same(fast, reduce_reference(mix, kmax))
        _assert_same(fast, _one_by_one(mix, kmax))


def test_lanes_with_tied_lowest_weights_and_close_candidates():
    """product(a, a) ties its weights in pairs (most lanes finish alone, the lanes stop);
    means packed close together leave candidates the bound cannot exclude; one group with
    ties in a few lanes only."""
    rng = np.random.default_rng(42)
    a, b = _batch(rng, _LANES, spread=0.05)
    close = product(a, b)
    tied = product(a, a)
    w = close.weights.copy()
    w[:3, 5] = w[:3, 9]                                   # three lanes with one weight tie
    few = DiagMixture(w / w.sum(-1, keepdims=True), close.means, close.variances)
    for mix in (close, tied, few):
        fast = reduce(mix, 6)
        _assert_same(fast, reduce_reference(mix, 6))
        _assert_same(fast, _one_by_one(mix, 6))


def test_mixed_component_counts_and_empty_slots():
    """Zero-weight slots: a group with different counts is reduced mixture by mixture; a
    group with the same count below the full width still takes the lanes."""
    rng = np.random.default_rng(43)
    a, b = _batch(rng, 2 * _LANES)
    mix = product(a, b)
    w = mix.weights.copy()
    w[:_LANES, 7] = 0.0                                   # first group: all 63 components
    w[_LANES + 1, 3] = 0.0                                # second group: mixed counts
    mix = DiagMixture(w, mix.means, mix.variances)
    fast = reduce(mix, 5)
    _assert_same(fast, reduce_reference(mix, 5))
    _assert_same(fast, _one_by_one(mix, 5))
