"""Ray tracer: hand-computed single-wall and street-canyon paths, opaque buildings,
unreachable links, caching, input errors."""

import json

import numpy as np
import pytest
from shapely.geometry import box

from radioloc.channel.raytrace import (C_LIGHT, TraceConfig, knife_edge_loss_db, trace_links,
                                       trace_links_cached)
from radioloc.channel.scene import Scene, city_grid, scene_from_geojson, street_positions
from radioloc.core.errors import ConfigError, InputError


def test_single_wall_reflection_delay_and_free_space_gain():
    cfg = TraceConfig(max_order=3)
    lam = C_LIGHT / cfg.carrier_hz
    scene = Scene.from_polygons([box(-100, 10, 100, 20)])
    ch = trace_links(scene, [[0.0, 0.0]], [[30.0, 0.0]], cfg)
    assert ch.n_paths[0] == 2 and ch.los[0]
    L = np.hypot(30.0, 20.0)                                # image of tx at (0, 20)
    np.testing.assert_allclose(ch.delays[0, :2], [30.0 / C_LIGHT, L / C_LIGHT], rtol=1e-12)
    cos_t = 20.0 / L
    root = np.sqrt(cfg.wall_permittivity - (1 - cos_t**2))
    gamma = (cos_t - root) / (cos_t + root)
    np.testing.assert_allclose(ch.gains[0, 0], lam / (4 * np.pi * 30) * np.exp(-2j * np.pi * 30 / lam))
    np.testing.assert_allclose(ch.gains[0, 1], gamma * lam / (4 * np.pi * L) * np.exp(-2j * np.pi * L / lam))
    assert list(ch.kind[0, :2]) == [0, 1]


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_street_canyon_image_orders(order):
    scene = Scene.from_polygons([box(-200, 10, 200, 20), box(-200, -20, 200, -10)])
    ch = trace_links(scene, [[0.0, 0.0]], [[30.0, 0.0]], TraceConfig(max_order=order))
    assert ch.n_paths[0] == 1 + 2 * order
    expect = np.sort(np.concatenate([[30.0], np.repeat(np.hypot(30.0, 20.0 * np.arange(1, order + 1)), 2)]))
    np.testing.assert_allclose(ch.delays[0, : ch.n_paths[0]] * C_LIGHT, expect, rtol=1e-12)


def test_no_path_through_opaque_building():
    scene = Scene.from_polygons([box(-20, -20, 20, 20)])
    tx, rx = np.array([[-50.0, 0.0]]), np.array([[50.0, 0.0]])
    ch = trace_links(scene, tx, rx, TraceConfig(max_order=3, diffraction=False))
    assert ch.n_paths[0] == 0 and not ch.los[0] and ch.no_path[0]
    assert np.isnan(ch.first_delay()[0])
    # single-edge diffraction cannot turn round a block (two edges needed): still no path
    ch = trace_links(scene, tx, rx, TraceConfig(max_order=3))
    assert ch.n_paths[0] == 0


def test_diffraction_over_a_wedge_apex():
    from shapely.geometry import Polygon
    cfg = TraceConfig(max_order=3)
    scene = Scene.from_polygons([Polygon([(-20, -20), (20, -20), (0, 20)])])
    ch = trace_links(scene, [[-50.0, 0.0]], [[50.0, 0.0]], cfg)
    assert ch.n_paths[0] == 1 and ch.kind[0, 0] == -1 and not ch.los[0]
    L = 2 * np.hypot(50.0, 20.0)
    np.testing.assert_allclose(ch.delays[0, 0] * C_LIGHT, L)
    nu = 2 * np.sqrt((L - 100.0) / cfg.wavelength_m)
    amp = cfg.wavelength_m / (4 * np.pi * L) * 10 ** (-knife_edge_loss_db(nu) / 20)
    np.testing.assert_allclose(np.abs(ch.gains[0, 0]), amp)


