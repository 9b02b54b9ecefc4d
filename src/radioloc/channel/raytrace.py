"""2-D ray tracing over opaque building footprints.

Paths between a transmitter and a receiver in the horizontal plane:

* the direct path, present when the segment crosses no building (line of sight, LOS);
* specular reflections by the image method up to ``max_order`` bounces: the source is
  mirrored over the wall lines in turn, the path is traced back from the receiver through
  the images, and kept when every reflection point lies on its wall and every leg is clear;
* single-edge diffraction at building corners (only for links without LOS): the path
  tx -> corner -> rx with both legs clear, attenuated by the knife-edge loss J(nu).

The reference engine (``engine="numpy"``) is vectorised over links and wall sequences; the
candidate walls of a link come from the wall STRtree queried with the link's ellipse ``|p -
tx| + |p - rx| <= d + max_excess_m`` (paths longer than that are not traced). The default
compiled engine finds the same paths by a depth-first walk of the image tree per link (in
parallel over links) pruned by a visibility tree: per scene, the walls each wall can see
(:attr:`radioloc.channel.scene.Scene.visible`); per call, the walls each distinct end point
can see; per node, the beam through the parent's lit part. Blocking tests walk a uniform
grid.

Coefficients (the paper's [15] does not state them; these are the documented choices):

* amplitude of a path of unfolded length ``L``: free space ``lambda / (4 pi L)`` with
  phase ``exp(-j 2 pi L / lambda)``;
* reflection: Fresnel coefficient for the electric field perpendicular to the plane of
  incidence (vertical antennas over a horizontal 2-D plane),
  ``Gamma = (cos t - sqrt(eps - sin^2 t)) / (cos t + sqrt(eps - sin^2 t))``, ``t`` the
  angle from the wall normal, ``eps`` the walls' relative permittivity (default 5, concrete);
* diffraction: knife-edge with ``nu = 2 sqrt(Delta / lambda)`` (``Delta`` = excess length
  of tx -> corner -> rx over the straight line, the shadow-side Fresnel-Kirchhoff
  parameter ``nu = h sqrt(2 (d1 + d2) / (lambda d1 d2))`` written with ``Delta ~ h^2 (d1 +
  d2) / (2 d1 d2)``) and loss ``J(nu) = 6.9 + 20 log10(sqrt((nu - 0.1)^2 + 1) + nu - 0.1)``
  dB (ITU-R P.526, eq. (31)), an extra phase of ``-pi/4``, and the free-space amplitude of
  length ``d1 + d2``.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import shapely
from numba import njit, prange

from radioloc.channel.scene import Scene, _beam_blocked, _leg_blocked
from radioloc.core.errors import ConfigError, InputError
from radioloc.core.geometry import segment_intersections
from radioloc.core.validation import as_positions, check_positive

#: Speed of light [m/s].
C_LIGHT = 299_792_458.0

#: Path kinds in :attr:`LinkChannels.kind`.
KIND_LOS, KIND_DIFFRACTION = 0, -1


@dataclass(frozen=True)
class TraceConfig:
    """Ray tracer settings.

    max_order: highest number of specular reflections per path (0 = direct and diffraction).
    max_excess_m: paths longer than the straight line plus this are not traced.
    carrier_hz: carrier frequency (wavelength for free-space loss, Fresnel phase, knife edge).
    wall_permittivity: relative permittivity of the walls in the Fresnel coefficient.
    diffraction: whether to add single-corner knife-edge paths to links without LOS.
    """

    max_order: int = 3
    max_excess_m: float = 900.0
    carrier_hz: float = 900e6
    wall_permittivity: float = 5.0
    diffraction: bool = True

    def __post_init__(self):
        if not isinstance(self.max_order, (int, np.integer)) or not 0 <= self.max_order <= 6:
            raise ConfigError(f"max_order: expected an integer in 0..6, got {self.max_order!r}")
        check_positive(self.max_excess_m, "max_excess_m")
        check_positive(self.carrier_hz, "carrier_hz")
        check_positive(self.wall_permittivity, "wall_permittivity")

    @property
    def wavelength_m(self) -> float:
        """Carrier wavelength [m]."""
        return C_LIGHT / self.carrier_hz


@dataclass(frozen=True)
class LinkChannels:
    """Multipath channels of ``L`` links, padded to ``P`` paths, sorted by delay.

    Attributes
    ----------
    delays : ndarray (L, P)
        Path delays [s]; NaN in padding.
    gains : ndarray (L, P), complex
        Complex amplitude gains (free space, reflection and diffraction); 0 in padding.
    kind : ndarray (L, P), int
        0 direct, k > 0 number of reflections, -1 diffraction, -2 padding.
    n_paths : ndarray (L,)
        Number of paths of each link (0: no path between the two nodes).
    los : ndarray (L,), bool
        Whether the direct path is clear.
    """

    delays: np.ndarray
    gains: np.ndarray
    kind: np.ndarray
    n_paths: np.ndarray
    los: np.ndarray

    @property
    def no_path(self) -> np.ndarray:
        """Links with no path at all (the two nodes cannot hear each other)."""
        return self.n_paths == 0

    def first_delay(self) -> np.ndarray:
        """Delay of the earliest path of each link.

        Returns
        -------
        ndarray, shape (L,)
            Seconds; NaN when the link has no path.
        """
        out = np.full(self.delays.shape[0], np.nan)
        ok = self.n_paths > 0
        out[ok] = self.delays[ok, 0]
        return out


def _ellipses(tx: np.ndarray, rx: np.ndarray, L: np.ndarray, n: int = 24,
              points: bool = False) -> np.ndarray:
    """Polygons (n vertices, circumscribed) of the ellipses |p-tx|+|p-rx| <= L (or their
    vertices, shape (L, n, 2), with ``points``)."""
    c = 0.5 * (tx + rx)
    d = rx - tx
    dist = np.linalg.norm(d, axis=1)
    a = 0.5 * L
    b = np.sqrt(np.maximum(a**2 - (0.5 * dist) ** 2, 1e-6))
    ang = np.arctan2(d[:, 1], d[:, 0])
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    s = 1.0 / np.cos(np.pi / n)  # circumscribe so the polygon contains the ellipse
    ex = s * a[:, None] * np.cos(th)
    ey = s * b[:, None] * np.sin(th)
    ca, sa = np.cos(ang)[:, None], np.sin(ang)[:, None]
    pts = np.stack([c[:, 0:1] + ca * ex - sa * ey, c[:, 1:2] + sa * ex + ca * ey], axis=-1)
    return pts if points else shapely.polygons(pts)


def _fresnel(cos_t: np.ndarray, eps: float) -> np.ndarray:
    sin2 = 1.0 - cos_t**2
    root = np.sqrt(eps - sin2 + 0j)
    return (cos_t - root) / (cos_t + root)


def knife_edge_loss_db(nu: np.ndarray) -> np.ndarray:
    """Knife-edge diffraction loss ``J(nu)`` (ITU-R P.526, eq. (31)), 0 for ``nu <= -0.78``.

    Parameters
    ----------
    nu : ndarray
        Fresnel-Kirchhoff diffraction parameter.

    Returns
    -------
    ndarray
        Loss in dB, same shape as ``nu``.
    """
    nu = np.asarray(nu, float)
    j = 6.9 + 20 * np.log10(np.sqrt((nu - 0.1) ** 2 + 1) + nu - 0.1)
    return np.where(nu > -0.78, j, 0.0)


@njit(cache=True)
def _extend(last_img, last_wall, link, counts, offsets, wk, A, B, N, rx, lmax):
    """Children (parent index, wall) of every sequence: walls of the same link that face
    the last image, differ from the last wall, lie (partly) in front of it and inside the
    beam through it, and keep the lower bound of the path length within ``lmax``."""
    S = last_img.shape[0]
    total = 0
    for s in range(S):
        total += counts[link[s]]
    par = np.empty(total, np.int64)
    wal = np.empty(total, np.int64)
    n = 0
    for s in range(S):
        l = link[s]
        ix, iy = last_img[s, 0], last_img[s, 1]
        wp = last_wall[s]
        pax, pay = A[wp, 0], A[wp, 1]
        pbx, pby = B[wp, 0], B[wp, 1]
        pnx, pny = N[wp, 0], N[wp, 1]
        # beam edges lo, hi ordered counter-clockwise around the image
        if (pax - ix) * (pby - iy) - (pay - iy) * (pbx - ix) < 0:
            lox, loy, hix, hiy = pbx, pby, pax, pay
        else:
            lox, loy, hix, hiy = pax, pay, pbx, pby
        rxx, rxy = rx[l, 0], rx[l, 1]
        for q in range(offsets[l], offsets[l] + counts[l]):
            w = wk[q]
            if w == wp:
                continue
            ax, ay, bx, by = A[w, 0], A[w, 1], B[w, 0], B[w, 1]
            nx, ny = N[w, 0], N[w, 1]
            if (ix - ax) * nx + (iy - ay) * ny <= 0.0:
                continue
            if (ax - pax) * pnx + (ay - pay) * pny <= 1e-9 and (bx - pax) * pnx + (by - pay) * pny <= 1e-9:
                continue
            c1 = (lox - ix) * (ay - iy) - (loy - iy) * (ax - ix)
            c2 = (lox - ix) * (by - iy) - (loy - iy) * (bx - ix)
            if c1 < 0 and c2 < 0:
                continue
            c1 = (ax - ix) * (hiy - iy) - (ay - iy) * (hix - ix)
            c2 = (bx - ix) * (hiy - iy) - (by - iy) * (hix - ix)
            if c1 < 0 and c2 < 0:
                continue
            dx, dy = bx - ax, by - ay
            dd = dx * dx + dy * dy
            t = min(max(((ix - ax) * dx + (iy - ay) * dy) / dd, 0.0), 1.0)
            d1 = np.hypot(ax + t * dx - ix, ay + t * dy - iy)
            t = min(max(((rxx - ax) * dx + (rxy - ay) * dy) / dd, 0.0), 1.0)
            d2 = np.hypot(ax + t * dx - rxx, ay + t * dy - rxy)
            if d1 + d2 > lmax[l]:
                continue
            par[n] = s
            wal[n] = w
            n += 1
    return par[:n], wal[:n]


def _reflections(scene: Scene, tx, rx, lmax, cfg: TraceConfig, engine: str = "shapely"):
    """Specular paths of every link: (link, length, gain, order) arrays."""
    out = []
    if cfg.max_order == 0 or len(scene.walls) == 0:
        return out
    lk, wk = scene.wall_tree.query(_ellipses(tx, rx, lmax))
    order = np.lexsort((wk, lk))
    lk, wk = lk[order], wk[order]
    nl = len(tx)
    counts = np.bincount(lk, minlength=nl)
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
    A, B = scene.walls[:, 0], scene.walls[:, 1]
    N = scene.normals
    # level 1: sequences are (link, wall); images of tx
    link = lk
    seq = wk[:, None]
    img = tx[link] - 2 * np.einsum("ij,ij->i", tx[link] - A[wk], N[wk])[:, None] * N[wk]
    front = np.einsum("ij,ij->i", tx[link] - A[wk], N[wk]) > 0
    keep = front & (np.linalg.norm(img - rx[link], axis=1) <= lmax[link])
    link, seq, imgs = link[keep], seq[keep], img[keep][:, None, :]
    for k in range(1, cfg.max_order + 1):
        if k > 1:
            # extend every sequence by each candidate wall of its link (ragged: numba)
            parent, w = _extend(imgs[:, -1], seq[:, -1], link, counts, offsets, wk,
                                A, B, N, rx, lmax)
            lnk = link[parent]
            prev = imgs[parent, -1]
            dot = np.einsum("ij,ij->i", prev - A[w], N[w])
            new = prev - 2 * dot[:, None] * N[w]
            link = lnk
            seq = np.concatenate([seq[parent], w[:, None]], axis=1)
            imgs = np.concatenate([imgs[parent], new[:, None, :]], axis=1)
        if len(link) == 0:
            break
        # trace back from the receiver through the images
        S = len(link)
        pts = np.zeros((S, k + 2, 2))
        pts[:, 0] = tx[link]
        pts[:, -1] = rx[link]
        ok = np.ones(S, bool)
        p = rx[link].copy()
        for m in range(k - 1, -1, -1):
            w = seq[:, m]
            u, t = segment_intersections(imgs[:, m], p, A[w], B[w])
            good = np.isfinite(u) & np.isfinite(t)                 # parallel: no crossing
            ok &= good & (u > 0) & (u < 1) & (t >= 0) & (t <= 1)
            u = np.where(ok, u, 0.0)
            p = imgs[:, m] + u[:, None] * (p - imgs[:, m])
            pts[:, m + 1] = p
        idx = np.flatnonzero(ok)
        if idx.size == 0:
            continue
        P = pts[idx]
        blocked = scene.blocked(P[:, :-1], P[:, 1:], engine=engine).any(axis=1)
        idx, P = idx[~blocked], P[~blocked]
        if idx.size == 0:
            continue
        legs = np.diff(P, axis=1)
        lens = np.linalg.norm(legs, axis=2)
        length = lens.sum(axis=1)
        cos_t = np.abs(np.einsum("skj,skj->sk", legs[:, :-1] / lens[:, :-1, None], N[seq[idx]]))
        gamma = np.prod(_fresnel(cos_t, cfg.wall_permittivity), axis=1)
        out.append((link[idx], length, gamma, np.full(idx.size, k)))
    return out


def _distinct_points(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of ``p`` (shape (n, 2)) and the index of each row among them (the
    rows as complex numbers: one 1-D sort instead of a row-wise unique)."""
    z, inv = np.unique(p[:, 0] + 1j * p[:, 1], return_inverse=True)
    return np.ascontiguousarray(np.stack([z.real, z.imag], axis=1)), inv.astype(np.int64)


