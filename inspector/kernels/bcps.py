"""Best-case coherent point selection (BCPS), the rule of equation (1) of the paper.

For each contour point ``p`` of each camera with centre ``o``, among the candidate points
``q`` on the ray ``o -> p`` that belong to the reconstruction, select
``q* = argmin_q sd_ref(q)`` (signed distance to the aligned reference, negative inside).

Two ways to get the candidates:

* :func:`select_on_rays` (``ray``): the exact ray through the *sub-pixel* contour point,
  sampled where it lies inside the silhouettes of all the other cameras (the image-based
  visual hull of that ray); the minimum is refined to well below a pixel.
  :func:`select_on_camera_rays` does it for every camera's rays at once.
* :func:`select_on_surface` (``surface``, the paper's way): the reconstruction's surface
  points whose projection falls on a contour pixel.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from inspector.kernels.ray_search import ray_min_search
from inspector.kernels.silhouette import InsideRegion, sample_bilinear
from inspector.model import Camera

__all__ = ["confidence", "coarse_hull", "CoarseHull", "ray_min_distance", "ray_ranges", "Rays", "View", "hull_violation", "hull_membership", "select_on_rays",
           "select_on_camera_rays", "select_on_surface", "ray_box", "sparse_stride"]

SignedDistance = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True, eq=False)
class View:
    """A camera with its silhouette, as the selection needs it.

    Attributes
    ----------
    camera : Camera
    inside : (H, W) float32 or InsideRegion
        Signed inside-ness in pixels (:func:`inspector.kernels.silhouette.inside_map`):
        >= 0 inside the silhouette, minus the distance to it outside; or only its computed
        region (:func:`~inspector.kernels.silhouette.inside_region`), which the compiled
        kernels pack without ever writing the whole map (the numpy reference kernels
        write it whole on each use).
    open_border : bool
        The silhouette touches the image border: outside the image is unknown (inside).
    """

    camera: Camera
    inside: np.ndarray | InsideRegion
    open_border: bool = False


def sparse_stride(contour_points: Sequence[int], stride: int, most: int) -> int:
    """Every how many contour points a sparse selection (one that feeds a pose fit) takes
    one: ``stride``, or more so that the rig's ``contour_points`` (one count per camera)
    give at most about ``most`` rays.

    A pose has six degrees of freedom (seven with the size); the 7 000 rays that 16 cameras
    of 1 MP give a 30 mm cube at stride 3 fix it, and twice the cameras need not give twice
    the rays: with a fixed stride the sparse selections' cost grew with the camera count
    twice over (more rays, each tested against more cameras: issue 26,
    docs/benchmarks-5mp.md). With ``most`` 12 000 the stride stays 3 up to 36 000 contour
    points (16 cameras of 1 MP on the 60 mm bracket: 33 800).
    """
    return max(int(stride), -(-int(sum(contour_points)) // int(most)))


def hull_violation(X: np.ndarray, views: Sequence[View], limit: float = np.inf, skip: int = -1) -> np.ndarray:
    """How far outside the visual hull of ``views`` world points lie, in pixels.

    This is the numpy reference; :mod:`inspector.kernels.hull_jit` is the compiled
    equivalent used by default.

    Parameters
    ----------
    X : (N, 3) float
        World mm.
    limit : float
        Points already farther outside than this are not evaluated further (they keep a
        value > ``limit``): a cheap early exit.
    skip : int
        Index of a view to ignore (the camera whose own contour the rays go through).

    Returns
    -------
    (N,) float
        ``max`` over views of the distance outside that view's silhouette (0 inside).
    """
    v = np.zeros(len(X))
    alive = np.arange(len(X))
    for i, view in enumerate(views):
        if i == skip:
            continue
        if alive.size == 0:
            break
        uv, z = view.camera.project(X[alive])
        inside = view.inside.full() if isinstance(view.inside, InsideRegion) else view.inside
        g = sample_bilinear(inside, uv[:, 0], uv[:, 1], outside=np.inf if view.open_border else -1e6)
        g = np.where(z > 0, g, -1e6)
        v[alive] = np.maximum(v[alive], -g)
        alive = alive[v[alive] <= limit]
    return v


def hull_membership(X: np.ndarray, views: Sequence[View], tolerance_px: float = 0.0) -> np.ndarray:
    """Whether world points (N, 3) lie inside every view's silhouette cone (within a tolerance)."""
    return hull_violation(X, views, tolerance_px) <= tolerance_px


