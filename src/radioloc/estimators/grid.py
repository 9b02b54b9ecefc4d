"""Grid Bayes filter of Zickler & Veloso (paper 003, Sect. IV, Algorithms 1-3 and the grid
operations of Algorithm 4), batched over independent runs.

:class:`GridFilter` is the one grid filter of the toolkit (a recursive estimator of the
contract in ``docs/architecture.md``): the tethering world (as its injected tracker), the
Herald experiment and ``radioloc locate --method grid-rssi`` all run it. It is built from
the batched grid operations below, which stay public:

* :func:`probability_update` (Algorithm 1), :func:`get_location` (Algorithm 2),
  :func:`get_uncertainty` (Algorithm 3);
* :func:`blur_grid` and :func:`shift_grid` (BlurGrid, ShiftGrid of Algorithm 4), with
  :func:`floor_normalise`.

A grid is an array ``p`` of shape ``(B, h, w)``: ``B`` runs, ``h`` rows (y) and ``w``
columns (x). :class:`GridGeometry` gives the cell centres ``l_i`` in the filter's frame.
Every function works on the whole batch at once; the per-run arguments (tracker position,
RSSI, blur radius, shift) have a leading batch axis.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.results import Estimate, Track, track_from_steps
from radioloc.core.validation import (MAGNITUDE_LIMIT, as_float_array, check_positive,
                                      check_probability)
from radioloc.estimators import grid_kernels as _k
from radioloc.estimators.base import RecursiveEstimator
from radioloc.models.rssi_trapezoid import TrapezoidModel, as_rssi

_BLURS = ("fft", "recursive")

__all__ = ["GridGeometry", "GridState", "GridFilter", "cell_distances", "probability_update",
           "floor_normalise", "get_location", "get_uncertainty", "grid_moments", "blur_grid",
           "shift_grid"]


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
    if (isinstance(p, np.ndarray) and p.dtype == np.float64 and p.ndim == 3 and p.size
            and p.flags.c_contiguous and _k.grids_in_range(p, MAGNITUDE_LIMIT)):
        # the checks of as_float_array in one compiled pass (it names the bad cell when
        # this one finds any)
        pass
    else:
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
    return np.hypot(dx, dy)


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
    return _update(p, geom, pos, r, model, epsilon)


def _update(p, geom, pos, r, model, epsilon, prior_excess=None) -> np.ndarray:
    """Algorithm 1 by the fused kernels (``prior_excess``: ``p`` is an unfloored blur)."""
    if isinstance(model, TrapezoidModel):
        # the trapezoid is computed inside the fused kernel (one pass, no distance grid)
        i = as_rssi(r)
        return _k.trapezoid_update(p, geom.x, geom.y, pos, model.mu[i], model.tau[i],
                                   model.sigma[i], epsilon, prior_excess)
    lik = model.likelihood(cell_distances(geom, pos), r[:, None, None])
    return _k.weighted_update(p, lik, epsilon, prior_excess)


def floor_normalise(p: np.ndarray, epsilon: float) -> np.ndarray:
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

    Returns
    -------
    ndarray, shape (B, h, w)
        Grids summing to 1 with every cell ``>= epsilon``.
    """
    k = p.shape[1] * p.shape[2]
    if epsilon * k > 1:
        raise InputError(f"epsilon: {epsilon} x {k} cells exceeds 1")
    return _k.floor_normalise_into(np.asarray(p, dtype=float), epsilon)


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

    The blur is applied in the Fourier domain on a grid zero-padded by ``ceil(4 radius /
    cell_m)`` cells (so nothing wraps round the border), which lets every run use its own
    radius in one batched FFT per distinct padding; the padding of a run depends on its own
    radius only, so a run's result does not depend on the rest of the batch. Mass blurred
    beyond the border is lost and the grid renormalised by :func:`floor_normalise`.
    The paper calls the argument a radius; we use it as the Gaussian's standard deviation.

    ``method="recursive"`` blurs the runs whose standard deviation is at least
    ``grid_kernels.RECURSIVE_MIN_SIGMA`` cells with the separable recursive Gaussian of
    Young & van Vliet (a third-order recursion per direction, cost independent of the
    radius; zero outside the grid as above) and the others with the FFT. It is an
    approximation: its impulse response has the exact variance but departs from the
    Gaussian by 8.5-18 % of the peak value in one dimension (18 % at 2 cells, 9 % at 15,
    ``tests/test_grid_kernels.py`` bounds it at 20 %). Its intermediate grids are stored in
    float32 (the recursions run in float64): a relative error below ``2 * 2**-24`` per cell,
    five orders of magnitude under the approximation's (``tests/test_grid_fast.py``).

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
    s = rad / geom.cell_m                                            # std in cells
    if epsilon * h * w > 1:
        raise InputError(f"epsilon: {epsilon} x {h * w} cells exceeds 1")
    raw, excess = _blur_raw(p, s, float(epsilon), method)
    return _k.floor_normalise_into(raw, epsilon, excess,
                                   out=raw if raw.dtype == np.float64 else None)


