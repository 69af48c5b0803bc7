"""The BCPS points of a reference's sharp straight edges, moved onto the edges the rays show.

:func:`plane_edges` finds, once per reference, every convex edge where two plane features
meet (the line where their nominal planes cross, and the stretches of it the mesh's shared
triangle edges cover). :func:`snap_to_edges` takes one part's BCPS points near each such
edge, fits the edge to their contour rays (:func:`inspector.kernels.edges.fit_lines_to_rays`)
and moves each point along its ray to where the ray grazes the fitted edge: a point there
lies on both planes, so it belongs to both. Why: a silhouette shows a plane only along its
edges, and the visual hull places those points up to tens of microns outside the face
(``docs/characteristics.md``, "Why the cube missed"); the rays themselves are exact.

Concave edges are left alone (no contour ray touches one), and so are the ends of each edge
(a ray there may graze the neighbouring edge or the corner).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from inspector.kernels.edges import RayLines, closest_on_rays, fit_lines_to_rays, line_ray_distances, lines_jackknife
from inspector.kernels.features import Feature, mesh_topology
from inspector.kernels.fits import group_moments, planes_without

__all__ = ["EdgeSnap", "PlaneEdge", "plane_edges", "replica_planes", "snap_to_edges"]

#: Two planes meeting at less than this angle between their normals make no sharp edge.
MIN_EDGE_ANGLE_DEG = 30.0
#: Points within this many bands of an edge's end are not snapped (the corner's rays).
END_MARGIN_BANDS = 2.0
#: Rays an edge needs beyond the line's four parameters.
MIN_RAYS = 20
#: Rays an edge's line is fitted to, and points that represent it, at most (see
#: :func:`snap_to_edges`).
FIT_RAYS = 120
#: Robust trim of the rays farther from the fitted edge than this many robust standard
#: deviations (a ray grazing something else near the edge), twice.
TRIM_SIGMAS = 3.5


@dataclass(frozen=True)
class PlaneEdge:
    """A convex straight edge between two plane features of the reference.

    Attributes
    ----------
    a, b : str
        The two plane features' ids (``a < b``).
    point, direction : (3,) float
        The line where the nominal planes cross (reference frame, mm; unit direction).
    spans : (S, 2) float
        The stretches of the line the mesh's edge covers, as positions along ``direction``
        from ``point``, mm.
    positions : (int, int)
        The two features' positions in the sequence :func:`plane_edges` was given.
    """

    a: str
    b: str
    point: np.ndarray
    direction: np.ndarray
    spans: np.ndarray
    positions: tuple[int, int]


def plane_edges(vertices: np.ndarray, faces: np.ndarray, features: Sequence[Feature]) -> tuple[PlaneEdge, ...]:
    """The convex edges between the reference's plane features.

    Parameters
    ----------
    vertices : (V, 3) float
        The reference mesh, mm.
    faces : (F, 3) int
    features : sequence of Feature
        Its features (:func:`inspector.kernels.features.find_features`).

    Returns
    -------
    tuple of PlaneEdge
        Sorted by the features' ids.
    """
    V, Fm, normals, _, pairs = mesh_topology(vertices, faces)
    at = {f.id: k for k, f in enumerate(features)}
    planes = [f for f in features if f.kind == "plane"]
    owner = np.full(len(Fm), -1, np.int64)
    for k, f in enumerate(planes):
        owner[f.faces] = k
    oa, ob = owner[pairs[:, 0]], owner[pairs[:, 1]]
    sharp = np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]]) < np.cos(np.radians(MIN_EDGE_ANGLE_DEG))
    cross = (oa >= 0) & (ob >= 0) & (oa != ob) & sharp
    found: dict[tuple[int, int], list[tuple[np.ndarray, np.ndarray]]] = {}
    for (t1, t2), ka, kb in zip(pairs[cross], oa[cross], ob[cross]):
        shared = np.intersect1d(Fm[t1], Fm[t2])
        if len(shared) != 2:
            continue
        # Convex when the other triangle lies behind this one's plane.
        other = V[Fm[t2]].mean(axis=0) - V[shared[0]]
        if float(other @ normals[t1]) >= -1e-9:
            continue
        key = (int(min(ka, kb)), int(max(ka, kb)))
        found.setdefault(key, []).append((V[shared[0]], V[shared[1]]))
    out = []
    for (ka, kb), segs in found.items():
        fa, fb = planes[ka], planes[kb]
        na, nb = np.asarray(fa.nominal["normal"], float), np.asarray(fb.nominal["normal"], float)
        u = np.cross(na, nb)
        if np.linalg.norm(u) < np.sin(np.radians(MIN_EDGE_ANGLE_DEG)):
            continue
        u /= np.linalg.norm(u)
        # The point of both planes nearest the edge's first vertex.
        A = np.stack([na, nb, u])
        rhs = np.array([na @ np.asarray(fa.nominal["point"], float), nb @ np.asarray(fb.nominal["point"], float),
                        u @ segs[0][0]])
        p = np.linalg.solve(A, rhs)
        spans = np.sort(np.array([[(s - p) @ u, (e - p) @ u] for s, e in segs]), axis=1)
        a, b = sorted((fa.id, fb.id))
        out.append(PlaneEdge(a, b, p, u, _merged(spans), (at[a], at[b])))
    return tuple(sorted(out, key=lambda e: (e.a, e.b)))


def _merged(spans: np.ndarray) -> np.ndarray:
    spans = spans[np.argsort(spans[:, 0])]
    merged = [spans[0].copy()]
    for lo, hi in spans[1:]:
        if lo <= merged[-1][1] + 1e-6:
            merged[-1][1] = max(merged[-1][1], hi)
        else:
            merged.append(np.array([lo, hi]))
    return np.asarray(merged)


@dataclass(frozen=True)
class EdgeSnap:
    """Points moved onto the edges their rays graze.

    Attributes
    ----------
    index : (K,) int
        Which points moved.
    points : (K, 3) float
        Where to, mm.
    pairs : tuple of (str, str)
        The two features' ids of each fitted edge (``edge`` indexes it).
    edge : (K,) int
        Which fitted edge (position in ``lines``) each moved point is on.
    along : (K,) float
        Its position along that edge's fitted line, mm.
    lines : tuple of (point (3,), direction (3,))
        The fitted edges.
    jackknife : tuple of dict
        Per fitted edge: camera -> the line fitted without that camera's rays, or None when
        the other cameras do not fix it (:func:`inspector.kernels.edges.lines_jackknife`;
        empty without groups). A camera not in the dict gave the edge no ray.
    dropped : (D,) int
        The points of a fitted edge that were not moved: the moved points of that edge
        represent them (:data:`FIT_RAYS` per edge at most).
    """

    index: np.ndarray
    points: np.ndarray
    pairs: tuple[tuple[str, str], ...]
    edge: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))
    along: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    lines: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
    jackknife: tuple[dict[object, tuple[np.ndarray, np.ndarray] | None], ...] = ()
    dropped: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def edges(self) -> int:
        """How many edges were fitted."""
        return len(self.pairs)


def snap_to_edges(points: np.ndarray, origins: np.ndarray, edges: Sequence[PlaneEdge], band_mm: float, *,
                  groups: np.ndarray | None = None, nearest: np.ndarray | None = None) -> EdgeSnap:
    """Move the points near each edge onto the edge their contour rays show.

    Parameters
    ----------
    points : (N, 3) float
        BCPS points in the reference frame, mm; each lies on its contour ray.
    origins : (N, 3) float
        The centre of the camera whose ray gave each point, same frame, mm.
    edges : sequence of PlaneEdge
        The reference's (:func:`plane_edges`).
    band_mm : float
        A point within ``2 * band_mm`` of a CAD edge is a candidate (the part's size may
        differ from the CAD's); the rays the fitted edge does not explain are trimmed.
    groups : (N,) int, optional
        Each point's camera: an edge seen by fewer than two cameras is not fitted (their
        rays all lie in one plane, which does not fix a line).
    nearest : (N,) int, optional
        The position (:attr:`PlaneEdge.positions`) of the feature whose reference triangle
        is nearest each point (-1: none): only the points nearest one of an edge's two
        planes are its candidates. None: every point is a candidate of every edge.

    Returns
    -------
    EdgeSnap
        A point near two edges (a corner) is not moved.
    """
    P = np.asarray(points, float).reshape(-1, 3)
    O = np.asarray(origins, float).reshape(-1, 3)
    reach = 2.0 * band_mm
    margin = END_MARGIN_BANDS * band_mm
    candidates, hits = _candidates(P, edges, reach, margin, nearest)
    sets = [(k, idx[hits[idx] == 1]) for k, idx in candidates]
    sets = [(k, idx) for k, idx in sets
            if len(idx) >= MIN_RAYS and (groups is None or groups[idx].min() != groups[idx].max())]
    if not sets:
        return EdgeSnap(np.zeros(0, np.int64), np.zeros((0, 3)), ())
    mine = [edges[k] for k, _ in sets]
    every = np.concatenate([idx for _, idx in sets])
    every_li = np.concatenate([np.full(len(idx), j) for j, (_, idx) in enumerate(sets)])
    # Each edge is fitted to, and represented by, at most FIT_RAYS of its rays, evenly spread:
    # a line's four parameters from a thousand rays or from a hundred differ by a fraction of
    # a micron, and a plane through its edges is as well fixed by a hundred points on each.
    # The edge's other points are left out (``dropped``), not kept where the hull placed them
    # (a few of them graze nothing: their planes' points near the edge are its rays' anyway).
    n = np.bincount(every_li, minlength=len(mine))
    rank = np.arange(len(every)) - np.concatenate([[0], np.cumsum(n)[:-1]])[every_li]
    sub = rank % np.maximum(1, -(-n // FIT_RAYS))[every_li] == 0
    ray, li = every[sub], every_li[sub]
    Oe = O[ray]
    De = P[ray] - Oe
    De /= np.linalg.norm(De, axis=1)[:, None]
    lines, keep = _fit_edges(Oe, De, li, mine)
    good = lines.determined & (np.bincount(li[keep], minlength=len(mine)) >= MIN_RAYS) & \
        np.array([_near(lines.point[j], lines.direction[j], e, reach) for j, e in enumerate(mine)])
    Q = closest_on_rays(Oe, De, lines.point[li], lines.direction[li])
    # A ray nearly along the edge meets it far from where its point was: left as it was.
    ok = keep & good[li] & np.isfinite(Q).all(axis=1) & (np.linalg.norm(Q - P[ray], axis=1) <= reach)
    dropped = every[~sub & good[every_li]]
    slot = np.cumsum(good) - 1  # the fitted edges, renumbered
    jacks: tuple[dict[object, tuple[np.ndarray, np.ndarray] | None], ...] = tuple({} for _ in range(int(good.sum())))
    if groups is not None:
        use = keep & good[li]
        labels, Ck, Uk, fixed, present = lines_jackknife(Oe[use], De[use], li[use], groups[ray][use], lines)
        jacks = tuple({label: ((Ck[j, g], Uk[j, g]) if fixed[j, g] else None)
                       for g, label in enumerate(labels.tolist()) if present[j, g]} for j in np.flatnonzero(good))
    along = np.einsum("ij,ij->i", Q[ok] - lines.point[li[ok]], lines.direction[li[ok]])
    return EdgeSnap(ray[ok], Q[ok], tuple((e.a, e.b) for e, g in zip(mine, good) if g), slot[li[ok]],
                    along, tuple((lines.point[j], lines.direction[j]) for j in np.flatnonzero(good)), jacks, dropped)


def _candidates(P: np.ndarray, edges: Sequence[PlaneEdge], reach: float, margin: float,
                nearest: np.ndarray | None) -> tuple[list[tuple[int, np.ndarray]], np.ndarray]:
    """Each edge's candidate points (within ``reach`` of its line, ``margin`` inside its
    spans' ends) and how many edges each point is a candidate of (N,)."""
    # Candidates of an edge: the points whose nearest reference triangle is on one of its two
    # planes (``nearest``), taken as slices of the points sorted by that plane, not every
    # point against every edge.
    if nearest is None:
        order, Ps, blocks = np.arange(len(P)), P, {-1: (0, len(P))}
    else:
        near_f = np.asarray(nearest, np.int64).ravel()
        order = np.argsort(near_f, kind="stable")
        Ps = P[order]
        top = max(max(e.positions) for e in edges) + 1
        cuts = np.searchsorted(near_f[order], np.arange(top + 1))
        blocks = {f: (int(cuts[f]), int(cuts[f + 1])) for f in range(top)}
    candidates: list[tuple[int, np.ndarray]] = []
    hits = np.zeros(len(P), np.int64)
    for k, e in enumerate(edges):
        found = []
        for f in ((-1,) if nearest is None else e.positions):
            lo_i, hi_i = blocks.get(f, (0, 0))
            d = Ps[lo_i:hi_i] - e.point
            a = np.einsum("ij,j->i", d, e.direction)  # not `@`: a matrix-vector product may wake BLAS threads
            ok = np.einsum("ij,ij->i", d, d) - a * a <= reach * reach
            inside = np.zeros(len(d), bool)
            for lo, hi in e.spans:
                inside |= (a >= lo + margin) & (a <= hi - margin)
            found.append(order[lo_i:hi_i][ok & inside])
        idx = np.sort(np.concatenate(found))  # in the points' order, however found: the same subsample
        hits[idx] += 1
        candidates.append((k, idx))
    return candidates, hits