class Rays(NamedTuple):
    """One camera's rays through its contour points, world frame.

    Attributes
    ----------
    origin : (3,) float
        The camera centre, mm.
    dirs : (M, 3) float
        Unit directions.
    t0, t1 : (M,) float
        Depth range along each ray where it can meet the part, mm (``t0 > t1``: none).
    """

    origin: np.ndarray
    dirs: np.ndarray
    t0: np.ndarray
    t1: np.ndarray

    def take(self, rows: slice | np.ndarray) -> Rays:
        """The rays ``rows`` (a slice, indices or a mask)."""
        return Rays(self.origin, self.dirs[rows], self.t0[rows], self.t1[rows])


class CoarseHull(NamedTuple):
    """One camera's rays' coarse samples, hull-tested once an inspection (:func:`coarse_hull`).

    Attributes
    ----------
    start, samples : (M,) int
        Where each ray's samples begin in ``values`` (-1: none), and how many.
    values : (S,) float
        Hull violations, px (inf: rejected); shared by the cameras tested together.
    key : tuple
        What the table was made for (step, acceptance, bounds): a selection with other
        parameters refuses it.
    """

    start: np.ndarray
    samples: np.ndarray
    values: np.ndarray
    key: tuple[float, float, bytes]

    def take(self, rows: slice | np.ndarray) -> CoarseHull:
        """The rays ``rows``, as :meth:`Rays.take`."""
        return CoarseHull(self.start[rows], self.samples[rows], self.values, self.key)


def ray_box(origin: np.ndarray, dirs: np.ndarray, bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Entry and exit parameters of rays ``origin + t * dirs`` in an axis-aligned box.

    Parameters
    ----------
    origin : (3,) float
    dirs : (M, 3) float
    bounds : (2, 3) float
        Box min and max, mm.

    Returns
    -------
    t0, t1 : (M,) float
        ``t0 > t1`` when the ray misses the box.
    """
    # Per axis, then fmax / fmin across the axes (NaN ignored, as nanmax): with nanmax over (M, 3) rows it was 5x slower.
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.ascontiguousarray(np.asarray(dirs, dtype=np.float64).T)
        a = (bounds[0] - origin)[:, None] * inv
        b = (bounds[1] - origin)[:, None] * inv
    near, far = np.minimum(a, b), np.maximum(a, b)
    lo, hi = np.fmax(np.fmax(near[0], near[1]), near[2]), np.fmin(np.fmin(far[0], far[1]), far[2])
    return np.maximum(lo, 0.0), hi


def _view_speeds(views: Sequence[View], bounds: np.ndarray) -> list[float]:
    """Per view, an upper bound of how fast a point's projection moves inside ``bounds``:
    the focal length over the least depth of ``bounds``' sphere, px per mm (a selection's
    bound is the largest over the cameras other than its own)."""
    centre = bounds.mean(axis=0)
    radius = 0.5 * float(np.linalg.norm(bounds[1] - bounds[0]))
    out = []
    for v in views:
        depth = float(np.linalg.norm(v.camera.centre - centre)) - radius
        out.append(float(max(v.camera.K[0, 0], v.camera.K[1, 1])) / max(depth, 1e-3))
    return out


def _cost(sd, viol, tol, weight):
    """Selection cost: signed distance plus ``weight`` mm per pixel of violation beyond ``tol``."""
    return sd + weight * np.maximum(viol - tol, 0.0)


def _evaluate(origin, dirs, t, valid, hull, sd_fn, eps, tol, weight, centre=None):
    """Hull violation (px), signed distance and selection cost on a (R, K) grid of ray
    parameters ``t`` (entries where ``valid`` is False are skipped: violation inf).

    The cost is the signed distance plus ``weight`` mm per pixel of violation beyond
    ``tol`` (inf beyond ``eps``): strict BCPS where the silhouettes agree, and a graceful
    choice where sub-pixel contours disagree by a fraction of a pixel (silhouette corners).

    ``centre = (t_c, s_c, c_c)`` per row (a sample already evaluated: its ray parameter,
    signed distance and cost) prunes exactly: the signed distance is 1-Lipschitz, so a
    sample's cost is at least ``s_c - |t - t_c| + penalty``; samples whose bound cannot beat
    ``c_c`` are not queried (their cost stays inf).
    """
    R, K = t.shape
    viol = np.full(R * K, np.inf)
    sd = np.full(R * K, np.inf)
    flat = np.flatnonzero(valid.ravel())
    X = origin[None, :] + t.ravel()[flat, None] * dirs[flat // K]
    v = hull(X, eps)
    viol[flat] = v
    keep = v <= eps
    if centre is not None:
        t_c, s_c, c_c = (np.repeat(a, K)[flat] for a in centre)
        bound = _cost(s_c - np.abs(t.ravel()[flat] - t_c), v, tol, weight)
        keep &= ~(bound >= c_c)
    if keep.any():
        sd[flat[keep]] = sd_fn(X[keep])
    cost = _cost(sd, viol, tol, weight)
    return viol.reshape(R, K), sd.reshape(R, K), cost.reshape(R, K)


def ray_ranges(
    camera: Camera, uv: np.ndarray, origin: np.ndarray, dirs: np.ndarray, points: np.ndarray, radius_mm: float,
    *, compiled: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Where each contour ray can meet the reconstruction: the depth span of the
    reconstruction's surface points projecting within about ``radius_mm`` of the ray (plus
    that margin), from a coarse image grid (vectorised, conservative).

    Parameters
    ----------
    camera : Camera
    uv : (M, 2) float
        Contour points the rays go through.
    origin, dirs : (3,), (M, 3)
        The rays.
    points : (N, 3) float
        Reconstruction surface points, world mm.
    radius_mm : float
    compiled : bool
        Use the Numba kernel (:func:`inspector.kernels.bcps_jit.ray_ranges`, same result).

    Returns
    -------
    t0, t1 : (M,) float
        ``t0 > t1`` for a ray with no reconstruction point near it.
    """
    from scipy.ndimage import maximum_filter, minimum_filter

    M = len(uv)
    t0 = np.full(M, np.inf)
    t1 = np.full(M, -np.inf)
    if M == 0 or len(points) == 0:
        return t0, t1
    puv, z = camera.project(points)
    front = z > 0
    puv, z = puv[front], z[front]
    if z.size == 0:
        return t0, t1
    rho = radius_mm * float(np.sqrt(camera.K[0, 0] * camera.K[1, 1])) / float(np.median(z))
    # A ray point at depth z lies at t = z / cos(angle to the optical axis).
    cos = dirs @ np.asarray(camera.R, float)[2]
    if compiled:
        from inspector.kernels import bcps_jit

        return bcps_jit.ray_ranges(puv, z, uv, cos, rho, radius_mm)
    # Depth range of the reconstruction per image cell of rho px, widened to the 3x3
    # neighbouring cells: every point within rho px of a contour point is counted.
    cell = np.floor(puv / rho).astype(np.int64)
    lo = cell.min(axis=0) - 1
    cell -= lo
    shape = (int(cell[:, 1].max()) + 2, int(cell[:, 0].max()) + 2)
    zmin = np.full(shape, np.inf)
    zmax = np.full(shape, -np.inf)
    np.minimum.at(zmin, (cell[:, 1], cell[:, 0]), z)
    np.maximum.at(zmax, (cell[:, 1], cell[:, 0]), z)
    zmin = minimum_filter(zmin, size=3, mode="constant", cval=np.inf)
    zmax = maximum_filter(zmax, size=3, mode="constant", cval=-np.inf)
    q = np.floor(uv / rho).astype(np.int64) - lo
    ok = (q[:, 0] >= 0) & (q[:, 0] < shape[1]) & (q[:, 1] >= 0) & (q[:, 1] < shape[0])
    t0[ok] = zmin[q[ok, 1], q[ok, 0]] / cos[ok]
    t1[ok] = zmax[q[ok, 1], q[ok, 0]] / cos[ok]
    return t0 - radius_mm, t1 + radius_mm


