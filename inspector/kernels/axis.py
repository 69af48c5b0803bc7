"""Turns of the reference about its axis of near-symmetry, pure kernels.

A shaft with a keyway, a flange keyed by its bolt holes, a gear with a missing tooth: the
features that fix the turn about such an axis are small, and a fit on points can end
anywhere about it. This module finds the axis (:func:`near_axis`: the principal axis of the
surface's exact second moments with two nearly equal partners, corrected to the geometric
axis), scans every turn of the reference about it for a set of points
(:func:`scan_about_axis` -> :class:`AxisScan`: the points' robust loss, which turns are the
reference's own symmetries, which keep it inside the visual hull), says what such a scan
tells of a pose's turn (:func:`pose_confidence`), and where in space a turn can change the
distance to the reference at all (:func:`turn_zone` -> :class:`TurnZone`).

Conventions as in :mod:`~inspector.kernels.rigid`: mm, ``pose`` reference -> world, ``W``
world -> the reference's internal (bounding-box centred) frame.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from inspector.kernels.rigid import (
    POKE_TOLERANCE,
    REF_SAMPLES,
    RefMesh,
    as_mesh,
    as_points,
    as_pose,
    poking,
    positive,
    robust_fit,
    transform,
    turns_about_axis,
)
from inspector.kernels.robust import tukey_loss
from inspector.model import PoseConfidence

__all__ = ["AMBIGUOUS_POINTS", "DEGENERATE", "AxisScan", "TurnZone", "axis_turns", "near_axis", "pose_confidence", "scan_about_axis",
           "scan_turns", "turn_zone"]

#: Variance ratio of two principal axes above which they are ill-defined (the third is
#: then an axis of near-symmetry; the global alignment also samples turns about it).
DEGENERATE = 0.8


def near_axis(ref: RefMesh) -> tuple[np.ndarray, np.ndarray] | None:
    """The reference's axis of near-symmetry: unit direction (3,) and a point on it (3,),
    internal frame; None when it has no single such axis.

    The principal axis of the surface's exact second moments whose two partners have
    nearly equal variance (ratio above ``DEGENERATE``: a shaft, a nut, a flange, a hub, a
    gear), through the surface's centroid; a box, a cube or a sphere has none. Exact
    moments, not samples: a flange's axis from 1500 samples is half a degree off, which
    hides its own symmetries (a turn by 90 degrees about a tilted axis moves its rim).
    """
    cache = _SELF_CACHE.setdefault(ref.index, {}) if ref.index is not None else ref.__dict__
    if "near_axis" in cache:
        return cache["near_axis"]
    tri = ref.vertices[ref.faces]
    A = ref.face_areas
    centre = (A[:, None] * tri.sum(axis=1)).sum(axis=0) / (3.0 * ref.area)
    t = tri - centre
    s = t.sum(axis=1)
    # Integral of x x^T over a triangle: A / 12 (s s^T + sum_i v_i v_i^T).
    M = (np.einsum("f,fi,fj->ij", A, s, s) + np.einsum("f,fki,fkj->ij", A, t, t)) / (12.0 * ref.area)
    vals, vecs = np.linalg.eigh(M)
    E, lam = vecs[:, ::-1], np.maximum(vals[::-1], 0.0)
    close01, close12 = lam[1] >= DEGENERATE * lam[0], lam[2] >= DEGENERATE * lam[1]
    near = None if close01 == close12 else _true_axis(ref, (E[:, 2] if close01 else E[:, 0]), centre)
    cache["near_axis"] = near
    return near


def _true_axis(ref: RefMesh, axis: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The geometric axis near the principal one: the reference turned by 90 degrees about
    (``axis``, ``centre``) is fitted back onto itself (robustly: the keying features are
    outliers), and the axis of the composed rotation is returned with its point nearest
    ``centre``. A keyway tilts a shaft's principal axis by 0.7 degree, which a turn by
    180 degrees turns into half a millimetre at its ends."""
    s, _ = ref.sample(REF_SAMPLES, np.random.default_rng(2))
    T = turns_about_axis(axis, centre, np.array([90.0]))[0]
    W, dist, _ = robust_fit(ref, transform(T[None], s)[0], np.eye(4), floor_mm=1e-3 * ref.diag,
                             start_mm=0.05 * ref.diag, iterations=40, tol=1e-7 * ref.diag)
    if np.mean(dist <= 0.01 * ref.diag) < 0.5:
        return axis, centre
    M = W @ T
    R = M[:3, :3]
    a = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if np.linalg.norm(a) < 1e-9:
        return axis, centre
    a = a / np.linalg.norm(a)
    a = a if a @ axis >= 0 else -a
    # Points c with R c + t = c: least squares (I - R) c = t, then the one nearest centre.
    c = np.linalg.lstsq(np.eye(3) - R, M[:3, 3], rcond=None)[0]
    c = c + ((centre - c) @ a) * a
    return a, c

