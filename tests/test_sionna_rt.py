"""Sionna RT channel provider: a small street scene traced in 3-D (skips when the optional
``radioloc[rt]`` extra or its LLVM library cannot be loaded), and the install hint when absent."""

import sys

import numpy as np
import pytest

from radioloc.channel import sionna_rt
from radioloc.channel.raytrace import C_LIGHT, TraceConfig, trace_links, trace_links_cached
from radioloc.channel.scene import Scene
from radioloc.core.errors import ConfigError

OK, WHY = sionna_rt.available()
needs_sionna = pytest.mark.skipif(not OK, reason=f"Sionna RT unavailable: {WHY}")

# a street between two rows of buildings, and a block that hides node 2 from node 0
SCENE = Scene.from_polygons([[[0, 5], [50, 5], [50, 30], [0, 30]],
                             [[0, -30], [50, -30], [50, -5], [0, -5]],
                             [[60, -20], [80, -20], [80, 20], [60, 20]]])
TX = np.array([[-10.0, 0.0], [-10.0, 0.0], [40.0, 0.0]])
RX = np.array([[40.0, 0.0], [100.0, 0.0], [-10.0, 0.0]])


@needs_sionna
def test_sionna_traces_los_reflections_and_through_wall_paths(tmp_path):
    cfg = sionna_rt.SionnaConfig(max_depth=3, samples_per_src=20_000, max_paths_per_src=20_000)
    ch = trace_links_cached(SCENE, TX, RX, cfg, tmp_path)
    d = np.linalg.norm(RX - TX, axis=1)
    # link 0: line of sight down the street, then wall reflections (d^2 + 10^2 for the walls at +-5 m)
    assert ch.los[0] and ch.kind[0, 0] == 0
    np.testing.assert_allclose(ch.delays[0, 0] * C_LIGHT, d[0], atol=1e-3)
    refl = ch.delays[0][ch.kind[0] == 1] * C_LIGHT
    assert np.min(np.abs(refl - np.hypot(d[0], 10.0))) < 1e-2
    # the channel is reciprocal: link 2 is link 0 reversed
    short = [np.sort(ch.delays[k][ch.delays[k] * C_LIGHT < d[0] + 15.0]) for k in (0, 2)]
    assert short[0].size >= 5
    np.testing.assert_allclose(short[1], short[0], atol=1e-12)
    # link 1 crosses the block at x = 60..80: no LOS, first path through the walls at the
    # straight-line delay; for the opaque 2-D tracer the two nodes cannot hear each other
    assert not ch.los[1] and ch.kind[1, 0] == sionna_rt.KIND_TRANSMISSION
    np.testing.assert_allclose(ch.delays[1, 0] * C_LIGHT, d[1], atol=1e-3)
    assert abs(ch.gains[1, 0]) < C_LIGHT / cfg.carrier_hz / (4 * np.pi * d[1])   # walls attenuate
    opaque = trace_links(SCENE, TX[1:2], RX[1:2], TraceConfig(max_order=3))
    assert opaque.n_paths[0] == 0
    # the result is cached under the provider's own key
    assert len(list(tmp_path.glob("*.npz"))) == 1
    again = trace_links_cached(SCENE, TX, RX, cfg, tmp_path)
    np.testing.assert_array_equal(again.delays, ch.delays)


def test_missing_sionna_raises_config_error_with_install_hint(monkeypatch):
    monkeypatch.setattr(sionna_rt, "_RT", None)
    monkeypatch.setitem(sys.modules, "mitsuba", None)          # import mitsuba -> ImportError
    with pytest.raises(ConfigError, match=r"radioloc\[rt\]"):
        sionna_rt.load_sionna()
    with pytest.raises(ConfigError, match="libllvm19"):
        trace_links_cached(SCENE, TX, RX, sionna_rt.SionnaConfig(), cache_dir="/nonexistent")


def test_sionna_config_validated():
    with pytest.raises(ConfigError, match="max_depth"):
        sionna_rt.SionnaConfig(max_depth=-1)
    with pytest.raises(ConfigError, match="antenna_height_m"):
        sionna_rt.SionnaConfig(antenna_height_m=30.0, building_height_m=20.0)
    with pytest.raises(ConfigError, match="config"):
        trace_links_cached(SCENE, TX, RX, object(), cache_dir="/nonexistent")


def test_prism_mesh_is_closed_with_outward_normals():
    v, f = sionna_rt.prism_mesh_arrays(SCENE, 20.0)
    tri = v[f].astype(float)                                   # (F, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    u = n / np.linalg.norm(n, axis=1, keepdims=True)
    centre = tri.mean(axis=1)

    def solid(p):                                              # inside a building's volume
        return SCENE.inside(p[:, :2]) & (p[:, 2] > 0) & (p[:, 2] < 20.0)

    # every normal points out of the solid: a step against it is inside, along it outside
    assert solid(centre - 0.01 * u).all() and not solid(centre + 0.01 * u).any()
    # closed: every edge is shared by exactly two triangles
    e = np.round(v[np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])], 4)   # (E, 2, 3)
    first = [tuple(a) <= tuple(b) for a, b in zip(e[:, 0].tolist(), e[:, 1].tolist())]
    keyed = np.where(np.array(first)[:, None, None], e, e[:, ::-1]).reshape(len(e), -1)
    _, counts = np.unique(keyed, axis=0, return_counts=True)
    assert np.all(counts == 2)
