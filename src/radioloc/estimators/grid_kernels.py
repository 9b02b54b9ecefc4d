"""Compiled kernels of the grid Bayes filter (paper 003, Algorithm 1 and Algorithm 4's BlurGrid).

Each kernel works on a batch of grids ``p`` of shape ``(B, h, w)`` in one pass per operation
(no temporaries the size of the grid), parallel over rows or column blocks with numba's
``prange``. Every run is computed from its own arguments only and every sum is taken in a
fixed order (per row, then over rows), so a run's result does not depend on the rest of the
batch. The plain NumPy functions of :mod:`radioloc.estimators.grid` are the reference
(``tests/test_grid_kernels.py`` compares them on random inputs).

* :func:`trapezoid_update` - Algorithm 1 with the trapezoid likelihood computed in the loop:
  ``p_i <- max(p_i L(|l_i - s_a|), eps) / sum``.
* :func:`trapezoid_update_blocks` - the same reading the block layout (the recursive step);
  each block column is classed by its cells' squared distances (likelihood exactly 0,
  exactly 1, or the ramps' full formula), so the square root and division run only on the
  ramps, and the block is transposed back into rows in registers (:func:`_transpose4`).
* :func:`trapezoid_posterior_blocks` - the same without the normalisation pass: the
  unnormalised posterior and its factor ``1 / sum``, which the next step's column pass
  applies as it reads the grid (``gaussian_blocks(..., scale=...)``).
* :func:`weighted_update` - the same with a likelihood grid given by the caller (any model).
* :func:`floor_normalise_into` - ``p <- eps + (1 - k eps) (p - eps)_+ / sum (p - eps)_+``.
* :func:`recursive_gaussian` - separable recursive Gaussian of Young & van Vliet (1995):
  third-order causal and anti-causal recursions along columns (streamed over whole rows of
  a chunk of columns, SIMD across columns), written into a block layout of ``LANES`` rows
  whose row recursions run on the rows of a block at once (SIMD across rows; see
  :func:`gaussian_blocks`), with the zero boundary of the exact blur: the recursions
  run on through ``tail`` zero cells past the far border before the anti-causal pass
  starts, so the mass blurred out of the grid is lost as in the exact (FFT) blur.
"""

from __future__ import annotations

import math
import platform

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["trapezoid_update", "trapezoid_update_blocks", "trapezoid_posterior_blocks",
           "weighted_update",
           "floor_normalise_into", "yvv_coefficients", "recursive_gaussian", "gaussian_blocks",
           "grids_in_range", "RECURSIVE_MIN_SIGMA", "LANES"]

def _transpose4_codegen(nontemporal):
    def codegen(context, builder, signature, args):
        sty, _, _, dty, _, _ = signature.args
        s, i, j, d, r, c = args
        sa = context.make_array(sty)(context, builder, s)
        da = context.make_array(dty)(context, builder, d)
        i64 = ir.IntType(64)
        vin = ir.VectorType(context.get_data_type(sty.dtype), 4)
        vout = ir.VectorType(context.get_data_type(dty.dtype), 4)
        sshape = cgutils.unpack_tuple(builder, sa.shape)
        sstr = cgutils.unpack_tuple(builder, sa.strides)
        dshape = cgutils.unpack_tuple(builder, da.shape)
        dstr = cgutils.unpack_tuple(builder, da.strides)
        rows = []
        for k in range(4):
            p = cgutils.get_item_pointer2(context, builder, sa.data, sshape, sstr, sty.layout,
                                          [builder.add(i, ir.Constant(i64, k)), j])
            rows.append(builder.load(builder.bitcast(p, vin.as_pointer()), align=8))
        a, b, cc, dd = rows
        m = lambda *ix: ir.Constant(ir.VectorType(ir.IntType(32), 4), list(ix))
        lo01 = builder.shuffle_vector(a, b, m(0, 4, 2, 6))
        hi01 = builder.shuffle_vector(a, b, m(1, 5, 3, 7))
        lo23 = builder.shuffle_vector(cc, dd, m(0, 4, 2, 6))
        hi23 = builder.shuffle_vector(cc, dd, m(1, 5, 3, 7))
        outs = [builder.shuffle_vector(lo01, lo23, m(0, 1, 4, 5)),
                builder.shuffle_vector(hi01, hi23, m(0, 1, 4, 5)),
                builder.shuffle_vector(lo01, lo23, m(2, 3, 6, 7)),
                builder.shuffle_vector(hi01, hi23, m(2, 3, 6, 7))]
        # a non-temporal store needs its natural alignment (the vector's size)
        align = 4 * context.get_abi_sizeof(context.get_data_type(dty.dtype)) if nontemporal else 4
        for k in range(4):
            v = outs[k]
            if vout != vin:
                v = builder.fptrunc(v, vout)
            p = cgutils.get_item_pointer2(context, builder, da.data, dshape, dstr, dty.layout,
                                          [builder.add(r, ir.Constant(i64, k)), c])
            st = builder.store(v, builder.bitcast(p, vout.as_pointer()), align=align)
            if nontemporal:
                st.set_metadata("nontemporal",
                                builder.module.add_metadata([ir.Constant(ir.IntType(32), 1)]))
        return context.get_dummy_value()
    return codegen


@intrinsic
def _transpose4(typingctx, src, i, j, dst, r, c):
    """``dst[r + k, c + l] = src[i + l, j + k]`` for ``k, l < 4`` (2-D C arrays, float64
    source, float64 or float32 destination converted with round to nearest): four vector
    loads, eight shuffles, four vector stores (numba runs no SLP vectoriser, and LLVM's loop
    vectoriser leaves a transposition as scalar loads and stores)."""
    return types.void(src, i, j, dst, r, c), _transpose4_codegen(False)


@intrinsic
def _transpose4_nt(typingctx, src, i, j, dst, r, c):
    """:func:`_transpose4` with non-temporal stores (written to memory without reading the
    destination's cache lines first). Each row ``dst[r + k, c:c + 4]`` must be aligned to
    its size (32 bytes float64, 16 float32); :func:`_sfence` orders the stores."""
    return types.void(src, i, j, dst, r, c), _transpose4_codegen(True)


@intrinsic
def _sfence(typingctx):
    """The x86 ``sfence``: the non-temporal stores issued before it are visible before any
    store after it."""
    def codegen(context, builder, signature, args):
        fn = builder.module.declare_intrinsic("llvm.x86.sse.sfence",
                                              fnty=ir.FunctionType(ir.VoidType(), []))
        builder.call(fn, [])
        return context.get_dummy_value()
    return types.void(), codegen


