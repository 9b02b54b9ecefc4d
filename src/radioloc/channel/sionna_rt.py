"""Sionna RT as a second channel provider: 3-D ray tracing of extruded building footprints.

The home-made tracer (:mod:`radioloc.channel.raytrace`) works in the horizontal plane with
opaque buildings, specular reflections and single-corner knife-edge diffraction. This module
hands the same footprints to Sionna RT (``pip install 'radioloc[rt]'``), which traces in 3-D
with reflection, diffraction (UTD, on every wedge: building corners and roof edges) and
refraction: a ray crossing a wall is transmitted through it as through a slab of the wall
material and thickness, so a link behind a building keeps a through-wall first path whose
excess delay is small (the walls add no geometric length; the interior is air).

The scene: every footprint of :class:`radioloc.channel.scene.Scene` becomes a closed prism
(walls, a roof and a floor; no ground plane, as in the 2-D tracer) of height
``building_height_m``; transmitters and receivers stand ``antenna_height_m`` above the
ground with isotropic, vertically polarised antennas. The result is a
:class:`radioloc.channel.raytrace.LinkChannels`, the structure the urban simulation consumes,
with path kinds 0 (direct), ``k > 0`` (``k`` specular reflections only), -1 (at least one
diffraction) and -3 (at least one transmission through a wall, no diffraction).

Sionna RT is imported lazily (the first trace). It runs on the CPU through Dr.Jit's LLVM
back end, which needs ``libLLVM`` (Debian: ``apt-get install libllvm19``); when
``DRJIT_LIBLLVM_PATH`` is unset, the usual Debian locations are tried.
"""

from __future__ import annotations

import glob
import os
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon

from radioloc.channel.raytrace import KIND_DIFFRACTION, KIND_LOS, LinkChannels
from radioloc.channel.scene import Scene
from radioloc.core.errors import ConfigError, InputError
from radioloc.core.validation import as_positions, check_positive

#: Path kind of a path transmitted through at least one wall (and not diffracted).
KIND_TRANSMISSION = -3

#: How to get the optional dependency.
INSTALL_HINT = ("the 'sionna' channel provider needs Sionna RT: pip install 'radioloc[rt]' "
                "(or pip install sionna-rt) and an LLVM shared library for its CPU back end "
                "(Debian: apt-get install libllvm19; set DRJIT_LIBLLVM_PATH to libLLVM-19.so)")

_LLVM_GLOBS = ("/usr/lib/x86_64-linux-gnu/libLLVM-1*.so", "/usr/lib/aarch64-linux-gnu/libLLVM-1*.so",
               "/usr/lib/llvm-1*/lib/libLLVM-1*.so", "/usr/lib/x86_64-linux-gnu/libLLVM.so.1*",
               "/usr/lib/llvm-1*/lib/libLLVM.so")

_RT = None          # the imported sionna.rt module (lazy)


@dataclass(frozen=True)
class SionnaConfig:
    """Settings of the Sionna RT provider; (*) marks choices no paper states.

    max_depth: interactions per path (reflections, diffractions and wall crossings count
        alike; crossing one building takes two).
    max_excess_m: paths longer than the straight line plus this are dropped (as in the 2-D
        tracer).
    carrier_hz: carrier frequency.
    building_height_m: height of every extruded footprint (*).
    antenna_height_m: height of every node (*).
    wall_permittivity, wall_conductivity_s_m, wall_thickness_m: the walls' material (*):
        concrete after ITU-R P.2040 at 900 MHz (relative permittivity 5.24, conductivity
        0.0462 f^0.7822 S/m with f in GHz) and 0.3 m thick.
    reflection, refraction, diffraction: interaction types traced.
    samples_per_src, max_paths_per_src: Sionna's ray budget per source.
    """

    max_depth: int = 4
    max_excess_m: float = 900.0
    carrier_hz: float = 900e6
    building_height_m: float = 20.0
    antenna_height_m: float = 1.5
    wall_permittivity: float = 5.24
    wall_conductivity_s_m: float = 0.0426
    wall_thickness_m: float = 0.3
    reflection: bool = True
    refraction: bool = True
    diffraction: bool = True
    samples_per_src: int = 200_000
    max_paths_per_src: int = 200_000

    def __post_init__(self):
        if not isinstance(self.max_depth, (int, np.integer)) or not 0 <= self.max_depth <= 8:
            raise ConfigError(f"max_depth: expected an integer in 0..8, got {self.max_depth!r}")
        for name in ("max_excess_m", "carrier_hz", "building_height_m", "antenna_height_m",
                     "wall_permittivity", "wall_thickness_m", "samples_per_src", "max_paths_per_src"):
            check_positive(getattr(self, name), name)
        check_positive(self.wall_conductivity_s_m, "wall_conductivity_s_m", allow_zero=True)
        if self.antenna_height_m >= self.building_height_m:
            raise ConfigError(f"antenna_height_m: {self.antenna_height_m} must be below "
                              f"building_height_m = {self.building_height_m}")