def _diffractions(scene: Scene, tx, rx, lmax, nlos, cfg: TraceConfig, engine: str = "shapely"):
    if not cfg.diffraction or len(scene.corners) == 0 or not nlos.any():
        return []
    links = np.flatnonzero(nlos)
    C = scene.corners
    if engine == "compiled":
        x0, y0, h, nx, ny, cs, cw = scene.grid
        pts, inv = _distinct_points(np.concatenate([tx[links], rx[links]]))
        li, ci = np.nonzero(_corner_paths(np.ascontiguousarray(tx[links]),
                                          np.ascontiguousarray(rx[links]),
                                          inv[:len(links)], inv[len(links):],
                                          np.ascontiguousarray(pts),
                                          np.ascontiguousarray(lmax[links], dtype=float),
                                          np.ascontiguousarray(C), 1e-3,
                                          np.ascontiguousarray(scene.walls[:, 0]),
                                          np.ascontiguousarray(scene.walls[:, 1]),
                                          x0, y0, h, nx, ny, cs, cw))
        link = links[li]
    else:
        d1 = np.linalg.norm(C[None] - tx[links, None], axis=2)
        d2 = np.linalg.norm(C[None] - rx[links, None], axis=2)
        li, ci = np.nonzero(d1 + d2 <= lmax[links, None])
        link = links[li]
        clear = ~(scene.blocked(tx[link], C[ci], engine=engine)
                  | scene.blocked(C[ci], rx[link], engine=engine))
        link, ci = link[clear], ci[clear]
    a = np.linalg.norm(C[ci] - tx[link], axis=1)
    b = np.linalg.norm(rx[link] - C[ci], axis=1)
    d = np.linalg.norm(rx[link] - tx[link], axis=1)
    length = a + b
    nu = 2.0 * np.sqrt(np.maximum(length - d, 0.0) / cfg.wavelength_m)
    g = 10 ** (-knife_edge_loss_db(nu) / 20) * np.exp(-1j * np.pi / 4)
    return [(link, length, g, np.full(link.size, KIND_DIFFRACTION))]