def _fit_edges(O: np.ndarray, D: np.ndarray, li: np.ndarray, edges: Sequence[PlaneEdge]
               ) -> tuple[RayLines, np.ndarray]:
    """The edges fitted to the rays (O, D) (N, 3) near them (``li``: each ray's edge), each
    trimmed twice of the rays it does not explain (beyond :data:`TRIM_SIGMAS` robust standard
    deviations). Returns the lines and the rays kept (N,)."""
    L = len(edges)
    n = np.bincount(li, minlength=L)
    first = np.concatenate([[0], np.cumsum(n)[:-1]])  # the rays of each edge are contiguous
    starts = np.array([e.point for e in edges]), np.array([e.direction for e in edges])
    lines = fit_lines_to_rays(O, D, li, *starts)
    keep = np.ones(len(li), bool)
    cut = np.full(L, 1e-4)
    for _ in range(2):
        r = line_ray_distances(lines.point[li], lines.direction[li], O, D)
        r = np.where(np.isfinite(r), r, np.inf)  # a ray parallel to its edge: never kept
        for j in range(L):
            rj = r[first[j]:first[j] + n[j]][keep[first[j]:first[j] + n[j]]]
            if len(rj):
                cut[j] = max(TRIM_SIGMAS * 1.4826 * float(np.median(np.abs(rj - np.median(rj)))), 1e-4)
        new = np.abs(r) <= cut[li]
        if (new == keep).all():
            break
        keep = new
        lines = fit_lines_to_rays(O[keep], D[keep], li[keep], lines.point, lines.direction)
    return lines, keep


