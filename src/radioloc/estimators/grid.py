"""Grid Bayes filter of Zickler & Veloso (paper 003, Sect. IV, Algorithms 1-3 and the grid
operations of Algorithm 4), batched over independent runs.

A grid state is an array ``p`` of shape ``(B, h, w)``: ``B`` runs, ``h`` rows (y) and ``w``
columns (x). :class:`GridGeometry` gives the cell centres ``l_i`` in the tracker's local frame.
Every function works on the whole batch at once; the per-run arguments (tracker position,
RSSI, blur radius, shift) have a leading batch axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.validation import as_float_array, check_positive, check_probability
from radioloc.models.rssi_trapezoid import TrapezoidModel


@dataclass(frozen=True)
class GridGeometry:
    """A ``w`` x ``h`` grid of square cells of side ``cell_m``.

    ``origin`` is the lower-left corner of the grid; the centre of the cell in row ``r``,
    column ``c`` is ``origin + ((c + 1/2) cell_m, (r + 1/2) cell_m)``.
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
        """A grid whose centre is at ``centre``."""
        return cls(w, h, cell_m, (centre[0] - 0.5 * w * cell_m, centre[1] - 0.5 * h * cell_m))

    @property
    def k(self) -> int:
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
        """The initial grid ``p_i = 1/k`` for ``batch`` runs, shape ``(batch, h, w)``."""
        return np.full((int(batch), self.h, self.w), 1.0 / self.k)

    def extent(self) -> tuple[float, float, float, float]:
        """``(left, right, bottom, top)`` for ``imshow(..., origin='lower')``."""
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
    """Distance from each run's ``position`` ``(B, 2)`` to every cell centre, ``(B, h, w)``."""
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


def floor_normalise(p: np.ndarray, epsilon: float) -> np.ndarray:
    """Renormalise grids to sum 1 with every cell ``>= epsilon``.

    ``p <- eps + (1 - k eps) (p - eps)_+ / sum (p - eps)_+``; used after blur and shift, where
    mass leaves through the grid border (the paper states the floor only for Algorithm 1).
    A grid with no mass above ``eps`` becomes uniform.
    """
    k = p.shape[1] * p.shape[2]
    if epsilon * k > 1:
        raise InputError(f"epsilon: {epsilon} x {k} cells exceeds 1")
    excess = np.maximum(p - epsilon, 0.0)
    total = excess.sum(axis=(1, 2), keepdims=True)
    safe = np.where(total > 0, total, 1.0)
    share = np.where(total > 0, excess / safe, 1.0 / k)
    return epsilon + (1.0 - k * epsilon) * share


def get_location(p, geom: GridGeometry, *, include_peak: bool = False) -> np.ndarray:
    """Algorithm 2 (GetLocation): peak cell plus an interpolated sub-cell offset vector.

    ``final_offset = sum_j v_j (l_j - l_max) / sum_j v_j`` over the 8-connected neighbours
    ``j`` of the peak cell (those inside the grid), ``v_j = p_j / max_prob``. The paper
    prints ``|l_j - l_max|``; a norm would always push the estimate towards +x, +y, so the
    bars are read as the offset vector. ``include_peak=True`` also counts the peak cell
    (``v = 1``, offset 0) in the average, a variant the paper does not use.

    Returns
    -------
    ndarray, shape (B, 2)
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
    """Algorithm 3 (GetUncertainty): ``sqrt(sum_i p_i |l_i - l_max|^2)``, shape ``(B,)``."""
    p = _check_grid(p, geom)
    B, h, w = p.shape
    r0, c0 = np.divmod(p.reshape(B, -1).argmax(axis=1), w)
    dx2 = (geom.x[None, :] - geom.x[c0][:, None]) ** 2               # (B, w)
    dy2 = (geom.y[None, :] - geom.y[r0][:, None]) ** 2               # (B, h)
    return np.sqrt(np.einsum("bhw,bw->b", p, dx2) + np.einsum("bhw,bh->b", p, dy2))


def blur_grid(p, geom: GridGeometry, radius_m, epsilon: float = 0.0) -> np.ndarray:
    """BlurGrid: circular Gaussian blur with standard deviation ``radius_m`` per run.

    The blur is applied in the Fourier domain on a zero-padded grid (so nothing wraps round
    the border), which lets every run use its own radius in one batched FFT; mass blurred
    beyond the border is lost and the grid renormalised by :func:`floor_normalise`.
    The paper calls the argument a radius; we use it as the Gaussian's standard deviation.

    Parameters
    ----------
    radius_m : float or array_like, shape (B,)
        Blur radius in metres (0 leaves the grid unchanged up to the floor).
    """
    p = _check_grid(p, geom)
    B, h, w = p.shape
    rad = np.broadcast_to(as_float_array(radius_m, "radius_m", nonnegative=True), (B,))
    s = rad / geom.cell_m                                            # std in cells
    pad = int(np.ceil(4.0 * s.max())) if s.size else 0
    pad = min(pad, max(h, w))
    H, W = h + 2 * pad, w + 2 * pad
    fy = np.fft.fftfreq(H)[:, None]
    fx = np.fft.rfftfreq(W)[None, :]
    kernel = np.exp(-2.0 * np.pi**2 * s[:, None, None] ** 2 * (fx**2 + fy**2)[None])
    spec = np.fft.rfft2(p, s=(H, W), axes=(1, 2))
    out = np.fft.irfft2(spec * kernel, s=(H, W), axes=(1, 2))[:, :h, :w]
    return floor_normalise(np.maximum(out, 0.0), epsilon)


def shift_grid(p, geom: GridGeometry, shift_m, epsilon: float = 0.0) -> np.ndarray:
    """ShiftGrid: translate each run's grid by ``shift_m`` ``(B, 2)`` metres (x, y).

    Sub-cell shifts use bilinear interpolation between the four nearest whole-cell shifts;
    cells shifted in from outside the grid are empty and the grid is renormalised with
    :func:`floor_normalise`. A whole-cell shift moves every value by exactly that many cells.
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
