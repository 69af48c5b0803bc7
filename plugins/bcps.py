"""Stages ``bcps.ray`` and ``bcps.surface``: best-case coherent points, then pose refinement.

Both apply the signed-argmin rule (see :mod:`inspector.kernels.bcps`). With
``refine_pose`` the stage also finishes the alignment the paper's way round: select,
re-align the reference on the selected points, select again.
"""

from __future__ import annotations

import dataclasses
import weakref
from dataclasses import dataclass
from typing import Literal

import numpy as np

from inspector import hookimpl
from inspector.errors import StageError
from inspector.kernels import bcps as bk
from inspector.kernels.threads import map_threads
from inspector.kernels.prior import SizePrior, fit_size_prior
from inspector.kernels.robust import tukey_loss
from inspector.model import Alignment, BcpsPoints, PoseConfidence
from inspector.params import param
from inspector.pipeline import InspectionContext
from inspector.registry import StageRegistry, StageSpec


@dataclass(frozen=True)
class RayParams:
    step_mm: float = param(0.25, "coarse sampling step along each contour ray, mm", min=0.01, max=5.0)
    refine_levels: int = param(3, "refinement levels around the coarse minimum (each 5x finer: 2 um after 3)", min=0, max=6)
    refine_pose: bool = param(True, "re-align the reference on the selected points, then select again")
    refine_robust_mm: float = param(0.1, "robust scale of the re-alignment (points beyond are down-weighted), mm", min=0.001, max=100.0)
    refine_start_mm: float = param(1.0, "initial robust scale of the re-alignment, shrinking to refine_robust_mm, mm", min=0.001, max=100.0)
    refine_stride: int = param(3, "the selection that feeds the re-alignment uses every n-th contour point", min=1, max=1000)
    tolerance_px: float = param(0.05, "hull tolerance of a strict candidate, px (contour noise)", min=0.0, max=2.0)
    accept_px: float = param(0.2, "largest hull violation of a selected point, px, plus the silhouettes' contour uncertainty (hard-edged images: 0.3 px; beyond: the ray has no point)", min=0.0, max=5.0)
    violation_weight: float = param(3.0, "cost of 1 px of hull violation, in pixel footprints of deviation", min=0.0, max=1000.0)
    backend: Literal["numba", "numpy"] = param("numba", "hull kernel: compiled (numba) or the numpy reference")
    margin_mm: float = param(2.0, "margin added around the reconstruction's bounds for the rays, mm", min=0.0, max=100.0)
    prior: Literal["size", "nominal"] = param(
        "size", "what the final selection is made against: the reference under the part's best-fit scale "
        "(size), or the nominal reference; deviations are always against the nominal", )


@dataclass(frozen=True)
class SurfaceParams:
    refine_pose: bool = param(True, "re-align the reference on the selected points, then select again")
    refine_robust_mm: float = param(0.3, "robust scale of the re-alignment, mm", min=0.001, max=100.0)
    refine_start_mm: float = param(1.0, "initial robust scale of the re-alignment, shrinking to refine_robust_mm, mm", min=0.001, max=100.0)


def _bounds(ctx: InspectionContext, margin: float) -> np.ndarray:
    pts = ctx.need("reconstruction", "bcps").points
    if len(pts) == 0:
        raise StageError("the reconstruction is empty")
    return np.stack([pts.min(axis=0) - margin, pts.max(axis=0) + margin])


def _views(ctx: InspectionContext, cache: dict) -> list[bk.View]:
    if "views" not in cache:
        from inspector.kernels.silhouette import inside_map

        sils = ctx.need("silhouettes", "bcps")
        # OpenCV's distance transform and numpy release the GIL: cameras in parallel
        # (0.065 -> 0.035 s for 16 cameras on 2 cores).
        maps = map_threads(lambda s: inside_map(s.soft), sils)
        cache["views"] = [bk.View(cam, m, s.touches_border) for cam, m, s in zip(ctx.capture.rig.cameras, maps, sils)]
        if cache.get("backend", "numba") == "numba":
            from inspector.kernels.hull_jit import stack_views

            cache["stack"] = stack_views(cache["views"])
    return cache["views"]



