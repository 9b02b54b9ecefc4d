"""Compiled kernels of the channel family (numba), in one module.

Each kernel here is the compiled form of a NumPy (or shapely) definition in the module that
calls it, chosen by that function's ``backend="numba" | "numpy"``:

- :meth:`radioloc.channel.scene.Scene.blocked`: a segment blocked by a building (grid walk
  of the walls; the definition is shapely's intersection test);
- :func:`radioloc.channel.raytrace.trace_links`: image-method reflections and corner
  diffractions (a depth-first walk of the image tree per link; the definition is the
  vectorised NumPy/shapely tracer in the same module);
- :func:`radioloc.channel.gsic.omp_sic_toa` / ``matched_filter_toa``: the OMP and SIC
  sweeps over ACK sets (the definition is the NumPy form in the same module);
- :func:`radioloc.channel.cdma.received_acks`: the chip-sampled sum of delayed codes.

The kernels call one another only within this module, so numba's on-disk cache, which
checks a kernel against its own file alone, never keeps stale code.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


# --- scene ----------------------------------------------------------------------------

@njit(cache=True)
def _seg_hits(px, py, qx, qy, ax, ay, bx, by):
    """Whether the closed segments p-q and a-b intersect (touching counts)."""
    d1 = (bx - ax) * (py - ay) - (by - ay) * (px - ax)
    d2 = (bx - ax) * (qy - ay) - (by - ay) * (qx - ax)
    if (d1 > 0 and d2 > 0) or (d1 < 0 and d2 < 0):
        return False
    d3 = (qx - px) * (ay - py) - (qy - py) * (ax - px)
    d4 = (qx - px) * (by - py) - (qy - py) * (bx - px)
    if (d3 > 0 and d4 > 0) or (d3 < 0 and d4 < 0):
        return False
    if d1 == 0 and d2 == 0 and d3 == 0 and d4 == 0:          # collinear: overlap of extents
        if max(px, qx) < min(ax, bx) or max(ax, bx) < min(px, qx):
            return False
        if max(py, qy) < min(ay, by) or max(ay, by) < min(py, qy):
            return False
    return True


@njit(cache=True)
def _walk_start(px, py, ex, ey, g0x, g0y, h, nx, ny):
    """Start of a grid walk (Amanatides-Woo) along ``p + s e``, ``s`` in [0, 1]: the segment
    clipped to the grid box, the first cell, the steps and the parameters of the next cell
    boundaries. ``ok`` is False when the segment misses the box."""
    x1, y1 = g0x + nx * h, g0y + ny * h
    s0, s1 = 0.0, 1.0
    for k in range(2):
        p = px if k == 0 else py
        e = ex if k == 0 else ey
        lo = g0x if k == 0 else g0y
        hi = x1 if k == 0 else y1
        if e == 0.0:
            if p < lo or p > hi:
                return False, s1, 0, 0, 1, 1, np.inf, np.inf, np.inf, np.inf
        else:
            ta = (lo - p) / e
            tb = (hi - p) / e
            if ta > tb:
                ta, tb = tb, ta
            s0 = max(s0, ta)
            s1 = min(s1, tb)
    if s0 > s1:
        return False, s1, 0, 0, 1, 1, np.inf, np.inf, np.inf, np.inf
    cx, cy = px + s0 * ex, py + s0 * ey
    ci = min(max(int((cx - g0x) / h), 0), nx - 1)
    cj = min(max(int((cy - g0y) / h), 0), ny - 1)
    stepx = 1 if ex > 0 else -1
    stepy = 1 if ey > 0 else -1
    if ex != 0.0:
        tmx = (g0x + (ci + (1 if ex > 0 else 0)) * h - px) / ex
        tdx = h / abs(ex)
    else:
        tmx = np.inf
        tdx = np.inf
    if ey != 0.0:
        tmy = (g0y + (cj + (1 if ey > 0 else 0)) * h - py) / ey
        tdy = h / abs(ey)
    else:
        tmy = np.inf
        tdy = np.inf
    return True, s1, ci, cj, stepx, stepy, tmx, tmy, tdx, tdy


@njit(cache=True)
def _leg_blocked(ax, ay, bx, by, trim, A, B, g0x, g0y, h, nx, ny, cstart, cwalls, stamp, tag):
    """Whether the leg a -> b, both ends pulled in by ``min(trim, L / 4)``, crosses a wall.

    Walls are found with a uniform grid (cell side ``h``, origin ``g0``) walked along the
    leg (Amanatides-Woo); ``stamp``/``tag`` avoid testing a wall twice."""
    dx, dy = bx - ax, by - ay
    L = np.sqrt(dx * dx + dy * dy)
    if L <= 0:
        return False
    ux, uy = dx / max(L, 1e-12), dy / max(L, 1e-12)
    t = min(trim, 0.25 * L)
    px, py = ax + ux * t, ay + uy * t
    qx, qy = bx - ux * t, by - uy * t
    ex, ey = qx - px, qy - py
    ok, s1, ci, cj, stepx, stepy, tmx, tmy, tdx, tdy = _walk_start(px, py, ex, ey, g0x, g0y, h,
                                                                   nx, ny)
    if not ok:
        return False
    for _ in range(nx + ny + 2):
        c = ci * ny + cj
        for q in range(cstart[c], cstart[c + 1]):
            w = cwalls[q]
            if stamp[w] == tag:
                continue
            stamp[w] = tag
            if _seg_hits(px, py, qx, qy, A[w, 0], A[w, 1], B[w, 0], B[w, 1]):
                return True
        if min(tmx, tmy) > s1:
            break
        if tmx < tmy:
            ci += stepx
            tmx += tdx
        else:
            cj += stepy
            tmy += tdy
        if ci < 0 or ci >= nx or cj < 0 or cj >= ny:
            break
    return False


@njit(cache=True, parallel=True)
def _blocked_batch(a, b, trim, A, B, g0x, g0y, h, nx, ny, cstart, cwalls):
    """:meth:`Scene.blocked` for many legs (compiled, grid-accelerated)."""
    n = a.shape[0]
    out = np.zeros(n, np.bool_)
    W = A.shape[0]
    nchunk = 64
    for c in prange(nchunk):
        stamp = np.zeros(W, np.int64)
        tag = 0
        for i in range(c, n, nchunk):
            tag += 1
            out[i] = _leg_blocked(a[i, 0], a[i, 1], b[i, 0], b[i, 1], trim, A, B, g0x, g0y, h,
                                  nx, ny, cstart, cwalls, stamp, tag)
    return out


@njit(cache=True)
def _beam_blocked(e0x, e0y, e1x, e1y, f0x, f0y, f1x, f1y, A, B, bbox, bstart,
                  g0x, g0y, h, nx, ny, bcs, bcell, stamp, tag):
    """Whether one convex building spans the beam between the edges e0 -> e1 and f0 -> f1
    (the two sides of a convex quadrilateral or triangle of rays): it then meets both sides
    (1 cm or more from their ends), and every ray between them crosses it.

    The convex buildings come from :attr:`Scene.convex_grid` (``bbox`` their envelopes,
    ``bcs``/``bcell`` the buildings of each cell) walked along the first side; a building
    whose envelope misses either side is skipped before its walls are tested."""
    dx, dy = e1x - e0x, e1y - e0y
    L = np.sqrt(dx * dx + dy * dy)
    gx, gy = f1x - f0x, f1y - f0y
    M = np.sqrt(gx * gx + gy * gy)
    d = 0.01
    if L <= 4 * d or M <= 4 * d:
        return False
    px, py = e0x + dx / L * d, e0y + dy / L * d
    qx, qy = e1x - dx / L * d, e1y - dy / L * d
    rx_, ry_ = f0x + gx / M * d, f0y + gy / M * d
    sx, sy = f1x - gx / M * d, f1y - gy / M * d
    elx, ehx = min(px, qx) - 1e-7, max(px, qx) + 1e-7
    ely, ehy = min(py, qy) - 1e-7, max(py, qy) + 1e-7
    flx, fhx = min(rx_, sx) - 1e-7, max(rx_, sx) + 1e-7
    fly, fhy = min(ry_, sy) - 1e-7, max(ry_, sy) + 1e-7
    ex, ey = qx - px, qy - py
    ok, s1, ci, cj, stepx, stepy, tmx, tmy, tdx, tdy = _walk_start(px, py, ex, ey, g0x, g0y, h,
                                                                   nx, ny)
    if not ok:
        return False
    for _ in range(nx + ny + 2):
        c = ci * ny + cj
        for q in range(bcs[c], bcs[c + 1]):
            b = bcell[q]
            if stamp[b] == tag:
                continue
            stamp[b] = tag
            if (bbox[b, 0] > ehx or bbox[b, 2] < elx or bbox[b, 1] > ehy or bbox[b, 3] < ely
                    or bbox[b, 0] > fhx or bbox[b, 2] < flx or bbox[b, 1] > fhy
                    or bbox[b, 3] < fly):
                continue
            hit = False
            for v in range(bstart[b], bstart[b + 1]):
                if _seg_hits(px, py, qx, qy, A[v, 0], A[v, 1], B[v, 0], B[v, 1]):
                    hit = True
                    break
            if not hit:
                continue
            for v in range(bstart[b], bstart[b + 1]):
                if _seg_hits(rx_, ry_, sx, sy, A[v, 0], A[v, 1], B[v, 0], B[v, 1]):
                    return True
        if min(tmx, tmy) > s1:
            break
        if tmx < tmy:
            ci += stepx
            tmx += tdx
        else:
            cj += stepy
            tmy += tdy
        if ci < 0 or ci >= nx or cj < 0 or cj >= ny:
            break
    return False


@njit(cache=True)
def _cross(ox, oy, ax, ay, bx, by):
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


@njit(cache=True)
def _quad_spanned(ax, ay, bx, by, cx, cy, dx, dy, A, B, bbox, bstart, g0x, g0y, h, nx, ny,
                  bcs, bcell, stamp, tag):
    """Whether one convex footprint spans the quadrilateral between the segments a-b and
    c-d (False when that quadrilateral is not strictly convex)."""
    # pair the ends so that the sides a -> x and b -> y do not cross
    xx, xy, yx, yy = cx, cy, dx, dy
    if _cross(ax, ay, cx, cy, bx, by) * _cross(ax, ay, cx, cy, dx, dy) < 0 and \
            _cross(bx, by, dx, dy, ax, ay) * _cross(bx, by, dx, dy, cx, cy) < 0:
        xx, xy, yx, yy = dx, dy, cx, cy
    # quadrilateral a, b, y, x strictly convex (all turns of one sign)
    t0 = _cross(ax, ay, bx, by, yx, yy)
    t1 = _cross(bx, by, yx, yy, xx, xy)
    t2 = _cross(yx, yy, xx, xy, ax, ay)
    t3 = _cross(xx, xy, ax, ay, bx, by)
    if not ((t0 > 0 and t1 > 0 and t2 > 0 and t3 > 0)
            or (t0 < 0 and t1 < 0 and t2 < 0 and t3 < 0)):
        return False
    return _beam_blocked(ax, ay, xx, xy, bx, by, yx, yy, A, B, bbox, bstart,
                         g0x, g0y, h, nx, ny, bcs, bcell, stamp, tag)


@njit(cache=True, parallel=True)
def _wall_pairs_visible(A, B, fstart, fwalls, bbox, bstart, g0x, g0y, h, nx, ny, bcs, bcell,
                        nsub):
    """For every pair (p, w) of the follower lists, False when the two walls, cut into
    ``nsub`` equal pieces each, have every pair of pieces spanned by a convex footprint
    (see :attr:`Scene.visible`)."""
    P = fstart.shape[0] - 1
    W = A.shape[0]
    keep = np.ones(fwalls.shape[0], np.bool_)
    for p in prange(P):
        stamp = np.zeros(W, np.int64)
        tag = 0
        ax, ay = A[p, 0], A[p, 1]
        ux, uy = (B[p, 0] - ax) / nsub, (B[p, 1] - ay) / nsub
        for q in range(fstart[p], fstart[p + 1]):
            w = fwalls[q]
            cx, cy = A[w, 0], A[w, 1]
            vx, vy = (B[w, 0] - cx) / nsub, (B[w, 1] - cy) / nsub
            hidden = True
            for i in range(nsub):
                for j in range(nsub):
                    tag += 1
                    if not _quad_spanned(ax + i * ux, ay + i * uy, ax + (i + 1) * ux,
                                         ay + (i + 1) * uy, cx + j * vx, cy + j * vy,
                                         cx + (j + 1) * vx, cy + (j + 1) * vy, A, B, bbox,
                                         bstart, g0x, g0y, h, nx, ny, bcs, bcell, stamp,
                                         tag):
                        hidden = False
                        break
                if not hidden:
                    break
            keep[q] = not hidden
    return keep


# --- raytrace -------------------------------------------------------------------------

@njit(cache=True)
def _in_beam_within_reach(ix, iy, lox, loy, hix, hiy, ax, ay, bx, by, rxx, rxy, lmax):
    """Whether wall ``a -> b`` is not wholly outside the beam from image ``i`` between the
    edges through ``lo`` and ``hi`` (counter-clockwise), and the shortest path image -> wall
    -> receiver is at most ``lmax``."""
    c1 = (lox - ix) * (ay - iy) - (loy - iy) * (ax - ix)
    c2 = (lox - ix) * (by - iy) - (loy - iy) * (bx - ix)
    if c1 < 0 and c2 < 0:
        return False
    c1 = (ax - ix) * (hiy - iy) - (ay - iy) * (hix - ix)
    c2 = (bx - ix) * (hiy - iy) - (by - iy) * (hix - ix)
    if c1 < 0 and c2 < 0:
        return False
    dx, dy = bx - ax, by - ay
    dd = dx * dx + dy * dy
    t = min(max(((ix - ax) * dx + (iy - ay) * dy) / dd, 0.0), 1.0)
    d1 = np.hypot(ax + t * dx - ix, ay + t * dy - iy)
    t = min(max(((rxx - ax) * dx + (rxy - ay) * dy) / dd, 0.0), 1.0)
    d2 = np.hypot(ax + t * dx - rxx, ay + t * dy - rxy)
    return not d1 + d2 > lmax          # as written: a NaN length is not out of reach


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
            if not _in_beam_within_reach(ix, iy, lox, loy, hix, hiy, ax, ay, bx, by, rxx, rxy,
                                         lmax[l]):
                continue
            par[n] = s
            wal[n] = w
            n += 1
    return par[:n], wal[:n]


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
                if not _in_beam_within_reach(ix0, iy0, lox, loy, hix, hiy, ax, ay, bx, by, rxx,
                                             rxy, lmax[l]):
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


# --- gsic -----------------------------------------------------------------------------

@njit(cache=True)
def _omp1(z, Xn, c, T, eta2, relative, floor, ks, amps):
    """OMP of one user's correlator output ``z`` (D,) with code ``c`` (``Xn[c, c]`` its
    normalised autocorrelation): writes the support cells ``ks`` and amplitudes ``amps``
    (length >= T) and returns the number of taps."""
    D = z.shape[0]
    resid = z.copy()
    p = np.empty(D)
    strongest = 0.0
    for d in range(D):
        v = z[d].real ** 2 + z[d].imag ** 2
        if v > strongest:
            strongest = v
    strongest *= relative
    n = 0
    for t in range(T):
        kbest = 0
        pbest = -1.0
        for d in range(D):
            v = resid[d].real ** 2 + resid[d].imag ** 2
            p[d] = v
            if v > pbest:
                pbest = v
                kbest = d
        fl = np.median(p) / np.log(2.0) if floor < 0 else floor
        thr = max(eta2 * fl, strongest)
        if not pbest > thr:
            break
        ks[t] = kbest
        n = t + 1
        G = np.empty((n, n), np.complex128)
        rhs = np.empty((n, 1), np.complex128)
        for i in range(n):
            for j in range(n):
                G[i, j] = Xn[c, c, ks[i] - ks[j] + D - 1]
            G[i, i] += 1e-9
            rhs[i, 0] = z[ks[i]]
        a = np.linalg.solve(G, rhs)
        for i in range(n):
            amps[i] = a[i, 0]
        for d in range(D):
            resid[d] = z[d]
        for i in range(n):
            a = amps[i]
            off = D - 1 - ks[i]
            for d in range(D):
                resid[d] -= a * Xn[c, c, d + off]
    return n


@njit(cache=True, parallel=True)
def _omp_batch(z, Xn, cidx, T, eta2):
    """Matched filter: OMP of every user of every ACK set on ``z`` itself."""
    B, U, D = z.shape
    taps = np.zeros((B, U, D), np.complex128)
    for b in prange(B):
        ks = np.zeros(T, np.int64)
        amps = np.zeros(T, np.complex128)
        for u in range(U):
            n = _omp1(z[b, u], Xn, cidx[b, u], T, eta2, 0.0, -1.0, ks, amps)
            for i in range(n):
                taps[b, u, ks[i]] += amps[i]
    return taps


@njit(cache=True)
def _add_user(Zall, Xn, cb, v, ks, amps, n, sign):
    """Zall[w] += sign * (correlation of user v's reconstruction with code w), w != v."""
    U, D = Zall.shape
    cv = cb[v]
    for w in range(U):
        if w == v:
            continue
        cw = cb[w]
        for i in range(n):
            a = sign * amps[i]
            off = D - 1 - ks[i]
            for d in range(D):
                Zall[w, d] += a * Xn[cw, cv, d + off]


@njit(cache=True)
def _sic1(z, X, Xn, E, cb, y_energy, N, iterations, T, first_taps, early, joint, eta2,
          noise_var, ks, amps, nt):
    """The sweeps of one ACK set; taps as (ks, amps, nt) per user.

    ``Zall[u]`` is user u's correlator output of ``y`` minus every *other* user's
    reconstruction, kept up to date as users change their taps."""
    U, D = z.shape
    Zall = z.copy()
    nks = np.zeros(T, np.int64)
    namps = np.zeros(T, np.complex128)
    done = np.zeros(U, np.bool_)
    for u in range(U):
        nt[u] = 0
    for sweep in range(iterations):
        rel = 0.0 if sweep == iterations - 1 else early
        ntaps = first_taps if (sweep == 0 and iterations > 1) else T
        done[:] = False
        for _stage in range(U):
            best = -1.0
            ub = 0
            for u in range(U):
                if done[u]:
                    continue
                pk = 0.0
                for d in range(D):
                    v = Zall[u, d].real ** 2 + Zall[u, d].imag ** 2
                    if v > pk:
                        pk = v
                if pk > best:
                    best = pk
                    ub = u
            u = ub
            done[u] = True
            cu = cb[u]
            floor = noise_var / E[cu] if noise_var >= 0 else -1.0
            n = _omp1(Zall[u], Xn, cu, ntaps, eta2, rel, floor, nks, namps)
            # merge duplicate cells (as the dense tap array does)
            m = 0
            for i in range(n):
                found = -1
                for j in range(m):
                    if nks[j] == nks[i]:
                        found = j
                if found >= 0:
                    namps[found] += namps[i]
                else:
                    nks[m] = nks[i]
                    namps[m] = namps[i]
                    m += 1
            _add_user(Zall, Xn, cb, u, ks[u], amps[u], nt[u], 1.0)      # put the old back
            _add_user(Zall, Xn, cb, u, nks, namps, m, -1.0)             # remove the new
            nt[u] = 0
            for i in range(m):
                if namps[i] != 0:
                    ks[u, nt[u]] = nks[i]
                    amps[u, nt[u]] = namps[i]
                    nt[u] += 1
        if joint:
            _joint1(z, X, E, cb, y_energy, N, T, eta2, noise_var, ks, amps, nt)
            for u in range(U):
                for d in range(D):
                    Zall[u, d] = z[u, d]
            for u in range(U):
                _add_user(Zall, Xn, cb, u, ks[u], amps[u], nt[u], -1.0)


@njit(cache=True)
def _joint1(z, X, E, cb, y_energy, N, T, eta2, noise_var, ks, amps, nt):
    """Joint least squares of every user's taps, pruning at the noise threshold, twice."""
    U, D = z.shape
    for _rep in range(2):
        # taps in increasing cell order per user (the order of the dense reference)
        n = 0
        for u in range(U):
            for i in range(nt[u]):
                for j in range(nt[u] - 1 - i):
                    if ks[u, j] > ks[u, j + 1]:
                        k0 = ks[u, j]
                        ks[u, j] = ks[u, j + 1]
                        ks[u, j + 1] = k0
                        a0 = amps[u, j]
                        amps[u, j] = amps[u, j + 1]
                        amps[u, j + 1] = a0
            n += min(nt[u], T)
        uu = np.empty(n, np.int64)
        kk = np.empty(n, np.int64)
        m = 0
        for u in range(U):
            for i in range(min(nt[u], T)):
                uu[m] = u
                kk[m] = ks[u, i]
                m += 1
        G = np.empty((n, n), np.complex128)
        rhs = np.empty((n, 1), np.complex128)
        for i in range(n):
            ci = cb[uu[i]]
            for j in range(n):
                G[i, j] = X[ci, cb[uu[j]], kk[i] - kk[j] + D - 1]
            G[i, i] += 1e-9
            rhs[i, 0] = z[uu[i], kk[i]] * E[ci]
        if n == 0:
            return
        a = np.linalg.solve(G, rhs)
        if noise_var >= 0:
            nv = noise_var
        else:                                   # ||y - sum a_i s_i||^2 / N
            q = y_energy
            for i in range(n):
                q -= 2.0 * (np.conj(a[i, 0]) * rhs[i, 0]).real
                G[i, i] -= 1e-9
            for i in range(n):
                acc = 0.0 + 0.0j
                for j in range(n):
                    acc += G[i, j] * a[j, 0]
                q += (np.conj(a[i, 0]) * acc).real
            nv = q / N
        for u in range(U):
            nt[u] = 0
        for i in range(n):
            u = uu[i]
            v = a[i, 0]
            if v.real ** 2 + v.imag ** 2 > eta2 * nv / E[cb[u]]:
                ks[u, nt[u]] = kk[i]
                amps[u, nt[u]] = v
                nt[u] += 1


@njit(cache=True, parallel=True)
def _sic_batch(z, X, Xn, E, cidx, y_energy, N, iterations, T, first_taps, early, joint, eta2,
               noise_var):
    B, U, D = z.shape
    taps = np.zeros((B, U, D), np.complex128)
    for b in prange(B):
        ks = np.zeros((U, T), np.int64)
        amps = np.zeros((U, T), np.complex128)
        nt = np.zeros(U, np.int64)
        _sic1(z[b], X, Xn, E, cidx[b], y_energy[b], N, iterations, T, first_taps, early, joint,
              eta2, noise_var, ks, amps, nt)
        for u in range(U):
            for i in range(nt[u]):
                taps[b, u, ks[u, i]] += amps[u, i]
    return taps


# --- cdma -----------------------------------------------------------------------------

@njit(cache=True)
def _synthesize(out, delays, gains, code_idx, codes, sample_s, chip_s):
    """Add sum_p g_p c(floor((n Ts - tau_p) / Tc)) to ``out[b]`` for every user and path."""
    B, U, P = delays.shape
    N = out.shape[1]
    L = codes.shape[1]
    for b in range(B):
        for u in range(U):
            c = codes[code_idx[b, u]]
            for p in range(P):
                g = gains[b, u, p]
                if g == 0:
                    continue
                tau = delays[b, u, p]
                n0 = int(np.ceil(tau / sample_s - 1e-9))
                if n0 < 0:
                    n0 = 0
                for n in range(n0, N):
                    m = int(np.floor((n * sample_s - tau) / chip_s + 1e-9))
                    if m >= L:
                        break
                    if m >= 0:
                        out[b, n] += g * c[m]