def axis_turns(ref: RefMesh, angles_deg: tuple[float, ...]) -> np.ndarray:
    """Internal-frame rotations (K, 4, 4) about the reference's axis of near-symmetry:
    the identity first, then one turn per angle; the identity alone for a reference with
    no single such axis (a box, a cube, a sphere)."""
    near = near_axis(ref)
    if near is None or not len(angles_deg):
        return np.eye(4)[None]
    return turns_about_axis(near[0], near[1], np.concatenate([[0.0], np.asarray(angles_deg, float)]))


# --------------------------------------------------------------------------- turns about the axis

#: The axis scan: turns spaced so that the reference's outermost point moves by at most
#: one Tukey cutoff between two of them (a feature is never skipped), at most this many
#: turns; points used (a regular subset).
_SCAN_MAX_TURNS = 360
_SCAN_POINTS = 2000
#: A turn is a symmetry of the reference when it moves fewer than this fraction of its
#: surface (area-uniform samples) farther than ``_SELF_TOL_MM`` off itself (tessellation
#: of a 30 mm circle in 128 sections: 9 um).
_SELF_SAMPLES = 4000
_SELF_TOL_MM = 0.05
_SYMMETRY_FRACTION = 0.002


@dataclass(frozen=True, eq=False)
class AxisScan:
    """Points against the reference turned about its axis of near-symmetry.

    Attributes
    ----------
    axis : (3,) float
        Unit direction of the axis, reference frame.
    centre : (3,) float
        A point of the axis, reference frame, mm.
    angles_deg : (K,) float
        The turns scanned, degrees in [0, 360), 0 first (the pose given).
    cost : (K,) float
        Mean Tukey loss of the points against the reference at ``pose`` turned by each
        angle: 0 when every point is on the surface, 1 when every point is beyond
        ``cutoff_mm``.
    moved : (K,) float
        Fraction of the reference's surface each turn moves off itself (0: a symmetry).
    cutoff_mm : float
        Tukey cutoff, mm.
    radius_mm : float
        Largest distance of the reference's surface from the axis, mm.
    n_points : int
        Points scanned (the loss is averaged over a regular subset of them).
    poke : (K,) float or None
        With hull points: the fraction of them each turn puts deeper than the hull depth
        inside the reference (0 where the turned reference is inside the visual hull).
    """

    axis: np.ndarray
    centre: np.ndarray
    angles_deg: np.ndarray
    cost: np.ndarray
    moved: np.ndarray
    cutoff_mm: float
    radius_mm: float
    n_points: int = 0
    poke: np.ndarray | None = None

    @property
    def inside_hull(self) -> np.ndarray:
        """(K,) bool: turns that keep the reference inside the hull as well as the best turn
        does (all True without hull points)."""
        if self.poke is None:
            return np.ones(len(self.angles_deg), bool)
        return self.poke <= self.poke.min() + POKE_TOLERANCE

    @property
    def symmetric(self) -> np.ndarray:
        """(K,) bool: the turns that map the reference onto itself."""
        return self.moved < _SYMMETRY_FRACTION

    def distinct(self, width_deg: float | None = None) -> np.ndarray:
        """(K,) bool: turns that are neither near 0 nor near a symmetry of the reference
        (within ``width_deg``, default: the angle over which the outermost point moves two
        cutoffs)."""
        w = width_deg if width_deg is not None else np.degrees(2.0 * self.cutoff_mm / self.radius_mm)
        sym = self.angles_deg[self.symmetric]
        gap = np.abs((self.angles_deg[:, None] - sym[None, :] + 180.0) % 360.0 - 180.0)
        return ~(gap <= w).any(axis=1)

    def minima(self, n: int) -> np.ndarray:
        """Indices of the ``n`` lowest local minima of ``cost`` (circular), lowest first."""
        c = self.cost
        is_min = (c <= np.roll(c, 1)) & (c <= np.roll(c, -1))
        idx = np.flatnonzero(is_min)
        return idx[np.argsort(c[idx], kind="stable")][:n]


