"""Exact signed distance to a closed triangle mesh, compiled, with a narrow-band cell index.

Why
---
BCPS asks for about a million signed distances per capture, all within a few millimetres
of the reference surface. A general query structure (Open3D's Embree scene: ~0.4 us per
query on 2 cores even for a 12-triangle cube) spends its time walking a hierarchy and
casting a ray for the sign. Near the surface the closest triangle is one of a handful
known in advance, so a regular grid that lists, per cell, the triangles that can be the
closest to any point of the cell answers with a few point-triangle distances.

Method
------
Cells of edge ``h`` (circumradius ``r = h * sqrt(3) / 2``) cover the mesh's box grown by
the band ``B``. With ``D(c)`` the exact distance from a cell centre ``c`` to the mesh, the
cell lists every triangle ``T`` with ``dist(c, T) <= D(c) + 2 r``: for any point ``p`` of
the cell, its closest triangle ``T*`` satisfies ``dist(c, T*) <= dist(p, T*) + r <=
dist(p, T_c) + r <= D(c) + 2 r`` (``T_c`` the closest to ``c``), so the list always holds
it and the answer is exact. Only cells with ``D(c) <= B`` get a list (the *band*); a query
in any other cell, or outside the grid, is answered by the fallback (Open3D), so every
query gets the exact distance. Points with ``|sd| <= B - r`` always fall in the band.

The sign is that of ``(p - q) . n`` with ``q`` the closest point and ``n`` the
*angle-weighted pseudo-normal* of the feature ``q`` lies on (face, edge or vertex;
Baerentzen and Aanaes, 2005), which is exact for a closed, consistently oriented mesh.
Distances are computed in float64 (Open3D works in float32: ~3e-6 mm at 30 mm).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numba
import numpy as np

__all__ = ["MeshDistance"]

#: Largest number of (cell, triangle) pairs examined when building the index; the band
#: is narrowed until the estimate fits (build time ~10 ns per pair on one core).
PAIR_BUDGET = 40_000_000
#: Bands tried, widest first, mm (queries with |sd| <= B - r are always in the band).
BANDS_MM = (8.0, 4.0, 2.5, 1.5, 1.0)

# OpenMP (libgomp): see inspector.kernels.hull_jit. This module is imported lazily
# (Reference.distance), so ``import inspector`` stays free of Numba.
numba.config.THREADING_LAYER = "omp"  # type: ignore[attr-defined]  # set at run time

@numba.njit(cache=True, inline="always")
def closest(px, py, pz, tri, t):
    """Squared distance from p to triangle t and the feature of the closest point
    (0 face, 1-3 vertices a, b, c, 4-6 edges ab, bc, ca) and that point."""
    ax, ay, az = tri[t, 0], tri[t, 1], tri[t, 2]
    bx, by, bz = tri[t, 3], tri[t, 4], tri[t, 5]
    cx, cy, cz = tri[t, 6], tri[t, 7], tri[t, 8]
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        qx, qy, qz, f = ax, ay, az, 1
    else:
        bpx, bpy, bpz = px - bx, py - by, pz - bz
        d3 = abx * bpx + aby * bpy + abz * bpz
        d4 = acx * bpx + acy * bpy + acz * bpz
        if d3 >= 0.0 and d4 <= d3:
            qx, qy, qz, f = bx, by, bz, 2
        else:
            vc = d1 * d4 - d3 * d2
            if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
                v = d1 / (d1 - d3)
                qx, qy, qz, f = ax + v * abx, ay + v * aby, az + v * abz, 4
            else:
                cpx, cpy, cpz = px - cx, py - cy, pz - cz
                d5 = abx * cpx + aby * cpy + abz * cpz
                d6 = acx * cpx + acy * cpy + acz * cpz
                if d6 >= 0.0 and d5 <= d6:
                    qx, qy, qz, f = cx, cy, cz, 3
                else:
                    vb = d5 * d2 - d1 * d6
                    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
                        w = d2 / (d2 - d6)
                        qx, qy, qz, f = ax + w * acx, ay + w * acy, az + w * acz, 6
                    else:
                        va = d3 * d6 - d5 * d4
                        if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
                            w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
                            qx, qy, qz, f = bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz), 5
                        else:
                            den = va + vb + vc
                            if den != 0.0:
                                v = vb / den
                                w = vc / den
                            else:  # degenerate triangle: its first vertex
                                v = 0.0
                                w = 0.0
                            qx = ax + abx * v + acx * w
                            qy = ay + aby * v + acy * w
                            qz = az + abz * v + acz * w
                            f = 0
    dx, dy, dz = px - qx, py - qy, pz - qz
    return dx * dx + dy * dy + dz * dz, f, dx, dy, dz

@numba.njit(cache=True, inline="always")
def nearest(px, py, pz, tri, lo, h, dims, start, items, dc):
    """Closest triangle of one point (mesh frame): ``(t, feature, dx, dy, dz, d2)`` with
    ``(dx, dy, dz) = p - q`` (``q`` the closest point); ``t = -1`` when not in the band.

    The cell's candidates are sorted by their distance ``dc`` to the cell centre ``c``;
    ``dist(p, T) >= dc - |p - c|`` ends the scan once no later candidate can be closer."""
    i = int(math.floor((px - lo[0]) / h))
    j = int(math.floor((py - lo[1]) / h))
    k = int(math.floor((pz - lo[2]) / h))
    if i < 0 or j < 0 or k < 0 or i >= dims[0] or j >= dims[1] or k >= dims[2]:
        return -1, 0, 0.0, 0.0, 0.0, np.inf
    cell = (i * dims[1] + j) * dims[2] + k
    s = start[cell]
    e = start[cell + 1]
    if e <= s:
        return -1, 0, 0.0, 0.0, 0.0, np.inf
    ex = px - (lo[0] + (i + 0.5) * h)
    ey = py - (lo[1] + (j + 0.5) * h)
    ez = pz - (lo[2] + (k + 0.5) * h)
    off = math.sqrt(ex * ex + ey * ey + ez * ez)
    best = np.inf
    bestd = np.inf
    bt = 0
    bf = 0
    bx = 0.0
    by = 0.0
    bz = 0.0
    for m in range(s, e):
        if dc[m] - off > bestd:
            break
        t = items[m]
        d2, f, dx, dy, dz = closest(px, py, pz, tri, t)
        if d2 < best:
            best = d2
            bestd = math.sqrt(d2) * (1.0 + 1e-12)
            bt = t
            bf = f
            bx = dx
            by = dy
            bz = dz
    return bt, bf, bx, by, bz, best


@numba.njit(cache=True, inline="always")
def signed_at(px, py, pz, tri, pn, lo, h, dims, start, items, dc):
    """Signed distance of one point (mesh frame), NaN when not in the band."""
    t, f, dx, dy, dz, d2 = nearest(px, py, pz, tri, lo, h, dims, start, items, dc)
    if t < 0:
        return np.nan
    d = math.sqrt(d2)
    side = dx * pn[t, f, 0] + dy * pn[t, f, 1] + dz * pn[t, f, 2]
    return -d if side < 0.0 else d


@numba.njit(parallel=True, cache=True, nogil=True)
def query(P, tri, pn, lo, h, dims, start, items, dc, out):
    for n in numba.prange(P.shape[0]):
        out[n] = signed_at(P[n, 0], P[n, 1], P[n, 2], tri, pn, lo, h, dims, start, items, dc)


@numba.njit(cache=True, inline="always")
def closest_one(n, P, tri, lo, h, dims, start, items, dc, out_q, out_t):
    """Point ``n``'s closest point and triangle into ``out_q``, ``out_t``."""
    t, _, dx, dy, dz, _ = nearest(P[n, 0], P[n, 1], P[n, 2], tri, lo, h, dims, start, items, dc)
    out_t[n] = t
    if t >= 0:
        out_q[n, 0] = P[n, 0] - dx
        out_q[n, 1] = P[n, 1] - dy
        out_q[n, 2] = P[n, 2] - dz