def _near(point: np.ndarray, direction: np.ndarray, e: PlaneEdge, reach: float) -> bool:
    """Whether a fitted line stays within ``reach`` of the CAD edge ``e`` along its spans (a
    fit that wandered off to other rays is not the edge)."""
    ends = e.point + np.array([e.spans.min(), e.spans.max()])[:, None] * e.direction
    d = ends - point
    off = d - (d @ direction)[:, None] * direction
    return bool(np.linalg.norm(off, axis=1).max() <= reach)


def replica_planes(points: np.ndarray, weights: np.ndarray, groups: np.ndarray, moved: np.ndarray,
                   snap: EdgeSnap, normal: np.ndarray, *, min_points: int = 10) -> dict[object, dict[str, object] | None]:
    """A plane's delete-one-camera jackknife when some of its points were snapped onto edges:
    without each camera, its points go, and the snapped points move with the edges fitted
    without that camera.

    Parameters
    ----------
    points : (N, 3) float
        The plane's points (snapped ones where they were snapped), mm.
    weights : (N,) float
    groups : (N,)
        Each point's camera.
    moved : (N,) int
        Each point's position in ``snap``'s moved points, -1 for one not snapped.
    snap : EdgeSnap
        The snap (with its edges' jackknife lines).
    normal : (3,) float
        The side each plane's normal is turned to.
    min_points : int
        Fewer points left: None.

    Returns
    -------
    dict
        Camera -> ``{"kind": "plane", "point", "normal"}`` (as
        :func:`inspector.kernels.fits.plane_jackknife`'s), or None.

    Notes
    -----
    A replica's snapped points are taken on its edge's line, at their positions along it:
    the plane of points on lines follows from each line and three sums of the positions
    per camera (count, sum, sum of squares), so every replica costs 3 x 3 sums, not a pass
    over the points (the microns by which a ray's point lies beside its edge do not move a
    plane fitted through edges tens of millimetres long).
    """
    P = np.asarray(points, float)
    w = np.asarray(weights, float)
    labels, gi = np.unique(np.asarray(groups), return_inverse=True)
    gi = gi.ravel()
    G = len(labels)
    c0 = (w[:, None] * P).sum(0) / max(float(w.sum()), 1e-300)
    m = moved >= 0
    # The points that never move: their moments without each camera.
    W, S, M, n = group_moments(P[~m] - c0, w[~m], gi[~m], G)
    Wk, Sk, Mk, nk = W.sum() - W, S.sum(0) - S, M.sum(0) - M, n.sum() - n
    pos, eg = moved[m], snap.edge[moved[m]]
    for e in np.unique(eg):
        on = eg == e
        t, we, ge = snap.along[pos[on]], w[m][on], gi[m][on]
        # Count, sum and sum of squares of the positions along the edge, without each camera.
        sums = [np.bincount(ge, weights=we * t ** power, minlength=G) for power in range(3)]
        s0, s1, s2 = (x.sum() - x for x in sums)
        ne = int(on.sum()) - np.bincount(ge, minlength=G)
        jk = snap.jackknife[e]
        # Each camera's replica of this edge's line: refitted without it, or as fitted (a
        # camera that gave it no ray); None: without it the edge is not fixed, and its
        # points are left out of that replica.
        lines = [jk[label] if label in jk else snap.lines[e] for label in labels.tolist()]
        have = np.array([ln is not None for ln in lines])
        p = np.array([ln[0] if ln is not None else c0 for ln in lines]) - c0
        u = np.array([ln[1] if ln is not None else np.zeros(3) for ln in lines])
        s0, s1, s2, ne = (np.where(have, x, 0) for x in (s0, s1, s2, ne))
        Wk += s0
        Sk += s0[:, None] * p + s1[:, None] * u
        pu = p[:, :, None] * u[:, None, :]
        Mk += (s0[:, None, None] * p[:, :, None] * p[:, None, :] + s1[:, None, None] * (pu + pu.transpose(0, 2, 1))
               + s2[:, None, None] * u[:, :, None] * u[:, None, :])
        nk += ne
    return planes_without(Wk, Sk, Mk, nk, labels, c0, normal, min_points=min_points)