def ray_min_distance(
    origin: np.ndarray,
    dirs: np.ndarray,
    t0: np.ndarray,
    t1: np.ndarray,
    sd_fn: SignedDistance,
    *,
    step_mm: float = 0.25,
    levels: int = 3,
) -> np.ndarray:
    """Smallest signed distance to a surface along each ray: the silhouette residual.

    A contour ray of a part grazes it and enters it nowhere. For the reference at the part's
    pose the smallest signed distance along the ray is therefore 0; it is positive where the
    reference's silhouette lies inside the observed one by that much (the ray misses it) and
    negative where the ray cuts through the reference (as deep as the ray goes in). Unlike
    the BCPS selection this does not let the hull choose the point: a turned keyway that the
    selection can absorb within a ray's hull segment still shows here.

    Parameters
    ----------
    origin : (3,) float
        Optical centre, mm.
    dirs : (M, 3) float
        Unit ray directions.
    t0, t1 : (M,) float
        Where along each ray to look, mm from ``origin`` (:func:`ray_ranges`); ``t0 > t1``: no range.
    sd_fn : callable
        ``(N, 3) world mm -> (N,)`` signed distance, mm (negative inside).
    step_mm : float
        The range is sampled every 4 steps, then every step about the ``RAY_SEEDS`` lowest
        samples (2 steps either side), and the lowest of those is refined ``levels`` times on
        9 samples about it, each level 4 times finer (0.25 mm and 3 levels: 4 um).
    levels : int

    Returns
    -------
    (M,) float
        mm; NaN for a ray without range.
    """
    return ray_min_search(np.asarray(origin, float).reshape(3), dirs, t0, t1, sd_fn, step_mm=step_mm, levels=levels)