def select_rays(ctx: InspectionContext, pose: np.ndarray, p: RayParams, cache: dict,
                prior: SizePrior | None = None) -> BcpsPoints:
    """Run the ``ray`` method on every camera for the reference placed at ``pose``.

    With a ``prior`` the candidates are ranked by their signed distance to the sized
    reference; the deviations returned are against the nominal one placed on the part
    (:meth:`SizePrior.rigid`).
    """
    sils = ctx.need("silhouettes", "bcps")
    ref = ctx.need("reference", "bcps")
    rig = ctx.capture.rig
    views = _views(ctx, cache)
    bounds = _bounds(ctx, p.margin_mm)
    prior = prior if prior is not None else SizePrior()
    sized = not prior.is_identity
    place = prior.placement(pose)  # = pose for the nominal reference
    nominal = prior.rigid(pose)
    inv = np.linalg.inv(place)

    def sd_fn(X: np.ndarray) -> np.ndarray:
        return prior.scale * ref.distance(X @ inv[:3, :3].T + inv[:3, 3])
    # Hard-edged silhouettes are less exact than the hull tolerance assumes: a ray's true
    # point can lie a few tenths of a pixel outside them (shaft, binary images: 10 points
    # 1-1.8 px off in bulges at 0.2 px, a false reject).
    accept = p.accept_px + max(s.edge_px for s in sils)
    out = {k: [] for k in ("points", "deviation", "camera", "pixel", "segment")}
    stride = cache.get("stride", 1)
    for i, (cam, sil) in enumerate(zip(rig.cameras, sils)):
        if len(sil.contour) == 0:
            continue
        origin, dirs, (r0, r1) = _contour_rays(ctx, cache, i)
        sub = slice(None, None, stride)
        pts, dev, seg, ok = bk.select_on_rays(
            origin, dirs[sub], views, i, sd_fn, bounds, stack=cache.get("stack"), step_mm=p.step_mm,
            refine_levels=cache.get("refine_levels", p.refine_levels), tolerance_px=p.tolerance_px,
            accept_px=accept,
            violation_weight=p.violation_weight, t_range=(r0[sub], r1[sub]),
            mesh=ref.distance if cache.get("stack") is not None else None, pose=place, sd_scale=prior.scale,
        )
        out["points"].append(pts[ok])
        out["deviation"].append(ref.signed_distance(pts[ok], nominal) if sized else dev[ok])
        out["camera"].append(np.full(int(ok.sum()), i, np.int32))
        out["pixel"].append(sil.contour[sub][ok])
        out["segment"].append(seg[ok])
    return _assemble(out, "ray")


def _contour_rays(ctx: InspectionContext, cache: dict, i: int) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Camera ``i``'s rays through its sub-pixel contour points: origin (3,), directions
    (M, 3) and the depth range (t0, t1) (M,) each can meet the reconstruction in (cached)."""
    ranges = cache.setdefault("ranges", {})
    if i not in ranges:
        cam = ctx.capture.rig.cameras[i]
        contour = ctx.need("silhouettes", "bcps")[i].contour
        recon = ctx.need("reconstruction", "bcps")
        origin, dirs = cam.rays(contour)
        # Only where the ray passes near the reconstruction (the hull is conservative).
        # A pose update can move a grazing ray's optimum far along it: every pass
        # searches the whole range.
        ranges[i] = (origin, dirs, bk.ray_ranges(
            cam, contour, origin, dirs, recon.points, max(1.0, 2.0 * recon.voxel_mm),
            compiled=cache.get("stack") is not None,
        ))
    return ranges[i]


def _assemble(out: dict[str, list[np.ndarray]], method: str) -> BcpsPoints:
    if not out["points"] or sum(len(a) for a in out["points"]) == 0:
        raise StageError("no contour ray met the reconstruction (no point selected)")
    return BcpsPoints(
        points=np.concatenate(out["points"]),
        deviation=np.concatenate(out["deviation"]),
        camera=np.concatenate(out["camera"]),
        pixel=np.concatenate(out["pixel"]),
        segment_mm=np.concatenate(out["segment"]),
        method=method,
    )


def select_surface(ctx: InspectionContext, pose: np.ndarray, p: SurfaceParams, cache: dict) -> BcpsPoints:
    """Run the ``surface`` method (the paper's) for the reference placed at ``pose``."""
    import cv2

    sils = ctx.need("silhouettes", "bcps")
    ref = ctx.need("reference", "bcps")
    recon = ctx.need("reconstruction", "bcps")
    sd = ref.signed_distance(recon.points, pose)
    out = {k: [] for k in ("points", "deviation", "camera", "pixel", "segment")}
    kernel = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)
    for i, (cam, sil) in enumerate(zip(ctx.capture.rig.cameras, sils)):
        m = sil.mask.astype(np.uint8)
        contour = sil.mask & ~cv2.erode(m, kernel, borderType=cv2.BORDER_REPLICATE).astype(bool)
        idx, pix, seg, dev = bk.select_on_surface(recon.points, sd, cam, contour)
        out["points"].append(recon.points[idx])
        out["deviation"].append(dev)
        out["camera"].append(np.full(len(idx), i, np.int32))
        out["pixel"].append(pix)
        out["segment"].append(seg)
    return _assemble(out, "surface")