@numba.njit(parallel=True, cache=True, nogil=True)
def closest_query(P, tri, pn, lo, h, dims, start, items, dc, out_q, out_t):
    """Closest points (N, 3) and their triangles (N,) (-1: not in the band)."""
    for n in numba.prange(P.shape[0]):
        closest_one(n, P, tri, lo, h, dims, start, items, dc, out_q, out_t)


@numba.njit(parallel=True, cache=True, nogil=True)
def residual_query(Q, centre, tri, pn, lo, h, dims, start, items, dc, fnormals, out_c, out_n, out_r, out_t):
    """Points ``Q`` (N, 3) of a frame offset by ``centre`` from the mesh's: their closest
    points in that frame, their triangles' normals, the distances and the triangles (-1: not
    in the band, the rest of the row not written), with the same operations, in the same
    order, as :meth:`MeshDistance.closest` and numpy after it."""
    for i in numba.prange(Q.shape[0]):
        px = Q[i, 0] + centre[0]
        py = Q[i, 1] + centre[1]
        pz = Q[i, 2] + centre[2]
        t, _, dx, dy, dz, _ = nearest(px, py, pz, tri, lo, h, dims, start, items, dc)
        out_t[i] = t
        if t < 0:
            continue
        c0 = (px - dx) - centre[0]
        c1 = (py - dy) - centre[1]
        c2 = (pz - dz) - centre[2]
        out_c[i, 0] = c0
        out_c[i, 1] = c1
        out_c[i, 2] = c2
        out_n[i, 0] = fnormals[t, 0]
        out_n[i, 1] = fnormals[t, 1]
        out_n[i, 2] = fnormals[t, 2]
        e0 = Q[i, 0] - c0
        e1 = Q[i, 1] - c1
        e2 = Q[i, 2] - c2
        out_r[i] = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)