def _reflections_compiled(scene: Scene, tx, rx, lmax, cfg: TraceConfig):
    """Specular paths of every link by the compiled image-tree walk (same paths, same order
    as :func:`_reflections`)."""
    if cfg.max_order == 0 or len(scene.walls) == 0:
        return []
    ell = _ellipses(tx, rx, lmax, points=True)                       # (L, 24, 2)
    elo, ehi = ell.min(axis=1), ell.max(axis=1)
    W = scene.walls
    wlo, whi = np.minimum(W[:, 0], W[:, 1]), np.maximum(W[:, 0], W[:, 1])
    # the STRtree query without predicate: wall envelope meets the ellipse polygon's envelope
    hit = ((wlo[None, :, 0] <= ehi[:, None, 0]) & (wlo[None, :, 1] <= ehi[:, None, 1])
           & (whi[None, :, 0] >= elo[:, None, 0]) & (whi[None, :, 1] >= elo[:, None, 1]))
    x0, y0, h, nx, ny, cs, cw = scene.grid
    fs, fw = scene.visible
    _, bstart = scene.convex_buildings
    bbox, bcs, bcell = scene.convex_grid
    A = np.ascontiguousarray(W[:, 0])
    B = np.ascontiguousarray(W[:, 1])
    # wall visibility from each distinct end point (links of a network share their nodes)
    pts, inv = _distinct_points(np.concatenate([tx, rx]))
    txi, rxi = inv[:len(tx)], inv[len(tx):]
    pvis = _point_wall_visible(pts, hit, txi, rxi, A, B, scene.normals, bbox, bstart, x0, y0,
                               h, nx, ny, bcs, bcell)
    cap = 256
    while True:
        ln, gm, od, n, over = _reflect_links(np.ascontiguousarray(tx), np.ascontiguousarray(rx),
                                             np.ascontiguousarray(lmax, dtype=float), hit,
                                             A, B, scene.normals,
                                             int(cfg.max_order), float(cfg.wall_permittivity),
                                             1e-3, x0, y0, h, nx, ny, cs, cw, fs, fw, bbox, bcs, bcell,
                                             bstart, cap, pvis, txi, rxi)
        if not over.any():
            break
        cap *= 4
    keep = np.arange(ln.shape[1])[None, :] < n[:, None]
    link = np.nonzero(keep)[0]
    order_k = od[keep]
    # the reference emits level by level across links: order (level, link, walk order)
    o = np.lexsort((np.nonzero(keep)[1], link, order_k))
    return [(link[o], ln[keep][o], gm[keep][o], order_k[o])]