def _refine(origin, d, tbest, vbest, sbest, hull, sd_fn, step_mm, levels, offsets, half, lip, accept_px, tol, weight):
    """Refine each ray's seed ``(t, violation, sd)`` ``levels`` times on a grid of
    ``offsets`` (each level ``half`` times finer); returns the refined ``(t, v, sd)``."""
    n = len(tbest)
    ar = np.arange(n)
    every = np.ones((n, len(offsets)), bool)
    h = step_mm
    for _ in range(levels):
        tt = tbest[:, None] + h * offsets[None, :]
        eps = max(0.5 * lip * h / half, accept_px)
        cbest = _cost(sbest, vbest, tol, weight)
        v2, s2, c2 = _evaluate(origin, d, tt, every, hull, sd_fn, eps, tol, weight, centre=(tbest, sbest, cbest))
        has = np.isfinite(c2).any(axis=1)
        k2 = np.where(has, np.argmin(c2, axis=1), np.argmin(v2, axis=1))
        # Keep the previous best where nothing queried beats it (pruned samples cannot).
        stay = np.isfinite(cbest) & ~(c2[ar, k2] < cbest)
        move = ~stay
        tbest = np.where(move, tt[ar, k2], tbest)
        vbest = np.where(move, v2[ar, k2], vbest)
        sbest = np.where(move, s2[ar, k2], sbest)
        h = h / half
    return tbest, vbest, sbest


@dataclass(frozen=True)
class _RaySearch:
    """The search settings of :func:`select_on_rays` (see its parameters)."""

    step_mm: float
    refine_levels: int
    refine_samples: int
    tolerance_px: float
    accept_px: float
    violation_weight: float
    max_points: int


