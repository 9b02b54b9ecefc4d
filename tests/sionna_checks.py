"""Sionna RT test bodies, run in a child process by ``tests/test_sionna_rt.py`` (Dr.Jit is
native code that can abort the interpreter)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from radioloc.channel import sionna_rt
from radioloc.channel.raytrace import C_LIGHT, TraceConfig, trace_links, trace_links_cached
from radioloc.channel.scene import Scene

# a street between two rows of buildings, and a block that hides node 2 from node 0
SCENE = Scene.from_polygons([[[0, 5], [50, 5], [50, 30], [0, 30]],
                             [[0, -30], [50, -30], [50, -5], [0, -5]],
                             [[60, -20], [80, -20], [80, 20], [60, 20]]])
TX = np.array([[-10.0, 0.0], [-10.0, 0.0], [40.0, 0.0]])
RX = np.array([[40.0, 0.0], [100.0, 0.0], [-10.0, 0.0]])


def street_scene(cache_dir: str) -> None:
    """Line of sight, wall reflections, reciprocity, a through-wall first path, the cache."""
    tmp_path = Path(cache_dir)
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


def crash(message: str) -> None:
    """Print a line, then abort the interpreter (the isolation's own test)."""
    import os
    import sys

    print(message, flush=True)
    sys.stderr.flush()
    os.abort()