def test_knife_edge_loss_known_values():
    np.testing.assert_allclose(knife_edge_loss_db(0.0), 6.02, atol=0.05)   # grazing: -6 dB
    assert knife_edge_loss_db(-1.0) == 0.0
    assert knife_edge_loss_db(3.0) > knife_edge_loss_db(1.0) > 6.0


def test_batched_equals_one_by_one_and_cache(tmp_path):
    scene = city_grid(1, size_m=500.0)
    rng = np.random.default_rng(0)
    from radioloc.channel.scene import street_positions
    p = street_positions(scene, 4, rng, half_width_m=200.0)
    tx, rx = p[[0, 1, 2]], p[[3, 2, 0]]
    cfg = TraceConfig(max_order=2)
    both = trace_links(scene, tx, rx, cfg)
    for i in range(3):
        one = trace_links(scene, tx[i:i + 1], rx[i:i + 1], cfg)
        n = one.n_paths[0]
        assert both.n_paths[i] == n
        np.testing.assert_allclose(both.delays[i, :n], one.delays[0, :n])
        np.testing.assert_allclose(both.gains[i, :n], one.gains[0, :n])
    first = trace_links_cached(scene, tx, rx, cfg, tmp_path)
    assert len(list(tmp_path.glob("*.npz"))) == 1
    again = trace_links_cached(scene, tx, rx, cfg, tmp_path)
    np.testing.assert_array_equal(first.gains, again.gains)
    np.testing.assert_array_equal(first.n_paths, both.n_paths)
    trace_links_cached(scene, tx, rx, TraceConfig(max_order=1), tmp_path)
    assert len(list(tmp_path.glob("*.npz"))) == 2              # key includes the config


def test_reciprocity():
    scene = city_grid(2, size_m=400.0)
    from radioloc.channel.scene import street_positions
    p = street_positions(scene, 2, np.random.default_rng(3), half_width_m=150.0)
    a = trace_links(scene, p[:1], p[1:])
    b = trace_links(scene, p[1:], p[:1])
    assert a.n_paths[0] == b.n_paths[0]
    n = a.n_paths[0]
    np.testing.assert_allclose(a.delays[0, :n], b.delays[0, :n])
    np.testing.assert_allclose(np.sort(np.abs(a.gains[0, :n])), np.sort(np.abs(b.gains[0, :n])))


def test_city_grid_seeded_and_geojson(tmp_path):
    a, b, c = city_grid(5), city_grid(5), city_grid(6)
    assert a.digest() == b.digest() != c.digest()
    span = np.ptp(a.walls.reshape(-1, 2), axis=0)
    assert np.all((span > 800) & (span < 1000))
    feats = [{"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [
        [[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]]]}}]
    path = tmp_path / "b.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    s = scene_from_geojson(path)
    assert len(s.polygons) == 1 and s.walls.shape == (4, 2, 2)
    # outward normals of a counter-clockwise square
    centre = np.array([5.0, 5.0])
    mid = s.walls.mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", mid - centre, s.normals) > 0)


def test_bad_input():
    scene = Scene.from_polygons([box(0, 0, 10, 10)])
    with pytest.raises(InputError, match="tx"):
        trace_links(scene, [[5.0, 5.0]], [[20.0, 20.0]])
    with pytest.raises(InputError, match="rx"):
        trace_links(scene, [[20.0, 5.0]], [[np.nan, 1.0]])
    with pytest.raises(ConfigError, match="max_order"):
        TraceConfig(max_order=-1)
    with pytest.raises(InputError, match="polygons"):
        Scene.from_polygons([[[0, 0], [1, 1]]])
    with pytest.raises(InputError, match="geojson"):
        scene_from_geojson("/nonexistent/file.geojson")


from hypothesis import given, settings, strategies as st  # noqa: E402

_CANYON = Scene.from_polygons([box(-300, 10, 300, 30), box(-300, -30, 300, -10), box(40, -8, 60, 8)])


