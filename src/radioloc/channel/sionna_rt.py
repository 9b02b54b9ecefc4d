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
back end, which needs ``libLLVM`` of version :data:`LLVM_MIN_VERSION` or later (Debian:
``apt-get install libllvm19``). :func:`llvm_library` picks the newest suitable one in the
usual places, or checks ``DRJIT_LIBLLVM_PATH`` when it is set; an older LLVM is refused with
a :class:`~radioloc.core.errors.ConfigError` before Dr.Jit loads it, since Dr.Jit aborts the
whole process on LLVM 15 and 16.
"""

from __future__ import annotations

import glob
import importlib.metadata
import os
import re
import subprocess
import sys
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

#: The oldest LLVM whose shared library Dr.Jit runs correctly on. Found by experiment on
#: Debian 12 (x86_64) with sionna-rt 2.2, Mitsuba 3.9 and Dr.Jit 1.5, tracing a street scene:
#: LLVM 14 is refused by Dr.Jit itself; LLVM 15 and 16 abort the whole process while
#: compiling a kernel (``LLVM ERROR: Cannot select: ... fmaximum``: their x86 back end
#: cannot lower ``llvm.maximum``); LLVM 19 traces correctly. 17 and 18 are not packaged for
#: Debian 12 and were not tried, so they are refused too.
LLVM_MIN_VERSION = 19

#: How to get the optional dependency.
INSTALL_HINT = ("the 'sionna' channel provider needs Sionna RT: pip install 'radioloc[rt]' "
                "(or pip install sionna-rt) and an LLVM shared library, version "
                f">= {LLVM_MIN_VERSION}, for its CPU back end (Debian: apt-get install "
                f"libllvm{LLVM_MIN_VERSION}; or set DRJIT_LIBLLVM_PATH to such a libLLVM)")

_LLVM_GLOBS = ("/usr/lib/x86_64-linux-gnu/libLLVM*.so*", "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
               "/usr/lib/llvm-*/lib/libLLVM*.so*", "/usr/local/lib/libLLVM*.so*",
               "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib", "/usr/local/opt/llvm/lib/libLLVM*.dylib")

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


def llvm_version(path: str) -> int | None:
    """The major version of the LLVM shared library at ``path``, or None if unknown.

    Read from the file name after resolving links (``libLLVM-15.so``, ``libLLVM.so.19.1``,
    ``libLLVM-14.0.6.so.1``); a name without a version is asked in a separate process
    (``LLVMGetVersion``, LLVM 16 and later), so that loading it cannot harm this one.
    """
    for name in (os.path.basename(path), os.path.basename(os.path.realpath(path))):
        m = re.match(r"libLLVM[-.](?:so\.)?(\d+)", name)
        if m:
            return int(m.group(1))
    probe = ("import ctypes, sys\n"
             "lib = ctypes.CDLL(sys.argv[1])\n"
             "v = [ctypes.c_uint() for _ in range(3)]\n"
             "lib.LLVMGetVersion(*[ctypes.byref(x) for x in v])\n"
             "print(v[0].value)\n")
    try:
        out = subprocess.run([sys.executable, "-c", probe, path], capture_output=True,
                             text=True, timeout=60)
        return int(out.stdout.strip()) if out.returncode == 0 else None
    except (OSError, ValueError, subprocess.TimeoutExpired):
        return None


def _installed_llvm() -> dict[str, int | None]:
    """Every LLVM shared library found in the usual places, with its major version."""
    found = {}
    for pattern in _LLVM_GLOBS:
        for hit in glob.glob(pattern):
            real = os.path.realpath(hit)
            if real not in found.values() and os.path.isfile(real):
                found[hit] = real
    versions: dict[str, int | None] = {}
    for hit, real in found.items():
        if real not in versions:
            versions[real] = llvm_version(hit)
    return versions


def llvm_library() -> str:
    """The LLVM shared library that Dr.Jit is to load: the newest suitable one.

    ``DRJIT_LIBLLVM_PATH``, when set, is checked rather than searched for.

    Returns
    -------
    str
        The library's path.

    Raises
    ------
    ConfigError
        ``DRJIT_LIBLLVM_PATH`` names a missing library or one older than
        :data:`LLVM_MIN_VERSION` (or of unknown version), or no suitable library is
        installed; the message names what was found and how to install a suitable one.
    """
    fix = (f"install LLVM >= {LLVM_MIN_VERSION} (Debian: apt-get install "
           f"libllvm{LLVM_MIN_VERSION}) and set DRJIT_LIBLLVM_PATH to its libLLVM, or unset "
           "DRJIT_LIBLLVM_PATH to let radioloc pick one")
    given = os.environ.get("DRJIT_LIBLLVM_PATH")
    if given:
        if not os.path.isfile(given):
            raise ConfigError(f"DRJIT_LIBLLVM_PATH: no file at {given}; {fix}")
        version = llvm_version(given)
        if version is None or version < LLVM_MIN_VERSION:
            what = "of unknown version" if version is None else f"LLVM {version}"
            raise ConfigError(f"DRJIT_LIBLLVM_PATH: {given} is {what}; Dr.Jit (Sionna RT) "
                              f"needs LLVM >= {LLVM_MIN_VERSION} (older ones abort the "
                              f"process or are refused); {fix}")
        return given
    found = _installed_llvm()
    suitable = [(v, p) for p, v in found.items() if v is not None and v >= LLVM_MIN_VERSION]
    if suitable:
        return max(suitable)[1]
    seen = ", ".join(sorted({f"LLVM {v}" if v else "LLVM of unknown version"
                             for v in found.values()})) or "none"
    raise ConfigError(f"provider: Sionna RT needs LLVM >= {LLVM_MIN_VERSION} for its CPU "
                      f"back end; found {seen}: {fix}")


def check_requirements() -> tuple[bool, str]:
    """Whether Sionna RT and a suitable LLVM are installed, without loading either.

    Nothing native is loaded, so this is safe to call in any process (a test collector,
    a command-line check); :func:`available` also imports Sionna RT.

    Returns
    -------
    ok : bool
    reason : str
        Empty when ``ok``; else what is missing and how to install it.
    """
    for dist in ("sionna-rt", "mitsuba", "drjit"):     # metadata only: nothing is imported
        try:
            importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            return False, f"provider: {INSTALL_HINT} (package {dist} not installed)"
    try:
        llvm_library()
    except ConfigError as exc:
        return False, str(exc)
    return True, ""


def load_sionna():
    """Import Sionna RT on its CPU (LLVM) variant, once.

    Dr.Jit is pointed at :func:`llvm_library` (the newest suitable libLLVM) before it is
    imported: an older LLVM would abort the interpreter at the first trace.

    Returns
    -------
    module
        ``sionna.rt``.

    Raises
    ------
    ConfigError
        Sionna RT or a suitable LLVM library is not installed (the message says how to
        install).
    """
    global _RT
    if _RT is not None:
        return _RT
    ok, why = check_requirements()
    if not ok:
        raise ConfigError(why)
    os.environ["DRJIT_LIBLLVM_PATH"] = llvm_library()
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
    """Whether Sionna RT can be loaded here (it is imported, with a suitable LLVM).

    Returns
    -------
    ok : bool
    reason : str
        Empty when ``ok``; else what is missing and how to install it.
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