_G = 8
"""Lanes of one register-held recursion (:func:`_yvv_lanes`): its three state vectors, the
four coefficients and the input fit in the 16 AVX2 registers."""


def _yvv_lanes_codegen(accumulate):
    def codegen(context, builder, signature, args):
        sty, dty, stty, accty = signature.args[0], signature.args[2], signature.args[11], \
            signature.args[12]
        (src, cs, dst, cd, r0, dr, n, g, a1, a2, a3, st, acc, eps) = args
        i32, i64 = ir.IntType(32), ir.IntType(64)
        V = ir.VectorType(ir.DoubleType(), _G)
        i8p = ir.IntType(8).as_pointer()

        def base(aty, a, col):
            arr = context.make_array(aty)(context, builder, a)
            strides = cgutils.unpack_tuple(builder, arr.strides)
            p = cgutils.get_item_pointer2(context, builder, arr.data,
                                          cgutils.unpack_tuple(builder, arr.shape), strides,
                                          aty.layout, [r0, col])
            dt = context.get_data_type(aty.dtype)
            return (builder.bitcast(p, i8p), builder.mul(strides[0], dr),
                    ir.VectorType(dt, _G), context.get_abi_sizeof(dt))

        sbase, sstep, svt, salign = base(sty, src, cs)
        dbase, dstep, dvt, dalign = base(dty, dst, cd)

        def splat(v):
            u = ir.Constant(V, ir.Undefined)
            return builder.shuffle_vector(builder.insert_element(u, v, ir.Constant(i32, 0)), u,
                                          ir.Constant(ir.VectorType(i32, _G), [0] * _G))

        fma = cgutils.get_or_insert_function(builder.module, ir.FunctionType(V, [V, V, V]),
                                             "llvm.fma.v%df64" % _G)
        vg, va1, va2, va3, veps = splat(g), splat(a1), splat(a2), splat(a3), splat(eps)
        zero = ir.Constant(V, [0.0] * _G)
        stp = builder.bitcast(context.make_array(stty)(context, builder, st).data,
                              V.as_pointer())
        accp = builder.bitcast(context.make_array(accty)(context, builder, acc).data,
                               V.as_pointer())
        # the state in allocas of the entry block: promoted to registers by LLVM
        y = [cgutils.alloca_once(builder, V) for _ in range(3)]
        for k in range(3):
            builder.store(builder.load(builder.gep(stp, [ir.Constant(i64, k)]), align=8), y[k])
        av = cgutils.alloca_once(builder, V)
        if accumulate:
            builder.store(builder.load(accp, align=8), av)
        with cgutils.for_range(builder, n) as loop:
            k = loop.index
            sp = builder.bitcast(builder.gep(sbase, [builder.mul(k, sstep)]), svt.as_pointer())
            x = builder.load(sp, align=salign)
            if svt != V:
                x = builder.fpext(x, V)
            y1, y2, y3 = (builder.load(p) for p in y)
            # _yvv's rounding: a1 y1 + (a2 y2 + (a3 y3 + g x)) with the FMAs the compiler
            # forms for it (fma(g, x, a3 y3) innermost; tested bit for bit)
            t = builder.call(fma, [vg, x, builder.fmul(va3, y3)])
            t = builder.call(fma, [va2, y2, t])
            yn = builder.call(fma, [va1, y1, t])
            sv = yn if dvt == V else builder.fptrunc(yn, dvt)
            dp = builder.bitcast(builder.gep(dbase, [builder.mul(k, dstep)]), dvt.as_pointer())
            builder.store(sv, dp, align=dalign)
            if accumulate:                       # sum (stored - eps)_+ per lane
                d = builder.fsub(sv if dvt == V else builder.fpext(sv, V), veps)
                m = builder.select(builder.fcmp_ordered(">", d, zero), d, zero)
                builder.store(builder.fadd(builder.load(av), m), av)
            builder.store(y2, y[2])
            builder.store(y1, y[1])
            builder.store(yn, y[0])
        for k in range(3):
            builder.store(builder.load(y[k]), builder.gep(stp, [ir.Constant(i64, k)]), align=8)
        if accumulate:
            builder.store(builder.load(av), accp, align=8)
        return context.get_dummy_value()
    return codegen


@intrinsic
def _yvv_lanes(typingctx, src, cs, dst, cd, r0, dr, n, g, a1, a2, a3, st, acc, eps):
    """The third-order recursion :func:`_yvv` on ``_G`` lanes at once with its state in
    registers: for ``k < n``, row ``r = r0 + k dr``: ``dst[r, cd + l] = yvv(src[r, cs + l],
    state)`` for ``l < _G`` (2-D C arrays, float64 or float32, converted to and from float64;
    ``src`` may be ``dst``). ``st`` (float64, ``(3, _G)``) holds the state, newest output
    first, and receives it back. ``acc`` and ``eps`` are not used (see
    :func:`_yvv_lanes_acc`). Explicit vectors: numba runs no SLP vectoriser, and LLVM's loop
    vectoriser keeps the state of a recursion across columns in memory."""
    sig = types.void(src, cs, dst, cd, r0, dr, n, g, a1, a2, a3, st, acc, eps)
    return sig, _yvv_lanes_codegen(False)


@intrinsic
def _yvv_lanes_acc(typingctx, src, cs, dst, cd, r0, dr, n, g, a1, a2, a3, st, acc, eps):
    """:func:`_yvv_lanes` that also adds ``max(v - eps, 0)`` of each stored value ``v``
    (as stored: rounded if ``dst`` is float32) to ``acc[l]`` (float64, ``(_G,)``), in the
    order of the rows."""
    sig = types.void(src, cs, dst, cd, r0, dr, n, g, a1, a2, a3, st, acc, eps)
    return sig, _yvv_lanes_codegen(True)


@intrinsic
def _prefetch(typingctx, arr, i, j):
    """Software prefetch of the cache line holding ``arr[i, j]`` (2-D array) into all cache
    levels (``llvm.prefetch``, read, locality 3); a no-op on the values."""
    def codegen(context, builder, signature, args):
        aty = signature.args[0]
        a, ii, jj = args
        aa = context.make_array(aty)(context, builder, a)
        p = cgutils.get_item_pointer2(context, builder, aa.data,
                                      cgutils.unpack_tuple(builder, aa.shape),
                                      cgutils.unpack_tuple(builder, aa.strides), aty.layout,
                                      [ii, jj])
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
            "llvm.prefetch.p0i8")
        builder.call(fn, [builder.bitcast(p, i8p), ir.Constant(i32, 0), ir.Constant(i32, 3),
                          ir.Constant(i32, 1)])
        return context.get_dummy_value()
    return types.void(arr, i, j), codegen