@settings(max_examples=30, deadline=None)
@given(st.floats(-250, 250), st.floats(-9, 9), st.floats(-250, 250), st.floats(-9, 9))
def test_paths_never_shorter_than_straight_line_and_reciprocal(x0, y0, x1, y1):
    a, b = np.array([[x0, y0]]), np.array([[x1, y1]])
    if _CANYON.inside(np.vstack([a, b]), 0.5).any() or np.hypot(x1 - x0, y1 - y0) < 1.0:
        return
    cfg = TraceConfig(max_order=2)
    fwd, back = trace_links(_CANYON, a, b, cfg), trace_links(_CANYON, b, a, cfg)
    n = fwd.n_paths[0]
    assert back.n_paths[0] == n
    d = np.hypot(x1 - x0, y1 - y0)
    assert np.all(fwd.delays[0, :n] * C_LIGHT >= d - 1e-6)
    np.testing.assert_allclose(fwd.delays[0, :n], back.delays[0, :n], rtol=1e-9)
    assert fwd.los[0] == (n > 0 and fwd.kind[0, 0] == 0)
    # free-space amplitude bound: no path is stronger than free space over its length
    lam = cfg.wavelength_m
    assert np.all(np.abs(fwd.gains[0, :n]) <= lam / (4 * np.pi * fwd.delays[0, :n] * C_LIGHT) * (1 + 1e-9))


def _rotated_scene(rng, n=25):
    """Random rotated rectangles and L-shapes (walls at every angle, concave footprints)."""
    from shapely.affinity import rotate
    from shapely.geometry import box as _box
    polys = []
    for _ in range(n * 3):
        c = rng.uniform(-200, 200, 2)
        p = _box(*(c - rng.uniform(5, 25, 2)), *(c + rng.uniform(5, 25, 2)))
        if rng.random() < 0.4:                                   # an L-shaped (concave) block
            p = p.difference(_box(*c, *(c + 30)))
        p = rotate(p, rng.uniform(0, 180))
        if all(not p.buffer(2.0).intersects(q) for q in polys):
            polys.append(p)
        if len(polys) == n:
            break
    return Scene.from_polygons(polys)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_compiled_tracer_equals_numpy_reference_on_random_links(order):
    rng = np.random.default_rng(order)
    for scene in (city_grid(rng, size_m=500.0), _rotated_scene(rng)):
        pts = street_positions(scene, 16, rng, half_width_m=200.0)
        tx, rx = pts[:8], pts[8:]
        cfg = TraceConfig(max_order=order, max_excess_m=400.0)
        fast = trace_links(scene, tx, rx, cfg)
        ref = trace_links(scene, tx, rx, cfg, backend="numpy")
        np.testing.assert_array_equal(fast.n_paths, ref.n_paths)
        np.testing.assert_array_equal(fast.kind, ref.kind)
        np.testing.assert_array_equal(fast.los, ref.los)
        np.testing.assert_allclose(fast.delays, ref.delays, rtol=1e-12, atol=0)
        np.testing.assert_allclose(fast.gains, ref.gains, rtol=1e-9, atol=1e-15)
        assert ref.n_paths.sum() > 8


def test_compiled_blocking_equals_shapely_on_random_segments():
    rng = np.random.default_rng(3)
    for scene in (city_grid(rng, size_m=500.0), _rotated_scene(rng)):
        a = rng.uniform(-260, 260, (6000, 2))
        a = a[~scene.inside(a)]
        b = a + rng.normal(0, 120, a.shape)
        fast = scene.blocked(a, b)
        ref = scene.blocked(a, b, backend="numpy")
        np.testing.assert_array_equal(fast, ref)
        assert 0.2 < ref.mean() < 0.95
    with pytest.raises(ConfigError, match="backend"):
        scene.blocked(a, b, backend="gpu")
