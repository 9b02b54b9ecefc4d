"""Grid Bayes filter of Zickler & Veloso (paper 003, Sect. IV, Algorithms 1-3 and the grid
operations of Algorithm 4), batched over independent runs.

:class:`GridFilter` is the one grid filter of the toolkit (a recursive estimator of the
contract in ``docs/architecture.md``): the tethering world (as its injected tracker), the
Herald experiment and ``radioloc locate --method grid-rssi`` all run it. It is built from
the batched grid operations below, which stay public and are the NumPy definitions of the
algorithms:

* :func:`probability_update` (Algorithm 1), :func:`get_location` (Algorithm 2),
  :func:`get_uncertainty` (Algorithm 3);
* :func:`blur_grid` and :func:`shift_grid` (BlurGrid, ShiftGrid of Algorithm 4), with
  :func:`floor_normalise`.

The same filter takes :class:`~radioloc.models.measurement.Observation` inputs of any
measurement model with a log-likelihood on 2-D positions (``GridFilter.tags``): the
likelihood of Algorithm 1 is then ``exp(sum of the model's logpdf at the cell centres)``,
on the filter's grid or on a grid built around each run's Gaussian prior; the paper's
RSSI readings are one configuration of it.

``GridFilter(backend="numba")`` (the default) runs its update with a
:class:`~radioloc.models.rssi_trapezoid.TrapezoidModel`, and its recursive blur, through the
compiled kernels of :mod:`radioloc.estimators.grid_compiled`; ``backend="numpy"`` runs the
definitions here. Both give the same grids to rounding (within 1e-10 relative, held by
``tests/test_grid_backend.py``).

A grid is an array ``p`` of shape ``(B, h, w)``: ``B`` runs, ``h`` rows (y) and ``w``
columns (x). :class:`GridGeometry` gives the cell centres ``l_i`` in the filter's frame.
Every function works on the whole batch at once; the per-run arguments (tracker position,
RSSI, blur radius, shift) have a leading batch axis.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from radioloc.core.backend import check_backend
from radioloc.core.errors import ConfigError, InputError
from radioloc.core.results import Estimate, Track, track_from_steps
from radioloc.core.validation import (LENGTH_LIMIT_M, MAGNITUDE_LIMIT, as_float_array,
                                      check_memory, check_positive, check_probability,
                                      check_symmetric, refuse_infinite)
from radioloc.estimators import grid_compiled as _c
from radioloc.estimators.base import RecursiveEstimator, Tags
from radioloc.estimators.observation_rows import (common_steps, flatten_step, log_likelihood_at,
                                                  observation_list, unflatten_estimate)
from radioloc.models.measurement import Observation
from radioloc.models.rssi_trapezoid import TrapezoidModel, as_rssi

_BLURS = ("fft", "recursive")

RECURSIVE_MIN_SIGMA = 2.0
"""Smallest standard deviation, in cells, blurred by the recursive Gaussian (below it the
exact blur is used: Young & van Vliet's fit holds for ``sigma >= 0.5`` and its error grows as
``sigma`` falls)."""

__all__ = ["GridGeometry", "GridState", "GridFilter", "cell_distances", "probability_update",
           "floor_normalise", "get_location", "get_uncertainty", "grid_moments", "blur_grid",
           "shift_grid", "yvv_coefficients", "RECURSIVE_MIN_SIGMA"]


@dataclass(frozen=True)
class GridGeometry:
    """A ``w`` x ``h`` grid of square cells of side ``cell_m``.

    The centre of the cell in row ``r``, column ``c`` is
    ``origin + ((c + 1/2) cell_m, (r + 1/2) cell_m)``.

    Parameters
    ----------
    w, h : int
        Columns (along x) and rows (along y).
    cell_m : float
        Cell side, metres.
    origin : tuple of float
        Lower-left corner ``(x, y)`` of the grid, metres.
    """

    w: int
    h: int
    cell_m: float
    origin: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        for name in ("w", "h"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise InputError(f"{name}: expected a positive integer number of cells, got {v}")
        check_positive(self.cell_m, "cell_m")

    @classmethod
    def centred(cls, w: int, h: int, cell_m: float, centre=(0.0, 0.0)) -> "GridGeometry":
        """A grid whose centre is at ``centre``.

        Parameters
        ----------
        w, h : int
            Columns and rows.
        cell_m : float
            Cell side, metres.
        centre : tuple of float
            Centre ``(x, y)`` of the grid, metres.

        Returns
        -------
        GridGeometry
        """
        return cls(w, h, cell_m, (centre[0] - 0.5 * w * cell_m, centre[1] - 0.5 * h * cell_m))

    @property
    def k(self) -> int:
        """Number of cells ``w h``."""
        return self.w * self.h

    @property
    def x(self) -> np.ndarray:
        """Cell-centre x of each column, shape ``(w,)``."""
        return self.origin[0] + (np.arange(self.w) + 0.5) * self.cell_m

    @property
    def y(self) -> np.ndarray:
        """Cell-centre y of each row, shape ``(h,)``."""
        return self.origin[1] + (np.arange(self.h) + 0.5) * self.cell_m

    def uniform(self, batch: int) -> np.ndarray:
        """The initial grid ``p_i = 1/k`` for ``batch`` runs.

        Parameters
        ----------
        batch : int
            Number of runs B.

        Returns
        -------
        ndarray, shape (batch, h, w)
        """
        return np.full((int(batch), self.h, self.w), 1.0 / self.k)

    def extent(self) -> tuple[float, float, float, float]:
        """The grid's outer edges, for ``imshow(..., origin='lower')``.

        Returns
        -------
        tuple of float
            ``(left, right, bottom, top)``, metres.
        """
        x0, y0 = self.origin
        return (x0, x0 + self.w * self.cell_m, y0, y0 + self.h * self.cell_m)


def _check_grid(p, geom: GridGeometry) -> np.ndarray:
    p = as_float_array(p, "grid", ndim=3, nonnegative=True)
    if p.shape[1:] != (geom.h, geom.w):
        raise InputError(f"grid: expected shape (B, {geom.h}, {geom.w}), got {p.shape}")
    return p


def _check_batch(value, name: str, batch: int, trailing: tuple[int, ...] = ()) -> np.ndarray:
    arr = as_float_array(value, name)
    arr = np.broadcast_to(arr, arr.shape) if arr.shape == (batch, *trailing) else arr
    if arr.shape != (batch, *trailing):
        raise InputError(f"{name}: expected shape {(batch, *trailing)}, got {arr.shape}")
    return arr


def cell_distances(geom: GridGeometry, position) -> np.ndarray:
    """Distance from each run's position to every cell centre.

    Parameters
    ----------
    geom : GridGeometry
        The grid.
    position : array_like, shape (B, 2)
        One ``(x, y)`` position per run, metres.

    Returns
    -------
    ndarray, shape (B, h, w)
        Distances in metres.
    """
    pos = as_float_array(position, "position", ndim=2, last_dim=2)
    dx = geom.x[None, None, :] - pos[:, 0, None, None]
    dy = geom.y[None, :, None] - pos[:, 1, None, None]
    return np.sqrt(dx * dx + dy * dy)


def probability_update(p, geom: GridGeometry, tracker_xy, rssi, model: "TrapezoidModel",
                       epsilon: float) -> np.ndarray:
    """Algorithm 1 (ProbabilityUpdate): ``p_i <- max(p_i L(|l_i - s_a| | rss), eps)``, then normalise.

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Prior grids (each summing to 1).
    geom : GridGeometry
        The grid.
    tracker_xy : array_like, shape (B, 2)
        Tracker position ``s_a`` of each run in the grid frame.
    rssi : array_like of int, shape (B,)
        Measured RSSI of each run (0..100).
    model : TrapezoidModel or any object with ``likelihood(dist, rssi)``
        The sensor model ``L(dist | rssi)``.
    epsilon : float
        Minimum cell probability. With a prior whose cells are all ``>= epsilon`` the
        normaliser is ``<= 1``, so the posterior's cells stay ``>= epsilon``.

    Returns
    -------
    ndarray, shape (B, h, w)
        Posterior grids (a new array).
    """
    p = _check_grid(p, geom)
    check_probability(epsilon, "epsilon")
    pos = _check_batch(tracker_xy, "tracker_xy", p.shape[0], (2,))
    r = _check_batch(rssi, "rssi", p.shape[0])
    lik = model.likelihood(cell_distances(geom, pos), r[:, None, None])
    post = np.maximum(p * lik, epsilon)
    return post / post.sum(axis=(1, 2), keepdims=True)


def floor_normalise(p, epsilon: float, excess=None) -> np.ndarray:
    """Renormalise grids to sum 1 with every cell ``>= epsilon``.

    ``p <- eps + (1 - k eps) (p - eps)_+ / sum (p - eps)_+``; used after blur and shift, where
    mass leaves through the grid border (the paper states the floor only for Algorithm 1).
    A grid with no mass above ``eps`` becomes uniform.

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Non-negative grids.
    epsilon : float
        Minimum cell probability (``epsilon k <= 1``).
    excess : ndarray, shape (B,), optional
        ``sum (p - eps)_+`` of each grid when already known.

    Returns
    -------
    ndarray, shape (B, h, w)
        Grids summing to 1 with every cell ``>= epsilon``.
    """
    p = np.asarray(p, dtype=float)
    k = p.shape[1] * p.shape[2]
    if epsilon * k > 1:
        raise InputError(f"epsilon: {epsilon} x {k} cells exceeds 1")
    over = np.maximum(p - epsilon, 0.0)
    t = over.sum(axis=(1, 2)) if excess is None else np.asarray(excess, dtype=float)
    t = t[:, None, None]
    share = np.where(t > 0, over / np.where(t > 0, t, 1.0), 1.0 / k)
    return epsilon + (1.0 - k * epsilon) * share


def get_location(p, geom: GridGeometry, *, include_peak: bool = False) -> np.ndarray:
    """Algorithm 2 (GetLocation): peak cell plus an interpolated sub-cell offset vector.

    ``final_offset = sum_j v_j (l_j - l_max) / sum_j v_j`` over the 8-connected neighbours
    ``j`` of the peak cell (those inside the grid), ``v_j = p_j / max_prob``. The paper
    prints ``|l_j - l_max|``; a norm would always push the estimate towards +x, +y, so the
    bars are read as the offset vector. ``include_peak=True`` also counts the peak cell
    (``v = 1``, offset 0) in the average, a variant the paper does not use.

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Grids.
    geom : GridGeometry
        The grid.
    include_peak : bool
        Also average the peak cell itself (not the paper's rule).

    Returns
    -------
    ndarray, shape (B, 2)
        Location ``(x, y)`` of each run, metres.
    """
    p = _check_grid(p, geom)
    B, h, w = p.shape
    flat = p.reshape(B, -1)
    idx = flat.argmax(axis=1)
    r0, c0 = np.divmod(idx, w)
    max_prob = flat[np.arange(B), idx]
    dr, dc = np.meshgrid([-1, 0, 1], [-1, 0, 1], indexing="ij")
    keep = ~((dr == 0) & (dc == 0)) if not include_peak else np.ones_like(dr, bool)
    dr, dc = dr[keep], dc[keep]                                     # (n,)
    rr, cc = r0[:, None] + dr, c0[:, None] + dc                      # (B, n)
    inside = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
    vals = p[np.arange(B)[:, None], np.clip(rr, 0, h - 1), np.clip(cc, 0, w - 1)]
    v = np.where(inside, vals / np.where(max_prob > 0, max_prob, 1.0)[:, None], 0.0)
    vsum = v.sum(axis=1)
    off = np.stack([(v * dc).sum(axis=1), (v * dr).sum(axis=1)], axis=-1) * geom.cell_m
    off = np.where(vsum[:, None] > 0, off / np.where(vsum > 0, vsum, 1.0)[:, None], 0.0)
    peak = np.stack([geom.x[c0], geom.y[r0]], axis=-1)
    return peak + off


def get_uncertainty(p, geom: GridGeometry) -> np.ndarray:
    """Algorithm 3 (GetUncertainty): ``sqrt(sum_i p_i |l_i - l_max|^2)``.

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Grids.
    geom : GridGeometry
        The grid.

    Returns
    -------
    ndarray, shape (B,)
        Spread of each grid about its peak cell centre ``l_max``, metres.
    """
    p = _check_grid(p, geom)
    B, h, w = p.shape
    r0, c0 = np.divmod(p.reshape(B, -1).argmax(axis=1), w)
    dx2 = (geom.x[None, :] - geom.x[c0][:, None]) ** 2               # (B, w)
    dy2 = (geom.y[None, :] - geom.y[r0][:, None]) ** 2               # (B, h)
    return np.sqrt(np.einsum("bhw,bw->b", p, dx2) + np.einsum("bhw,bh->b", p, dy2))


def blur_grid(p, geom: GridGeometry, radius_m, epsilon: float = 0.0, *,
              method: str = "fft") -> np.ndarray:
    """BlurGrid: circular Gaussian blur with standard deviation ``radius_m`` per run.

    ``method="fft"`` (exact): the blur is applied in the Fourier domain on a grid
    zero-padded by ``ceil(4 radius / cell_m)`` cells (so nothing wraps round the border),
    which lets every run use its own radius in one batched FFT per distinct padding; the
    padding of a run depends on its own radius only, so a run's result does not depend on
    the rest of the batch. Mass blurred beyond the border is lost and the grid renormalised
    by :func:`floor_normalise`. The paper calls the argument a radius; we use it as the
    Gaussian's standard deviation.

    ``method="recursive"`` blurs the runs whose standard deviation is at least
    :data:`RECURSIVE_MIN_SIGMA` cells with the separable recursive Gaussian of Young & van
    Vliet (a third-order causal and anti-causal recursion along each axis, cost independent
    of the radius; zero outside the grid as above) and the others with the FFT. It is an
    approximation: its impulse response has the exact variance but departs from the
    Gaussian by 8.5-18 % of the peak value in one dimension (18 % at 2 cells, 9 % at 15).

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Grids.
    geom : GridGeometry
        The grid.
    radius_m : float or array_like, shape (B,)
        Blur radius in metres (0 leaves the grid unchanged up to the floor).
    epsilon : float
        Minimum cell probability after renormalisation.
    method : {"fft", "recursive"}
        Exact Gaussian by FFT (default), or the recursive approximation for wide blurs.

    Returns
    -------
    ndarray, shape (B, h, w)
        Blurred grids (a new array).
    """
    p = _check_grid(p, geom)
    if method not in _BLURS:
        raise InputError(f"method: expected one of {_BLURS}, got {method!r}")
    B, h, w = p.shape
    rad = np.broadcast_to(as_float_array(radius_m, "radius_m", nonnegative=True), (B,))
    if epsilon * h * w > 1:
        raise InputError(f"epsilon: {epsilon} x {h * w} cells exceeds 1")
    raw, excess = _blur_raw(p, rad / geom.cell_m, float(epsilon), method, "numpy")
    return floor_normalise(raw, epsilon, excess)


def _blur_raw(p: np.ndarray, s: np.ndarray, epsilon: float, method: str, backend: str
              ) -> tuple[np.ndarray, np.ndarray]:
    """The blur of :func:`blur_grid` (standard deviations ``s`` in cells) before the floor:
    ``(grids, sum (grids - eps)_+)``; the recursive blur by ``backend``."""
    B, h, w = p.shape
    wide = s >= RECURSIVE_MIN_SIGMA if method == "recursive" else np.zeros(B, bool)
    if wide.all():
        return _recursive_blur(p, s, epsilon, backend)
    out, excess = np.empty_like(p), np.empty(B)
    if wide.any():
        out[wide], excess[wide] = _recursive_blur(p[wide], s[wide], epsilon, backend)
    # each run's padding depends on its own radius only (so a run's result does not depend
    # on the other runs of the batch); one batched FFT per distinct padding
    pads = np.minimum(np.ceil(4.0 * s).astype(np.int64), max(h, w))
    for pad in np.unique(pads[~wide]):
        sel = (pads == pad) & ~wide
        H, W = h + 2 * int(pad), w + 2 * int(pad)
        fy = np.fft.fftfreq(H)[:, None]
        fx = np.fft.rfftfreq(W)[None, :]
        kernel = np.exp(-2.0 * np.pi**2 * s[sel, None, None] ** 2 * (fx**2 + fy**2)[None])
        spec = np.fft.rfft2(p[sel], s=(H, W), axes=(1, 2))
        out[sel] = np.maximum(np.fft.irfft2(spec * kernel, s=(H, W), axes=(1, 2))[:, :h, :w], 0.0)
        excess[sel] = np.maximum(out[sel] - epsilon, 0.0).sum(axis=(1, 2))
    return out, excess


@functools.lru_cache(maxsize=256)
def _yvv_coefficients(sigma: float) -> tuple[float, float, float, float]:
    q0 = (0.98711 * sigma - 0.96330 if sigma >= 2.5
          else 3.97156 - 4.14554 * np.sqrt(max(1.0 - 0.26891 * sigma, 0.0)))
    # the published q gives a response wider than sigma (about 10 %); solve for the q whose
    # causal-times-anti-causal impulse response has variance exactly sigma^2
    lo, hi = 1e-3, max(2.0 * q0, 1.0)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        g, a1, a2, a3 = _yvv_from_q(mid)
        d = 1.0 - a1 - a2 - a3
        d1 = -(a1 + 2.0 * a2 + 3.0 * a3)
        d2 = -(2.0 * a2 + 6.0 * a3)
        # twice the second cumulant of 1 / D(x), D(x) = 1 - a1 x - a2 x^2 - a3 x^3, at x = 1
        if 2.0 * (-(d2 + d1) / d + (d1 / d) ** 2) > sigma**2:
            hi = mid
        else:
            lo = mid
    return _yvv_from_q(0.5 * (lo + hi))


def _yvv_from_q(q: float) -> tuple[float, float, float, float]:
    b0 = 1.57825 + 2.44413 * q + 1.4281 * q**2 + 0.422205 * q**3
    b1 = (2.44413 * q + 2.85619 * q**2 + 1.26661 * q**3) / b0
    b2 = -(1.4281 * q**2 + 1.26661 * q**3) / b0
    b3 = 0.422205 * q**3 / b0
    return (1.0 - (b1 + b2 + b3), b1, b2, b3)


def yvv_coefficients(sigma_cells) -> np.ndarray:
    """Young & van Vliet (1995) recursion coefficients for standard deviations in cells.

    ``b0 = 1.57825 + 2.44413 q + 1.4281 q^2 + 0.422205 q^3``, ``b1 = 2.44413 q + 2.85619 q^2
    + 1.26661 q^3``, ``b2 = -(1.4281 q^2 + 1.26661 q^3)``, ``b3 = 0.422205 q^3``,
    ``g = 1 - (b1 + b2 + b3) / b0``; ``q`` is solved (from the paper's
    ``q = 0.98711 sigma - 0.96330`` or ``3.97156 - 4.14554 sqrt(1 - 0.26891 sigma)``) so that
    the causal-times-anti-causal impulse response has variance exactly ``sigma^2``.

    Parameters
    ----------
    sigma_cells : array_like, shape (B,)
        Standard deviations in cells (``>= 0.5``).

    Returns
    -------
    ndarray, shape (B, 4)
        ``(g, b1 / b0, b2 / b0, b3 / b0)`` per run: ``y_n = g x_n + a1 y_{n-1} + a2 y_{n-2}
        + a3 y_{n-3}``.
    """
    s = np.asarray(sigma_cells, dtype=float).reshape(-1)
    return np.array([_yvv_coefficients(float(v)) for v in s]).reshape(-1, 4)


def _yvv_tails(s: np.ndarray) -> np.ndarray:
    # zero cells the recursions run through past the far border (they decay with the
    # Gaussian: 6 sigma of zeros lose < 1e-8 of the mass)
    return np.ceil(6.0 * s).astype(np.int64) + 3


def _yvv_axis(x: np.ndarray, coef, tail: int) -> np.ndarray:
    """Young & van Vliet's recursions along axis 1 of ``x`` ``(B, n, m)``: the causal
    ``w_i = a1 w_{i-1} + (a2 w_{i-2} + (a3 w_{i-3} + g x_i))`` over the ``n`` cells and
    ``tail`` zeros past the border, then the anti-causal ``v_i = a1 v_{i+1} + (a2 v_{i+2} +
    (a3 v_{i+3} + g w_i))`` back from the tail's end (both started from zero)."""
    g, a1, a2, a3 = coef
    B, n, m = x.shape
    wv = np.zeros((B, n + tail + 3, m))            # w_i at index i + 3
    for i in range(n + tail):
        xi = x[:, i] if i < n else np.zeros((B, m))
        wv[:, i + 3] = a1 * wv[:, i + 2] + (a2 * wv[:, i + 1] + (a3 * wv[:, i] + g * xi))
    v = np.zeros((B, n + tail + 3, m))             # v_i at index i
    for i in range(n + tail - 1, -1, -1):
        v[:, i] = a1 * v[:, i + 1] + (a2 * v[:, i + 2] + (a3 * v[:, i + 3] + g * wv[:, i + 3]))
    return v[:, :n]


def _recursive_blur(p: np.ndarray, s: np.ndarray, epsilon: float, backend: str
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The recursive Gaussian of standard deviation ``s[b]`` cells of each grid, along the
    rows' axis then the columns' (zero outside the grid; not clipped), and its
    ``sum (v - eps)_+``."""
    coef, tails = yvv_coefficients(s), _yvv_tails(s)
    B, h, w = p.shape
    if backend == "numba":
        # one run at a time (the transposed scratch holds one grid): along the rows' axis
        # into the transposed layout, then along the columns' back; the first pass also
        # checks the grid (the full check names a bad cell)
        p, out, total = np.ascontiguousarray(p), np.empty((B, h, w)), np.empty(B)
        mid = np.empty((1, w, h))
        for k in range(B):
            run = slice(k, k + 1)
            for src, dst, n, limit in ((p[run], mid, w, MAGNITUDE_LIMIT),
                                       (mid, out[run], h, np.inf)):
                jobs = (1, -(-n // _c.CHUNK))
                excess, bad = np.empty(jobs), np.empty(jobs, np.int64)
                _c.yvv_transposed(src, coef[run], tails[run], epsilon, limit, dst, excess, bad)
                if bad.any():
                    as_float_array(p, "grid", nonnegative=True)
            total[k] = excess.sum()
        return out, total
    out = np.empty_like(p)
    for si in np.unique(s):                          # the runs of one radius at once
        sel = s == si
        b = np.flatnonzero(sel)[0]
        cols = _yvv_axis(p[sel], coef[b], tails[b])
        out[sel] = _yvv_axis(cols.transpose(0, 2, 1), coef[b], tails[b]).transpose(0, 2, 1)
    return out, np.maximum(out - epsilon, 0.0).sum(axis=(1, 2))


def shift_grid(p, geom: GridGeometry, shift_m, epsilon: float = 0.0) -> np.ndarray:
    """ShiftGrid: translate each run's grid by ``shift_m`` ``(B, 2)`` metres (x, y).

    Sub-cell shifts use bilinear interpolation between the four nearest whole-cell shifts;
    cells shifted in from outside the grid are empty and the grid is renormalised with
    :func:`floor_normalise`. A whole-cell shift moves every value by exactly that many cells.

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Grids.
    geom : GridGeometry
        The grid.
    shift_m : array_like, shape (B, 2)
        Translation ``(x, y)`` of each run's grid, metres.
    epsilon : float
        Minimum cell probability after renormalisation.

    Returns
    -------
    ndarray, shape (B, h, w)
        Shifted grids (a new array).
    """
    p = _check_grid(p, geom)
    B, h, w = p.shape
    sh = _check_batch(shift_m, "shift_m", B, (2,)) / geom.cell_m
    ix, iy = np.floor(sh[:, 0]).astype(np.int64), np.floor(sh[:, 1]).astype(np.int64)
    fx, fy = sh[:, 0] - ix, sh[:, 1] - iy
    b = np.arange(B)[:, None, None]
    rows0 = np.arange(h)[None, :] - iy[:, None]                      # source rows, (B, h)
    cols0 = np.arange(w)[None, :] - ix[:, None]
    out = np.zeros_like(p)
    for drow, wy in ((0, 1.0 - fy), (1, fy)):
        for dcol, wx in ((0, 1.0 - fx), (1, fx)):
            rows, cols = rows0 - drow, cols0 - dcol
            ok = ((rows >= 0) & (rows < h))[:, :, None] & ((cols >= 0) & (cols < w))[:, None, :]
            src = p[b, np.clip(rows, 0, h - 1)[:, :, None], np.clip(cols, 0, w - 1)[:, None, :]]
            out += (wy * wx)[:, None, None] * np.where(ok, src, 0.0)
    return floor_normalise(out, epsilon)


def grid_moments(p, geom: GridGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of the position under each grid (cell centres as support).

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Grids (each summing to 1).
    geom : GridGeometry
        The grid.

    Returns
    -------
    mean : ndarray, shape (B, 2)
        ``sum_i p_i l_i``, ``(x, y)`` metres.
    covariance : ndarray, shape (B, 2, 2)
        ``sum_i p_i (l_i - mean)(l_i - mean)^T``, m^2 (the cells' own extent is not added).
    """
    p = _check_grid(p, geom)
    px = p.sum(axis=1)                                               # (B, w)
    py = p.sum(axis=2)                                               # (B, h)
    mx = px @ geom.x
    my = py @ geom.y
    dx = geom.x[None, :] - mx[:, None]                               # (B, w)
    dy = geom.y[None, :] - my[:, None]                               # (B, h)
    vxx = np.einsum("bw,bw->b", px, dx * dx)
    vyy = np.einsum("bh,bh->b", py, dy * dy)
    vxy = np.einsum("bhw,bh,bw->b", p, dy, dx)
    cov = np.stack([np.stack([vxx, vxy], -1), np.stack([vxy, vyy], -1)], -2)
    return np.stack([mx, my], axis=-1), cov


@dataclass(frozen=True, eq=False)
class GridState:
    """State of a batch of grid filters (immutable).

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Posterior grid of each run (sums to 1, every cell ``>= epsilon``).
    time : float
        Time of the state, seconds.
    offset : ndarray, shape (B, 2), optional
        Where each run's grid sits: the cell centres are ``offset + l_i`` (a grid built
        around each run's prior, which moves with ``velocity``); None: the filter's
        geometry as it is.
    velocity : ndarray, shape (B, 2), optional
        Constant velocity the grid drifts with (m/s), from the prior of a motion model
        with velocity; None: no drift.
    pvv : ndarray, shape (B,), optional
        The prior's per-axis velocity variance (m^2/s^2), blurred in at each step.
    geometry : GridGeometry, optional
        The grid of a state built around the prior (cells relative to ``offset``); None:
        the filter's.
    """

    p: np.ndarray
    time: float = 0.0
    offset: np.ndarray | None = None
    velocity: np.ndarray | None = None
    pvv: np.ndarray | None = None
    geometry: GridGeometry | None = None

    @property
    def batch(self) -> int:
        """Number of runs B."""
        return int(np.shape(self.p)[0])

    def __getitem__(self, index: Any) -> "GridState":
        """Select runs (a slice or index array keeps the batch axis).

        Parameters
        ----------
        index : slice, int array or bool array
            Runs to keep.

        Returns
        -------
        GridState
        """
        def keep(a):
            if a is None:
                return None
            return a[index] if np.ndim(a[index]) == np.ndim(a) else a[index][None]
        return GridState(keep(self.p), self.time, keep(self.offset), keep(self.velocity),
                         keep(self.pvv), self.geometry)


_LOCATIONS = ("mean", "peak")


class GridFilter(RecursiveEstimator):
    """Grid Bayes filter of paper 003 (Algorithms 1-3, the grid operations of Algorithm 4).

    A recursive estimator (see ``docs/architecture.md``): :meth:`init` makes the uniform
    (or a given) grid for a batch of runs, :meth:`step` predicts (ShiftGrid, BlurGrid) and
    updates (ProbabilityUpdate, Algorithm 1) every run at once, :meth:`estimate` reads the
    position, :meth:`run` filters a whole series into a :class:`~radioloc.core.results.Track`.
    :meth:`predict` and :meth:`update` are the two halves of :meth:`step`, for callers that
    act between them (the tethering behaviour of Algorithm 4 reads the predicted grid
    before the new reading arrives).

    Motion model: the paper blurs the grid by a radius ``gamma`` per step (Algorithm 4);
    ``blur_m`` is that radius, used as the standard deviation of the Gaussian blur
    (:func:`blur_grid`). Alternatively ``motion`` takes a position-only random walk
    (:class:`radioloc.models.motion.RandomWalk`): the blur over ``dt`` is then its per-axis
    standard deviation ``sqrt(q dt)``, the exact Gaussian prediction of that model. Give
    one or neither (``blur_m = 0`` and no ``motion``: a static target, no prediction).
    A caller that knows part of the target's motion passes ``shift_m`` (a known
    displacement: ShiftGrid) and ``extra_blur_m`` (an extra blur radius, e.g. Algorithm 4's
    ``|odometry step|`` before the frames are synchronised) to :meth:`predict`.

    Any measurement model: :meth:`run` and :meth:`step` also take
    :class:`~radioloc.models.measurement.Observation` inputs of any model whose tags fit
    (``tags``: a ``logpdf`` on 2-D positions, reading the position only): range (Gaussian,
    LOS/NLOS), time difference, bearing, RSS (log-distance, trapezoid, calibration
    mixture), ... The update is Algorithm 1 with ``L_i = exp(sum logpdf(z | l_i) - max)``
    over every row of every observation of the step (:meth:`update_observations`); the
    paper's readings ``(tracker_xy, rssi)`` with ``model`` are the same filter with the
    model's likelihood (a configuration: same grids to rounding with ``epsilon = 0``). The
    grid is the filter's ``geometry`` or, without one, a square grid of ``cell_m`` cells
    around each run's Gaussian prior (``prior_mean``, ``prior_cov``; :meth:`prior_grid`).
    A motion model with velocity (``WhiteAccelerationCV``, ``ConstantVelocity``) is
    carried as the prior's velocity, which the grid drifts with, and its position noise
    blurs the grid (:meth:`drift`): the grid holds positions only.

    Parameters
    ----------
    geometry : GridGeometry, optional
        The grid (cells in the filter's frame); None: a grid around each run's prior.
    model : object with ``likelihood(dist, rssi)``, optional
        Sensor model ``L(dist | rssi)`` of the readings form:
        :class:`~radioloc.models.rssi_trapezoid.TrapezoidModel`,
        :class:`~radioloc.models.rssi_logdistance.LogDistanceGaussian`, ... (observations
        carry their own models).
    epsilon : float, optional
        Minimum cell probability (Algorithm 1); ``epsilon k <= 1``. Default ``1e-6`` with a
        readings ``model`` (the paper-003 experiments), else ``1e-12`` (a floor of
        ``1e-6`` per cell would outweigh a posterior narrower than the grid).
    blur_m : float
        BlurGrid radius per step (the paper's ``gamma``), metres.
    motion : motion model, optional
        2-D: a random walk (``RandomWalk``) whose ``Q(dt)`` sets the blur instead of
        ``blur_m``, or a model with velocity (observations with ``prior_mean``: see above).
    location : {"mean", "peak"}
        What :meth:`estimate` reports as the position: the grid mean (the posterior mean,
        default), or GetLocation (Algorithm 2, the paper's: peak cell plus an
        interpolated offset).
    blur : {"fft", "recursive"}
        How BlurGrid blurs (:func:`blur_grid`'s ``method``): the exact Gaussian by FFT
        (default; the paper-003 experiments use it), or the recursive approximation, whose
        cost does not grow with the radius (wide blurs on large grids).
    backend : {"numba", "numpy"}
        ``"numba"`` (default): the update with a
        :class:`~radioloc.models.rssi_trapezoid.TrapezoidModel` and the recursive blur run
        as compiled kernels (:mod:`radioloc.estimators.grid_compiled`); ``"numpy"``: every
        operation runs its NumPy definition (:func:`probability_update`,
        :func:`blur_grid`, ...). The two agree to rounding (within 1e-10 relative).
    cell_m : float
        Cell side of the grids built around the priors, metres.
    span_m : float, optional
        Their half-width, metres; default four times the largest prior position standard
        deviation of the batch.

    Raises
    ------
    ConfigError
        A setting out of range, naming it.
    """

    name = "grid"
    tags = Tags(kinds=None, uses="logpdf", dims=(2,), recursive=True, generic=True,
                reads=("position",))

    def __init__(self, geometry: GridGeometry | None = None, model: Any = None, *,
                 epsilon: float | None = None, blur_m: float = 0.0, motion: Any = None,
                 location: str = "mean", blur: str = "fft", backend: str = "numba",
                 cell_m: float = 0.25, span_m: float | None = None) -> None:
        if geometry is not None and not isinstance(geometry, GridGeometry):
            raise ConfigError(f"geometry: expected a GridGeometry, got {type(geometry).__name__}")
        if model is not None and not callable(getattr(model, "likelihood", None)):
            raise ConfigError(f"model: needs a likelihood(dist, rssi) method, got {type(model).__name__}")
        if epsilon is None:
            epsilon = 1e-6 if model is not None else 1e-12
        eps = check_probability(epsilon, "epsilon")
        if geometry is not None and eps * geometry.k > 1:
            raise ConfigError(f"epsilon: {eps} x {geometry.k} cells exceeds 1")
        blur_v = check_positive(blur_m, "blur_m", allow_zero=True, maximum=LENGTH_LIMIT_M)
        self.cell_m = check_positive(cell_m, "cell_m", maximum=LENGTH_LIMIT_M)
        self.span_m = None if span_m is None else check_positive(span_m, "span_m",
                                                                 maximum=LENGTH_LIMIT_M)
        if motion is not None:
            if not callable(getattr(motion, "Q", None)) or getattr(motion, "dim", None) != 2 \
                    or getattr(motion, "state_dim", None) not in (2, 4):
                raise ConfigError("motion: the grid holds 2-D positions only; expected a 2-D "
                                  "random walk (RandomWalk) or a model with velocity "
                                  f"(WhiteAccelerationCV, ConstantVelocity), got {motion!r}")
            if blur_v > 0:
                raise ConfigError("blur_m: give either blur_m or a motion model, not both")
        if location not in _LOCATIONS:
            raise ConfigError(f"location: expected one of {_LOCATIONS}, got {location!r}")
        if blur not in _BLURS:
            raise ConfigError(f"blur: expected one of {_BLURS}, got {blur!r}")
        check_backend(backend)
        self.geometry = geometry
        self.model = model
        self.epsilon = eps
        self.blur_m = blur_v
        self.motion = motion
        self.location = location
        self.blur = blur
        self.backend = backend

    # ---- the contract -------------------------------------------------------------
    def init(self, batch: int | None = None, *, prior=None, time: float = 0.0,
             prior_mean=None, prior_cov=None) -> GridState:
        """The filter state before the first reading.

        Parameters
        ----------
        batch : int, optional
            Number of runs B of a uniform prior ``p_i = 1/k`` (the paper's).
        prior : array_like, shape (B, h, w), optional
            Prior grids instead (normalised, floored at ``epsilon`` and renormalised).
        time : float
            Time of the state, seconds.
        prior_mean, prior_cov : array_like, shape (B, n) and (n, n) or (B, n, n), optional
            A Gaussian prior instead, on the state of the motion model (``n = 2``: the
            position; ``n = 4``: position and velocity, whose mean the grid drifts with):
            its position density on the cells of the filter's geometry or, without one, of
            a grid of ``cell_m`` cells around each run's prior mean (:meth:`prior_grid`).

        Returns
        -------
        GridState
        """
        if prior_mean is not None or prior_cov is not None:
            return self._gaussian_prior(prior_mean, prior_cov, time)
        if prior is None:
            if batch is None or int(batch) != batch or batch < 1:
                raise InputError(f"batch: expected a positive number of runs, got {batch!r}")
            return GridState(self._fixed_geometry("init").uniform(int(batch)), float(time))
        p = _check_grid(prior, self._fixed_geometry("init"))
        total = p.sum(axis=(1, 2), keepdims=True)
        if np.any(total <= 0):
            raise InputError(f"prior: grid {int(np.flatnonzero(total.ravel() <= 0)[0])} has no mass")
        if batch is not None and p.shape[0] != batch:
            raise InputError(f"prior: expected {batch} grids, got {p.shape[0]}")
        p = np.maximum(p / total, self.epsilon)
        return GridState(p / p.sum(axis=(1, 2), keepdims=True), float(time))

    def _check_state(self, state: GridState, cells: bool = True) -> GridState:
        # cells=False: the shape only (the compiled recursive blur checks the cells)
        if not isinstance(state, GridState):
            raise InputError(f"state: expected a GridState, got {type(state).__name__}")
        p = state.p
        if cells or not (isinstance(p, np.ndarray) and p.dtype == np.float64 and p.ndim == 3):
            p = _check_grid(p, self._geom(state))
        elif p.shape[1:] != (self._geom(state).h, self._geom(state).w):
            _check_grid(p, self._geom(state))
        return replace(state, p=np.ascontiguousarray(p))

    def blur_radius(self, dt: float) -> float:
        """Blur radius of the motion model over ``dt`` seconds.

        Parameters
        ----------
        dt : float
            Time step, seconds.

        Returns
        -------
        float
            ``sqrt(q dt)`` of the random walk, else ``blur_m`` (per step, whatever ``dt``).
        """
        if self.motion is None:
            return self.blur_m
        return float(np.sqrt(np.asarray(self.motion.Q(dt))[0, 0]))

    def predict(self, state: GridState, *, dt: float = 1.0, shift_m=None,
                extra_blur_m=None) -> GridState:
        """Prediction: ShiftGrid by a known displacement, then BlurGrid (Algorithm 4).

        A run whose shift is zero is not shifted and a run whose blur radius is zero is
        not blurred (both operations are then the identity).

        Parameters
        ----------
        state : GridState
            Current state (not modified).
        dt : float
            Time step, seconds (sets the blur of a ``motion`` model; advances the time).
        shift_m : array_like, shape (B, 2), optional
            Known displacement ``(x, y)`` of the target in the grid's frame, metres.
        extra_blur_m : array_like, shape (B,), optional
            Blur radius added to the motion model's, metres (>= 0).

        Returns
        -------
        GridState
            The predicted state at ``time + dt``.
        """
        state = self._check_state(state)
        dt = check_positive(dt, "dt", allow_zero=True)
        B, geom, p = state.batch, self._geom(state), state.p
        if shift_m is not None:
            shift = _check_batch(shift_m, "shift_m", B, (2,))
            moved = np.any(shift != 0.0, axis=-1)
            if moved.any():
                p = np.where(moved[:, None, None], shift_grid(p, geom, shift, self.epsilon), p)
        s = self._radius(B, dt, extra_blur_m) / geom.cell_m
        blur = s > 0
        if blur.any():
            raw, excess = _blur_raw(p, s, self.epsilon, self.blur, self.backend)
            p = np.where(blur[:, None, None], floor_normalise(raw, self.epsilon, excess), p)
        return replace(state, p=p, time=state.time + dt)

    def _radius(self, B: int, dt: float, extra_blur_m) -> np.ndarray:
        radius = np.full(B, self.blur_radius(dt))
        if extra_blur_m is not None:
            extra = as_float_array(extra_blur_m, "extra_blur_m", nonnegative=True)
            if extra.shape not in ((), (B,)):
                raise InputError(f"extra_blur_m: expected shape ({B},), got {extra.shape}")
            radius = extra + radius
        return radius

    def update(self, state: GridState, tracker_xy, rssi) -> GridState:
        """Measurement update: ProbabilityUpdate (Algorithm 1) of every run with a reading.

        Parameters
        ----------
        state : GridState
            Current state (not modified).
        tracker_xy : array_like, shape (B, 2)
            Where each reading was taken (the tracker's, or the anchor's, position in the
            grid's frame), metres; may be NaN where ``rssi`` is NaN.
        rssi : array_like, shape (B,)
            One reading per run on the model's scale; NaN = no reading (that run is left
            unchanged).

        Returns
        -------
        GridState
            The posterior state (same time).
        """
        self._paper_inputs()
        state = self._check_state(state)
        B = state.batch
        r = as_float_array(rssi, "rssi", allow_nan=True)
        if r.shape != (B,):
            raise InputError(f"rssi: expected shape ({B},), got {r.shape}")
        if np.any(np.isinf(r)):
            raise InputError(f"rssi: infinite value at index {int(np.flatnonzero(np.isinf(r))[0])}")
        xy = as_float_array(tracker_xy, "tracker_xy", allow_nan=True)
        if xy.shape != (B, 2):
            raise InputError(f"tracker_xy: expected shape ({B}, 2), got {xy.shape}")
        valid = np.isfinite(r)
        bad = valid & ~np.all(np.isfinite(xy), axis=-1)
        if bad.any():
            raise InputError(f"tracker_xy: non-finite position of run {int(np.flatnonzero(bad)[0])} "
                             "that has a reading")
        if not valid.any():
            return state
        if valid.all():
            return replace(state, p=self._posterior(state.p, None, xy, r))
        post = self._posterior(state.p, None, np.where(valid[:, None], xy, 0.0),
                               np.where(valid, r, r[valid][0]))
        return replace(state, p=np.where(valid[:, None, None], post, state.p))

    def _posterior(self, prior: np.ndarray, excess, xy: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Algorithm 1 of every run, of the prior ``floor_normalise(prior, eps, excess)``
        (of ``prior`` itself when ``excess`` is None)."""
        eps, geom = self.epsilon, self.geometry
        if self.backend == "numba" and isinstance(self.model, TrapezoidModel):
            B, k = prior.shape[0], geom.k
            if excess is None:
                base, scale = np.zeros(B), np.ones(B)
            else:
                mass = excess > 0
                base = np.where(mass, eps, 1.0 / k)
                scale = np.where(mass, (1.0 - k * eps) / np.where(mass, excess, 1.0), 0.0)
            i = as_rssi(r)
            m = self.model
            # a blurred prior is this step's own array: the posterior is written over it
            out, rows = np.empty(prior.shape) if excess is None else prior, np.empty(prior.shape[:2])
            _c.trapezoid_update(prior, geom.x, geom.y, np.ascontiguousarray(xy), m.mu[i],
                                m.tau[i], m.sigma[i], base, scale, eps, out, rows)
            out *= (1.0 / rows.sum(axis=1))[:, None, None]
            return out
        if excess is not None:
            prior = floor_normalise(prior, eps, excess)
        return probability_update(prior, geom, xy, r, self.model, eps)

    def step(self, state: GridState, tracker_xy, rssi=None, *, dt: float = 1.0, shift_m=None,
             extra_blur_m=None) -> GridState:
        """One filter step: :meth:`predict` then :meth:`update`.

        Parameters
        ----------
        state : GridState
            Current state (not modified).
        tracker_xy : array_like, shape (B, 2), or Observation(s)
            Where each reading was taken, metres (NaN allowed where ``rssi`` is NaN); or
            the observations of this step (``z`` ``(B, m)``, any model the tags accept),
            then ``rssi`` is not given: the grid drifts and blurs over ``dt`` by the motion
            model and is multiplied by every model's likelihood (:meth:`update_observations`).
        rssi : array_like, shape (B,)
            One reading per run; NaN = prediction only.
        dt : float
            Time since ``state``, seconds.
        shift_m : array_like, shape (B, 2), optional
            Known displacement of the target, metres (see :meth:`predict`).
        extra_blur_m : array_like, shape (B,), optional
            Extra blur radius, metres (see :meth:`predict`).

        Returns
        -------
        GridState
            The new state at ``time + dt``.
        """
        if _is_observations(tracker_xy):
            if rssi is not None or shift_m is not None or extra_blur_m is not None:
                raise InputError("rssi: observations carry their own values (give neither "
                                 "rssi, shift_m nor extra_blur_m with them)")
            return self.update_observations(self.drift(state, dt), tracker_xy)
        self._paper_inputs()
        if shift_m is None:
            # every run blurred and updated: the floor of the blur applied by the update
            # (the same grids as predict then update, one pass less)
            if not isinstance(state, GridState):
                raise InputError(f"state: expected a GridState, got {type(state).__name__}")
            dt = check_positive(dt, "dt", allow_zero=True)
            B = state.batch
            s = self._radius(B, dt, extra_blur_m) / self._geom(state).cell_m
            state = self._check_state(state, cells=not (
                self.backend == "numba" and self.blur == "recursive"
                and np.all(s >= RECURSIVE_MIN_SIGMA)))
            r = as_float_array(rssi, "rssi", allow_nan=True)
            xy = as_float_array(tracker_xy, "tracker_xy", allow_nan=True)
            if (r.shape == (B,) and xy.shape == (B, 2) and np.all(s > 0)
                    and np.all(np.isfinite(r)) and np.all(np.isfinite(xy))):
                raw, excess = _blur_raw(state.p, s, self.epsilon, self.blur, self.backend)
                return replace(state, p=self._posterior(raw, excess, xy, r),
                               time=state.time + dt)
        pred = self.predict(state, dt=dt, shift_m=shift_m, extra_blur_m=extra_blur_m)
        return self.update(pred, tracker_xy, rssi)

    def estimate(self, state: GridState) -> Estimate:
        """The position held by a state.

        Parameters
        ----------
        state : GridState
            A filter state.

        Returns
        -------
        Estimate
            ``position`` ``(B, 2)`` in ``(x, y)``: the grid mean or, with
            ``location="peak"``, GetLocation (Algorithm 2); ``covariance`` ``(B, 2, 2)``:
            the grid's covariance about its mean; ``time``; ``diagnostics``:
            ``uncertainty_m`` ``(B,)`` (GetUncertainty, Algorithm 3: the spread about the
            peak cell, which the tethering behaviour compares with its threshold ``v``) and
            ``grid_mean`` ``(B, 2)``.
        """
        state = self._check_state(state)
        geom = self._geom(state)
        mean, cov = grid_moments(state.p, geom)
        pos = mean if self.location == "mean" else get_location(state.p, geom)
        if state.offset is not None:
            mean, pos = mean + state.offset, pos + state.offset
        diag = {"uncertainty_m": get_uncertainty(state.p, geom), "grid_mean": mean}
        return Estimate(pos, cov, state.time, diag)

    def run(self, tracker_xy, rssi=None, *, time=None, dt: float = 1.0, shift_m=None,
            extra_blur_m=None, state: GridState | None = None, prior_mean=None,
            prior_cov=None) -> Track:
        """Filter a whole series of readings, or of observations of any model.

        ``run(observations, time=None, *, prior_mean, prior_cov)`` is the generic form
        (:meth:`run_observations`); ``run(tracker_xy, rssi, ...)`` the paper's readings
        with the filter's ``model``.

        Parameters
        ----------
        tracker_xy : array_like, shape (B, T, 2), or Observation(s)
            Where each reading was taken, metres (NaN allowed where ``rssi`` is NaN); or
            the observations (then the second argument is ``time``).
        rssi : array_like, shape (B, T)
            Readings; NaN = no reading at that step (prediction only).
        time : array_like, shape (T,), optional
            Time of each step, seconds, non-decreasing; default ``state.time + dt (1..T)``.
        dt : float
            Step length when ``time`` is not given, seconds.
        shift_m : array_like, shape (B, T, 2), optional
            Known displacement of the target before each step, metres.
        extra_blur_m : array_like, shape (B, T), optional
            Extra blur radius before each step, metres.
        state : GridState, optional
            Initial state; default the uniform grid at time 0.

        Returns
        -------
        Track
            ``position`` ``(B, T, 2)``, ``covariance`` ``(B, T, 2, 2)``, ``time`` ``(T,)``,
            ``diagnostics``: ``uncertainty_m``, ``grid_mean`` and ``measurements_used``
            (1 where a reading entered the update) per step.
        """
        if _is_observations(tracker_xy):
            if shift_m is not None or extra_blur_m is not None:
                raise InputError("shift_m: not taken with observations (give the motion "
                                 "model instead)")
            return self.run_observations(tracker_xy, rssi if time is None else time,
                                         prior_mean=prior_mean, prior_cov=prior_cov,
                                         state=state)
        self._paper_inputs()
        if prior_mean is not None or prior_cov is not None:
            raise InputError("prior_mean: a Gaussian prior is taken with observations; with "
                             "readings give state=GridFilter.init(prior=...)")
        r = as_float_array(rssi, "rssi", ndim=2, allow_nan=True)
        B, T = r.shape
        xy = as_float_array(tracker_xy, "tracker_xy", allow_nan=True)
        if xy.shape != (B, T, 2):
            raise InputError(f"tracker_xy: expected shape ({B}, {T}, 2), got {xy.shape}")
        if state is None:
            state = self.init(B)
        elif state.batch != B:
            raise InputError(f"state: holds {state.batch} runs, rssi has {B}")
        if time is None:
            t = state.time + dt * np.arange(1, T + 1)
        else:
            t = as_float_array(time, "time", ndim=1)
            if t.shape != (T,):
                raise InputError(f"time: expected {T} steps, got shape {t.shape}")
            if np.any(np.diff(t) < 0) or t[0] < state.time:
                raise InputError("time: must be non-decreasing and not before the state's time")
        shifts = None if shift_m is None else _check_batch(shift_m, "shift_m", B, (T, 2))
        blurs = None if extra_blur_m is None else _check_batch(extra_blur_m, "extra_blur_m", B, (T,))
        prev, out = state.time, []
        for k in range(T):
            state = self.step(state, xy[:, k], r[:, k], dt=float(t[k] - prev),
                              shift_m=None if shifts is None else shifts[:, k],
                              extra_blur_m=None if blurs is None else blurs[:, k])
            prev = t[k]
            est = self.estimate(state)
            used = np.isfinite(r[:, k]).astype(np.int64)
            out.append(Estimate(est.position, est.covariance, est.time,
                                {**est.diagnostics, "measurements_used": used}))
        return track_from_steps(out, time=t)
    # ---- any measurement model: Observation inputs ------------------------------------
    def _geom(self, state: GridState) -> GridGeometry:
        return state.geometry if state.geometry is not None else self._fixed_geometry("state")

    def _fixed_geometry(self, where: str) -> GridGeometry:
        if self.geometry is None:
            raise ConfigError(f"geometry: {where} needs the filter's GridGeometry (without one, "
                              "give prior_mean and prior_cov: a grid around each run's prior)")
        return self.geometry

    def _paper_inputs(self) -> None:
        """Refuse readings ``(tracker_xy, rssi)`` without the paper's model and grid."""
        if self.model is None:
            raise ConfigError("model: readings (tracker_xy, rssi) need the filter's "
                              "likelihood(dist, rssi) model; give observations instead")
        self._fixed_geometry("readings (tracker_xy, rssi)")

    @property
    def _state_size(self) -> int:
        return 2 if self.motion is None else int(self.motion.state_dim)

    def prior_grid(self, prior_cov) -> GridGeometry:
        """The grid built around each run's prior when the filter has no geometry: square,
        ``cell_m`` cells, centred on the prior mean (the state's ``offset``), half-width
        ``span_m`` or four times the largest position standard deviation of the batch.

        Parameters
        ----------
        prior_cov : ndarray, shape (..., n, n)

        Returns
        -------
        GridGeometry
            In the frame of the prior mean.
        """
        cov = np.asarray(prior_cov, dtype=float)[..., :2, :2]
        half = self.span_m
        if half is None:
            half = 4.0 * float(np.sqrt(np.max(np.linalg.eigvalsh(cov))))
        n = max(2, 2 * int(np.ceil(half / self.cell_m - 1e-9)))
        return GridGeometry.centred(n, n, self.cell_m)

    def _gaussian_prior(self, prior_mean, prior_cov, time: float) -> GridState:
        n = self._state_size
        if prior_mean is None or prior_cov is None:
            raise InputError("prior_mean: give both prior_mean and prior_cov")
        mean = as_float_array(prior_mean, "prior_mean", min_ndim=1)
        if mean.ndim > 2 or mean.shape[-1] != n:
            raise InputError(f"prior_mean: expected shape (B, {n}) (the state of "
                             f"{self.motion or 'a position grid'}), got {mean.shape}")
        mean = mean.reshape(-1, n)
        B = mean.shape[0]
        cov = as_float_array(prior_cov, "prior_cov", min_ndim=2)
        if cov.shape[-2:] != (n, n) or cov.shape[:-2] not in ((), (B,)):
            raise InputError(f"prior_cov: expected shape ({n}, {n}) or ({B}, {n}, {n}), got "
                             f"{cov.shape}")
        cov = np.broadcast_to(cov, (B, n, n))
        check_symmetric(cov, "prior_cov")
        try:
            np.linalg.cholesky(cov[:, :2, :2])
        except np.linalg.LinAlgError:
            raise InputError("prior_cov: the position block is not positive definite") from None
        if self.geometry is None:
            geom, offset = self.prior_grid(cov), mean[:, :2].copy()
            check_memory(8.0 * 4 * B * geom.k, "span_m", "the grids around the priors")
            if self.epsilon * geom.k > 1:
                raise ConfigError(f"epsilon: {self.epsilon} x {geom.k} cells exceeds 1 (raise "
                                  "cell_m or lower span_m)")
            d = _cell_points(geom)[None]                                  # (1, h, w, 2)
        else:
            geom, offset = None, None
            d = _cell_points(self.geometry)[None] - mean[:, None, None, :2]
        info = np.linalg.inv(cov[:, :2, :2])
        lq = -0.5 * np.einsum("bhwi,bij,bhwj->bhw", d, info, d)
        p = np.maximum(np.exp(lq - lq.max(axis=(1, 2), keepdims=True)), 0.0)
        p = np.maximum(p / p.sum(axis=(1, 2), keepdims=True), self.epsilon)
        p = p / p.sum(axis=(1, 2), keepdims=True)
        vel = pvv = None
        if n == 4:
            vel = mean[:, 2:4].copy()
            pvv = 0.5 * (cov[:, 2, 2] + cov[:, 3, 3])
        return GridState(p, float(time), offset, vel, pvv, geom)

    def drift(self, state: GridState, dt: float) -> GridState:
        """Prediction of the generic form over ``dt``: the grid drifts with the state's
        velocity (its frame moves when it was built around the prior; ShiftGrid on the
        filter's geometry) and is blurred by the position variance the motion model
        accrues, ``Q(dt)[0, 0]`` (or ``blur_m^2`` per step), plus ``dt^2`` times the
        prior's velocity variance (the velocity is not re-estimated: the grid carries
        positions only).

        Parameters
        ----------
        state : GridState
        dt : float
            Seconds (>= 0; 0 leaves the state as it is).

        Returns
        -------
        GridState
        """
        state = self._check_state(state)
        dt = check_positive(dt, "dt", allow_zero=True)
        if dt == 0:
            return state
        geom, p, offset, B = self._geom(state), state.p, state.offset, state.batch
        if state.velocity is not None:
            step = state.velocity * dt
            if offset is not None:
                offset = offset + step
            else:
                moved = np.any(step != 0.0, axis=-1)
                if moved.any():
                    p = np.where(moved[:, None, None], shift_grid(p, geom, step, self.epsilon), p)
        var = np.full(B, self.blur_radius(dt) ** 2)
        if state.pvv is not None:
            var = var + dt * dt * state.pvv
        s = np.sqrt(var) / geom.cell_m
        blur = s > 0
        if blur.any():
            raw, excess = _blur_raw(p, s, self.epsilon, self.blur, self.backend)
            p = np.where(blur[:, None, None], floor_normalise(raw, self.epsilon, excess), p)
        return replace(state, p=p, offset=offset, time=state.time + dt)

    def update_observations(self, state: GridState, observations) -> GridState:
        """Bayes' rule on the cells with any models' likelihoods (Algorithm 1 with
        ``L_i = exp(sum_rows logpdf(z | l_i) - max_i)``): ``p_i <- max(p_i L_i, eps)``,
        normalised. A run with no finite value is left as it is.

        Parameters
        ----------
        state : GridState
        observations : Observation or sequence of Observation
            One step: ``z`` ``(B, m)`` or ``(m,)``, rows NaN where absent.

        Returns
        -------
        GridState
        """
        obs = self._checked(observations)
        state = self._check_state(state)
        rows = []
        for o in obs:
            z = refuse_infinite(o.z, "z")
            rows.append((o.model, z, o.context))
        new, _ = self._update_rows(state, rows)
        return new

    def _checked(self, observations) -> list[Observation]:
        obs = observation_list(observations)
        for i, o in enumerate(obs):
            self.tags.require(o.model, f"observations[{i}].model", type(self).__name__)
            dim = o.context.points.shape[-1]
            if dim != 2 and o.context.height_m is None:
                raise ConfigError(f"observations[{i}].model: {type(self).__name__} holds 2-D "
                                  f"positions; the rows of {type(o.model).__name__} have "
                                  f"{dim}-D points (give context.height_m for 3-D anchors)")
        return obs

    def _update_rows(self, state: GridState, rows) -> tuple[GridState, np.ndarray]:
        """The update of :meth:`update_observations` on ``(model, z (B, m), context)``
        rows; also returns the number of finite values per run."""
        geom, B = self._geom(state), state.batch
        pos = _cell_points(geom)[None]
        if state.offset is not None:
            pos = pos + state.offset[:, None, None, :]
        pos = np.broadcast_to(pos, (B, geom.h, geom.w, 2))
        lp = log_likelihood_at(rows, pos)
        heard = sum((np.isfinite(np.broadcast_to(z, (B, z.shape[-1]))).sum(axis=-1)
                     for _, z, _ in rows), np.zeros(B, dtype=np.int64))
        top = lp.max(axis=(1, 2), keepdims=True)
        ok = np.isfinite(top)
        lik = np.where(ok, np.exp(lp - np.where(ok, top, 0.0)), 0.0)
        post = np.maximum(state.p * lik, self.epsilon)
        total = post.sum(axis=(1, 2), keepdims=True)
        post = np.where(total > 0, post / np.where(total > 0, total, 1.0), 1.0 / geom.k)
        return replace(state, p=np.where(heard[:, None, None] > 0, post, state.p)), heard

    def run_observations(self, observations, time=None, *, prior_mean=None, prior_cov=None,
                         state: GridState | None = None) -> Track:
        """Filter observations of any model the tags accept (a log-likelihood on
        positions, ``Tags(uses="logpdf")``; 2-D positions).

        Each step drifts and blurs the grid (:meth:`drift`; the first step is at the
        prior's time and is not predicted), then multiplies it by the likelihood of every
        observation's rows at the cells (:meth:`update_observations`).

        Parameters
        ----------
        observations : Observation or sequence of Observation
            ``z`` ``(..., T, m)`` each, the same ``T``; NaN rows are absent.
        time : array_like, shape (T,), optional
            Step times, seconds, non-decreasing; default ``0..T-1``.
        prior_mean, prior_cov : array_like, optional
            Gaussian prior at ``time[0]`` on the motion model's state (:meth:`init`);
            without them the filter's geometry starts uniform (the paper's prior).
        state : GridState, optional
            A state to start from instead (B runs: the observations' batch axes flattened).

        Returns
        -------
        Track
            ``position`` ``(..., T, 2)``, ``covariance`` ``(..., T, 2, 2)``, ``time``;
            diagnostics ``uncertainty_m``, ``grid_mean`` and ``measurements_used`` (values
            that entered the update) per step.
        """
        obs = self._checked(observations)
        T = common_steps(obs)
        t = np.arange(T, dtype=float) if time is None else as_float_array(time, "time", ndim=1)
        if t.shape != (T,):
            raise InputError(f"time: expected {T} steps, got shape {t.shape}")
        if np.any(np.diff(t) < 0):
            raise InputError("time: must be non-decreasing")
        shapes = [o.z.shape[:-2] for o in obs] + [o.at(0)[1].points.shape[:-2] for o in obs]
        if prior_mean is not None:
            shapes.append(np.shape(prior_mean)[:-1])
        try:
            batch = np.broadcast_shapes(*shapes)
        except ValueError:
            raise InputError(f"observations: batch shapes {shapes} do not broadcast") from None
        B = int(np.prod(batch, dtype=np.int64))
        if state is not None:
            if not isinstance(state, GridState) or state.batch != B:
                raise InputError(f"state: expected a GridState of {B} runs")
        elif prior_mean is not None or prior_cov is not None:
            if prior_mean is None or prior_cov is None:
                raise InputError("prior_mean: give both prior_mean and prior_cov")
            n = self._state_size
            mean = as_float_array(prior_mean, "prior_mean", min_ndim=1)
            if mean.shape[-1] != n:
                raise InputError(f"prior_mean: last axis must hold the {n} entries of the state "
                                 f"of {self.motion or 'a position grid'}, got shape {mean.shape}")
            cov = as_float_array(prior_cov, "prior_cov", min_ndim=2)
            if cov.ndim > 2:
                cov = np.broadcast_to(cov, batch + cov.shape[-2:]).reshape((B,) + cov.shape[-2:])
            state = self._gaussian_prior(np.broadcast_to(mean, batch + (n,)).reshape(B, n), cov,
                                         float(t[0]))
        else:
            state = self.init(B, time=float(t[0]))
        out = []
        for k in range(T):
            if k:
                state = self.drift(state, float(t[k] - t[k - 1]))
            rows = [(o.model,) + flatten_step(*o.at(k), batch) for o in obs]
            state, heard = self._update_rows(state, rows)
            est = self.estimate(state)
            out.append(unflatten_estimate(Estimate(est.position, est.covariance, est.time,
                                           {**est.diagnostics, "measurements_used": heard}),
                                  batch))
        return track_from_steps(out, time=t)


def _is_observations(value) -> bool:
    """Whether an argument holds observations (the generic form) rather than readings."""
    if isinstance(value, Observation):
        return True
    return isinstance(value, (list, tuple)) and bool(value) and isinstance(value[0], Observation)


def _cell_points(geom: GridGeometry) -> np.ndarray:
    """Cell centres ``(h, w, 2)`` in ``(x, y)`` order."""
    gx, gy = np.meshgrid(geom.x, geom.y)
    return np.stack([gx, gy], axis=-1)