def _size_prior(ctx: InspectionContext, sel: BcpsPoints, pose: np.ndarray, p: RayParams,
                start: np.ndarray | None = None, axis: np.ndarray | None = None) -> SizePrior:
    """The part's best-fit size model, from a first selection (see :mod:`inspector.kernels.prior`).

    ``axis`` (3,), reference frame: an axis of near-symmetry whose turn the silhouettes
    decide; the fit's rotation loses its component about it (the points pin that turn so
    weakly that the fit wanders: a keyed shaft at 0.98 on 8 cameras, 5 degrees).
    """
    ref = ctx.need("reference", "bcps")
    V = ref.vertices
    prior = fit_size_prior(ref.to_reference_frame(sel.points, pose), ref.distance,
                           centre=0.5 * (V.min(axis=0) + V.max(axis=0)), robust_mm=p.refine_robust_mm,
                           start_mm=p.refine_start_mm, start=start)
    if axis is None or prior.is_identity:
        return prior
    w = np.asarray(prior.rotation, float)
    a = np.asarray(axis, float)
    q = w - (w @ a) * a
    return dataclasses.replace(prior, rotation=(float(q[0]), float(q[1]), float(q[2])))


#: Largest size error (relative) the pose search must tolerate.
_SIZE_RANGE = 0.035
#: A re-fit that turns the pose by more than this (degrees) is followed by a new selection
#: and re-fit, at most this many times in all.
_RESELECT_DEG = 0.05
_ATTEMPTS = 4
#: The turn about an axis of near-symmetry, judged on the silhouettes: Tukey cutoff of the
#: contour rays' residuals (mm); the scan's step, about (degrees; its cutoff is as wide as the
#: outermost point moves in a step); every n-th contour ray; the coarse (search) and fine
#: (polish) sampling along the rays (step mm, refinement levels); the basin search's step
#: (degrees) and how many of the scan's lowest minima it searches; a turn beyond this
#: (degrees) is settled again by the points; the final polish's half-width (degrees) and
#: every Brent search's tolerance (degrees).
_SIL_CUTOFF_MM = 0.1
_SIL_STEP_DEG = 5.0
_SIL_STRIDE = 9
_SIL_FINE_STRIDE = 3
_SIL_COARSE = (0.5, 2)
_SIL_FINE = (0.25, 3)
_SIL_LOCAL_DEG = 1.0
_SIL_BASINS = 2
_SIL_RESETTLE_DEG = 3.0
_SIL_POLISH_DEG = 1.5
_SIL_XATOL_DEG = 0.02