@numba.njit(parallel=True, cache=True, nogil=True)
def gradient_query(P, tri, pn, lo, h, dims, start, items, dc, out_sd, out_c, out_g, out_t):
    """Points ``P`` (N, 3): signed distances, closest points, the distance's unit gradient and
    the triangles (-1: not in the band, the rest of the row not written), with the same
    operations as :func:`query`, :func:`closest_query` and the numpy of
    :meth:`MeshDistance.gradients` after them."""
    for i in numba.prange(P.shape[0]):
        px = P[i, 0]
        py = P[i, 1]
        pz = P[i, 2]
        t, f, dx, dy, dz, d2 = nearest(px, py, pz, tri, lo, h, dims, start, items, dc)
        out_t[i] = t
        if t < 0:
            continue
        d = math.sqrt(d2)
        side = dx * pn[t, f, 0] + dy * pn[t, f, 1] + dz * pn[t, f, 2]
        sd = -d if side < 0.0 else d
        c0 = px - dx
        c1 = py - dy
        c2 = pz - dz
        out_sd[i] = sd
        out_c[i, 0] = c0
        out_c[i, 1] = c1
        out_c[i, 2] = c2
        g0 = px - c0
        g1 = py - c1
        g2 = pz - c2
        if math.sqrt(g0 * g0 + g1 * g1 + g2 * g2) > 1e-9:
            out_g[i, 0] = g0 / sd
            out_g[i, 1] = g1 / sd
            out_g[i, 2] = g2 / sd
        else:  # on the surface: its face's normal
            out_g[i, 0] = pn[t, 0, 0]
            out_g[i, 1] = pn[t, 0, 1]
            out_g[i, 2] = pn[t, 0, 2]


@numba.njit(cache=True, nogil=True)
def closest_query_serial(P, tri, pn, lo, h, dims, start, items, dc, out_q, out_t):
    """:func:`closest_query` on the calling thread only. After a parallel region OpenMP's
    workers spin ~10 ms of CPU waiting for the next one (libgomp's default); a caller with one
    small query (the characteristics' 15000 points: 2.6 ms here against 1.2 ms on two
    threads) leaves that CPU to the rest of the cell."""
    for n in range(P.shape[0]):
        closest_one(n, P, tri, lo, h, dims, start, items, dc, out_q, out_t)


@numba.njit(cache=True, inline="always")
def cell_range(tb, t, reach, lo, h, dims):
    """Index ranges ``j0..j1``, ``k0..k1`` (inclusive) of the cells whose centre may lie
    within ``reach`` of triangle ``t``'s box along y and z."""
    j0 = max(int(math.floor((tb[t, 1] - reach - lo[1]) / h - 0.5)), 0)
    j1 = min(int(math.ceil((tb[t, 4] + reach - lo[1]) / h - 0.5)), dims[1] - 1)
    k0 = max(int(math.floor((tb[t, 2] - reach - lo[2]) / h - 0.5)), 0)
    k1 = min(int(math.ceil((tb[t, 5] + reach - lo[2]) / h - 0.5)), dims[2] - 1)
    return j0, j1, k0, k1


@numba.njit(cache=True, inline="always")
def box_dist2(x, y, z, tb, t):
    dx = max(tb[t, 0] - x, 0.0, x - tb[t, 3])
    dy = max(tb[t, 1] - y, 0.0, y - tb[t, 4])
    dz = max(tb[t, 2] - z, 0.0, z - tb[t, 5])
    return dx * dx + dy * dy + dz * dz