def trace_links(scene: Scene, tx: np.ndarray, rx: np.ndarray,
                config: TraceConfig | None = None, engine: str = "compiled") -> LinkChannels:
    """Trace every link ``tx[i] -> rx[i]``.

    Parameters
    ----------
    scene : Scene
    tx, rx : array_like, shape (L, 2)
        End points of the links; neither may lie inside a building.
    config : TraceConfig, optional
    engine : {"compiled", "numpy"}
        The compiled image-tree walk with grid-accelerated blocking tests (default, in
        parallel over links) or the NumPy/shapely reference (same paths).

    Returns
    -------
    LinkChannels
        Padded per-link paths; links with no path have ``n_paths == 0`` (not an error).
    """
    cfg = config or TraceConfig()
    tx = as_positions(tx, "tx", dims=(2,)).reshape(-1, 2)
    rx = as_positions(rx, "rx", dims=(2,)).reshape(-1, 2)
    if tx.shape != rx.shape:
        raise InputError(f"tx, rx: shapes differ ({tx.shape} vs {rx.shape})")
    for name, p in (("tx", tx), ("rx", rx)):
        inside = scene.inside(p)
        if inside.any():
            raise InputError(f"{name}: point {int(np.argmax(inside))} lies inside a building")
    lam = cfg.wavelength_m
    dist = np.linalg.norm(rx - tx, axis=1)
    if np.any(dist <= 0):
        raise InputError(f"tx, rx: link {int(np.argmin(dist))} has coincident end points")
    if engine not in ("compiled", "numpy"):
        raise ConfigError(f"engine: expected 'compiled' or 'numpy', got {engine!r}")
    bl = "compiled" if engine == "compiled" else "shapely"
    lmax = dist + cfg.max_excess_m
    los = ~scene.blocked(tx, rx, engine=bl)
    parts = [(np.flatnonzero(los), dist[los], np.ones(los.sum(), complex),
              np.full(los.sum(), KIND_LOS))]
    if engine == "compiled":
        parts += _reflections_compiled(scene, tx, rx, lmax, cfg)
    else:
        parts += _reflections(scene, tx, rx, lmax, cfg, bl)
    parts += _diffractions(scene, tx, rx, lmax, ~los, cfg, bl)
    link = np.concatenate([p[0] for p in parts]).astype(int)
    length = np.concatenate([p[1] for p in parts])
    coef = np.concatenate([p[2] for p in parts])
    kind = np.concatenate([p[3] for p in parts]).astype(int)
    gain = coef * lam / (4 * np.pi * length) * np.exp(-2j * np.pi * length / lam)
    order = np.lexsort((length, link))
    link, length, gain, kind = link[order], length[order], gain[order], kind[order]
    n = np.bincount(link, minlength=len(tx))
    P = max(int(n.max()) if n.size else 0, 1)
    pos = np.arange(link.size) - np.repeat(np.cumsum(n) - n, n)
    delays = np.full((len(tx), P), np.nan)
    gains = np.zeros((len(tx), P), complex)
    kinds = np.full((len(tx), P), -2)
    delays[link, pos] = length / C_LIGHT
    gains[link, pos] = gain
    kinds[link, pos] = kind
    return LinkChannels(delays, gains, kinds, n, los)