def _turn_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle of the rotation between two poses (4, 4), degrees."""
    R = a[:3, :3].T @ b[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


_ZONES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


class _TurnJudge:
    """The silhouette loss of the reference turned about its axis, under one placement.

    The loss of a turn is the mean Tukey loss (0..1) at ``_SIL_CUTOFF_MM`` of the silhouette
    residuals (:func:`~inspector.kernels.bcps.ray_min_distance`) of every ``stride``-th
    contour ray against the reference placed by ``pose`` under ``prior`` and turned about its
    own axis (:func:`_turned`), about the residuals' median at the judged turn. The residuals
    are what the silhouettes say about a pose before any point is selected: for the sized
    reference at the part's pose every contour ray grazes it (keyed shaft at 0.98, 16
    cameras: 1st-99th percentile -5 to +6 um). The BCPS selection cannot judge a turn as
    well: each ray's point may lie anywhere on its hull segment (3.5 mm median), so it
    follows the reference it is selected against.

    Only the rays through the reference's :class:`~inspector.kernels.registration.TurnZone`
    are evaluated at each turn; the others add the same loss at every turn (evaluated once).
    """

    def __init__(self, ctx: InspectionContext, cache: dict, pose: np.ndarray, prior: SizePrior, axis: np.ndarray,
                 centre: np.ndarray, stride: int, fine: bool) -> None:
        from inspector.kernels.registration import turn_zone

        ref = ctx.need("reference", "bcps")
        # The zone depends on the reference alone (40-85 ms): once per reference, not per part.
        zone = _ZONES.get(ref)
        if zone is None:
            zone = _ZONES[ref] = turn_zone(ref.distance.near, ref.vertices, axis, centre)
        self.pose, self.prior, self.axis, self.centre = pose, prior, np.asarray(axis, float), np.asarray(centre, float)
        self._ref, self._fine = ref, fine
        self._place = prior.placement(pose)
        inv = np.linalg.inv(self._place)
        self._rays, rest = [], []
        n = 0
        for i, sil in enumerate(ctx.need("silhouettes", "bcps")):
            if len(sil.contour) == 0:
                continue
            origin, dirs, (r0, r1) = _contour_rays(ctx, cache, i)
            sub = slice(None, None, stride)
            d, a, b = dirs[sub], r0[sub], r1[sub]
            ok = a <= b
            n += int(ok.sum())
            act = ok & self._crosses(zone, origin, d, a, b, inv)
            self._rays.append((origin, d[act], a[act], b[act]))
            rest.append((origin, d[ok & ~act], a[ok & ~act], b[ok & ~act]))
        self.n = n
        # The median and the turn-independent part, from the rays left out.
        r_act = self._at_pose = self._residuals(np.eye(4))
        r_rest = np.concatenate([self._min_distance(inv, *ray) for ray in rest]) if rest else np.zeros(0)
        r_all = np.concatenate([r_act, r_rest])
        r_all = r_all[np.isfinite(r_all)]
        self.median = float(np.median(r_all)) if len(r_all) else 0.0
        self._rest = r_rest[np.isfinite(r_rest)] - self.median

    @staticmethod
    def _crosses(zone, origin: np.ndarray, dirs: np.ndarray, t0: np.ndarray, t1: np.ndarray, inv: np.ndarray) -> np.ndarray:
        """(M,) bool: rays with a point (every 0.5 mm of their range) in the zone's variable cells."""
        if not len(dirs):
            return np.zeros(0, bool)
        top = np.where(t0 <= t1, t1, t0)
        n = int(np.ceil(float(np.max(top - t0)) / 0.5)) + 1
        tt = np.minimum(t0[:, None] + 0.5 * np.arange(n)[None, :], top[:, None])
        X = (origin + tt[..., None] * dirs[:, None, :]).reshape(-1, 3)
        Y = X @ inv[:3, :3].T + inv[:3, 3]
        # inv maps the world into the nominal reference's frame (before any size model): the zone's.
        return zone.hits(Y).reshape(tt.shape).any(axis=1)

    def _min_distance(self, inv: np.ndarray, origin: np.ndarray, dirs: np.ndarray, t0: np.ndarray,
                      t1: np.ndarray) -> np.ndarray:
        index, scale = self._ref.distance.near, self.prior.scale

        def sd(X: np.ndarray) -> np.ndarray:
            return scale * index(X @ inv[:3, :3].T + inv[:3, 3])

        step, levels = _SIL_FINE if self._fine else _SIL_COARSE
        return bk.ray_min_distance(origin, dirs, t0, t1, sd, step_mm=step, levels=levels)

    def _residuals(self, turn: np.ndarray) -> np.ndarray:
        inv = np.linalg.inv(self._place @ turn)
        res = [self._min_distance(inv, *ray) for ray in self._rays]
        return np.concatenate(res) if res else np.zeros(0)

    def loss(self, angle_deg: float, cutoff_mm: float = _SIL_CUTOFF_MM) -> float:
        """Mean loss (0..1) of the rays at the turn ``angle_deg`` about the axis, Tukey cutoff
        ``cutoff_mm``."""
        r = self._at_pose if angle_deg == 0.0 else self._residuals(_turn(self.axis, self.centre, angle_deg))
        r = r[np.isfinite(r)] - self.median
        return float(np.sum(tukey_loss(r, cutoff_mm)) + np.sum(tukey_loss(self._rest, cutoff_mm))) / max(self.n, 1)

    def turned(self, angle_deg: float) -> np.ndarray:
        """The judged pose turned by ``angle_deg`` (:func:`_turned`)."""
        return _turned(self.pose, self.prior, self.axis, self.centre, angle_deg)