def _blur_raw(p: np.ndarray, s: np.ndarray, epsilon: float, method: str
              ) -> tuple[np.ndarray, np.ndarray]:
    """The blur of :func:`blur_grid` before the floor: ``(grids, sum (grids - eps)_+)``."""
    B, h, w = p.shape
    if method == "recursive":
        wide = s >= _k.RECURSIVE_MIN_SIGMA
        if wide.all():
            return _k.recursive_gaussian(p, s, epsilon, np.float32)
        if wide.any():
            out, excess = _blur_raw(p, s * ~wide, epsilon, "fft")
            out[wide], excess[wide] = _k.recursive_gaussian(p[wide], s[wide], epsilon,
                                                            np.float32)
            return out, excess
    # each run's padding depends on its own radius only (so a run's result does not depend
    # on the other runs of the batch); one batched FFT per distinct padding
    pads = np.minimum(np.ceil(4.0 * s).astype(np.int64), max(h, w))
    out = np.empty_like(p)
    for pad in np.unique(pads):
        sel = pads == pad
        H, W = h + 2 * int(pad), w + 2 * int(pad)
        fy = np.fft.fftfreq(H)[:, None]
        fx = np.fft.rfftfreq(W)[None, :]
        kernel = np.exp(-2.0 * np.pi**2 * s[sel, None, None] ** 2 * (fx**2 + fy**2)[None])
        spec = np.fft.rfft2(p[sel], s=(H, W), axes=(1, 2))
        out[sel] = np.fft.irfft2(spec * kernel, s=(H, W), axes=(1, 2))[:, :h, :w]
    np.maximum(out, 0.0, out=out)
    rows = np.empty((B, h))
    _k._excess_rows(out, epsilon, rows)
    return out, rows.sum(axis=1)


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