def _find_llvm() -> str | None:
    for pattern in _LLVM_GLOBS:
        hits = sorted(glob.glob(pattern))
        if hits:
            return hits[-1]
    return None


def load_sionna():
    """Import Sionna RT on its CPU (LLVM) variant, once.

    Returns
    -------
    module
        ``sionna.rt``.

    Raises
    ------
    ConfigError
        Sionna RT or the LLVM library is not installed (the message says how to install).
    """
    global _RT
    if _RT is not None:
        return _RT
    if not os.environ.get("DRJIT_LIBLLVM_PATH"):
        lib = _find_llvm()
        if lib:
            os.environ["DRJIT_LIBLLVM_PATH"] = lib
    try:
        import mitsuba as mi
    except ImportError as exc:
        raise ConfigError(f"provider: {INSTALL_HINT} ({exc})") from None
    try:
        if mi.variant() is None or not str(mi.variant()).startswith("llvm"):
            mi.set_variant("llvm_ad_mono_polarized")
        import sionna.rt as rt
    except ImportError as exc:
        raise ConfigError(f"provider: {INSTALL_HINT} ({exc})") from None
    except Exception as exc:  # Dr.Jit raises RuntimeError/ImportError flavours without LLVM
        raise ConfigError(f"provider: {INSTALL_HINT} ({type(exc).__name__}: {exc})") from None
    _RT = rt
    return rt


def available() -> tuple[bool, str]:
    """Whether Sionna RT can be loaded here.

    Returns
    -------
    ok : bool
    reason : str
        Empty when ``ok``; else the install hint and the error.
    """
    try:
        load_sionna()
    except ConfigError as exc:
        return False, str(exc)
    return True, ""


def _triangles(poly: Polygon) -> np.ndarray:
    """Triangles (T, 3, 2) covering a footprint (constrained Delaunay, kept inside)."""
    tri = shapely.constrained_delaunay_triangles(poly)
    out = []
    for t in tri.geoms:
        xy = np.asarray(t.exterior.coords)[:3, :2]
        # counter-clockwise seen from above: the roof normal points up
        if (xy[1, 0] - xy[0, 0]) * (xy[2, 1] - xy[0, 1]) - (xy[1, 1] - xy[0, 1]) * (xy[2, 0] - xy[0, 0]) < 0:
            xy = xy[::-1]
        out.append(xy)
    return np.asarray(out).reshape(-1, 3, 2)