def _silhouette_scan(judge: _TurnJudge, scan):
    """``scan``'s turns about the axis, about every ``_SIL_STEP_DEG``, judged on the
    silhouettes at a cutoff as wide as the outermost point moves between two of them (at 0.1
    mm a flat's basin is +-0.6 degree wide on a Ø20 shaft, and a grid would step over it):
    an :class:`~inspector.kernels.registration.AxisScan` whose cost is :meth:`_TurnJudge.loss`
    (``inf`` for a turn that leaves the visual hull, the pose's own for a symmetry of the
    reference) and whose ``n_points`` are the contour points it stands for."""
    k = max(1, int(round(len(scan.angles_deg) * _SIL_STEP_DEG / 360.0)))
    idx = np.arange(0, len(scan.angles_deg), k)
    turns = scan.angles_deg[idx]
    wide = max(_SIL_CUTOFF_MM, scan.radius_mm * np.radians(360.0 / len(scan.angles_deg) * k))
    cost = np.full(len(idx), np.inf)
    for j, i in enumerate(idx):
        if j == 0 or (scan.inside_hull[i] and not scan.symmetric[i]):
            cost[j] = judge.loss(float(turns[j]), wide)
    cost[scan.symmetric[idx]] = cost[0]
    return dataclasses.replace(scan, angles_deg=turns, cost=cost, moved=scan.moved[idx],
                               poke=None if scan.poke is None else scan.poke[idx], cutoff_mm=wide,
                               n_points=judge.n * _SIL_STRIDE)


def _basins(sil) -> list[float]:
    """The turns (degrees, -180..180) of the scan's lowest local minima, the pose's own
    turn (0) whenever it is one, none near another symmetry of the reference."""
    a = (sil.angles_deg + 180.0) % 360.0 - 180.0
    sym = a[sil.symmetric & (np.abs(a) > 1e-9)]
    gap = np.abs((a[:, None] - sym[None, :] + 180.0) % 360.0 - 180.0)
    near = (gap <= 1.5 * _SIL_STEP_DEG).any(axis=1) if len(sym) else np.zeros(len(a), bool)
    out = [float(a[i]) for i in sil.minima(len(a)) if np.isfinite(sil.cost[i]) and not near[i]]
    return out or [0.0]


def _polish_turn(judge: _TurnJudge, around: float, half_deg: float) -> tuple[float, float]:
    """The turn (degrees) within ``around +- half_deg`` whose silhouettes fit best at
    ``_SIL_CUTOFF_MM``, and its loss: a bounded Brent search to ``_SIL_XATOL_DEG``."""
    from scipy.optimize import minimize_scalar

    best = minimize_scalar(judge.loss, bounds=(around - half_deg, around + half_deg), method="bounded",
                           options={"xatol": _SIL_XATOL_DEG})
    return float(best.x), float(best.fun)


def _search_turn(judge: _TurnJudge, start: float, half_deg: float, radius_mm: float) -> tuple[float, float]:
    """The best turn (degrees) within ``half_deg`` of ``start``, and its loss at
    ``_SIL_CUTOFF_MM``: every ``_SIL_LOCAL_DEG`` there (at the cutoff of that step at the
    outermost radius), then a Brent search about the best of those."""
    cutoff = max(_SIL_CUTOFF_MM, radius_mm * np.radians(_SIL_LOCAL_DEG))
    grid = start + np.arange(-half_deg, half_deg + 1e-9, _SIL_LOCAL_DEG)
    b = float(grid[int(np.argmin([judge.loss(float(a), cutoff) for a in grid]))])
    return _polish_turn(judge, b, _SIL_LOCAL_DEG)