_SELF_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


@dataclass(frozen=True, eq=False)
class TurnZone:
    """Where a turn of the reference about its axis can change the distance to it.

    Turning about the axis keeps a point's distance ``rho`` from the axis and its height
    ``z`` along it; a point whose signed distance to the reference is the same at every turn
    of the reference (a surface of revolution nearby, or far from any surface) is
    *invariant*. A ray all of whose points are invariant has the same silhouette residual at
    every turn, so a search over turns need not look at it (a keyed shaft: 60 % of the
    contour rays; the others carry all the evidence).

    Attributes
    ----------
    axis, centre : (3,) float
        The axis (unit) and a point on it, reference frame.
    z0 : float
        Height of the grid's first row, mm.
    cell_mm : float
    variable : (R, Z) bool
        Cells (``rho`` from 0, ``z`` from ``z0``) where the signed distance varies with the
        turn and comes within the band of the surface, dilated by one cell.
    """

    axis: np.ndarray
    centre: np.ndarray
    z0: float
    cell_mm: float
    variable: np.ndarray

    def hits(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: which reference-frame points (N, 3), mm, lie in a variable cell."""
        rel = np.asarray(points, float).reshape(-1, 3) - self.centre
        z = rel @ self.axis
        rho = np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - z * z, 0.0))
        i = np.floor(rho / self.cell_mm).astype(np.int64)
        j = np.floor((z - self.z0) / self.cell_mm).astype(np.int64)
        R, Z = self.variable.shape
        ok = (i < R) & (j >= 0) & (j < Z)
        out = np.zeros(len(rel), bool)
        out[ok] = self.variable[i[ok], j[ok]]
        return out


def turn_zone(index: Any, vertices: np.ndarray, axis: np.ndarray, centre: np.ndarray, *, cell_mm: float = 0.5,
              band_mm: float = 1.0, tol_mm: float = 0.005, turns: int = 120) -> TurnZone:
    """The :class:`TurnZone` of a reference about (``axis``, ``centre``).

    Parameters
    ----------
    index : callable
        ``(N, 3) -> (N,)`` signed distance to the reference, reference frame, mm (NaN far
        from it is fine: e.g. ``MeshDistance.near``).
    vertices : (V, 3) float
        The reference's vertices (its extent), mm.
    axis, centre : (3,) float
        Unit axis and a point on it, reference frame.
    cell_mm : float
        Grid cell in ``rho`` and ``z``, mm.
    band_mm : float
        Only distances within this of the surface count, mm.
    tol_mm : float
        A cell varies when its distance ranges over more than this, mm.
    turns : int
        Turns sampled at each cell centre (every 3 degrees: a Ø5 bolt hole on a Ø38 circle
        spans 15).
    """
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    c = np.asarray(centre, float)
    rel = np.asarray(vertices, float) - c
    z = rel @ a
    rho = np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - z * z, 0.0))
    e1 = np.cross(a, (1.0, 0.0, 0.0) if abs(a[0]) < 0.9 else (0.0, 1.0, 0.0))
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    z0 = float(z.min()) - band_mm - cell_mm
    nr = int(np.ceil((float(rho.max()) + band_mm) / cell_mm)) + 1
    nz = int(np.ceil((float(z.max()) + band_mm + cell_mm - z0) / cell_mm)) + 1
    r_c = (np.arange(nr) + 0.5) * cell_mm
    z_c = z0 + (np.arange(nz) + 0.5) * cell_mm
    phi = np.linspace(0.0, 2.0 * np.pi, int(turns), endpoint=False)
    R, Z, F = np.meshgrid(r_c, z_c, phi, indexing="ij")
    X = c + Z.reshape(-1, 1) * a + (R * np.cos(F)).reshape(-1, 1) * e1 + (R * np.sin(F)).reshape(-1, 1) * e2
    sd = np.asarray(index(X), float).reshape(R.shape)
    sd = np.where(np.isnan(sd), np.inf, sd)
    near = np.abs(sd).min(axis=2) < band_mm
    spread = np.where(np.isfinite(sd), sd, 1e9).max(axis=2) - sd.min(axis=2)
    variable = near & (spread > tol_mm)
    from scipy.ndimage import binary_dilation

    variable = binary_dilation(variable, np.ones((3, 3), bool))
    return TurnZone(axis=a, centre=c, z0=z0, cell_mm=float(cell_mm), variable=variable)


def _self_moved(ref: RefMesh, axis: np.ndarray, centre: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Fraction (K,) of the reference's surface samples that the turns ``T`` (K, 4, 4)
    move farther than ``_SELF_TOL_MM`` off the reference."""
    s, _ = ref.sample(_SELF_SAMPLES, np.random.default_rng(1))
    return np.mean(ref.distance(transform(T, s)) > _SELF_TOL_MM, axis=1)


def scan_turns(ref: RefMesh, points: np.ndarray, W: np.ndarray, cutoff_mm: float,
          hull: tuple[np.ndarray, float] | None = None) -> AxisScan | None:
    """Scan the turns of the reference about its near-symmetry axis for world ``points``
    (N, 3) and the world -> internal transform ``W`` (4, 4); None without such an axis.
    ``hull``: visual-hull points (H, 3), world, and the depth that counts, mm."""
    near = near_axis(ref)
    if near is None:
        return None
    axis, centre = near
    s, _ = ref.sample(REF_SAMPLES, np.random.default_rng(0))
    rel = s - centre
    radius = float(np.sqrt(np.max(np.sum(rel * rel, axis=1) - (rel @ axis) ** 2)))
    step = np.degrees(cutoff_mm / max(radius, 1e-9))
    # A multiple of 120 turns, so that the symmetries of 2-6, 8, 10 and 12 holes or teeth
    # are among them.
    k = int(min(_SCAN_MAX_TURNS, 120 * np.ceil(360.0 / step / 120)))
    angles = np.arange(k) * (360.0 / k)
    T = turns_about_axis(axis, centre, angles)
    # The reference's own symmetries depend on it alone: computed once per distance index.
    cache = _SELF_CACHE.setdefault(ref.index, {}) if ref.index is not None else {}
    if k not in cache:
        cache[k] = _self_moved(ref, axis, centre, T)
    x = points[:: max(1, len(points) // _SCAN_POINTS)]
    # The reference turned by an angle is the points turned back by it (in its frame).
    back = turns_about_axis(axis, centre, -angles) @ W
    cost = np.mean(tukey_loss(ref.distance(transform(back, x)), cutoff_mm), axis=1)
    poke = None if hull is None else poking(ref, hull[0], back, hull[1])
    return AxisScan(axis=axis, centre=centre + ref.centre, angles_deg=angles, cost=cost, moved=cache[k],
                    cutoff_mm=float(cutoff_mm), radius_mm=radius, n_points=len(points), poke=poke)

def scan_about_axis(
    points: np.ndarray,
    ref_vertices: np.ndarray,
    ref_faces: np.ndarray,
    pose: np.ndarray,
    *,
    cutoff_mm: float,
    index: Any = None,
    hull_points: np.ndarray | None = None,
    hull_mm: float = 1.0,
) -> AxisScan | None:
    """How well ``points`` fit the reference at ``pose`` turned about its near-symmetry axis.

    Parameters
    ----------
    points : (N, 3) float
        World points on the part's surface (e.g. BCPS points), mm; N >= 6.
    ref_vertices, ref_faces : (V, 3) float, (F, 3) int
        Reference mesh, reference frame, mm.
    pose : (4, 4) float
        Reference -> world pose.
    cutoff_mm : float
        Tukey cutoff of the loss, mm; also sets the spacing of the turns (the reference's
        outermost point moves one cutoff between two).
    index : MeshDistance, optional
        The reference's exact distance index (needed for ``hull_points``).
    hull_points : (H, 3) float, optional
        Surface points of the part's visual hull, world, mm: the scan also says which turns
        keep the reference inside the hull (:attr:`AxisScan.poke`).
    hull_mm : float
        Depth inside the reference beyond which a hull point counts, mm.

    Returns
    -------
    AxisScan or None
        None for a reference with no single axis of near-symmetry.
    """
    pts = as_points("points", points, min_rows=6)
    verts, faces = as_mesh(ref_vertices, ref_faces)
    ref = RefMesh(verts, faces, index)
    hull = None if hull_points is None else (as_points("hull_points", hull_points), positive("hull_mm", hull_mm))
    return scan_turns(ref, pts, ref.w_from_pose(as_pose(pose)), positive("cutoff_mm", cutoff_mm), hull)


#: A runner-up turn pinned by fewer points than this (margin x points) is ambiguous.
AMBIGUOUS_POINTS = 30


def pose_confidence(scan: AxisScan | None) -> PoseConfidence:
    """What an :class:`AxisScan` about the final pose says of the pose's turn.

    The runner-up is the lowest local minimum of the loss among the turns that are
    neither within two cutoffs (at the outermost radius) of the pose or of a symmetry of
    the reference, nor put the reference out of the visual hull. Its margin is a lower
    bound of the evidence for the pose: the points were selected against it.
    """
    if scan is None:
        return PoseConfidence()
    sym = scan.angles_deg[scan.symmetric & (scan.angles_deg > 0)]
    a = (scan.angles_deg + 180.0) % 360.0 - 180.0
    inside = scan.inside_hull
    # The hull range: the turns about the pose, both ways, before the first one out of it.
    order_pos = np.flatnonzero(a >= 0)[np.argsort(a[a >= 0])]
    order_neg = np.flatnonzero(a <= 0)[np.argsort(-a[a <= 0])]

    def reach(order: np.ndarray) -> float:
        out = np.flatnonzero(~inside[order])
        return float(a[order[out[0] - 1]]) if len(out) and out[0] > 0 else float(a[order[-1]])

    hull_range = (reach(order_neg), reach(order_pos))
    c = scan.cost
    is_min = (c <= np.roll(c, 1)) & (c <= np.roll(c, -1))
    cand = np.flatnonzero(is_min & scan.distinct() & inside)
    base = PoseConfidence(axis=(float(scan.axis[0]), float(scan.axis[1]), float(scan.axis[2])),
                          symmetry_deg=tuple(float(v) for v in sym), hull_range_deg=hull_range,
                          cutoff_mm=scan.cutoff_mm)
    if not len(cand):
        return base
    best = cand[np.argmin(c[cand])]
    margin = float(c[best] - c[0])
    points = int(round(margin * scan.n_points))
    return replace(base, runner_up_deg=float(a[best]), margin=margin, margin_points=points,
                   ambiguous=points < AMBIGUOUS_POINTS)