_PF_ROWS = 8
"""Rows ahead of the column pass's causal loop whose cache lines it prefetches (measured on
2 x 1000 x 1000 float64 grids: the pass 4.5-4.9 -> 3.3-3.8 cycles per cell of CPU; a prefetch
starting at column c0 instead of at its line's start made unaligned grids slower, 5.0 -> 6.8)."""


def _aligned_empty(shape: tuple[int, ...], dtype, align: int = 64) -> np.ndarray:
    # an uninitialised C array whose data start at a multiple of align bytes
    dtype = np.dtype(dtype)
    n = int(np.prod(shape)) * dtype.itemsize
    buf = np.empty(n + align, np.uint8)
    off = (-buf.ctypes.data) % align
    return buf[off:off + n].view(dtype).reshape(shape)


NONTEMPORAL = platform.machine().lower() in ("x86_64", "amd64")
"""Whether the recursive step may write its float64 posterior with non-temporal stores
(x86 only)."""

NONTEMPORAL_MIN_BYTES = 8 * 2**20
"""Smallest float64 posterior (all runs) written with non-temporal stores. Measured per CPU
second on 2 x 1000 x 1000 grids (16 MB): the step 1.03-1.06x faster with them; on
2 x 600 x 600 (5.8 MB) even; on 2 x 300 x 300 (1.4 MB, held in the cache until the next
step reads it) 0.84-0.89x. With float32 storage they were 0.81-0.85x at every size (16-byte
stores), so float32 posteriors use ordinary stores."""

RECURSIVE_MIN_SIGMA = 2.0
"""Smallest standard deviation, in cells, blurred by the recursive Gaussian (below it the
exact blur is used: Young & van Vliet's fit holds for ``sigma >= 0.5`` and its error grows as
``sigma`` falls)."""



@njit(inline="always")
def _floored(x, mode, c, eps, k):
    # the prior cell after floor_normalise (mode 1), uniform (mode 2) or as it is (mode 0)
    if mode == 1:
        v = x - eps
        return eps + c * v if v > 0.0 else eps
    if mode == 2:
        return 1.0 / k
    return x


@njit(parallel=True, cache=True)
def _bad_rows(p, limit, bad):
    B, h, w = p.shape
    for job in prange(B * h):
        b = job // h
        r = job - b * h
        row = p[b, r]
        n = 0
        for j in range(w):
            v = row[j]
            n += 0 if (v >= 0.0 and v <= limit) else 1     # NaN fails both tests
        bad[b, r] = n


def grids_in_range(p: np.ndarray, limit: float) -> bool:
    """Whether every cell of a float64 grid batch is finite and in ``[0, limit]``.

    One compiled pass, parallel over rows (the NumPy checks of
    :func:`radioloc.core.validation.as_float_array` make several passes and temporaries).

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Grids, float64.
    limit : float
        Largest accepted value.

    Returns
    -------
    bool
    """
    bad = np.empty(p.shape[:2], np.int64)
    _bad_rows(p, float(limit), bad)
    return not bad.any()


def _grid_array(p) -> np.ndarray:
    # a C-contiguous float32 or float64 grid (a float32 blur is read as it is)
    p = np.asarray(p)
    if p.dtype == np.float32:
        return np.ascontiguousarray(p)
    return np.ascontiguousarray(p, dtype=np.float64)


def _floor_args(B: int, k: int, epsilon: float, excess) -> tuple[np.ndarray, np.ndarray]:
    if excess is None:
        return np.zeros(B, np.int64), np.zeros(B)
    t = np.asarray(excess, dtype=np.float64)
    c = (1.0 - k * epsilon) / np.where(t > 0.0, t, 1.0)
    return np.where(t > 0.0, 1, 2).astype(np.int64), c




def yvv_coefficients(sigma_cells) -> np.ndarray:
    """Young & van Vliet (1995) recursion coefficients for standard deviations in cells.

    ``q = 0.98711 sigma - 0.96330`` (``sigma >= 2.5``), else
    ``q = 3.97156 - 4.14554 sqrt(1 - 0.26891 sigma)``; ``b0 = 1.57825 + 2.44413 q +
    1.4281 q^2 + 0.422205 q^3``, ``b1 = 2.44413 q + 2.85619 q^2 + 1.26661 q^3``,
    ``b2 = -(1.4281 q^2 + 1.26661 q^3)``, ``b3 = 0.422205 q^3``, ``B = 1 - (b1 + b2 + b3) / b0``.

    Parameters
    ----------
    sigma_cells : array_like, shape (B,)
        Standard deviations in cells (``>= 0.5``).

    Returns
    -------
    ndarray, shape (B, 4)
        ``(B, b1 / b0, b2 / b0, b3 / b0)`` per run.
    """
    s = np.asarray(sigma_cells, dtype=float).reshape(-1)
    key = s.tobytes()
    if key not in _COEF_CACHE:
        if len(_COEF_CACHE) > 256:
            _COEF_CACHE.clear()
        _COEF_CACHE[key] = _solve_coefficients(s)
    return _COEF_CACHE[key].copy()


_COEF_CACHE: dict[bytes, np.ndarray] = {}


def _solve_coefficients(s: np.ndarray) -> np.ndarray:
    q0 = np.where(s >= 2.5, 0.98711 * s - 0.96330,
                  3.97156 - 4.14554 * np.sqrt(np.maximum(1.0 - 0.26891 * s, 0.0)))
    # the published q gives a response wider than sigma (about 10 %); solve for the q whose
    # causal-times-anti-causal impulse response has variance exactly sigma^2
    lo, hi = np.full_like(s, 1e-3), np.maximum(2.0 * q0, 1.0)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        wide = _yvv_variance(mid) > s**2
        hi, lo = np.where(wide, mid, hi), np.where(wide, lo, mid)
    return _yvv_from_q(0.5 * (lo + hi))


def _yvv_from_q(q):
    b0 = 1.57825 + 2.44413 * q + 1.4281 * q**2 + 0.422205 * q**3
    b1 = (2.44413 * q + 2.85619 * q**2 + 1.26661 * q**3) / b0
    b2 = -(1.4281 * q**2 + 1.26661 * q**3) / b0
    b3 = 0.422205 * q**3 / b0
    return np.stack([1.0 - (b1 + b2 + b3), b1, b2, b3], axis=-1)