def prism_mesh_arrays(scene: Scene, height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of the extruded footprints (walls and roofs).

    Parameters
    ----------
    scene : Scene
        The footprints.
    height_m : float
        Building height.

    Returns
    -------
    vertices : ndarray, shape (V, 3), float32
    faces : ndarray, shape (F, 3), uint32
        Triangles with outward normals (counter-clockwise seen from outside).
    """
    verts, faces = [], []
    n0 = 0
    for poly in scene.polygons:
        ring = np.asarray(poly.exterior.coords)[:-1, :2]             # counter-clockwise
        n = len(ring)
        v = np.concatenate([np.c_[ring, np.zeros(n)], np.c_[ring, np.full(n, height_m)]])
        i = np.arange(n)
        j = (i + 1) % n
        walls = np.concatenate([np.stack([i, j, n + j], 1), np.stack([i, n + j, n + i], 1)])
        tri = _triangles(poly)
        m = 3 * len(tri)
        roof_v = np.c_[tri.reshape(-1, 2), np.full(m, height_m)]
        floor_v = np.c_[tri.reshape(-1, 2), np.zeros(m)]
        roof_f = 2 * n + np.arange(m).reshape(-1, 3)
        floor_f = (2 * n + m + np.arange(m).reshape(-1, 3))[:, ::-1]      # normal down
        verts += [v, roof_v, floor_v]
        faces += [walls + n0, roof_f + n0, floor_f + n0]
        n0 += len(v) + 2 * m
    if not verts:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32)
    return np.concatenate(verts).astype(np.float32), np.concatenate(faces).astype(np.uint32)


def _mi_scene(rt, scene: Scene, cfg: SionnaConfig):
    import mitsuba as mi
    s = rt.load_scene()
    s.frequency = float(cfg.carrier_hz)
    v, f = prism_mesh_arrays(scene, cfg.building_height_m)
    if len(f):
        mesh = mi.Mesh("buildings", len(v), len(f), has_vertex_normals=False,
                       has_vertex_texcoords=False)
        p = mi.traverse(mesh)
        p["vertex_positions"] = mi.Float(v.ravel())
        p["faces"] = mi.UInt32(f.ravel())
        p.update()
        mat = rt.RadioMaterial("walls", thickness=float(cfg.wall_thickness_m),
                               relative_permittivity=float(cfg.wall_permittivity),
                               conductivity=float(cfg.wall_conductivity_s_m))
        s.edit(add=[rt.SceneObject(mi_mesh=mesh, name="buildings", radio_material=mat)])
    s.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    s.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    return s


def trace_links_sionna(scene: Scene, tx: np.ndarray, rx: np.ndarray,
                       config: SionnaConfig | None = None) -> LinkChannels:
    """Trace every link ``tx[i] -> rx[i]`` with Sionna RT.

    The distinct end points become Sionna transmitters and receivers; one solver call
    traces every transmitter to every receiver and the requested pairs are kept.

    Parameters
    ----------
    scene : Scene
        Building footprints (extruded to ``config.building_height_m``).
    tx, rx : array_like, shape (L, 2)
        End points of the links, metres; neither may lie inside a building.
    config : SionnaConfig, optional

    Returns
    -------
    LinkChannels
        Padded per-link paths sorted by delay (kinds: module docstring); links with no path
        have ``n_paths == 0``.

    Raises
    ------
    ConfigError
        Sionna RT is not installed.
    InputError
        Bad end points.
    """
    cfg = config or SionnaConfig()
    tx = as_positions(tx, "tx", dims=(2,)).reshape(-1, 2)
    rx = as_positions(rx, "rx", dims=(2,)).reshape(-1, 2)
    if tx.shape != rx.shape:
        raise InputError(f"tx, rx: shapes differ ({tx.shape} vs {rx.shape})")
    for name, p in (("tx", tx), ("rx", rx)):
        inside = scene.inside(p)
        if inside.any():
            raise InputError(f"{name}: point {int(np.argmax(inside))} lies inside a building")
    dist = np.linalg.norm(rx - tx, axis=1)
    if np.any(dist <= 0):
        raise InputError(f"tx, rx: link {int(np.argmin(dist))} has coincident end points")
    rt = load_sionna()
    import mitsuba as mi
    L = len(tx)
    ut, ti = np.unique(np.round(tx, 6), axis=0, return_inverse=True)
    ur, ri = np.unique(np.round(rx, 6), axis=0, return_inverse=True)
    s = _mi_scene(rt, scene, cfg)
    h = float(cfg.antenna_height_m)
    for k, p in enumerate(ut):
        s.add(rt.Transmitter(name=f"tx{k}", position=mi.Point3f(float(p[0]), float(p[1]), h)))
    for k, p in enumerate(ur):
        s.add(rt.Receiver(name=f"rx{k}", position=mi.Point3f(float(p[0]), float(p[1]), h)))
    paths = rt.PathSolver()(s, max_depth=int(cfg.max_depth), los=True,
                            specular_reflection=bool(cfg.reflection), diffuse_reflection=False,
                            refraction=bool(cfg.refraction), diffraction=bool(cfg.diffraction),
                            samples_per_src=int(cfg.samples_per_src),
                            max_num_paths_per_src=int(cfg.max_paths_per_src))
    a_re, a_im = paths.a
    a = (np.asarray(a_re) + 1j * np.asarray(a_im)).reshape(len(ur), len(ut), -1)
    tau = np.asarray(paths.tau).reshape(len(ur), len(ut), -1)
    valid = np.asarray(paths.valid).reshape(len(ur), len(ut), -1).astype(bool)
    inter = np.asarray(paths.interactions).reshape(-1, len(ur), len(ut), tau.shape[-1])
    if tau.shape[-1] == 0:
        return LinkChannels(np.full((L, 1), np.nan), np.zeros((L, 1), complex),
                            np.full((L, 1), -2), np.zeros(L, int), np.zeros(L, bool))
    # requested pairs: (L, P)
    a, tau, valid = a[ri, ti], tau[ri, ti], valid[ri, ti]
    inter = inter[:, ri, ti]                                                # (depth, L, P)
    length = tau * 2.99792458e8
    valid &= np.isfinite(tau) & (length <= (dist + cfg.max_excess_m)[:, None]) & (np.abs(a) > 0)
    diffr = ((inter & 8) != 0).any(axis=0)
    refr = ((inter & 4) != 0).any(axis=0)
    nspec = ((inter & 1) != 0).sum(axis=0)
    kind = np.where(diffr, KIND_DIFFRACTION, np.where(refr, KIND_TRANSMISSION, nspec))
    direct = valid & (kind == KIND_LOS) & (inter == 0).all(axis=0)
    n = valid.sum(axis=1)
    P = max(int(n.max()) if n.size else 0, 1)
    key = np.where(valid, tau, np.inf)
    order = np.argsort(key, axis=1, kind="stable")[:, :P]
    rows = np.arange(L)[:, None]
    keep = np.arange(P)[None, :] < n[:, None]
    delays = np.where(keep, tau[rows, order], np.nan)
    gains = np.where(keep, a[rows, order], 0.0)
    kinds = np.where(keep, kind[rows, order], -2)
    return LinkChannels(delays.astype(float), gains.astype(complex), kinds.astype(int), n,
                        direct.any(axis=1))
