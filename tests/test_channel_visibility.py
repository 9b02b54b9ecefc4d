"""Pruning structures of the compiled ray tracer: the wall-to-wall visibility lists (a
sub-list of the follower lists; every pair they drop is really hidden, by the shapely
reference), and the tracer on network links whose end points are shared (equal to the NumPy/shapely reference)."""

import numpy as np
import pytest
from test_channel_raytrace import _rotated_scene

from radioloc.channel.scene import Scene, city_grid


def _pairs(start, walls):
    p = np.repeat(np.arange(len(start) - 1), np.diff(start))
    return set(zip(p.tolist(), walls.tolist()))


def test_visible_followers_are_followers_in_order_and_prune():
    scene = city_grid(0)
    fs, fw = scene.facing
    vs, vw = scene.visible
    assert vs.shape == fs.shape and vs[0] == 0 and vs[-1] == len(vw)
    for p in range(len(fs) - 1):
        v = vw[vs[p]:vs[p + 1]]
        assert np.all(np.diff(v) > 0)
        assert np.all(np.isin(v, fw[fs[p]:fs[p + 1]]))
    assert len(vw) < 0.5 * len(fw)          # a city hides most of the walls facing a wall


def test_hidden_pairs_have_no_clear_segment():
    rng = np.random.default_rng(7)
    for scene in (city_grid(rng, size_m=500.0), _rotated_scene(rng)):
        hidden = sorted(_pairs(*scene.facing) - _pairs(*scene.visible))
        assert len(hidden) > 100
        pick = rng.choice(len(hidden), size=min(400, len(hidden)), replace=False)
        p, w = np.array(hidden)[pick].T
        u = rng.uniform(0.01, 0.99, (len(p), 20, 1))
        v = rng.uniform(0.01, 0.99, (len(p), 20, 1))
        W = scene.walls
        a = W[p, 0][:, None] + u * (W[p, 1] - W[p, 0])[:, None]
        b = W[w, 0][:, None] + v * (W[w, 1] - W[w, 0])[:, None]
        assert scene.blocked(a, b, backend="numpy").all()


def test_two_facing_walls_with_a_block_between():
    # two slabs facing each other, a block between them spanning the whole gap: hidden;
    # a narrow block leaves the pair visible
    slabs = [[(-50, 40), (50, 40), (50, 50), (-50, 50)], [(-50, -50), (50, -50), (50, -40), (-50, -40)]]
    for mid, hidden in (([(-60, -5), (60, -5), (60, 5), (-60, 5)], True),
                        ([(-5, -5), (5, -5), (5, 5), (-5, 5)], False)):
        scene = Scene.from_polygons(slabs + [mid])
        W = scene.walls
        top = int(np.flatnonzero((W[:, :, 1] == 40).all(axis=1))[0])
        bottom = int(np.flatnonzero((W[:, :, 1] == -40).all(axis=1))[0])
        assert (top, bottom) in _pairs(*scene.facing)
        assert ((top, bottom) not in _pairs(*scene.visible)) == hidden


@pytest.mark.parametrize("order", [2, 3])
def test_compiled_tracer_equals_reference_on_network_links(order):
    # all pairs of a few nodes, both directions: end points shared between links (the
    # compiled tracer tests walls and corners once per distinct end point)
    from radioloc.channel.raytrace import TraceConfig, trace_links
    from radioloc.channel.scene import street_positions
    rng = np.random.default_rng(20 + order)
    for scene in (city_grid(rng, size_m=500.0), _rotated_scene(rng)):
        nodes = street_positions(scene, 5, rng, half_width_m=200.0)
        i, j = np.nonzero(~np.eye(5, dtype=bool))
        cfg = TraceConfig(max_order=order, max_excess_m=300.0)
        fast = trace_links(scene, nodes[i], nodes[j], cfg)
        ref = trace_links(scene, nodes[i], nodes[j], cfg, backend="numpy")
        np.testing.assert_array_equal(fast.n_paths, ref.n_paths)
        np.testing.assert_array_equal(fast.kind, ref.kind)
        np.testing.assert_array_equal(fast.los, ref.los)
        np.testing.assert_allclose(fast.delays, ref.delays, rtol=1e-12, atol=0)
        np.testing.assert_allclose(fast.gains, ref.gains, rtol=1e-9, atol=1e-15)
        assert (ref.kind > 1).sum() > 5 and (ref.kind == -1).sum() > 0