def _yvv_variance(q):
    """Variance of the impulse response ``g / D(z) D(1/z)``, ``D(x) = 1 - a1 x - a2 x^2 - a3 x^3``:
    twice the second cumulant ``-(x^2 D'' + x D') / D + (x D' / D)^2`` at ``x = 1``."""
    _, a1, a2, a3 = _yvv_from_q(q).T
    d = 1.0 - a1 - a2 - a3
    d1 = -(a1 + 2.0 * a2 + 3.0 * a3)
    d2 = -(2.0 * a2 + 6.0 * a3)
    return 2.0 * (-(d2 + d1) / d + (d1 / d) ** 2)


_FM = {"contract"}
_TILE = 16                # columns of the update's transposition tile (a 64-byte line of float32)
_COL_CHUNK = 64           # columns of one job of the vertical pass (a 512 kB float64 buffer at h = 1000)
LANES = 32
"""Rows per block of the blurred grid's block layout ``(B, ceil(h / LANES), w, LANES)``: the
row recursions run on the ``LANES`` rows of a block at once (contiguous SIMD lanes)."""
assert LANES % _G == 0


@njit(inline="always")
def _yvv(x, y1, y2, y3, g, a1, a2, a3):
    # one step of the third-order recursion, the newest output last (one FMA on the
    # dependency chain through y1)
    return a1 * y1 + (a2 * y2 + (a3 * y3 + g * x))


@njit(cache=True, inline="always", fastmath=_FM)
def _through_border(tb, st, o1, o2, o3, n, g, a1, a2, a3):
    """The causal recursion on through the zero border (``tb`` rows of ``n`` lanes receive
    it), then the anti-causal one from the border's far end back to the grid's edge
    (state ``st`` reset first). Returns the rotated state rows ``(o1, o2, o3)`` for the
    anti-causal pass over the grid."""
    tail = tb.shape[0]
    for t in range(tail):
        o = tb[t]
        for j in range(n):
            y = _yvv(0.0, o1[j], o2[j], o3[j], g, a1, a2, a3)
            o3[j] = y
            o[j] = y
        o1, o2, o3 = o3, o1, o2
    st[:] = 0.0
    for t in range(tail - 1, -1, -1):
        x = tb[t]
        for j in range(n):
            o3[j] = _yvv(x[j], o1[j], o2[j], o3[j], g, a1, a2, a3)
        o1, o2, o3 = o3, o1, o2
    return o1, o2, o3


@njit(parallel=True, cache=True, fastmath=_FM)
def _vert_blocks(p, scale, blk, coef, tails, limit, bad):
    """Column recursions ``anti(causal(scale p))`` along the rows' axis, streamed over whole
    rows of a chunk of ``_COL_CHUNK`` columns (contiguous vectors, float64 state and buffer),
    written into the block layout ``blk[b, r // LANES, c, r % LANES]``. ``scale[b]``
    multiplies each cell of grid ``b`` as it is read (in float64: the same rounding as a
    scaling pass writing ``scale p`` first; ``p`` float64 or float32). ``bad[job]`` counts the
    cells of the chunk (scaled) that are not in ``[0, limit]`` (NaN included): the input
    check, fused. The lanes of the last block past the grid's last row are written zero.
    The anti-causal recursions run ``_G`` columns at a time with their state in registers
    (:func:`_yvv_lanes`); the causal loop streams whole rows of the chunk, prefetching the
    row ``_PF_ROWS`` ahead."""
    B, h, w = p.shape
    nch = (w + _COL_CHUNK - 1) // _COL_CHUNK
    for job in prange(B * nch):
        b = job // nch
        c0 = (job - b * nch) * _COL_CHUNK
        c1 = min(w, c0 + _COL_CHUNK)
        n = c1 - c0
        nw = (n + _G - 1) // _G * _G              # whole groups of _G columns (zero padded)
        g, a1, a2, a3 = coef[b, 0], coef[b, 1], coef[b, 2], coef[b, 3]
        sc = scale[b]
        tail = tails[b]
        pb = p[b]
        bb = blk[b]
        nb = bb.shape[0]
        buf = np.empty((h, nw))                   # the causal outputs
        if nw > n:
            buf[:, n:] = 0.0
        st = np.zeros((3, nw))                    # the last three outputs
        tb = np.zeros((tail, nw))                 # the causal outputs past the border
        o1 = st[0]
        o2 = st[1]
        o3 = st[2]
        nbad = 0
        isz = pb.itemsize
        line = 64 // isz                          # cells per 64-byte cache line
        rowb = pb.strides[0]
        addr = pb.ctypes.data + c0 * isz          # (lead: cells of the row's first line
                                                  # before column c0)
        for r in range(h):                                   # causal
            if _PF_ROWS and r + _PF_ROWS < h:   # the row _PF_ROWS ahead, line by line
                lead = (addr + (r + _PF_ROWS) * rowb) % 64 // isz
                for j in range(c0 - lead, c1, line):
                    _prefetch(pb, r + _PF_ROWS, j)
            x = pb[r, c0:c1]
            o = buf[r]
            for j in range(n):
                v = np.float64(x[j]) * sc
                nbad += 0 if (v >= 0.0 and v <= limit) else 1    # NaN fails both tests
                y = _yvv(v, o1[j], o2[j], o3[j], g, a1, a2, a3)
                o3[j] = y
                o[j] = y
            o1, o2, o3 = o3, o1, o2
        bad[job] = nbad
        o1, o2, o3 = _through_border(tb, st, o1, o2, o3, nw, g, a1, a2, a3)
        # anti-causal, _G columns at a time with the state in registers, a block of LANES
        # rows at a time, each stored transposed as it is done
        sg = np.empty((3, _G))
        for q0 in range(0, n, _G):
            m = min(_G, n - q0)
            for j in range(_G):
                sg[0, j] = o1[q0 + j]
                sg[1, j] = o2[q0 + j]
                sg[2, j] = o3[q0 + j]
            for kb in range(nb - 1, -1, -1):
                r0 = kb * LANES
                r1 = min(h, r0 + LANES)
                _yvv_lanes(buf, q0, buf, q0, r1 - 1, -1, r1 - r0, g, a1, a2, a3, sg, sg[0], 0.0)
                dst = bb[kb, c0 + q0:c0 + q0 + m]
                if r1 - r0 == LANES and m == _G:
                    for j in range(0, _G, 4):
                        for i in range(0, LANES, 4):
                            _transpose4(buf, r0 + i, q0 + j, dst, j, i)
                else:
                    for j in range(m):
                        for i in range(r1 - r0):
                            dst[j, i] = buf[r0 + i, q0 + j]
                        for i in range(r1 - r0, LANES):     # the lanes past the last row
                            dst[j, i] = 0.0