@numba.njit(parallel=True, cache=True, nogil=True)
def build_dmin(tri, tb, lo, h, dims, reach, dmin):
    """dmin[cell] = distance from the cell centre to the mesh, for cells within
    ``reach`` of some triangle (others stay inf). Parallel over x-slabs."""
    F = tri.shape[0]
    for i in numba.prange(dims[0]):
        x = lo[0] + (i + 0.5) * h
        for t in range(F):
            if x < tb[t, 0] - reach or x > tb[t, 3] + reach:
                continue
            j0, j1, k0, k1 = cell_range(tb, t, reach, lo, h, dims)
            for j in range(j0, j1 + 1):
                y = lo[1] + (j + 0.5) * h
                for k in range(k0, k1 + 1):
                    z = lo[2] + (k + 0.5) * h
                    cell = (i * dims[1] + j) * dims[2] + k
                    cur = dmin[cell]
                    b2 = box_dist2(x, y, z, tb, t)
                    if b2 > reach * reach or b2 >= cur * cur:
                        continue
                    d2, _, _, _, _ = closest(x, y, z, tri, t)
                    d = math.sqrt(d2)
                    if d < cur:
                        dmin[cell] = d
    return dmin

@numba.njit(parallel=True, cache=True, nogil=True)
def build_lists(tri, tb, lo, h, dims, band, two_r, dmin, count, start, items, dc, fill):
    """``fill`` False: count[cell] = candidates; True: write them at start[cell]."""
    F = tri.shape[0]
    reach = band + two_r
    for i in numba.prange(dims[0]):
        x = lo[0] + (i + 0.5) * h
        for t in range(F):
            if x < tb[t, 0] - reach or x > tb[t, 3] + reach:
                continue
            j0, j1, k0, k1 = cell_range(tb, t, reach, lo, h, dims)
            for j in range(j0, j1 + 1):
                y = lo[1] + (j + 0.5) * h
                for k in range(k0, k1 + 1):
                    cell = (i * dims[1] + j) * dims[2] + k
                    dm = dmin[cell]
                    if not (dm <= band):
                        continue
                    lim = dm + two_r
                    z = lo[2] + (k + 0.5) * h
                    if box_dist2(x, y, z, tb, t) > lim * lim:
                        continue
                    d2, _, _, _, _ = closest(x, y, z, tri, t)
                    if d2 <= lim * lim * (1.0 + 1e-12) + 1e-18:
                        if fill:
                            items[start[cell] + count[cell]] = t
                            dc[start[cell] + count[cell]] = math.sqrt(d2)
                        count[cell] += 1

@numba.njit(parallel=True, cache=True, nogil=True)
def sort_lists(start, items, dc):
    """Sort each cell's candidates by their distance to the cell centre."""
    for cell in numba.prange(start.shape[0] - 1):
        s = start[cell]
        e = start[cell + 1]
        if e - s > 1:
            o = np.argsort(dc[s:e])
            it = items[s:e][o]
            d = dc[s:e][o]
            items[s:e] = it
            dc[s:e] = d


def _pseudo_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Angle-weighted pseudo-normals per triangle feature, (F, 7, 3): face, vertices a, b,
    c, edges ab, bc, ca (unnormalised: only their direction is used)."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    ln = np.linalg.norm(n, axis=1)
    nf = np.divide(n, ln[:, None], out=np.zeros_like(n), where=ln[:, None] > 0)
    # vertex normals: sum of incident face normals weighted by the incident angle
    vn = np.zeros_like(V)
    for k in range(3):
        p = V[F[:, k]]
        e1 = V[F[:, (k + 1) % 3]] - p
        e2 = V[F[:, (k + 2) % 3]] - p
        den = np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
        cosang = np.divide(np.einsum("ij,ij->i", e1, e2), den, out=np.ones(len(F)), where=den > 0)
        ang = np.arccos(np.clip(cosang, -1.0, 1.0))
        np.add.at(vn, F[:, k], nf * ang[:, None])
    # edge normals: sum of the two faces' normals
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])  # (3F, 2): ab, bc, ca
    key = np.sort(edges, axis=1)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    en = np.zeros((inv.max() + 1, 3))
    np.add.at(en, inv, np.tile(nf, (3, 1)))
    nF = len(F)
    pn = np.empty((nF, 7, 3))
    pn[:, 0] = nf
    pn[:, 1:4] = vn[F]
    pn[:, 4] = en[inv[:nF]]
    pn[:, 5] = en[inv[nF : 2 * nF]]
    pn[:, 6] = en[inv[2 * nF :]]
    return pn