def default_cache_dir() -> Path:
    """The ray-tracing cache folder.

    Returns
    -------
    Path
        ``$RADIOLOC_CACHE/channels`` or ``~/.cache/radioloc/channels``.
    """
    root = os.environ.get("RADIOLOC_CACHE")
    return (Path(root) if root else Path.home() / ".cache" / "radioloc") / "channels"


def trace_links_cached(scene: Scene, tx: np.ndarray, rx: np.ndarray,
                       config=None, cache_dir: Path | str | None = None) -> LinkChannels:
    """Trace links with an ``.npz`` cache keyed by provider, scene, end points and config.

    The configuration's type selects the channel provider: :class:`TraceConfig` (or
    ``None``) the 2-D tracer :func:`trace_links`, a
    :class:`radioloc.channel.sionna_rt.SionnaConfig` Sionna RT
    (:func:`radioloc.channel.sionna_rt.trace_links_sionna`).

    Parameters
    ----------
    scene : Scene
    tx, rx : ndarray, shape (L, 2)
        End points of the links, metres.
    config : TraceConfig or SionnaConfig, optional
        Default ``TraceConfig()``.
    cache_dir : Path or str, optional
        ``None`` uses :func:`default_cache_dir`.

    Returns
    -------
    LinkChannels
    """
    cfg = config or TraceConfig()
    tx = as_positions(tx, "tx", dims=(2,)).reshape(-1, 2)
    rx = as_positions(rx, "rx", dims=(2,)).reshape(-1, 2)
    if isinstance(cfg, TraceConfig):
        tracer = trace_links
    else:
        from radioloc.channel.sionna_rt import SionnaConfig, trace_links_sionna
        if not isinstance(cfg, SionnaConfig):
            raise ConfigError(f"config: expected a TraceConfig or SionnaConfig, got {type(cfg).__name__}")
        tracer = trace_links_sionna
    h = hashlib.sha256()
    h.update(type(cfg).__name__.encode())
    h.update(scene.digest().encode())
    h.update(np.round(tx, 6).tobytes() + np.round(rx, 6).tobytes())
    h.update(repr(sorted(asdict(cfg).items())).encode())
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    path = folder / f"{h.hexdigest()[:32]}.npz"
    if path.exists():
        try:
            with np.load(path) as z:
                return LinkChannels(z["delays"], z["gains"], z["kind"], z["n_paths"], z["los"])
        except (OSError, KeyError, ValueError):
            pass  # unreadable cache entry: trace again and overwrite
    ch = tracer(scene, tx, rx, cfg)
    folder.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
    np.savez(tmp, **asdict(ch))
    os.replace(tmp, path)
    return ch