@njit(parallel=True, cache=True)
def _horiz_blocks(blk, coef, tails, eps, rows):
    """Row recursions in place on each block of ``LANES`` rows (the lanes of one column are
    contiguous), ``_G`` lanes at a time with the state in registers (:func:`_yvv_lanes`,
    float64 state); ``rows[b, r]`` receives ``sum (v - eps)_+`` of row ``r`` from the stored
    values. The zero border as in :func:`_through_border`: the causal recursion runs on
    through ``tail`` zero cells (written to ``tb``), the anti-causal one back from their far
    end with its state reset."""
    B, nb, w, L = blk.shape
    h = rows.shape[1]
    for job in prange(B * nb):
        b = job // nb
        k = job - b * nb
        g, a1, a2, a3 = coef[b, 0], coef[b, 1], coef[b, 2], coef[b, 3]
        tail = tails[b]
        t = blk[b, k]
        st = np.empty((3, _G))
        tb = np.empty((tail, _G))
        acc = np.zeros(L)
        for j0 in range(0, L, _G):
            st[:] = 0.0
            _yvv_lanes(t, j0, t, j0, 0, 1, w, g, a1, a2, a3, st, acc, eps)      # causal
            tb[:] = 0.0
            _yvv_lanes(tb, 0, tb, 0, 0, 1, tail, g, a1, a2, a3, st, acc, eps)
            st[:] = 0.0
            _yvv_lanes(tb, 0, tb, 0, tail - 1, -1, tail, g, a1, a2, a3, st, acc, eps)
            _yvv_lanes_acc(t, j0, t, j0, w - 1, -1, w, g, a1, a2, a3, st,      # anti-causal
                           acc[j0:j0 + _G], eps)
        r0 = k * L
        for j in range(min(L, h - r0)):
            rows[b, r0 + j] = acc[j]