class MeshDistance:
    """Signed distance to a closed, outward-oriented triangle mesh (mm, negative inside).

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    fallback : callable, optional
        ``(N, 3) -> (N,)`` exact signed distance used for queries outside the band (e.g.
        Open3D's); when None those queries get NaN.
    fallback_closest : callable, optional
        ``(N, 3) -> (closest points (N, 3), triangle indices (N,))`` for
        :meth:`closest` outside the band; when None those get NaN and -1.
    cell_mm : float, optional
        Cell edge of the index (default: about 1/60 of the mesh's largest extent,
        within [0.25, 1] mm).
    band_mm : float, optional
        Band width (default: the widest of :data:`BANDS_MM` that fits the pair budget).

    Attributes
    ----------
    tri : (F, 9) float
        Triangle corners a, b, c.
    pn : (F, 7, 3) float
        Pseudo-normals per feature (face, vertices a, b, c, edges ab, bc, ca); ``pn[:, 0]``
        are the triangles' unit normals.
    band_mm, cell_mm : float
    n_cells : int
        Cells of the grid; ``n_band`` of them have a candidate list, ``n_items`` entries in all.
    """

    def __init__(
        self,
        vertices: np.ndarray,
        faces: np.ndarray,
        *,
        fallback: Callable[[np.ndarray], np.ndarray] | None = None,
        fallback_closest: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None,
        cell_mm: float | None = None,
        band_mm: float | None = None,
    ) -> None:
        V = np.ascontiguousarray(vertices, dtype=np.float64)
        F = np.ascontiguousarray(faces, dtype=np.int64)
        if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
            raise ValueError("MeshDistance needs (V, 3) vertices and a non-empty (F, 3) face array")
        self.fallback = fallback
        self.fallback_closest = fallback_closest
        self.tri = np.ascontiguousarray(V[F].reshape(-1, 9))
        self.pn = np.ascontiguousarray(_pseudo_normals(V, F))
        tb = np.concatenate([V[F].min(axis=1), V[F].max(axis=1)], axis=1)
        self._tb = np.ascontiguousarray(tb)
        vlo, vhi = V.min(axis=0), V.max(axis=0)
        ext = float(np.max(vhi - vlo))
        h = float(cell_mm) if cell_mm else min(max(ext / 60.0, 0.25), 1.0)
        r2 = math.sqrt(3.0) * h  # 2 r
        band = BANDS_MM[-1] if band_mm is None else band_mm
        if band_mm is None:
            size = tb[:, 3:] - tb[:, :3]
            for band in BANDS_MM:
                pairs = float(np.sum(np.prod(size + 2.0 * (band + r2) + h, axis=1))) / h**3
                if pairs <= PAIR_BUDGET:
                    break
        self.band_mm = float(band)
        self.cell_mm = h
        lo = vlo - self.band_mm - h
        dims = np.ceil((vhi + self.band_mm + h - lo) / h).astype(np.int64)
        self._lo = lo
        self._dims = dims
        n = int(np.prod(dims))
        dmin = np.full(n, np.inf)
        build_dmin(self.tri, self._tb, lo, h, dims, self.band_mm + r2, dmin)
        count = np.zeros(n, dtype=np.int64)
        start = np.zeros(n + 1, dtype=np.int64)
        items = np.zeros(0, dtype=np.int32)
        dc = np.zeros(0)
        build_lists(self.tri, self._tb, lo, h, dims, self.band_mm, r2, dmin, count, start, items, dc, False)
        np.cumsum(count, out=start[1:])
        items = np.empty(int(start[-1]), dtype=np.int32)
        dc = np.empty(int(start[-1]))
        count[:] = 0
        build_lists(self.tri, self._tb, lo, h, dims, self.band_mm, r2, dmin, count, start, items, dc, True)
        sort_lists(start, items, dc)
        self._start = start
        self._items = items
        self._dc = dc
        self.n_cells = n
        self.n_band = int(np.count_nonzero(count))
        self.n_items = int(len(items))

    def args(self) -> tuple:
        """Arrays for :func:`signed_at` (inlinable in other kernels): tri, pn, lo, h, dims, start, items, dc."""
        return (self.tri, self.pn, self._lo, self.cell_mm, self._dims, self._start, self._items, self._dc)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Signed distances (N,) mm of points (N, 3) mm in the mesh's frame."""
        out = self.near(points)
        miss = np.isnan(out)
        if self.fallback is not None and miss.any():
            out[miss] = self.fallback(np.asarray(points, dtype=np.float64).reshape(-1, 3)[miss])
        return out

    def near(self, points: np.ndarray) -> np.ndarray:
        """Signed distances (N,) mm of points (N, 3) mm, NaN beyond the band (no fallback):
        for callers that only care about points close to the surface."""
        P = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        out = np.empty(len(P))
        if len(P):
            query(P, *self.args(), out)  # type: ignore[call-arg]  # a Numba dispatcher
        return out

    def residuals(self, points: np.ndarray, centre: np.ndarray,
                  face_normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For points (N, 3) mm of a frame whose origin is at ``centre`` (3,) in the mesh's
        (the mesh's frame minus ``centre``): their closest surface points (N, 3) in that
        frame, ``face_normals[triangle]`` (N, 3) of the triangles they lie on, and their
        distances (N,) mm; one compiled pass (the fits' Gauss-Newton steps ask this of
        every point, 45 times an inspection), the same numbers as :meth:`closest` and the
        numpy after it. Beyond the band the fallback answers; without one, NaN (and the
        last face's normal, as indexing by -1 gives)."""
        Q = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        centre = np.ascontiguousarray(centre, dtype=np.float64)
        c = np.full((len(Q), 3), np.nan)
        n = np.empty((len(Q), 3))
        r = np.full(len(Q), np.nan)
        tid = np.empty(len(Q), dtype=np.int64)
        if len(Q):
            fn = np.ascontiguousarray(face_normals, dtype=np.float64)
            residual_query(Q, centre, *self.args(), fn, c, n, r, tid)  # type: ignore[call-arg]  # a Numba dispatcher
            miss = tid < 0
            if miss.any():
                if self.fallback_closest is not None:
                    q, tid[miss] = self.fallback_closest(Q[miss] + centre)
                    c[miss] = q - centre
                    d = Q[miss] - c[miss]
                    r[miss] = np.sqrt(np.sum(d * d, axis=1))
                n[miss] = face_normals[tid[miss]]
        return c, n, r

    def gradients(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """For points (N, 3) mm: their signed distances (N,), closest surface points (N, 3),
        the distance's unit gradient (N, 3: ``(p - c) / sd``, the face's normal on the
        surface) and triangles (N,) in one compiled pass (the size fit asks this of every
        point at each step), the same numbers as ``self(p)``, :meth:`closest` and numpy after
        them. Beyond the band the fallbacks answer; without them, NaN and triangle -1."""
        P = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        sd = np.full(len(P), np.nan)
        c = np.full((len(P), 3), np.nan)
        g = np.full((len(P), 3), np.nan)
        tid = np.full(len(P), -1, dtype=np.int64)
        if len(P):
            gradient_query(P, *self.args(), sd, c, g, tid)  # type: ignore[call-arg]  # a Numba dispatcher
            miss = tid < 0
            if miss.any() and self.fallback is not None:
                sd[miss] = self.fallback(P[miss])
            if miss.any() and self.fallback_closest is not None:
                c[miss], tid[miss] = self.fallback_closest(P[miss])
                gm = P[miss] - c[miss]
                far = np.linalg.norm(gm, axis=1) > 1e-9
                g[miss] = np.where(far[:, None], gm / np.where(far, sd[miss], 1.0)[:, None],
                                   self.pn[np.maximum(tid[miss], 0), 0])
        return sd, c, g, tid

    def closest(self, points: np.ndarray, *, parallel: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Closest surface points (N, 3) and their triangles (N,) of points (N, 3), mesh frame;
        ``parallel=False``: on the calling thread only (:func:`closest_query_serial`)."""
        P = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        q = np.full((len(P), 3), np.nan)
        tid = np.full(len(P), -1, dtype=np.int64)
        if len(P):
            query_fn = closest_query if parallel else closest_query_serial
            query_fn(P, *self.args(), q, tid)  # type: ignore[call-arg]  # a Numba dispatcher
            miss = tid < 0
            if self.fallback_closest is not None and miss.any():
                q[miss], tid[miss] = self.fallback_closest(P[miss])
        return q, tid