def select_on_rays(
    origin: np.ndarray, dirs: np.ndarray, views: Sequence[View], skip: int, sd_fn: SignedDistance, bounds: np.ndarray,
    *, step_mm: float = 0.25, refine_levels: int = 2, refine_samples: int = 11, tolerance_px: float = 0.05,
    accept_px: float = 1.0, violation_weight: float = 3.0, max_points: int = 1_000_000, stack: object | None = None,
    t_range: tuple[np.ndarray, np.ndarray] | None = None, mesh: object | None = None, pose: np.ndarray | None = None,
    sd_scale: float = 1.0, segments: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """BCPS on exact rays (the ``ray`` method).

    A contour ray grazes the part, so its candidate set is often a very short segment or a
    single point (wherever the same edge is on another camera's contour too). The coarse
    grid therefore accepts samples within what a point's projection can move between two
    samples (so no candidate interval is skipped); each refinement level tightens this,
    down to ``accept_px``, and ranks samples by signed distance plus a penalty for any
    violation beyond ``tolerance_px``.

    Parameters
    ----------
    origin : (3,) float
        Optical centre of the camera, mm.
    dirs : (M, 3) float
        Unit directions of the rays through its sub-pixel contour points.
    views : sequence of View
        Every camera of the rig with its silhouette.
    skip : int
        Index of the camera whose contour the rays go through (not a constraint).
    sd_fn : callable
        ``(N, 3) world mm -> (N,)`` signed distance to the aligned reference, mm.
    bounds : (2, 3) float
        Box containing the object (e.g. the reconstruction's, with a margin).
    step_mm : float
        Coarse sampling step along the rays; the minimum is then refined ``refine_levels``
        times on a grid of ``refine_samples`` around it, each level
        ``(refine_samples - 1) / 2`` times finer.
    tolerance_px : float
        Hull tolerance, px, within which a point is a strict candidate (image noise moves
        contours by a few hundredths of a pixel).
    accept_px : float
        Points up to this far outside the hull remain candidates at a cost of ``violation_weight`` pixel
        footprints of deviation per pixel beyond ``tolerance_px``; rays whose best point is
        farther out have no candidate.
    violation_weight : float
        Cost of one pixel of hull violation, in pixel footprints of signed distance
        (3: measured best on simulated cubes; 1 lets points wander off the surface, 10
        brings back outliers at silhouette corners).
    max_points : int
        Samples evaluated at once (memory bound).
    stack : hull_jit.CameraStack, optional
        ``views`` packed for the compiled kernel (:func:`hull_jit.stack_views`); when
        None the numpy reference implementation is used.
    t_range : (t0, t1) of (M,) arrays, optional
        Where along each ray to look (e.g. :func:`ray_ranges`), intersected with
        ``bounds``; rays with an empty range have no candidate.
    mesh, pose : MeshDistance and (4, 4) float, optional
        The reference's distance index (:class:`~inspector.kernels.meshdist.MeshDistance`)
        and its pose (reference -> world; ``sd_fn`` must be the same function). With
        ``stack``, the compiled search of :mod:`inspector.kernels.bcps_jit` runs the whole
        selection (same result); rays it flags (a distance outside the index's band)
        take the numpy path with ``sd_fn``.
    sd_scale : float
        With ``mesh``: ``pose`` may be the affine placement of a scaled reference
        (:meth:`inspector.kernels.prior.SizePrior.placement`) whose signed distance is
        ``sd_scale * mesh(pose^-1 x)``; ``sd_fn`` must be that function.
    segments : bool
        False: no segment lengths (``segment_mm`` NaN); the compiled search then tests
        only the coarse samples that can win (the same points).

    Returns
    -------
    points : (M, 3) float
        Selected point per ray (NaN where the ray has no candidate).
    deviation : (M,) float
        Signed distance of the selected point, mm (NaN where none).
    segment_mm : (M,) float
        Length of the ray's candidate set at the coarse tolerance, mm (0 where none; NaN
        everywhere when not ``segments``).
    valid : (M,) bool
    """
    M = len(dirs)
    t0, t1 = t_range if t_range is not None else (np.full(M, -np.inf), np.full(M, np.inf))
    return select_on_camera_rays(
        [(skip, Rays(origin, dirs, t0, t1))], views, sd_fn, bounds, step_mm=step_mm, refine_levels=refine_levels,
        refine_samples=refine_samples, tolerance_px=tolerance_px, accept_px=accept_px,
        violation_weight=violation_weight, max_points=max_points, stack=stack, mesh=mesh, pose=pose,
        sd_scale=sd_scale, segments=segments,
    )[0]


class _Camera(NamedTuple):
    """One camera's share of :func:`select_on_camera_rays` (``entry``: its place in ``rays``):
    its rays with a non-empty range ``hit`` (indices into ``dirs``), their ranges ``t0, t1``
    (M,) and its results ``out``, filled in place."""

    entry: int
    skip: int
    origin: np.ndarray
    dirs: np.ndarray
    hit: np.ndarray
    t0: np.ndarray
    t1: np.ndarray
    lip: float  # bound of the hull violation's rate along a ray, px / mm
    weight: float  # cost of one pixel of hull violation, mm
    out: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
    coarse: CoarseHull | None = None  # the rays hit's table of coarse violations


def select_on_camera_rays(
    rays: Sequence[tuple[int, Rays]], views: Sequence[View], sd_fn: SignedDistance, bounds: np.ndarray, *,
    step_mm: float = 0.25, refine_levels: int = 2, refine_samples: int = 11, tolerance_px: float = 0.05,
    accept_px: float = 1.0, violation_weight: float = 3.0, max_points: int = 1_000_000, stack: object | None = None,
    mesh: object | None = None, pose: np.ndarray | None = None, sd_scale: float = 1.0, segments: bool = True,
    coarse: Sequence[CoarseHull] | None = None,
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """:func:`select_on_rays` for the rays of several cameras at once.

    Parameters
    ----------
    rays : sequence of (int, Rays)
        Each camera's index in ``views`` (its ``skip``) and its rays, whose ``t0, t1`` are
        the ``t_range``.
    views, sd_fn, bounds, step_mm, refine_levels, refine_samples, tolerance_px, accept_px,
    violation_weight, max_points, stack, mesh, pose, sd_scale, segments
        As :func:`select_on_rays`. The compiled search (``stack``, ``mesh`` and ``pose``)
        answers every camera's rays in one call: the same points as one call per camera,
        without a parallel region's start and end per camera.
    coarse : sequence of CoarseHull, optional
        For the compiled search: each entry of ``rays``' table from :func:`coarse_hull`
        (the same rays, or the same ``take``), read instead of testing the coarse samples
        against the hull again (the same results). ValueError when a table was made for
        another step, acceptance or ``bounds``.

    Returns
    -------
    list of (points, deviation, segment_mm, valid)
        :func:`select_on_rays`'s results for each entry of ``rays``, in order.
    """
    s = _RaySearch(step_mm, refine_levels, refine_samples, tolerance_px, accept_px, violation_weight, max_points)
    outs, todo = _cameras(rays, views, bounds, violation_weight, coarse)
    for c in todo:
        if c.coarse is not None and c.coarse.key != _coarse_key(s, c.lip, bounds):
            raise ValueError(f"camera {c.skip}: its coarse hull table was made for another step, acceptance or bounds")
    if todo and stack is not None and mesh is not None and pose is not None:
        _select_compiled(todo, views, sd_fn, bounds, s, stack, mesh, pose, sd_scale, segments)
    else:
        for c in todo:
            _select_sampled(c.origin, c.dirs, c.hit, c.t0, c.t1, _hull_of(views, c.skip, stack), sd_fn, c.lip, c.weight,
                            s, c.out)
    if not segments:
        for c in todo:
            c.out[2][:] = np.nan
    return outs


def _cameras(rays: Sequence[tuple[int, Rays]], views: Sequence[View], bounds: np.ndarray, violation_weight: float,
             coarse: Sequence[CoarseHull] | None = None,
             ) -> tuple[list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]], list[_Camera]]:
    """Each entry of ``rays``' results (to fill) and, for those with rays to search (a range
    inside ``bounds``, and another camera to test them against), its :class:`_Camera`."""
    speeds = _view_speeds(views, bounds)
    outs: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    todo: list[_Camera] = []
    for e, (skip, r) in enumerate(rays):
        M = len(r.dirs)
        out = (np.full((M, 3), np.nan), np.full(M, np.nan), np.zeros(M), np.zeros(M, bool))
        outs.append(out)
        t0, t1 = ray_box(r.origin, r.dirs, bounds)
        t0, t1 = np.maximum(t0, r.t0), np.minimum(t1, r.t1)
        hit = np.flatnonzero(t1 > t0)
        others = [v for i, v in enumerate(speeds) if i != skip]
        if hit.size and others:
            lip = max(0.0, *others)
            table = coarse[e].take(hit) if coarse is not None else None
            todo.append(_Camera(e, skip, r.origin, r.dirs, hit, t0, t1, lip, violation_weight / lip, out, table))
    return outs, todo