def _judge_turns(judge: _TurnJudge, scan) -> tuple[float, PoseConfidence]:
    """The turn (degrees) the silhouettes choose about the judged pose, and how firmly.

    The scan (:func:`_silhouette_scan`) names the basins; each of the ``_SIL_BASINS`` lowest
    is searched to its best turn (:func:`_search_turn`), and the lowest wins. The confidence
    (:func:`~inspector.kernels.registration.pose_confidence` of the scan for the axis, the
    symmetries and the hull range) takes its runner-up and margin from the other searched
    basins, each at its own best turn: a basin narrower than the scan's step is not judged
    by a turn beside it.
    """
    from inspector.kernels.registration import AMBIGUOUS_POINTS, pose_confidence

    sil = _silhouette_scan(judge, scan)
    found = [_search_turn(judge, b, _SIL_STEP_DEG, scan.radius_mm) for b in _basins(sil)[:_SIL_BASINS]]
    order = sorted(range(len(found)), key=lambda i: found[i][1])
    angle, loss = found[order[0]]
    conf = pose_confidence(sil)
    width = np.degrees(2.0 * _SIL_CUTOFF_MM / scan.radius_mm) + _SIL_LOCAL_DEG
    others = [found[i] for i in order[1:] if abs((found[i][0] - angle + 180.0) % 360.0 - 180.0) > width]
    if others:
        runner, rloss = others[0]
        margin = rloss - loss
        points = int(round(margin * judge.n * _SIL_STRIDE))
        conf = dataclasses.replace(conf, runner_up_deg=float((runner - angle + 180.0) % 360.0 - 180.0), margin=margin,
                                   margin_points=points, cutoff_mm=_SIL_CUTOFF_MM,
                                   ambiguous=points < AMBIGUOUS_POINTS)
    else:
        # One basin (the others are symmetries or leave the hull): no other turn competes.
        conf = dataclasses.replace(conf, runner_up_deg=None, margin=None, margin_points=None, ambiguous=False)
    return angle, conf


def _turned(pose: np.ndarray, prior: SizePrior, axis: np.ndarray, centre: np.ndarray, angle_deg: float) -> np.ndarray:
    """The rigid pose (4, 4) that places the reference as ``pose`` does, turned by
    ``angle_deg`` about its own axis *before* the size model: ``placement(result) =
    placement(pose) @ turn``. (Turning after it would also turn the model's shift and tilt,
    fitted at ``pose``: 0.03-0.05 mm at the ends of a 40 mm shaft after a half turn.)"""
    S = np.linalg.inv(pose) @ prior.placement(pose)
    return pose @ S @ _turn(axis, centre, angle_deg) @ np.linalg.inv(S)


def _axis_turn_deg(a: np.ndarray, b: np.ndarray, axis: np.ndarray) -> float:
    """The turn (degrees) about ``axis`` (reference frame) of placement ``b`` (4, 4, maybe
    scaled) relative to placement ``a``."""
    from scipy.spatial.transform import Rotation

    M = np.linalg.inv(a)[:3, :3] @ b[:3, :3]
    M = M / np.cbrt(np.linalg.det(M))
    return float(np.degrees(Rotation.from_matrix(M).as_rotvec() @ np.asarray(axis, float)))


def _turn(axis: np.ndarray, centre: np.ndarray, angle_deg: float) -> np.ndarray:
    """(4, 4) turn of the reference frame by ``angle_deg`` about the line (axis, centre)."""
    from inspector.kernels.registration import turns_about_axis

    return turns_about_axis(np.asarray(axis, float), np.asarray(centre, float), np.array([angle_deg]))[0]