@njit(parallel=True, cache=True)
def _from_blocks(blk, out):
    B, h, w = out.shape
    for job in prange(B * h):
        b = job // h
        r = job - b * h
        src = blk[b, r // LANES]
        lane = r % LANES
        o = out[b, r]
        for c in range(w):
            o[c] = src[c, lane]


def gaussian_blocks(p: np.ndarray, sigma_cells: np.ndarray, epsilon: float = 0.0,
                    dtype=np.float32, limit: float = np.inf, scale: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, int]:
    """The recursive Gaussian of :func:`recursive_gaussian` in the block layout.

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Grids (float64, or float32 read as it is; converted otherwise).
    sigma_cells : ndarray, shape (B,)
        Standard deviation of each run's blur, cells (``>= 0.5``).
    epsilon : float
        Floor whose excess ``sum (v - eps)_+`` is returned with the blur.
    dtype : {numpy.float32, numpy.float64}
        Storage of the blurred grids.
    limit : float
        Cells of ``scale p`` outside ``[0, limit]`` (or NaN) are counted (the input check).
    scale : ndarray, shape (B,), optional
        Factor of each grid, applied (in float64) as each cell is read: the blur of
        ``scale[b] p[b]``, bit for bit the blur of that product stored in float64 first
        (default 1).

    Returns
    -------
    blocks : ndarray, shape (B, ceil(h / LANES), w, LANES)
        ``blocks[b, r // LANES, c, r % LANES]`` is the blurred cell ``(r, c)``; the lanes
        past the last row are zero.
    excess : ndarray, shape (B,)
        ``sum (blurred - eps)_+`` of each grid, from the stored values.
    bad : int
        Number of cells of ``p`` outside ``[0, limit]``.
    """
    p = _grid_array(p)
    B, h, w = p.shape
    s = np.asarray(sigma_cells, dtype=np.float64).reshape(B)
    sc = np.ones(B) if scale is None else np.ascontiguousarray(scale, dtype=np.float64).reshape(B)
    if np.dtype(dtype) not in (np.dtype(np.float64), np.dtype(np.float32)):
        raise ValueError(f"dtype: float64 or float32, got {dtype}")
    coef = yvv_coefficients(s)
    # the recursions decay with the Gaussian: 6 sigma of zeros past the border lose < 1e-8
    tails = np.ceil(6.0 * s).astype(np.int64) + 3
    nb = (h + LANES - 1) // LANES
    blk = np.empty((B, nb, w, LANES), dtype)       # (the lanes past the last row: zeroed
                                                   # by _vert_blocks)
    bad = np.empty(B * ((w + _COL_CHUNK - 1) // _COL_CHUNK), np.int64)
    _vert_blocks(p, sc, blk, coef, tails, float(limit), bad)
    rows = np.empty((B, h))
    _horiz_blocks(blk, coef, tails, float(epsilon), rows)
    return blk, rows.sum(axis=1), int(bad.sum())


def recursive_gaussian(p: np.ndarray, sigma_cells: np.ndarray, epsilon: float = 0.0,
                       dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
    """Recursive Gaussian blur of each grid (zero outside the grid).

    Column recursions (SIMD across columns) write the block layout of
    :func:`gaussian_blocks`, whose row recursions run on ``LANES`` rows at once (SIMD across
    rows); this function copies the result back to the grid's layout.

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Grids (float64).
    sigma_cells : ndarray, shape (B,)
        Standard deviation of each run's blur, cells (``>= 0.5``).
    epsilon : float
        Floor whose excess ``sum (v - eps)_+`` is returned with the blur.
    dtype : {numpy.float64, numpy.float32}
        Storage of the blurred grid. The recursions always run in float64 and keep the
        column recursions' causal outputs in float64; float32 storage rounds each cell twice
        (after the column and after the row recursions: relative error below
        ``2 * 2**-24`` of the cell's value, tested), and halves the memory traffic.

    Returns
    -------
    blurred : ndarray, shape (B, h, w)
        Blurred grids of ``dtype`` (not clipped: values within rounding of 0 may be slightly
        negative; :func:`floor_normalise_into` floors them).
    excess : ndarray, shape (B,)
        ``sum (blurred - eps)_+`` of each grid, from the stored values (for
        :func:`floor_normalise_into`).
    """
    blk, excess, _ = gaussian_blocks(p, sigma_cells, epsilon, dtype)
    out = np.empty(np.shape(p), dtype)
    _from_blocks(blk, out)
    return out, excess


@njit(parallel=True, cache=True)
def _floor_normalise(p, out, fmode, fc, eps):
    B, h, w = p.shape
    k = h * w
    for job in prange(B * h):
        b = job // h
        r = job - b * h
        mode, c = fmode[b], fc[b]
        prow = p[b, r]
        orow = out[b, r]
        for j in range(w):
            orow[j] = _floored(prow[j], mode, c, eps, k)


@njit(parallel=True, cache=True)
def _excess_rows(p, eps, rows):
    B, h, w = p.shape
    for job in prange(B * h):
        b = job // h
        r = job - b * h
        acc = 0.0
        for j in range(w):
            v = p[b, r, j] - eps
            if v > 0.0:
                acc += v
        rows[b, r] = acc


def floor_normalise_into(p: np.ndarray, epsilon: float, excess: np.ndarray | None = None,
                         out: np.ndarray | None = None) -> np.ndarray:
    """``p <- eps + (1 - k eps) (p - eps)_+ / sum (p - eps)_+`` (uniform if no excess).

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Non-negative grids (float64).
    epsilon : float
        Floor (``epsilon k <= 1``, checked by the caller).
    excess : ndarray, shape (B,), optional
        ``sum (p - eps)_+`` of each grid when already known (computed otherwise).
    out : ndarray, shape (B, h, w), optional
        Output array (may be ``p``); a new array by default.

    Returns
    -------
    ndarray, shape (B, h, w)
    """
    p = _grid_array(p)
    if excess is None:
        rows = np.empty(p.shape[:2])
        _excess_rows(p, float(epsilon), rows)
        excess = rows.sum(axis=1)
    if out is None:
        out = np.empty(p.shape)
    mode, c = _floor_args(p.shape[0], p.shape[1] * p.shape[2], float(epsilon), excess)
    _floor_normalise(p, out, mode, c, float(epsilon))
    return out


@njit(inline="always")
def _trapezoid(d2, m, t, s):
    # the trapezoid likelihood at squared distance d2
    d = math.sqrt(d2)
    e = max(abs(d - m) - t, 0.0)
    return max(s - e, 0.0) / s


@njit(parallel=True, cache=True, fastmath={"reassoc"})
def _trapezoid_rows(p, xs, ys, pos, mu, tau, sig, eps, out, rows, fmode, fc):
    B, h, w = p.shape
    k = h * w
    for job in prange(B * h):
        b = job // h
        r = job - b * h
        px, py = pos[b, 0], pos[b, 1]
        m, t, s = mu[b], tau[b], sig[b]
        mode, c = fmode[b], fc[b]
        dy = ys[r] - py
        dy2 = dy * dy
        prow = p[b, r]
        orow = out[b, r]
        acc = 0.0
        for j in range(w):
            dx = xs[j] - px
            lik = _trapezoid(dx * dx + dy2, m, t, s)
            v = max(_floored(prow[j], mode, c, eps, k) * lik, eps)
            orow[j] = v
            acc += v
        rows[b, r] = acc


def _zones(mu, tau, sig):
    """Squared-distance bounds of the trapezoid's flat parts, per run: ``(zin, olo, ohi,
    zout)``. ``d2 <= zin`` or ``d2 >= zout``: the likelihood is exactly 0; ``olo <= d2 <=
    ohi``: exactly 1. A margin of ``1e-9 R^2`` (``R = mu + tau + sigma``) keeps every cell
    whose class rounding could change on the full formula's side (see _trapezoid)."""
    R = mu + tau + sig
    m = 1e-9 * R * R
    lo0 = mu - tau - sig
    lo1 = mu - tau
    zin = np.where(lo0 > 0.0, lo0 * lo0 - m, -1.0)
    olo = np.where(lo1 > 0.0, lo1 * lo1 + m, -1.0)
    ohi = (mu + tau) ** 2 - m
    zout = R * R + m
    return np.stack([zin, olo, ohi, zout], axis=-1)


@njit(inline="always")
def _zone(lo, hi, zin, olo, ohi, zout):
    # the class shared by every cell whose squared distance lies in [lo, hi]: 0 (likelihood
    # 0), 1 (likelihood 1) or 2 (mixed or on a ramp: the full formula)
    if hi <= zin or lo >= zout:
        return 0
    if lo >= olo and hi <= ohi:
        return 1
    return 2


@njit(inline="always")
def _block_rows(ys, py, r0, h, dy2):
    # dy^2 of the LANES rows of a block (the lanes past the last row repeat it) and its range
    lo, hi = np.inf, -np.inf
    for j in range(dy2.size):
        dy = ys[min(r0 + j, h - 1)] - py
        d = dy * dy
        dy2[j] = d
        lo = min(lo, d)
        hi = max(hi, d)
    return lo, hi


def _post_column_codegen(z, mode):
    def codegen(context, builder, signature, args):
        xty, vty, aty, dty = signature.args[:4]
        x, vals, acc, dy2, dx2, m, t, s, c, eps, kf = args
        i32, i64 = ir.IntType(32), ir.IntType(64)
        V = ir.VectorType(ir.DoubleType(), _G)

        def ptr(aty_, a):
            arr = context.make_array(aty_)(context, builder, a)
            dt = context.get_data_type(aty_.dtype)
            return (builder.bitcast(arr.data, ir.VectorType(dt, _G).as_pointer()),
                    cgutils.unpack_tuple(builder, arr.shape)[0],
                    context.get_abi_sizeof(dt), ir.VectorType(dt, _G))

        xp, nlanes, xal, xvt = ptr(xty, x)
        vp = ptr(vty, vals)[0]
        ap = ptr(aty, acc)[0]
        dp = ptr(dty, dy2)[0]

        def splat(v):
            u = ir.Constant(V, ir.Undefined)
            return builder.shuffle_vector(builder.insert_element(u, v, ir.Constant(i32, 0)), u,
                                          ir.Constant(ir.VectorType(i32, _G), [0] * _G))

        def vmax(a, b):                          # max(a, b) as numba's: b if b > a else a
            return builder.select(builder.fcmp_ordered(">", b, a), b, a)

        mod = builder.module
        fma = cgutils.get_or_insert_function(mod, ir.FunctionType(V, [V, V, V]),
                                             "llvm.fma.v%df64" % _G)
        sqrt = cgutils.get_or_insert_function(mod, ir.FunctionType(V, [V]),
                                              "llvm.sqrt.v%df64" % _G)
        fabs = cgutils.get_or_insert_function(mod, ir.FunctionType(V, [V]),
                                              "llvm.fabs.v%df64" % _G)
        veps, zero = splat(eps), ir.Constant(V, [0.0] * _G)
        n = builder.udiv(nlanes, ir.Constant(i64, _G))
        with cgutils.for_range(builder, n) as loop:
            i = loop.index
            if z == 0:
                v = veps
            else:
                if mode == 2:
                    f = splat(builder.fdiv(ir.Constant(ir.DoubleType(), 1.0), kf))
                else:
                    xv = builder.load(builder.gep(xp, [i]), align=xal)
                    if xvt != V:
                        xv = builder.fpext(xv, V)
                    if mode == 1:
                        d = builder.fsub(xv, veps)
                        f = builder.select(builder.fcmp_ordered(">", d, zero),
                                           builder.call(fma, [splat(c), d, veps]), veps)
                    else:
                        f = xv
                if z == 1:
                    v = vmax(f, veps)
                else:
                    dd = builder.call(sqrt, [builder.fadd(splat(dx2), builder.load(
                        builder.gep(dp, [i]), align=8))])
                    e = vmax(builder.fsub(builder.call(fabs, [builder.fsub(dd, splat(m))]),
                                          splat(t)), zero)
                    lik = builder.fdiv(vmax(builder.fsub(splat(s), e), zero), splat(s))
                    v = vmax(builder.fmul(f, lik), veps)
            builder.store(v, builder.gep(vp, [i]), align=8)
            a = builder.gep(ap, [i])
            builder.store(builder.fadd(builder.load(a, align=8), v), a, align=8)
        return context.get_dummy_value()
    return codegen


def _make_post_column(z, mode):
    @intrinsic
    def post(typingctx, x, vals, acc, dy2, dx2, m, t, s, c, eps, kf):
        sig = types.void(x, vals, acc, dy2, dx2, m, t, s, c, eps, kf)
        return sig, _post_column_codegen(z, mode)
    return post


_post_z0 = _make_post_column(0, 0)
_post_z1m0, _post_z1m1, _post_z1m2 = (_make_post_column(1, md) for md in range(3))
_post_z2m0, _post_z2m1, _post_z2m2 = (_make_post_column(2, md) for md in range(3))


@njit(inline="always")
def _post_column(x, vals, acc, dy2, z, mode, dx2, m, t, s, c, eps, kf):
    # the unnormalised posterior max(prior L, eps) of one block column into vals, added to
    # acc lane by lane (the floor, the class's likelihood and the row sums in explicit
    # vectors: no run-time alias checks; the lane count a multiple of _G)
    if z == 0:
        _post_z0(x, vals, acc, dy2, dx2, m, t, s, c, eps, kf)
    elif z == 1:
        if mode == 1:
            _post_z1m1(x, vals, acc, dy2, dx2, m, t, s, c, eps, kf)
        elif mode == 2:
            _post_z1m2(x, vals, acc, dy2, dx2, m, t, s, c, eps, kf)
        else:
            _post_z1m0(x, vals, acc, dy2, dx2, m, t, s, c, eps, kf)
    elif mode == 1:
        _post_z2m1(x, vals, acc, dy2, dx2, m, t, s, c, eps, kf)
    elif mode == 2:
        _post_z2m2(x, vals, acc, dy2, dx2, m, t, s, c, eps, kf)
    else:
        _post_z2m0(x, vals, acc, dy2, dx2, m, t, s, c, eps, kf)


@njit(parallel=True, cache=True, fastmath=_FM)
def _trapezoid_blocks(blk, xs, ys, pos, mu, tau, sig, zones, eps, out, rows, fmode, fc, nt):
    """The unnormalised posterior ``max(prior L, eps)`` of each cell from the block layout
    (the ``LANES`` rows of a block are the SIMD lanes), written in the grid's layout, with
    its row sums (cell by cell along each row). Each block column is classed by its cells'
    squared distances (:func:`_zone`): likelihood 0 and 1 need no square root. ``nt``: the
    whole tiles are written with non-temporal stores (``out`` 64-byte aligned and ``w % 4
    == 0``, checked by the caller)."""
    B, h, w = out.shape
    nb, L = blk.shape[1], blk.shape[3]
    kf = np.float64(h * w)
    for job in prange(B * nb):
        b = job // nb
        q = job - b * nb
        r0 = q * LANES
        nl = min(LANES, h - r0)
        px, py = pos[b, 0], pos[b, 1]
        m, t, s = mu[b], tau[b], sig[b]
        mode, c = fmode[b], fc[b]
        zin, olo, ohi, zout = zones[b, 0], zones[b, 1], zones[b, 2], zones[b, 3]
        dy2 = np.empty(L)
        ylo, yhi = _block_rows(ys, py, r0, h, dy2)
        acc = np.zeros(L)
        tile = np.empty((_TILE, L))
        src = blk[b, q]
        ob = out[b, r0:r0 + nl]
        whole = nl == LANES
        for c0 in range(0, w, _TILE):
            nc = min(_TILE, w - c0)
            for i in range(nc):
                col = c0 + i
                dx = xs[col] - px
                dx2 = dx * dx
                z = _zone(dx2 + ylo, dx2 + yhi, zin, olo, ohi, zout)
                _post_column(src[col], tile[i], acc, dy2, z, mode, dx2, m, t, s, c, eps, kf)
            n4 = nc - nc % 4 if whole else 0
            if nt:
                # each row's _TILE cells in a row: whole cache lines, written at once
                for j in range(0, LANES, 4):
                    for i in range(0, n4, 4):
                        _transpose4_nt(tile, i, j, ob, j, c0 + i)
            else:
                for j in range(0, LANES, 4):
                    for i in range(0, n4, 4):
                        _transpose4(tile, i, j, ob, j, c0 + i)
            for i in range(n4, nc):
                for j in range(nl):
                    ob[j, c0 + i] = tile[i, j]
        for j in range(nl):
            rows[b, r0 + j] = acc[j]
        if nt:
            _sfence()


@njit(parallel=True, cache=True, fastmath={"reassoc"})
def _weighted_rows(p, lik, eps, out, rows, fmode, fc):
    B, h, w = p.shape
    k = h * w
    for job in prange(B * h):
        b = job // h
        r = job - b * h
        mode, c = fmode[b], fc[b]
        prow = p[b, r]
        lrow = lik[b, r]
        orow = out[b, r]
        acc = 0.0
        for j in range(w):
            v = max(_floored(prow[j], mode, c, eps, k) * lrow[j], eps)
            orow[j] = v
            acc += v
        rows[b, r] = acc


@njit(parallel=True, cache=True)
def _scale_rows_by(out, scale):
    B, h, w = out.shape
    for job in prange(B * h):
        b = job // h
        r = job - b * h
        c = scale[b]
        for j in range(w):
            out[b, r, j] *= c


def _scale_rows(out: np.ndarray, total: np.ndarray) -> None:
    # out *= 1 / total per grid (the reciprocal in float64, then one product per cell)
    _scale_rows_by(out, 1.0 / total)


def trapezoid_update(p: np.ndarray, x: np.ndarray, y: np.ndarray, tracker_xy: np.ndarray,
                     mu: np.ndarray, tau: np.ndarray, sigma: np.ndarray, epsilon: float,
                     prior_excess: np.ndarray | None = None) -> np.ndarray:
    """Algorithm 1 with the trapezoid likelihood ``max(0, sigma - (|d - mu| - tau)_+) / sigma``.

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Prior grids.
    x, y : ndarray, shape (w,) and (h,)
        Cell-centre coordinates of the columns and rows, metres.
    tracker_xy : ndarray, shape (B, 2)
        Reading position of each run, metres.
    mu, tau, sigma : ndarray, shape (B,)
        Trapezoid of each run's reading, metres.
    epsilon : float
        Minimum cell probability.
    prior_excess : ndarray, shape (B,), optional
        Given: ``p`` is a blurred grid not yet floored and this its ``sum (p - eps)_+``;
        the prior is then ``floor_normalise_into(p, epsilon, prior_excess)``, computed
        cell by cell inside the update (the same numbers, one pass less).

    Returns
    -------
    ndarray, shape (B, h, w)
        Posterior grids ``max(p L, eps) / sum``.
    """
    p = _grid_array(p)
    out = np.empty(p.shape)
    rows = np.empty(p.shape[:2])
    f = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    mode, c = _floor_args(p.shape[0], p.shape[1] * p.shape[2], float(epsilon), prior_excess)
    _trapezoid_rows(p, f(x), f(y), f(tracker_xy), f(mu), f(tau), f(sigma), float(epsilon),
                    out, rows, mode, c)
    _scale_rows(out, rows.sum(axis=1))
    return out


def trapezoid_update_blocks(blk: np.ndarray, shape: tuple[int, int, int], x: np.ndarray,
                            y: np.ndarray, tracker_xy: np.ndarray, mu: np.ndarray,
                            tau: np.ndarray, sigma: np.ndarray, epsilon: float,
                            prior_excess: np.ndarray) -> np.ndarray:
    """:func:`trapezoid_update` of a blurred grid in the block layout of
    :func:`gaussian_blocks` (the prior is its floor, computed cell by cell).

    Parameters
    ----------
    blk : ndarray, shape (B, ceil(h / LANES), w, LANES)
        Blurred grids in the block layout (float32 or float64).
    shape : tuple of int
        ``(B, h, w)`` of the grids.
    x, y, tracker_xy, mu, tau, sigma, epsilon
        As in :func:`trapezoid_update`.
    prior_excess : ndarray, shape (B,)
        ``sum (blk - eps)_+`` of each grid (from :func:`gaussian_blocks`).

    Returns
    -------
    ndarray, shape (B, h, w)
        Posterior grids ``max(p L, eps) / sum`` (float64).
    """
    out, scale = trapezoid_posterior_blocks(blk, shape, x, y, tracker_xy, mu, tau, sigma,
                                            epsilon, prior_excess)
    _scale_rows_by(out, scale)
    return out


def trapezoid_posterior_blocks(blk: np.ndarray, shape: tuple[int, int, int], x: np.ndarray,
                               y: np.ndarray, tracker_xy: np.ndarray, mu: np.ndarray,
                               tau: np.ndarray, sigma: np.ndarray, epsilon: float,
                               prior_excess: np.ndarray, dtype=np.float64
                               ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`trapezoid_update_blocks` without its normalisation pass: the unnormalised
    posterior ``max(p L, eps)`` and the factor ``1 / sum`` that normalises it (the
    posterior of :func:`trapezoid_update_blocks` is ``raw * scale[:, None, None]``, bit for
    bit with ``dtype`` float64). The next step applies the factor as it reads the grid
    (``gaussian_blocks(..., scale=scale)``), which saves a read and a write of every cell.

    Parameters
    ----------
    blk, shape, x, y, tracker_xy, mu, tau, sigma, epsilon, prior_excess
        As in :func:`trapezoid_update_blocks`.
    dtype : {numpy.float64, numpy.float32}
        Storage of the unnormalised posterior. float32 rounds each cell once (relative
        error at most ``2**-24``); the sum is taken before the rounding, in float64.

    Returns
    -------
    raw : ndarray, shape (B, h, w)
        ``max(p L, eps)`` of each cell, of ``dtype``.
    scale : ndarray, shape (B,)
        ``1 / sum(max(p L, eps))`` of each grid (float64).
    """
    f = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    x, y, xy, mu, tau, sigma = f(x), f(y), f(tracker_xy), f(mu), f(tau), f(sigma)
    if np.dtype(dtype) not in (np.dtype(np.float64), np.dtype(np.float32)):
        raise ValueError(f"dtype: float64 or float32, got {dtype}")
    zones = _zones(mu, tau, sigma)
    mode, c = _floor_args(shape[0], shape[1] * shape[2], float(epsilon), prior_excess)
    # the posterior is written once and read only by the next step: non-temporal stores
    # (no read of its cache lines before the write) where every tile's rows are aligned and
    # the grids too large for the cache to keep them until then (see NONTEMPORAL_MIN_BYTES)
    nt = (NONTEMPORAL and np.dtype(dtype) == np.float64 and shape[2] % 4 == 0
          and np.prod(shape) * 8 >= NONTEMPORAL_MIN_BYTES)
    out = _aligned_empty(shape, dtype) if nt else np.empty(shape, dtype)
    rows = np.empty(shape[:2])
    _trapezoid_blocks(blk, x, y, xy, mu, tau, sigma, zones, float(epsilon), out, rows, mode, c,
                      nt)
    return out, 1.0 / rows.sum(axis=1)


def weighted_update(p: np.ndarray, likelihood: np.ndarray, epsilon: float,
                    prior_excess: np.ndarray | None = None) -> np.ndarray:
    """Algorithm 1 with a likelihood grid: ``max(p L, eps) / sum``.

    Parameters
    ----------
    p : ndarray, shape (B, h, w)
        Prior grids.
    likelihood : ndarray, shape (B, h, w)
        ``L(|l_i - s_a| | rss)`` of each cell.
    epsilon : float
        Minimum cell probability.
    prior_excess : ndarray, shape (B,), optional
        As in :func:`trapezoid_update`.

    Returns
    -------
    ndarray, shape (B, h, w)
        Posterior grids.
    """
    p = np.ascontiguousarray(p, dtype=np.float64)
    lik = np.ascontiguousarray(np.broadcast_to(likelihood, p.shape), dtype=np.float64)
    out = np.empty_like(p)
    rows = np.empty(p.shape[:2])
    mode, c = _floor_args(p.shape[0], p.shape[1] * p.shape[2], float(epsilon), prior_excess)
    _weighted_rows(p, lik, float(epsilon), out, rows, mode, c)
    _scale_rows(out, rows.sum(axis=1))
    return out