def _coarse_key(s: _RaySearch, lip: float, bounds: np.ndarray) -> tuple[float, float, bytes]:
    """What a camera's coarse samples' hull test depends on: the step, the acceptance
    ``max(0.5 * lip * step, accept)`` (the compiled search's, to the bit) and the bounds."""
    return float(s.step_mm), max(0.5 * lip * s.step_mm, s.accept_px), np.asarray(bounds, np.float64).tobytes()


def coarse_hull(rays: Sequence[tuple[int, Rays]], views: Sequence[View], bounds: np.ndarray, stack: object, *,
                step_mm: float = 0.25, accept_px: float = 1.0) -> list[CoarseHull]:
    """Hull-test the coarse samples of every camera's rays once, for
    :func:`select_on_camera_rays` (``coarse``) with the same ``bounds``, ``step_mm`` and
    ``accept_px``: the hull does not move with the reference's pose, so an inspection's
    selections then compute only the admitted samples' signed distances.

    Parameters
    ----------
    rays : sequence of (int, Rays)
        As :func:`select_on_camera_rays`: the rays the selections take (or ``take`` from).
    views, bounds, step_mm, accept_px
        As :func:`select_on_rays`; ``stack`` is ``views`` packed for the compiled kernels.

    Returns
    -------
    list of CoarseHull
        One per entry of ``rays``, sharing one array of violations.
    """
    from inspector.kernels import bcps_jit

    s = _RaySearch(step_mm, 0, 3, 0.0, accept_px, 1.0, 1)
    _, todo = _cameras(rays, views, bounds, 1.0)
    keys = [_coarse_key(s, c.lip, bounds) for c in todo]
    start, count, values = bcps_jit.coarse_violations(*_packed(todo), stack, [c.skip for c in todo],
                                                      [k[1] for k in keys], step_mm=step_mm, bounds=bounds)
    tables = [CoarseHull(np.full(len(r.dirs), -1, np.int64), np.zeros(len(r.dirs), np.int64), values,
                         (float(step_mm), float("nan"), b"")) for _, r in rays]  # (no ray to search)
    end = 0
    for c, key in zip(todo, keys):
        rows = slice(end, end + len(c.hit))
        tables[c.entry].start[c.hit], tables[c.entry].samples[c.hit], end = start[rows], count[rows], rows.stop
        tables[c.entry] = tables[c.entry]._replace(key=key)
    return tables