class GridState:
    """State of a batch of grid filters.

    The recursive step of :class:`GridFilter` (``blur="recursive"``) leaves its posterior
    unnormalised, ``raw``, with one factor per run, ``scale = 1 / sum(raw)``; the next step
    applies the factor as it reads the grid, so no pass over the grid normalises it. The
    normalised posterior :attr:`p` is computed from them when first read (``raw * scale``,
    in float64: bit for bit the grid a normalisation pass would have written) and kept.
    A state is immutable.

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Posterior grid of each run (sums to 1, every cell ``>= epsilon``).
    time : float
        Time of the state, seconds.
    """

    __slots__ = ("_raw", "_scale", "_p", "time")

    def __init__(self, p: np.ndarray, time: float = 0.0) -> None:
        object.__setattr__(self, "_raw", p)
        object.__setattr__(self, "_scale", None)
        object.__setattr__(self, "_p", p)
        object.__setattr__(self, "time", time)

    @classmethod
    def _unnormalised(cls, raw: np.ndarray, scale: np.ndarray, time: float) -> "GridState":
        # a state holding raw (float64 or float32) and its per-run factor scale (B,)
        state = cls.__new__(cls)
        object.__setattr__(state, "_raw", raw)
        object.__setattr__(state, "_scale", scale)
        object.__setattr__(state, "_p", None)
        object.__setattr__(state, "time", time)
        return state

    def __setattr__(self, name, value):
        raise AttributeError(f"GridState is immutable (cannot set {name!r})")

    def __reduce__(self):
        if self._scale is None:
            return (GridState, (self._p, self.time))
        return (GridState._unnormalised, (self._raw, self._scale, self.time))

    def __repr__(self) -> str:
        return f"GridState(p=<{self.batch} grids of {self._raw.shape[1:]}>, time={self.time!r})"

    @property
    def p(self) -> np.ndarray:
        """Posterior grid of each run, shape ``(B, h, w)``, float64 (normalised)."""
        if self._p is None:
            p = np.multiply(self._raw, self._scale[:, None, None], dtype=np.float64)
            object.__setattr__(self, "_p", p)
        return self._p

    @property
    def batch(self) -> int:
        """Number of runs B."""
        return int(self._raw.shape[0])

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
        if self._scale is None:
            p = self._p[index]
            return GridState(p if p.ndim == 3 else p[None], self.time)
        raw, scale = self._raw[index], self._scale[index]
        if raw.ndim == 2:
            raw, scale = raw[None], np.reshape(scale, (1,))
        return GridState._unnormalised(raw, scale, self.time)