def _run(select):
    def run(ctx: InspectionContext, p) -> InspectionContext:
        from inspector.kernels.registration import pose_confidence, refine_on_points, scan_about_axis

        alignment = ctx.need("alignment", "bcps")
        ref = ctx.need("reference", "bcps")
        cache: dict = {"backend": getattr(p, "backend", "numba"), "select": select}
        if not p.refine_pose:
            return ctx.evolve(bcps=select(ctx, alignment.pose, p, cache))

        def sparse(pose: np.ndarray, **prior) -> BcpsPoints:
            # A selection that only feeds a fit, which averages thousands of points: a
            # third of the rays and one refinement level less (25 um steps) are enough.
            if getattr(p, "refine_levels", 0) > 1:
                cache["refine_levels"] = p.refine_levels - 1
            cache["stride"] = getattr(p, "refine_stride", 1)
            try:
                return select(ctx, pose, p, cache, **prior)
            finally:
                cache.pop("refine_levels", None)
                cache.pop("stride", None)

        sel = sparse(alignment.pose)
        # A size error shifts every deviation the same way: it is not a misalignment.
        # Fitting the points themselves would slide the reference until some faces are
        # flush (BCPS points sit on edges, each close to two faces) and report the
        # others twice too far. So the fit is on the points moved by the median
        # deviation along the reference normals: a uniformly small part comes out
        # centred and uniformly small. The robust scale starts wide (refine_start_mm):
        # on a nearly symmetric part (a shaft with a flat) the few points that fix
        # the rotation about its axis are off by tenths of a millimetre, beyond the
        # final scale, until the fit has used them.
        # The first fit also scans every turn about the reference's axis of
        # near-symmetry, if it has one, and starts from the best few: the global
        # alignment's fit on the bulgy hull can end anywhere about it (shaft with a flat:
        # ten degrees, 1.2 mm at the flat, a false reject; flange keyed by four bolt
        # holes: 6 degrees; a keyed shaft: 160 degrees), a local minimum a single fit
        # does not leave.
        hull = ctx.need("reconstruction", "bcps")
        # The part lies inside its hull up to the voxel size; the nominal reference pokes out
        # of a part up to 3 % small by 3 % of its radius.
        hull_mm = max(2.0 * hull.voxel_mm, _SIZE_RANGE * float(np.ptp(ref.vertices, axis=0).max()) / 2.0)

        def settle(pose: np.ndarray, sel: BcpsPoints, scan: bool):
            for attempt in range(_ATTEMPTS):
                last = pose
                for i in range(2):
                    offset = float(np.median(ref.signed_distance(sel.points, pose)))
                    target = sel.points - offset * ref.surface_normals(sel.points, pose)
                    refined = refine_on_points(
                        target, ref.vertices, ref.faces, pose, robust_mm=p.refine_robust_mm, index=ref.distance,
                        start_mm=p.refine_start_mm, axis_scan=(scan and i == 0 and attempt == 0),
                        hull_points=hull.points, hull_mm=hull_mm,
                    )
                    pose = refined.pose
                    if abs(offset) < 0.5 * p.refine_robust_mm:
                        break
                # The selection follows the pose it is made against (a ray through a bolt
                # hole picks its point deepest in the reference's material when the
                # reference's hole is elsewhere), so one re-fit moves only part of the way:
                # select again and re-fit until the pose settles (flange keyed by four
                # holes, 6 degrees off after the global alignment: 2.1, 1.6, 0.55, 0.17
                # degrees after each re-fit).
                if attempt == _ATTEMPTS - 1 or _turn_deg(last, pose) < _RESELECT_DEG:
                    break
                sel = sparse(pose)
            return refined, sel

        refined, sel = settle(alignment.pose, sel, True)

        def scan_at(pose: np.ndarray, sel: BcpsPoints):
            return scan_about_axis(sel.points, ref.vertices, ref.faces, pose, cutoff_mm=p.refine_start_mm,
                                   index=ref.distance, hull_points=hull.points, hull_mm=hull_mm)

        scan = scan_at(refined.pose, sel)
        sized = getattr(p, "prior", "nominal") == "size"
        judged = None
        # The axis whose turn the silhouettes judge (None: no axis, or one every turn about
        # which is a symmetry).
        axis = scan.axis if scan is not None and scan.distinct().any() else None
        if scan is not None and axis is not None:
            # The turn about an axis of near-symmetry is fixed by features a fraction of a
            # millimetre deep in the silhouettes (a keyway: 0.1-0.5 mm in one or two views),
            # which the points selected against a pose cannot judge (they follow it). So the
            # turns are judged on the contour rays themselves, against the reference under
            # the part's size (a 2 % small shaft is 0.2 mm in everywhere, which would drown
            # the keyway): every 6 degrees the hull allows, then the two lowest basins each
            # to its best turn (:func:`_judge_turns`). Keyed shaft, 16 cameras, 0.98: the
            # points alone left it 120 degrees off; now 0.01.
            prior0 = _size_prior(ctx, sel, refined.pose, p, axis=axis) if sized else SizePrior()
            judge = _TurnJudge(ctx, cache, refined.pose, prior0, axis, scan.centre, _SIL_STRIDE, False)
            angle, confidence = _judge_turns(judge, scan)
            if abs(angle) > _SIL_RESETTLE_DEG:
                # Another turn: the points settle the other five degrees of freedom there
                # (and move the turn again: a keyed shaft on 8 cameras, up to 6.5 degrees),
                # and the silhouettes judge again about it, under a size model fitted there.
                turned = judge.turned(angle)
                refined, sel = settle(turned, sparse(turned), False)
                prior0 = _size_prior(ctx, sel, refined.pose, p, axis=axis) if sized else SizePrior()
                scan = scan_at(refined.pose, sel)
                judge = _TurnJudge(ctx, cache, refined.pose, prior0, axis, scan.centre, _SIL_STRIDE, False)
                angle, confidence = _judge_turns(judge, scan)
            refined = dataclasses.replace(refined, pose=judge.turned(angle))
            judged = prior0.placement(refined.pose)
        else:
            # No turn to judge (a torus: every turn is a symmetry): its axis and symmetries.
            confidence = pose_confidence(scan)

        def polish(pose: np.ndarray, prior: SizePrior) -> np.ndarray:
            # The size fit below keeps the turn (its rotation loses its component about the
            # axis), but its shift and tilt and the selections it stands on change the
            # silhouettes' best turn by tenths of a degree: the final turn is theirs, on the
            # fine loss of every third ray, about the turn judged above, when they decide it.
            if judged is None or axis is None or confidence.ambiguous:
                return pose
            since = _axis_turn_deg(judged, prior.placement(pose), axis)
            fine = _TurnJudge(ctx, cache, pose, prior, axis, scan.centre, _SIL_FINE_STRIDE, True)
            return fine.turned(_polish_turn(fine, -since, _SIL_POLISH_DEG)[0])

        alignment = Alignment(refined.pose, refined.fitness, refined.rmse_mm, f"{alignment.method}+bcps-refine")
        if not sized:
            alignment = dataclasses.replace(alignment, pose=polish(alignment.pose, SizePrior()), confidence=confidence)
            return ctx.evolve(bcps=select(ctx, alignment.pose, p, cache), alignment=alignment)
        prior = _size_prior(ctx, sel, alignment.pose, p, axis=axis)
        if not prior.is_identity:
            # The first selection was made against the nominal reference, whose deepest
            # points over the faces that moved more bias the scale towards 1 (hex nut at
            # 0.98: 0.9833). One more sparse selection against the fitted prior, and a
            # re-fit from it, remove most of that bias.
            # Repeated while the fit still turns the pose: the keying features of a scaled
            # part sit off the nominal at any turn, so the rigid re-fit above can end a
            # degree off (flange at 0.98: 1.09 degrees; 0.25 after one re-fit against the
            # prior).
            for _ in range(_ATTEMPTS - 1):
                refit = _size_prior(ctx, sparse(alignment.pose, prior=prior), alignment.pose, p, prior.rigid(), axis=axis)
                if refit.is_identity:
                    break
                step = _turn_deg(prior.rigid(alignment.pose), refit.rigid(alignment.pose))
                prior = refit
                if step < _RESELECT_DEG:
                    break
        alignment = dataclasses.replace(alignment, pose=polish(alignment.pose, prior))
        sel = dataclasses.replace(select(ctx, alignment.pose, p, cache, prior=prior), size=prior)
        if not prior.is_identity:
            alignment = dataclasses.replace(alignment, pose=prior.rigid(alignment.pose), method=f"{alignment.method}+size")
        alignment = dataclasses.replace(alignment, confidence=confidence)
        return ctx.evolve(bcps=sel, alignment=alignment)

    return run


@hookimpl
def inspector_register_stages(registry: StageRegistry) -> None:
    registry.add(
        StageSpec(
            name="bcps.ray",
            run=_run(select_rays),
            params=RayParams,
            requires=("segment", "carve", "align"),
            doc="BCPS on the exact rays through sub-pixel contour points (image-based visual hull), signed argmin",
        )
    )
    registry.add(
        StageSpec(
            name="bcps.surface",
            run=_run(select_surface),
            params=SurfaceParams,
            requires=("segment", "carve", "align"),
            doc="BCPS on the reconstruction's surface points falling on contour pixels (the paper's method)",
        )
    )