def _packed(todo: Sequence[_Camera]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The cameras' rays ``hit`` one after the other, as the compiled kernels take them:
    ``origins`` (E, 3), ``entry`` (M,) (each ray's camera in ``todo``), ``dirs``, ``t0``, ``t1``."""
    return (np.array([c.origin for c in todo], dtype=np.float64).reshape(-1, 3),
            np.concatenate([np.full(len(c.hit), e, np.int64) for e, c in enumerate(todo)] + [np.zeros(0, np.int64)]),
            np.concatenate([c.dirs[c.hit] for c in todo] + [np.zeros((0, 3))]),
            np.concatenate([c.t0[c.hit] for c in todo] + [np.zeros(0)]),
            np.concatenate([c.t1[c.hit] for c in todo] + [np.zeros(0)]))


def _hull_of(views: Sequence[View], skip: int, stack: object | None) -> Callable[[np.ndarray, float], np.ndarray]:
    """``(X (N, 3) world mm, limit px) -> (N,)`` hull violation, px, of every camera but
    ``skip``: the compiled kernel (:func:`inspector.kernels.hull_jit.violation`) on
    ``stack``, else :func:`hull_violation`."""
    if stack is not None:
        from inspector.kernels.hull_jit import violation

        def hull(X, limit):
            return violation(X, stack, limit, skip)
    else:

        def hull(X, limit):
            return hull_violation(X, views, limit, skip)

    return hull


def _select_compiled(
    todo: Sequence[_Camera], views: Sequence[View], sd_fn: SignedDistance, bounds: np.ndarray, s: _RaySearch,
    stack: object, mesh: object, pose: np.ndarray, sd_scale: float, segments: bool,
) -> None:
    """:func:`select_on_camera_rays` by the compiled search
    (:func:`inspector.kernels.bcps_jit.select_rays`), on every camera's rays ``hit`` at
    once; the rays it flags (a distance outside the index's band) take the numpy path with
    ``sd_fn``. Each camera's results are filled into its ``out``."""
    from inspector.kernels import bcps_jit

    tb, vb, sb, seg, oob = bcps_jit.select_rays(
        *_packed(todo), stack, [c.skip for c in todo], mesh, pose, step_mm=s.step_mm,
        refine_levels=s.refine_levels, refine_samples=s.refine_samples, tolerance_px=s.tolerance_px,
        accept_px=s.accept_px, weights=[c.weight for c in todo], lips=[c.lip for c in todo], bounds=bounds,
        sd_scale=sd_scale, segments=segments, coarse=_tables(todo),
    )
    end = 0
    for c in todo:
        part = slice(end, end + len(c.hit))
        end = part.stop
        points, deviation, segment, valid = c.out
        o = oob[part]
        ok = ~o & (vb[part] <= s.accept_px) & np.isfinite(sb[part])
        sel = c.hit[ok]
        points[sel] = c.origin + tb[part][ok, None] * c.dirs[sel]
        deviation[sel] = sb[part][ok]
        valid[sel] = True
        segment[c.hit[~o]] = seg[part][~o]
        if o.any():
            _select_sampled(c.origin, c.dirs, c.hit[o], c.t0, c.t1, _hull_of(views, c.skip, stack), sd_fn, c.lip,
                            c.weight, s, c.out)


def _tables(todo: Sequence[_Camera]) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The cameras' coarse tables as the compiled search reads them, ``(start, samples,
    values)`` over their rays ``hit`` in order; None unless every camera has one, all from
    one :func:`coarse_hull` (tables made apart: the samples are tested again)."""
    tabs = [c.coarse for c in todo if c.coarse is not None]
    if not tabs or len(tabs) < len(todo) or any(t.values is not tabs[0].values for t in tabs):
        return None
    return np.concatenate([t.start for t in tabs]), np.concatenate([t.samples for t in tabs]), tabs[0].values


def _select_sampled(
    origin: np.ndarray, dirs: np.ndarray, hit: np.ndarray, t0: np.ndarray, t1: np.ndarray,
    hull: Callable[[np.ndarray, float], np.ndarray], sd_fn: SignedDistance, lip: float, weight: float, s: _RaySearch,
    out: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
) -> None:
    """:func:`select_on_rays` by sampling (numpy) on the rays ``hit``, by chunks of at most
    ``s.max_points`` samples: a coarse grid every ``s.step_mm``, then two seeds (the best
    candidate, and the deepest accepted sample when it lies farther than a step from it)
    refined by :func:`_refine`.

    Parameters
    ----------
    hit : (H,) int
        Rays with a non-empty range ``t0 < t1`` (mm from ``origin``, (M,) each).
    hull : callable
        ``(X (N, 3) mm, limit px) -> (N,)`` hull violation, px (:func:`_hull_of`).
    lip : float
        Bound of the hull violation's rate along a ray, px / mm.
    weight : float
        Cost of one pixel of hull violation, mm.
    out : (points (M, 3), deviation (M,), segment_mm (M,), valid (M,))
        :func:`select_on_rays`'s results, filled in place for the rays ``hit``.
    """
    points, deviation, segment, valid = out
    step_mm, refine_levels, refine_samples = s.step_mm, s.refine_levels, s.refine_samples
    tolerance_px, accept_px = s.tolerance_px, s.accept_px
    K = int(np.ceil((t1[hit] - t0[hit]).max() / step_mm)) + 1
    chunk = max(1, s.max_points // max(K, refine_samples))
    half = (refine_samples - 1) // 2
    offsets = np.linspace(-1.0, 1.0, refine_samples)
    for start in range(0, hit.size, chunk):
        rows = hit[start : start + chunk]
        n = len(rows)
        ar = np.arange(n)
        d = dirs[rows]
        t = t0[rows, None] + step_mm * np.arange(K)[None, :]
        inside = t <= t1[rows, None] + 1e-9
        eps = max(0.5 * lip * step_mm, accept_px)
        viol, sd, cost = _evaluate(origin, d, t, inside, hull, sd_fn, eps, tolerance_px, weight)
        segment[rows] = np.isfinite(sd).sum(axis=1) * step_mm
        # Best candidate, or (none) the sample closest to the hull.
        has = np.isfinite(cost).any(axis=1)
        k = np.where(has, np.argmin(cost, axis=1), np.argmin(viol, axis=1))
        tbest = t[ar, k]
        vbest = viol[ar, k]
        sbest = sd[ar, k]
        # Second seed: the deepest accepted sample (see bcps_jit._select_kernel).
        kq = np.argmin(sd, axis=1)
        qt, qv, qs = t[ar, kq], viol[ar, kq], sd[ar, kq]
        two = has & (qs < sbest) & (np.abs(qt - tbest) > step_mm)
        tbest, vbest, sbest = _refine(origin, d, tbest, vbest, sbest, hull, sd_fn, step_mm, refine_levels, offsets,
                                      half, lip, accept_px, tolerance_px, weight)
        if two.any():
            t2, v2, s2 = _refine(origin, d[two], qt[two], qv[two], qs[two], hull, sd_fn, step_mm, refine_levels,
                                 offsets, half, lip, accept_px, tolerance_px, weight)
            win = _cost(s2, v2, tolerance_px, weight) < _cost(sbest[two], vbest[two], tolerance_px, weight)
            better = np.flatnonzero(two)[win]
            tbest[better], vbest[better], sbest[better] = t2[win], v2[win], s2[win]
        ok = (vbest <= accept_px) & np.isfinite(sbest)
        sel = rows[ok]
        points[sel] = origin + tbest[ok, None] * d[ok]
        deviation[sel] = sbest[ok]
        valid[sel] = True


def select_on_surface(
    points: np.ndarray,
    sd: np.ndarray,
    camera: Camera,
    contour_mask: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """BCPS on the reconstruction's surface points (the ``surface`` method, the paper's).

    Parameters
    ----------
    points : (N, 3) float
        Reconstruction surface points, world mm.
    sd : (N,) float
        Their signed distance to the aligned reference, mm.
    camera : Camera
    contour_mask : (H, W) bool
        The silhouette's contour pixels (object pixels with a background 4-neighbour).

    Returns
    -------
    index : (P,) int
        Selected point per contour pixel (indices into ``points``).
    pixel : (P, 2) float
        The contour pixel ``(u, v)``.
    segment_mm : (P,) float
        Depth extent of that pixel's candidates along the ray, mm.
    deviation : (P,) float
    """
    uv, z = camera.project(points)
    ui = np.rint(uv[:, 0]).astype(np.int64)
    vi = np.rint(uv[:, 1]).astype(np.int64)
    h, w = contour_mask.shape
    ok = (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h) & (z > 0)
    ok[ok] = contour_mask[vi[ok], ui[ok]]
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    key = vi[idx] * w + ui[idx]
    order = np.lexsort((sd[idx], key))  # by pixel, then by signed distance
    key_sorted = key[order]
    first = np.flatnonzero(np.r_[True, key_sorted[1:] != key_sorted[:-1]])
    chosen = idx[order[first]]
    zs = z[idx][order]
    zmax = np.maximum.reduceat(zs, first)
    zmin = np.minimum.reduceat(zs, first)
    pix = np.stack([ui[chosen], vi[chosen]], axis=1).astype(float)
    return chosen, pix, zmax - zmin, sd[chosen]


#: Candidate-segment length, in pixel footprints, at which a point's confidence is 0.5.
CONFIDENCE_HALF_PX = 10.0


def confidence(segment_mm: np.ndarray, footprint_mm: float) -> np.ndarray:
    """Confidence in [0, 1] of BCPS points from their candidate-segment length.

    The paper's future work: a contour ray that meets the reconstruction along a long
    segment (a grazing ray, a concavity, a bulge) leaves the point's position along the ray
    uncertain; a short one pins it down. ``confidence = 1 / (1 + L / (10 px))`` with ``L``
    the segment length in pixel footprints: 1 for a point-like candidate set, 0.5 for a
    segment of 10 pixels, 0.1 for 90 pixels.

    Parameters
    ----------
    segment_mm : (N,) float
    footprint_mm : float
        Pixel footprint at the rig centre, mm.
    """
    return 1.0 / (1.0 + np.asarray(segment_mm, float) / (CONFIDENCE_HALF_PX * footprint_mm))