def all_pairs(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(i, j)``, ``i < j``, of ``K`` nodes (the reciprocal links).

    Parameters
    ----------
    positions : ndarray, shape (K, D)

    Returns
    -------
    i, j : ndarray of int, shape (K (K - 1) / 2,)
    """
    K = len(positions)
    i, j = np.triu_indices(K, 1)
    return i, j

@njit(cache=True)
def _fresnel1(cos_t, eps):
    root = np.sqrt(complex(eps - (1.0 - cos_t * cos_t)))
    return (cos_t - root) / (cos_t + root)


@njit(cache=True)
def _emit(k, seq, imgs, txx, txy, rxx, rxy, A, B, N, eps, trim, g0x, g0y, h, nx, ny, cstart,
          cwalls, stamp, tagbox, pts):
    """Trace a sequence of ``k`` walls back from the receiver; the path's length and
    reflection coefficient, or length -1 when it is not a valid unblocked path."""
    px, py = rxx, rxy
    pts[k + 1, 0], pts[k + 1, 1] = rxx, rxy
    pts[0, 0], pts[0, 1] = txx, txy
    for m in range(k - 1, -1, -1):
        w = seq[m]
        ix, iy = imgs[m, 0], imgs[m, 1]
        rx_, ry_ = px - ix, py - iy
        sx, sy = B[w, 0] - A[w, 0], B[w, 1] - A[w, 1]
        qx, qy = A[w, 0] - ix, A[w, 1] - iy
        den = rx_ * sy - ry_ * sx
        if den == 0.0:
            return -1.0, 0j
        u = (qx * sy - qy * sx) / den
        t = (qx * ry_ - qy * rx_) / den
        if not (np.isfinite(u) and np.isfinite(t) and u > 0 and u < 1 and t >= 0 and t <= 1):
            return -1.0, 0j
        px = ix + u * (px - ix)
        py = iy + u * (py - iy)
        pts[m + 1, 0], pts[m + 1, 1] = px, py
    for m in range(k + 1):
        tagbox[0] += 1
        if _leg_blocked(pts[m, 0], pts[m, 1], pts[m + 1, 0], pts[m + 1, 1], trim, A, B, g0x, g0y,
                        h, nx, ny, cstart, cwalls, stamp, tagbox[0]):
            return -1.0, 0j
    length = 0.0
    gam = 1.0 + 0j
    for m in range(k + 1):
        lx, ly = pts[m + 1, 0] - pts[m, 0], pts[m + 1, 1] - pts[m, 1]
        ln = np.sqrt(lx * lx + ly * ly)
        length += ln
        if m < k:
            w = seq[m]
            c = abs(lx / ln * N[w, 0] + ly / ln * N[w, 1])
            gam *= _fresnel1(c, eps)
    return length, gam


@njit(cache=True, parallel=True)
def _point_wall_visible(pts, hit, txi, rxi, A, B, N, bbox, bstart, g0x, g0y, h, nx, ny, bcs,
                        bcell):
    """``vis[i, w]``: point ``i`` is in front of wall ``w`` and no convex footprint spans the
    triangle point-wall (computed where ``w`` is a candidate, ``hit[l, w]``, of a link ``l``
    that starts or ends at ``i``; False elsewhere)."""
    P = pts.shape[0]
    L, W = hit.shape
    vis = np.zeros((P, W), np.bool_)
    for i in prange(P):
        stamp = np.zeros(W, np.int64)
        need = np.zeros(W, np.bool_)
        for l in range(L):
            if txi[l] == i or rxi[l] == i:
                for w in range(W):
                    need[w] |= hit[l, w]
        tag = 0
        px, py = pts[i, 0], pts[i, 1]
        for w in range(W):
            if not need[w] or (px - A[w, 0]) * N[w, 0] + (py - A[w, 1]) * N[w, 1] <= 0:
                continue
            tag += 1
            vis[i, w] = not _beam_blocked(px, py, A[w, 0], A[w, 1], px, py, B[w, 0], B[w, 1],
                                          A, B, bbox, bstart, g0x, g0y, h, nx, ny, bcs,
                                          bcell, stamp, tag)
    return vis


@njit(cache=True)
def _in_wedge(ix, iy, c0x, c0y, c1x, c1y, px, py):
    """Whether the line from the image ``i`` to ``p`` meets the lit part c0-c1 (1 um of
    slack at both ends): the last reflection point of a valid path lies in the lit part."""
    ux, uy = c1x - c0x, c1y - c0y
    vx, vy = px - ix, py - iy
    den = vx * uy - vy * ux
    if den == 0.0:
        return True
    lam = ((c0x - ix) * uy - (c0y - iy) * ux) / den
    rx_, ry_ = ix + lam * vx - c0x, iy + lam * vy - c0y
    ln = np.sqrt(ux * ux + uy * uy)
    s = (rx_ * ux + ry_ * uy) / ln
    return -1e-6 <= s <= ln + 1e-6


@njit(cache=True, parallel=True)
def _reflect_links(tx, rx, lmax, hit, A, B, N, max_order, eps, trim,
                   g0x, g0y, h, nx, ny, cstart, cwalls, fstart, fwalls, bbox, bcs, bcell, bstart, cap,
                   pvis, txi, rxi):
    """Specular paths of every link by a depth-first walk of the image tree; ``cap`` paths
    at most per link.

    The tests of :func:`_extend`, in the same order, plus pruning tests that no valid path
    fails (a convex building that spans a beam cuts every ray of it):

    * a child wall must be a visible follower of its parent (:attr:`Scene.visible`: no
      convex building spans the quadrilaterals between the two walls' halves);
    * it must meet the beam of its parent's *lit part* (the aperture: the part of the
      parent wall inside the grandparent's beam, not the whole wall), and no convex
      building may span the beam from the parent's lit part (or from the transmitter,
      ``pvis[txi[l]]``) to the child's lit part;
    * a wall at the last depth must be seen by the receiver (``pvis[rxi[l]]``: in front,
      no convex building spanning the receiver-wall triangle);
    * a sequence is traced back only when the receiver is in front of its last wall, the
      line from its last image to the receiver meets the last lit part (:func:`_in_wedge`)
      and no convex building spans the beam from the lit part to the receiver."""
    L = tx.shape[0]
    W = A.shape[0]
    out_len = np.zeros((L, cap))
    out_gam = np.zeros((L, cap), np.complex128)
    out_ord = np.zeros((L, cap), np.int64)
    out_n = np.zeros(L, np.int64)
    overflow = np.zeros(L, np.bool_)
    for l in prange(L):
        stamp = np.zeros(W, np.int64)
        tagbox = np.zeros(1, np.int64)
        seq = np.zeros(max_order, np.int64)
        imgs = np.zeros((max_order, 2))
        pos = np.zeros(max_order, np.int64)          # next candidate index at each depth
        ap = np.zeros((max_order, 4))                # lit part of the wall at each depth
        pts = np.zeros((max_order + 2, 2))
        txx, txy, rxx, rxy = tx[l, 0], tx[l, 1], rx[l, 0], rx[l, 1]
        incand = hit[l]                              # the link's candidate walls
        # lastok: candidates the receiver sees (in front, no convex footprint spanning the
        # triangle receiver-wall); only they can be the last wall of a path
        # (pvis: the same test for every end point, computed once per point)
        lastok = pvis[rxi[l]]
        txvis = pvis[txi[l]]
        end = np.zeros(max_order, np.int64)
        end[0] = W
        # per-level buffers so that paths come out level by level, as in the reference
        nlev = np.zeros(max_order + 1, np.int64)
        lev_len = np.zeros((max_order + 1, cap))
        lev_gam = np.zeros((max_order + 1, cap), np.complex128)
        depth = 0
        pos[0] = 0
        while depth >= 0:
            if pos[depth] >= end[depth]:
                depth -= 1
                continue
            w = pos[0] if depth == 0 else fwalls[pos[depth]]
            if not incand[w]:
                pos[depth] += 1
                continue
            pos[depth] += 1
            if depth == max_order - 1 and not lastok[w]:
                continue
            if depth == 0:
                dot = (txx - A[w, 0]) * N[w, 0] + (txy - A[w, 1]) * N[w, 1]
                ix = txx - 2 * dot * N[w, 0]
                iy = txy - 2 * dot * N[w, 1]
                if not (dot > 0 and np.sqrt((ix - rxx) ** 2 + (iy - rxy) ** 2) <= lmax[l]):
                    continue
            else:
                wp = seq[depth - 1]
                ix0, iy0 = imgs[depth - 1, 0], imgs[depth - 1, 1]
                if w == wp:
                    continue
                ax, ay, bx, by = A[w, 0], A[w, 1], B[w, 0], B[w, 1]
                nx_, ny_ = N[w, 0], N[w, 1]
                if (ix0 - ax) * nx_ + (iy0 - ay) * ny_ <= 0.0:
                    continue
                pax, pay = A[wp, 0], A[wp, 1]
                pbx, pby = B[wp, 0], B[wp, 1]
                pnx, pny = N[wp, 0], N[wp, 1]
                if (ax - pax) * pnx + (ay - pay) * pny <= 1e-9 and (bx - pax) * pnx + (by - pay) * pny <= 1e-9:
                    continue
                if (pax - ix0) * (pby - iy0) - (pay - iy0) * (pbx - ix0) < 0:
                    lox, loy, hix, hiy = pbx, pby, pax, pay
                else:
                    lox, loy, hix, hiy = pax, pay, pbx, pby
                # the parent's lit part (a sub-segment of the parent wall)
                qax, qay, qbx, qby = ap[depth - 1, 0], ap[depth - 1, 1], ap[depth - 1, 2], ap[depth - 1, 3]
                if (qax - ix0) * (qby - iy0) - (qay - iy0) * (qbx - ix0) < 0:
                    qlx, qly, qhx, qhy = qbx, qby, qax, qay
                else:
                    qlx, qly, qhx, qhy = qax, qay, qbx, qby
                c1_ = (lox - ix0) * (ay - iy0) - (loy - iy0) * (ax - ix0)
                c2_ = (lox - ix0) * (by - iy0) - (loy - iy0) * (bx - ix0)
                if c1_ < 0 and c2_ < 0:
                    continue
                c1_ = (ax - ix0) * (hiy - iy0) - (ay - iy0) * (hix - ix0)
                c2_ = (bx - ix0) * (hiy - iy0) - (by - iy0) * (hix - ix0)
                if c1_ < 0 and c2_ < 0:
                    continue
                dx, dy = bx - ax, by - ay
                dd = dx * dx + dy * dy
                t = min(max(((ix0 - ax) * dx + (iy0 - ay) * dy) / dd, 0.0), 1.0)
                d1 = np.hypot(ax + t * dx - ix0, ay + t * dy - iy0)
                t = min(max(((rxx - ax) * dx + (rxy - ay) * dy) / dd, 0.0), 1.0)
                d2 = np.hypot(ax + t * dx - rxx, ay + t * dy - rxy)
                if d1 + d2 > lmax[l]:
                    continue
                # lit part of w: inside the beam through the parent's lit part, ahead of it
                t0, t1 = 0.0, 1.0
                for e in range(3):
                    if e == 0:
                        f0 = (qlx - ix0) * (ay - iy0) - (qly - iy0) * (ax - ix0)
                        f1 = (qlx - ix0) * (by - iy0) - (qly - iy0) * (bx - ix0)
                    elif e == 1:
                        f0 = (ax - ix0) * (qhy - iy0) - (ay - iy0) * (qhx - ix0)
                        f1 = (bx - ix0) * (qhy - iy0) - (by - iy0) * (qhx - ix0)
                    else:
                        f0 = (ax - pax) * pnx + (ay - pay) * pny
                        f1 = (bx - pax) * pnx + (by - pay) * pny
                    tol = 1e-9 * (abs(f0) + abs(f1)) + 1e-12
                    f0 += tol
                    f1 += tol
                    if f0 < 0 and f1 < 0:
                        t0, t1 = 1.0, 0.0
                        break
                    if f0 < 0:
                        t0 = max(t0, f0 / (f0 - f1))
                    elif f1 < 0:
                        t1 = min(t1, f0 / (f0 - f1))
                if t0 > t1:
                    continue
                dot = (ix0 - ax) * nx_ + (iy0 - ay) * ny_
                ix = ix0 - 2 * dot * nx_
                iy = iy0 - 2 * dot * ny_
            if depth == 0:
                c0x, c0y, c1x, c1y = A[w, 0], A[w, 1], B[w, 0], B[w, 1]
                if not txvis[w]:            # no convex footprint spans the triangle tx-wall
                    continue
            else:
                dx, dy = B[w, 0] - A[w, 0], B[w, 1] - A[w, 1]
                c0x, c0y = A[w, 0] + t0 * dx, A[w, 1] + t0 * dy
                c1x, c1y = A[w, 0] + t1 * dx, A[w, 1] + t1 * dy
                # the edge rays meet the parent wall line at q0, q1
                den0 = (c0x - ix0) * pnx + (c0y - iy0) * pny
                den1 = (c1x - ix0) * pnx + (c1y - iy0) * pny
                num = (pax - ix0) * pnx + (pay - iy0) * pny
                if den0 != 0.0 and den1 != 0.0:
                    u0 = num / den0
                    u1 = num / den1
                    if 0.0 < u0 < 1.0 and 0.0 < u1 < 1.0:
                        q0x, q0y = ix0 + u0 * (c0x - ix0), iy0 + u0 * (c0y - iy0)
                        q1x, q1y = ix0 + u1 * (c1x - ix0), iy0 + u1 * (c1y - iy0)
                        tagbox[0] += 1
                        if _beam_blocked(q0x, q0y, c0x, c0y, q1x, q1y, c1x, c1y, A, B, bbox,
                                         bstart, g0x, g0y, h, nx, ny, bcs, bcell, stamp,
                                         tagbox[0]):
                            continue
            seq[depth] = w
            imgs[depth, 0] = ix
            imgs[depth, 1] = iy
            ap[depth, 0], ap[depth, 1], ap[depth, 2], ap[depth, 3] = c0x, c0y, c1x, c1y
            k = depth + 1
            length = -1.0
            gam = 0j
            tagbox[0] += 1
            if (rxx - A[w, 0]) * N[w, 0] + (rxy - A[w, 1]) * N[w, 1] > 0 and _in_wedge(
                    ix, iy, c0x, c0y, c1x, c1y, rxx, rxy) and not _beam_blocked(
                    c0x, c0y, rxx, rxy, c1x, c1y, rxx, rxy, A, B, bbox, bstart,
                    g0x, g0y, h, nx, ny, bcs, bcell, stamp, tagbox[0]):
                length, gam = _emit(k, seq, imgs, txx, txy, rxx, rxy, A, B, N, eps, trim, g0x,
                                    g0y, h, nx, ny, cstart, cwalls, stamp, tagbox, pts)
            if length >= 0:
                if nlev[k] < cap:
                    lev_len[k, nlev[k]] = length
                    lev_gam[k, nlev[k]] = gam
                    nlev[k] += 1
                else:
                    overflow[l] = True
            if k < max_order:
                depth += 1
                pos[depth] = fstart[w]
                end[depth] = fstart[w + 1]
        n = 0
        for k in range(1, max_order + 1):
            for i in range(nlev[k]):
                if n < cap:
                    out_len[l, n] = lev_len[k, i]
                    out_gam[l, n] = lev_gam[k, i]
                    out_ord[l, n] = k
                    n += 1
                else:
                    overflow[l] = True
        out_n[l] = n
    return out_len, out_gam, out_ord, out_n, overflow




@njit(cache=True, parallel=True)
def _corner_legs(pts, need, C, to_point, trim, A, B, g0x, g0y, h, nx, ny, cstart, cwalls):
    """``blocked[i, c]``: the leg point ``i`` -> corner ``c`` (``to_point``: corner -> point)
    crosses a wall (:meth:`Scene.blocked`), computed where ``need[i, c]``."""
    P, NC = need.shape
    W = A.shape[0]
    out = np.zeros((P, NC), np.bool_)
    for i in prange(P):
        stamp = np.zeros(W, np.int64)
        tag = 0
        px, py = pts[i, 0], pts[i, 1]
        for c in range(NC):
            if not need[i, c]:
                continue
            tag += 1
            if to_point:
                out[i, c] = _leg_blocked(C[c, 0], C[c, 1], px, py, trim, A, B, g0x, g0y, h,
                                         nx, ny, cstart, cwalls, stamp, tag)
            else:
                out[i, c] = _leg_blocked(px, py, C[c, 0], C[c, 1], trim, A, B, g0x, g0y, h,
                                         nx, ny, cstart, cwalls, stamp, tag)
    return out


@njit(cache=True)
def _corner_paths(tx, rx, txi, rxi, pts, lmax, C, trim, A, B, g0x, g0y, h, nx, ny, cstart,
                  cwalls):
    """Diffraction corners of every link (compiled): ``ok[l, c]`` when ``|c - tx| + |c -
    rx| <= lmax`` and both legs tx -> c and c -> rx are clear (:meth:`Scene.blocked`); the
    legs are tested once per distinct end point (``pts``, ``txi``, ``rxi``) and corner."""
    L = tx.shape[0]
    NC = C.shape[0]
    P = pts.shape[0]
    near = np.zeros((L, NC), np.bool_)
    need = np.zeros((P, NC), np.bool_)
    for l in range(L):
        txx, txy, rxx, rxy = tx[l, 0], tx[l, 1], rx[l, 0], rx[l, 1]
        for c in range(NC):
            cx, cy = C[c, 0], C[c, 1]
            d1 = np.sqrt((cx - txx) * (cx - txx) + (cy - txy) * (cy - txy))
            d2 = np.sqrt((cx - rxx) * (cx - rxx) + (cy - rxy) * (cy - rxy))
            if d1 + d2 <= lmax[l]:
                near[l, c] = True
                need[txi[l], c] = True
    first = _corner_legs(pts, need, C, False, trim, A, B, g0x, g0y, h, nx, ny, cstart, cwalls)
    need[:] = False
    for l in range(L):
        for c in range(NC):
            if near[l, c] and not first[txi[l], c]:
                need[rxi[l], c] = True
    second = _corner_legs(pts, need, C, True, trim, A, B, g0x, g0y, h, nx, ny, cstart, cwalls)
    ok = np.zeros((L, NC), np.bool_)
    for l in range(L):
        for c in range(NC):
            ok[l, c] = near[l, c] and not first[txi[l], c] and not second[rxi[l], c]
    return ok