_LOCATIONS = ("mean", "peak")
_DTYPES = {"float64": np.float64, "float32": np.float32}


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

    Parameters
    ----------
    geometry : GridGeometry
        The grid (cells in the filter's frame).
    model : object with ``likelihood(dist, rssi)``
        Sensor model ``L(dist | rssi)``: :class:`~radioloc.models.rssi_trapezoid.TrapezoidModel`,
        :class:`~radioloc.models.rssi_logdistance.LogDistanceGaussian`, ...
    epsilon : float
        Minimum cell probability (Algorithm 1); ``epsilon k <= 1``.
    blur_m : float
        BlurGrid radius per step (the paper's ``gamma``), metres.
    motion : RandomWalk, optional
        Position-only motion model whose ``Q(dt)`` sets the blur instead of ``blur_m``.
    location : {"mean", "peak"}
        What :meth:`estimate` reports as the position: the grid mean (the posterior mean,
        default), or GetLocation (Algorithm 2, the paper's: peak cell plus an
        interpolated offset).
    blur : {"fft", "recursive"}
        How BlurGrid blurs (:func:`blur_grid`'s ``method``): the exact Gaussian by FFT
        (default; the paper-003 experiments use it), or the recursive approximation, whose
        cost does not grow with the radius (wide blurs on large grids).
    dtype : {"float64", "float32"}
        Storage of the unnormalised posterior written by the fused recursive step
        (``blur="recursive"`` with a :class:`~radioloc.models.rssi_trapezoid.TrapezoidModel`;
        float32 needs both). ``"float64"`` (default) stores it exactly. ``"float32"`` halves
        the state's memory traffic: each step rounds every cell of the posterior once to
        float32 (relative error at most ``2**-24``, about 6e-8; the recursions, sums and
        the normalising factor stay float64). The maps of a step (blur, likelihood product,
        floor, normalisation) are non-negative, so a relative error per cell carries
        through them with at most doubling by the normalisation: after ``T`` steps each
        cell of the posterior is within ``3 T 2**-24`` relative of the float64 filter's
        (a bound; measured: at most ``3.2 * 2**-24`` at any step of 40, the filter forgets
        old roundings), and the sum of :attr:`GridState.p` is 1 within ``2**-23``
        (measured 1e-8). Cells below float32's smallest normal number (1.2e-38, only with
        ``epsilon`` below it) lose relative precision. The public posterior
        :attr:`GridState.p` is float64 either way.

    Raises
    ------
    ConfigError
        A setting out of range, naming it.
    """

    name = "grid"

    def __init__(self, geometry: GridGeometry, model: Any, *, epsilon: float = 1e-6,
                 blur_m: float = 0.0, motion: Any = None, location: str = "mean",
                 blur: str = "fft", dtype: str = "float64") -> None:
        if not isinstance(geometry, GridGeometry):
            raise ConfigError(f"geometry: expected a GridGeometry, got {type(geometry).__name__}")
        if not callable(getattr(model, "likelihood", None)):
            raise ConfigError(f"model: needs a likelihood(dist, rssi) method, got {type(model).__name__}")
        eps = check_probability(epsilon, "epsilon")
        if eps * geometry.k > 1:
            raise ConfigError(f"epsilon: {eps} x {geometry.k} cells exceeds 1")
        blur_v = check_positive(blur_m, "blur_m", allow_zero=True)
        if motion is not None:
            if not callable(getattr(motion, "Q", None)) or getattr(motion, "state_dim", None) != 2 \
                    or getattr(motion, "dim", None) != 2:
                raise ConfigError("motion: the grid holds 2-D positions only; expected a "
                                  f"position-only 2-D model such as RandomWalk, got {motion!r}")
            if blur_v > 0:
                raise ConfigError("blur_m: give either blur_m or a motion model, not both")
        if location not in _LOCATIONS:
            raise ConfigError(f"location: expected one of {_LOCATIONS}, got {location!r}")
        if blur not in _BLURS:
            raise ConfigError(f"blur: expected one of {_BLURS}, got {blur!r}")
        if dtype not in _DTYPES:
            raise ConfigError(f"dtype: expected one of {tuple(_DTYPES)}, got {dtype!r}")
        if dtype == "float32" and (blur != "recursive" or not isinstance(model, TrapezoidModel)):
            raise ConfigError("dtype: 'float32' is the storage of the fused recursive step; it "
                              "needs blur='recursive' and a TrapezoidModel")
        self.geometry = geometry
        self.model = model
        self.dtype = _DTYPES[dtype]
        # the posterior dtypes the fused step reads as they are (a float32 grid of a user
        # takes the checked path, which converts it)
        self._fast_dtypes = (np.dtype(np.float64), np.dtype(self.dtype))
        self.epsilon = eps
        self.blur_m = blur_v
        self.motion = motion
        self.location = location
        self.blur = blur

    # ---- the contract -------------------------------------------------------------
    def init(self, batch: int | None = None, *, prior=None, time: float = 0.0) -> GridState:
        """The filter state before the first reading.

        Parameters
        ----------
        batch : int, optional
            Number of runs B of a uniform prior ``p_i = 1/k`` (the paper's).
        prior : array_like, shape (B, h, w), optional
            Prior grids instead (normalised, floored at ``epsilon`` and renormalised).
        time : float
            Time of the state, seconds.

        Returns
        -------
        GridState
        """
        if prior is None:
            if batch is None or int(batch) != batch or batch < 1:
                raise InputError(f"batch: expected a positive number of runs, got {batch!r}")
            return GridState(self.geometry.uniform(int(batch)), float(time))
        p = _check_grid(prior, self.geometry)
        total = p.sum(axis=(1, 2), keepdims=True)
        if np.any(total <= 0):
            raise InputError(f"prior: grid {int(np.flatnonzero(total.ravel() <= 0)[0])} has no mass")
        if batch is not None and p.shape[0] != batch:
            raise InputError(f"prior: expected {batch} grids, got {p.shape[0]}")
        p = np.maximum(p / total, self.epsilon)
        return GridState(p / p.sum(axis=(1, 2), keepdims=True), float(time))

    def _check_state(self, state: GridState) -> GridState:
        if not isinstance(state, GridState):
            raise InputError(f"state: expected a GridState, got {type(state).__name__}")
        _check_grid(state.p, self.geometry)
        return state

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
        B, geom, p = state.batch, self.geometry, state.p
        if shift_m is not None:
            shift = _check_batch(shift_m, "shift_m", B, (2,))
            moved = np.any(shift != 0.0, axis=-1)
            if moved.any():
                p = np.where(moved[:, None, None], shift_grid(p, geom, shift, self.epsilon), p)
        radius = self._radius(B, dt, extra_blur_m)
        blur = radius > 0
        if blur.any():
            p = np.where(blur[:, None, None], blur_grid(p, geom, radius, self.epsilon,
                                                             method=self.blur), p)
        return GridState(p, state.time + dt)

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
            return GridState(probability_update(state.p, self.geometry, xy, r, self.model,
                                                self.epsilon), state.time)
        post = probability_update(state.p, self.geometry, np.where(valid[:, None], xy, 0.0),
                                  np.where(valid, r, r[valid][0]), self.model, self.epsilon)
        return GridState(np.where(valid[:, None, None], post, state.p), state.time)

    def step(self, state: GridState, tracker_xy, rssi, *, dt: float = 1.0, shift_m=None,
             extra_blur_m=None) -> GridState:
        """One filter step: :meth:`predict` then :meth:`update`.

        Parameters
        ----------
        state : GridState
            Current state (not modified).
        tracker_xy : array_like, shape (B, 2)
            Where each reading was taken, metres (NaN allowed where ``rssi`` is NaN).
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
        if shift_m is None:
            # every run blurred and updated: the floor of the blur is applied inside the
            # update kernel (the same numbers as predict then update, one pass less)
            if not isinstance(state, GridState):
                raise InputError(f"state: expected a GridState, got {type(state).__name__}")
            dt = check_positive(dt, "dt", allow_zero=True)
            B, geom = state.batch, self.geometry
            radius = self._radius(B, dt, extra_blur_m)
            r = as_float_array(rssi, "rssi", allow_nan=True)
            xy = as_float_array(tracker_xy, "tracker_xy", allow_nan=True)
            s = radius / geom.cell_m
            raw, scale = state._raw, state._scale
            if (r.shape == (B,) and xy.shape == (B, 2) and np.all(np.isfinite(r))
                    and np.all(np.isfinite(xy)) and self.blur == "recursive"
                    and isinstance(self.model, TrapezoidModel)
                    and np.all(s >= _k.RECURSIVE_MIN_SIGMA) and isinstance(raw, np.ndarray)
                    and raw.dtype in self._fast_dtypes and raw.shape == (B, geom.h, geom.w)
                    and raw.flags.c_contiguous):
                # the blur in the block layout, the prior's normalisation and the input
                # check fused into its first pass (a bad cell is named by the full check),
                # the update reading the blocks; its normalisation is left to the next step
                # (or to the first read of the state's p)
                blk, excess, bad = _k.gaussian_blocks(raw, s, self.epsilon, np.float32,
                                                      MAGNITUDE_LIMIT, scale)
                if bad:
                    _check_grid(as_float_array(state.p, "grid", ndim=3, nonnegative=True), geom)
                i = as_rssi(r)
                m = self.model
                post, c = _k.trapezoid_posterior_blocks(
                    blk, raw.shape, geom.x, geom.y, xy, m.mu[i], m.tau[i], m.sigma[i],
                    self.epsilon, excess, self.dtype)
                return GridState._unnormalised(post, c, state.time + dt)
            state = self._check_state(state)
            if (r.shape == (B,) and xy.shape == (B, 2) and np.all(radius > 0)
                    and np.all(np.isfinite(r)) and np.all(np.isfinite(xy))):
                raw, excess = _blur_raw(state.p, s, self.epsilon, self.blur)
                post = _update(raw, self.geometry, xy, r, self.model, self.epsilon, excess)
                return GridState(post, state.time + dt)
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
        mean, cov = grid_moments(state.p, self.geometry)
        pos = mean if self.location == "mean" else get_location(state.p, self.geometry)
        diag = {"uncertainty_m": get_uncertainty(state.p, self.geometry), "grid_mean": mean}
        return Estimate(pos, cov, state.time, diag)

    def run(self, tracker_xy, rssi, *, time=None, dt: float = 1.0, shift_m=None,
            extra_blur_m=None, state: GridState | None = None) -> Track:
        """Filter a whole series of readings.

        Parameters
        ----------
        tracker_xy : array_like, shape (B, T, 2)
            Where each reading was taken, metres (NaN allowed where ``rssi`` is NaN).
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
