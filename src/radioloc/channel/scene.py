"""Building footprints for 2-D ray tracing.

A :class:`Scene` holds opaque building footprints (shapely polygons, exterior rings only),
their walls as segments with outward unit normals, their corners (diffraction edges), and
two shapely STRtree spatial indices (one over the polygons for blocking tests, one over the
walls for selecting reflectors near a link).

Scenes come from :func:`city_grid` (a random synthetic street grid), from a list of
polygons (:meth:`Scene.from_polygons`) or from a GeoJSON file (:func:`scene_from_geojson`).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import shapely
from shapely.geometry import Polygon, box, shape
from shapely.geometry.polygon import orient

from radioloc.channel import compiled
from radioloc.core.backend import check_backend
from radioloc.core.errors import InputError
from radioloc.core.rng import as_generator
from radioloc.core.validation import as_positions, check_positive


@dataclass(frozen=True, eq=False)
class Scene:
    """Opaque building footprints and the derived wall / corner arrays.

    Attributes
    ----------
    polygons : tuple of shapely Polygon
        Footprints, exterior oriented counter-clockwise (holes dropped).
    walls : ndarray, shape (W, 2, 2)
        Wall segments ``[start, end]`` in metres.
    normals : ndarray, shape (W, 2)
        Outward unit normal of each wall (right-hand side of a counter-clockwise ring).
    wall_building : ndarray, shape (W,)
        Index of the polygon each wall belongs to.
    corners : ndarray, shape (C, 2)
        Polygon vertices (candidate diffracting edges).
    """

    polygons: tuple
    walls: np.ndarray = field(repr=False)
    normals: np.ndarray = field(repr=False)
    wall_building: np.ndarray = field(repr=False)
    corners: np.ndarray = field(repr=False)
    building_tree: shapely.STRtree = field(repr=False)
    wall_tree: shapely.STRtree = field(repr=False)

    @classmethod
    def from_polygons(cls, polygons: Iterable[object]) -> "Scene":
        """Build a scene from shapely polygons or coordinate lists ``[[x, y], ...]``.

        Parameters
        ----------
        polygons : iterable of Polygon or array_like (V, 2)
            Building footprints, metres (holes are dropped).

        Returns
        -------
        Scene

        Raises
        ------
        InputError
            A polygon has fewer than 3 vertices, is invalid or has no area.
        """
        polys = []
        for i, p in enumerate(polygons):
            if not isinstance(p, Polygon):
                coords = as_positions(p, f"polygons[{i}]", dims=(2,))
                if coords.ndim != 2 or coords.shape[0] < 3:
                    raise InputError(f"polygons[{i}]: need at least 3 vertices, got shape {coords.shape}")
                p = Polygon(coords)
            if p.is_empty or not p.is_valid or p.area <= 0:
                raise InputError(f"polygons[{i}]: not a valid polygon with positive area")
            polys.append(orient(Polygon(p.exterior), 1.0))
        walls, normals, owner, corners = [], [], [], []
        for b, p in enumerate(polys):
            ring = np.asarray(p.exterior.coords)[:, :2]
            a, e = ring[:-1], ring[1:]
            keep = np.linalg.norm(e - a, axis=1) > 1e-9
            a, e = a[keep], e[keep]
            d = (e - a) / np.linalg.norm(e - a, axis=1, keepdims=True)
            walls.append(np.stack([a, e], axis=1))
            normals.append(np.stack([d[:, 1], -d[:, 0]], axis=1))
            owner.append(np.full(len(a), b))
            corners.append(a)
        if polys:
            W = np.concatenate(walls)
            N = np.concatenate(normals)
            O = np.concatenate(owner)
            C = np.concatenate(corners)
        else:
            W, N, O, C = np.zeros((0, 2, 2)), np.zeros((0, 2)), np.zeros(0, int), np.zeros((0, 2))
        return cls(tuple(polys), W, N, O, C, shapely.STRtree(polys),
                   shapely.STRtree(shapely.linestrings(W)))

    def digest(self) -> str:
        """A SHA-256 of the wall coordinates (the scene's identity for caching).

        Returns
        -------
        str
            Hexadecimal digest.
        """
        return hashlib.sha256(np.round(self.walls, 6).tobytes()).hexdigest()

    def inside(self, points: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """Whether each point lies inside (or within ``margin_m`` of) a building.

        Parameters
        ----------
        points : ndarray, shape (..., 2)
            Points, metres.
        margin_m : float
            Distance to a building that counts as inside.

        Returns
        -------
        ndarray of bool, shape (...)
        """
        pts = shapely.points(np.asarray(points, float).reshape(-1, 2))
        hit = np.zeros(len(pts), bool)
        if len(self.polygons):
            idx = self.building_tree.query(pts, predicate="dwithin", distance=margin_m) if margin_m > 0 \
                else self.building_tree.query(pts, predicate="intersects")
            hit[idx[0]] = True
        return hit.reshape(np.shape(points)[:-1])

    @cached_property
    def grid(self) -> tuple:
        """Uniform grid over the walls for the compiled blocking test.

        Returns
        -------
        tuple
            ``(x0, y0, h, nx, ny, cell_start, cell_walls)``: origin, cell side, cells per
            axis, and the walls overlapping each cell (cell ``i * ny + j``) as CSR arrays.
        """
        W = self.walls
        if len(W) == 0:
            return 0.0, 0.0, 1.0, 1, 1, np.zeros(2, np.int64), np.zeros(0, np.int64)
        lo = W.reshape(-1, 2).min(axis=0) - 1.0
        hi = W.reshape(-1, 2).max(axis=0) + 1.0
        h = float(max(10.0, np.sqrt((hi - lo).prod() / max(len(W), 1))))
        nx, ny = (np.ceil((hi - lo) / h).astype(int) + 1).tolist()
        wlo = np.minimum(W[:, 0], W[:, 1]) - 1e-6
        whi = np.maximum(W[:, 0], W[:, 1]) + 1e-6
        i0 = np.clip(np.floor((wlo - lo) / h).astype(int), 0, [nx - 1, ny - 1])
        i1 = np.clip(np.floor((whi - lo) / h).astype(int), 0, [nx - 1, ny - 1])
        cells, walls = [], []
        for w in range(len(W)):          # building the index once per scene
            ii, jj = np.meshgrid(np.arange(i0[w, 0], i1[w, 0] + 1), np.arange(i0[w, 1], i1[w, 1] + 1),
                                 indexing="ij")
            cells.append((ii * ny + jj).ravel())
            walls.append(np.full(ii.size, w))
        cells = np.concatenate(cells)
        walls = np.concatenate(walls)
        order = np.lexsort((walls, cells))
        start = np.concatenate([[0], np.cumsum(np.bincount(cells, minlength=nx * ny))]).astype(np.int64)
        return float(lo[0]), float(lo[1]), h, int(nx), int(ny), start, walls[order].astype(np.int64)

    @cached_property
    def convex_buildings(self) -> tuple[np.ndarray, np.ndarray]:
        """Which footprints are convex, and each footprint's walls.

        Returns
        -------
        convex : ndarray of bool, shape (n_buildings,)
        start : ndarray of int64, shape (n_buildings + 1,)
            The walls of building ``b`` are ``start[b]:start[b + 1]`` (walls are stored
            building by building).
        """
        convex = np.array([abs(p.convex_hull.area - p.area) <= 1e-9 * max(p.area, 1.0)
                           for p in self.polygons], bool)
        start = np.concatenate([[0], np.cumsum(np.bincount(self.wall_building,
                                                           minlength=len(self.polygons)))])
        return convex, start.astype(np.int64)

    @cached_property
    def convex_grid(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The convex footprints on the grid of :attr:`grid` (for the compiled beam test).

        Returns
        -------
        bbox : ndarray, shape (n_buildings, 4)
            Envelope ``(xmin, ymin, xmax, ymax)`` of every footprint.
        start, buildings : ndarray of int64
            CSR arrays: the convex footprints with a wall overlapping cell ``c`` (numbered as
            in :attr:`grid`) are ``buildings[start[c]:start[c + 1]]``, in increasing order.
        """
        x0, y0, h, nx, ny, cs, cw = self.grid
        convex, _ = self.convex_buildings
        W = self.walls
        nb = len(self.polygons)
        bbox = np.zeros((nb, 4))
        if nb:
            bbox[:, :2] = np.minimum.reduceat(W.min(axis=1), self.convex_buildings[1][:-1])
            bbox[:, 2:] = np.maximum.reduceat(W.max(axis=1), self.convex_buildings[1][:-1])
        cell = np.repeat(np.arange(len(cs) - 1), np.diff(cs))
        b = self.wall_building[cw] if len(cw) else np.zeros(0, np.int64)
        keep = convex[b] if len(b) else np.zeros(0, bool)
        pairs = np.unique(np.stack([cell[keep], b[keep]], axis=1), axis=0) if keep.any() \
            else np.zeros((0, 2), np.int64)
        start = np.concatenate([[0], np.cumsum(np.bincount(pairs[:, 0], minlength=len(cs) - 1))])
        return bbox, start.astype(np.int64), pairs[:, 1].astype(np.int64)

    @cached_property
    def facing(self) -> tuple[np.ndarray, np.ndarray]:
        """For every wall ``p``, the walls ``w`` that can follow it in a reflection sequence.

        ``w != p`` has an end more than 1e-9 m in front of ``p`` and ``p`` has an end in
        front of ``w`` (within 1e-9 m): a ray that leaves ``p``'s front side and hits ``w``
        from the front needs both. Lists in increasing wall order.

        Returns
        -------
        start, walls : ndarray of int64
            CSR arrays: the followers of wall ``p`` are ``walls[start[p]:start[p + 1]]``.
        """
        W, N = self.walls, self.normals
        if len(W) == 0:
            return np.zeros(1, np.int64), np.zeros(0, np.int64)
        A = W[:, 0]
        # ahead[p, w]: some end of w lies in front of p
        e = np.einsum("wej,pj->pwe", W, N) - np.einsum("pj,pj->p", A, N)[:, None, None]
        ahead = (e > 1e-9).any(axis=-1)
        back = (e > -1e-9).any(axis=-1).T                   # back[p, w]: some end of p ahead of w
        ok = ahead & back
        np.fill_diagonal(ok, False)
        p, w = np.nonzero(ok)
        start = np.concatenate([[0], np.cumsum(np.bincount(p, minlength=len(W)))]).astype(np.int64)
        return start, w.astype(np.int64)

    @cached_property
    def visible(self) -> tuple[np.ndarray, np.ndarray]:
        """For every wall ``p``, the followers (:attr:`facing`) that are not hidden from it.

        Both walls are cut in two halves; a follower ``w`` is hidden when, for each of the
        four pairs of halves, one convex footprint spans the quadrilateral between the two
        halves (their convex hull, when it is a strictly convex quadrilateral with the two
        halves as opposite sides): the footprint then cuts every segment from a point of the
        one half to a point of the other, so no reflection path goes from ``p`` to ``w``
        directly. The test is the one the tracer applies to beams (:func:`_beam_blocked`),
        applied once per scene; a pair it cannot decide is kept. Lists in increasing wall
        order (a sub-list of :attr:`facing`).

        Returns
        -------
        start, walls : ndarray of int64
            CSR arrays: the visible followers of wall ``p`` are
            ``walls[start[p]:start[p + 1]]``.
        """
        fs, fw = self.facing
        if len(fw) == 0:
            return fs, fw
        x0, y0, h, nx, ny, cs, cw = self.grid
        convex, bstart = self.convex_buildings
        bbox, bcs, bcell = self.convex_grid
        keep = compiled._wall_pairs_visible(np.ascontiguousarray(self.walls[:, 0]),
                                   np.ascontiguousarray(self.walls[:, 1]), fs, fw, bbox, bstart,
                                   x0, y0, h, nx, ny, bcs, bcell, 2)
        owner = np.repeat(np.arange(len(fs) - 1), np.diff(fs))
        count = np.bincount(owner[keep], minlength=len(fs) - 1)
        start = np.concatenate([[0], np.cumsum(count)]).astype(np.int64)
        return start, fw[keep]

    def blocked(self, a: np.ndarray, b: np.ndarray, trim_m: float = 1e-3,
                backend: str = "numba") -> np.ndarray:
        """Whether the segment ``a -> b`` passes through a building.

        Both ends are pulled in by ``min(trim_m, L / 4)`` so that a segment ending on a wall
        (a reflection point) or at a corner (a diffraction edge) is not blocked by that
        wall. The segment is blocked when it meets a wall (touching counts): buildings are
        closed polygons and the segments start outside them.

        Parameters
        ----------
        a, b : ndarray, shape (..., 2)
        trim_m : float
            How far both ends are pulled in.
        backend : {"numba", "numpy"}
            The compiled grid walk (default) or the definition: shapely's STRtree
            intersection test (which also counts a segment lying wholly inside a building).

        Returns
        -------
        ndarray of bool, shape (...)
        """
        if check_backend(backend) == "numba":
            a = np.asarray(a, float)
            b = np.asarray(b, float)
            shp = np.broadcast_shapes(a.shape, b.shape)[:-1]
            a = np.ascontiguousarray(np.broadcast_to(a, shp + (2,)).reshape(-1, 2))
            b = np.ascontiguousarray(np.broadcast_to(b, shp + (2,)).reshape(-1, 2))
            if len(a) == 0 or not len(self.polygons):
                return np.zeros(shp, bool)
            x0, y0, h, nx, ny, cs, cw = self.grid
            out = compiled._blocked_batch(a, b, float(trim_m), self.walls[:, 0].copy(), self.walls[:, 1].copy(),
                                 x0, y0, h, nx, ny, cs, cw)
            return out.reshape(shp)
        a = np.asarray(a, float)
        b = np.asarray(b, float)
        shp = np.broadcast_shapes(a.shape, b.shape)[:-1]
        a = np.broadcast_to(a, shp + (2,)).reshape(-1, 2)
        b = np.broadcast_to(b, shp + (2,)).reshape(-1, 2)
        out = np.zeros(len(a), bool)
        if len(a) == 0 or not len(self.polygons):
            return out.reshape(shp)
        d = b - a
        L = np.linalg.norm(d, axis=1, keepdims=True)
        u = d / np.maximum(L, 1e-12)
        t = np.minimum(trim_m, 0.25 * L)
        lines = shapely.linestrings(np.stack([a + u * t, b - u * t], axis=1))
        idx = self.building_tree.query(lines, predicate="intersects")
        out[idx[0]] = True
        return out.reshape(shp)


def city_grid(rng: np.random.Generator | int, *, size_m: float = 1000.0, block_m: float = 90.0,
              street_m: float = 22.0, max_split: int = 2, setback_m: float = 4.0) -> Scene:
    """A random synthetic city: a grid of blocks separated by streets.

    Each ``block_m`` square block is split into 1..``max_split`` x 1..``max_split`` lots;
    every lot holds one rectangular building pulled in from the lot edges by a random
    setback in ``[0, setback_m]`` (so walls are not all aligned) and an occasional lot is left
    empty (an open square, probability 0.1).

    Parameters
    ----------
    rng : Generator or int
        Generator of the layout (an integer is taken as a seed).
    size_m : float
        Side of the square city, centred on the origin.
    block_m, street_m : float
        Block side and street width.
    max_split : int
        Largest number of lots along each side of a block.
    setback_m : float
        Largest setback of a building from its lot edges.

    Returns
    -------
    Scene
    """
    check_positive(size_m, "size_m")
    check_positive(block_m, "block_m")
    check_positive(street_m, "street_m")
    rng = as_generator(rng)
    pitch = block_m + street_m
    n = int(size_m // pitch)
    origin = -0.5 * (n * pitch - street_m)
    polys = []
    for i in range(n):               # building the scene once; not a Monte Carlo loop
        for j in range(n):
            x0 = origin + i * pitch
            y0 = origin + j * pitch
            nx, ny = rng.integers(1, max_split + 1, size=2)
            for a in range(nx):
                for b in range(ny):
                    if rng.random() < 0.1:
                        continue
                    lx0 = x0 + a * block_m / nx
                    ly0 = y0 + b * block_m / ny
                    lx1 = lx0 + block_m / nx
                    ly1 = ly0 + block_m / ny
                    s = rng.uniform(0.0, setback_m, size=4)
                    polys.append(box(lx0 + s[0], ly0 + s[1], lx1 - s[2], ly1 - s[3]))
    return Scene.from_polygons(polys)


def scene_from_geojson(path: str | Path) -> Scene:
    """Read building footprints from a GeoJSON file (Polygon / MultiPolygon features).

    Coordinates are taken as planar metres (project the file beforehand).

    Parameters
    ----------
    path : str or Path
        The GeoJSON file (a FeatureCollection, a Feature or a geometry).

    Returns
    -------
    Scene

    Raises
    ------
    InputError
        The file is unreadable or holds no polygon.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"geojson {path}: cannot read ({exc})") from None
    feats: Sequence = data.get("features", [data]) if isinstance(data, dict) else []
    polys = []
    for k, f in enumerate(feats):
        geom = f.get("geometry", f) if isinstance(f, dict) else None
        try:
            g = shape(geom)
        except Exception as exc:  # shapely raises several types on malformed geometry
            raise InputError(f"geojson {path}: feature {k} is not a geometry ({exc})") from None
        if g.geom_type == "Polygon":
            polys.append(g)
        elif g.geom_type == "MultiPolygon":
            polys.extend(g.geoms)
        else:
            raise InputError(f"geojson {path}: feature {k} is a {g.geom_type}, expected Polygon")
    if not polys:
        raise InputError(f"geojson {path}: no polygon features")
    return Scene.from_polygons(polys)


def street_positions(scene: Scene, n: int, rng: np.random.Generator, *, half_width_m: float,
                     clearance_m: float = 3.0, max_tries: int = 10_000) -> np.ndarray:
    """``n`` random points in ``[-half_width_m, half_width_m]^2`` outside every building.

    Points closer than ``clearance_m`` to a building are rejected (vectorised rejection
    sampling in batches).

    Parameters
    ----------
    scene : Scene
    n : int
        Number of points.
    rng : Generator
    half_width_m : float
        Half side of the sampling square, centred on the origin.
    clearance_m : float
        Smallest distance to a building.
    max_tries : int
        Candidate points drawn at most.

    Returns
    -------
    ndarray, shape (n, 2)

    Raises
    ------
    InputError
        Fewer than ``n`` free points were found.
    """
    out = np.zeros((0, 2))
    for _ in range(max_tries // 256 + 1):
        cand = rng.uniform(-half_width_m, half_width_m, size=(256, 2))
        out = np.concatenate([out, cand[~scene.inside(cand, clearance_m)]])
        if len(out) >= n:
            return out[:n]
    raise InputError(f"street_positions: found only {len(out)} of {n} free points")


# ---------------------------------------------------------------- compiled tracer
