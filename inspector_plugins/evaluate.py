"""Stage ``evaluate.tolerance``: per-point tolerance bands, defect clusters and the verdict.

A BCPS deviation beyond tolerance is a real defect (the selection is the best case the
images allow); missing material is measured in full, excess material is a lower bound.
A part fails when a cluster of at least ``min_points`` out-of-tolerance points, selected on
the contours of at least ``min_cameras`` cameras, exists; smaller groups, and groups from
fewer cameras, are counted in ``stats.isolated_out_of_tolerance`` but do not reject it. Two
cameras by default: image noise in one camera moves its own contour only (sigma 6 with 1 %
impulses: 3 points 0.14 mm off, all from one camera, rejected a good cube-sphere), while a
defect large enough to matter lies on several cameras' contours (the dents of the
foreign-capture matrix: 2-6 cameras).

Calibration health (``stats.calibration``): every part also checks the rig it is measured
with. Each camera's contour rays should graze the reference sized and placed where all the
cameras put it (:mod:`inspector.kernels.health`); how far a camera's image is off from that
(``off_px``: its image shift fitted to its residuals, or its own uniform offset, in pixels,
the offset common to all cameras removed) is at most 0.13 px with an exact rig and about the
error for a camera turned by a pixel or more. A camera beyond ``health_px`` is *flagged*: a
warning names it, and a defect must stand on points that do not rest on a flagged camera
(``min_points`` of them, from ``min_cameras`` cameras) to reject the part; one that stands
only with them is kept aside in ``stats.unconfirmed_defects`` and the verdict is ``error``
naming the camera, never a fail (or a pass) on that camera's word.

Parameters that make a rejection impossible are refused, never run silently (issue 27):
``min_cameras`` above the rig's cameras, or ``min_points`` above the most points the rig's
images can give (one per pixel edge: :meth:`EvaluateParams.rig_problem`), stop the run when a
capture of that rig is inspected (a RecipeError, exit 2: nothing is written for it; ``inspector
recipe check --rig RIG.json`` says so before any run); ``min_points`` above the points measured
on one part makes that part's verdict ``error`` (it could not have been rejected), not a pass.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from inspector import hookimpl
from inspector.errors import RecipeError
from inspector.kernels import bcps as bk
from inspector.kernels.bcps import confidence
from inspector.kernels.deviation import cluster_points, deviation_stats
from inspector.kernels.extent import bounds_of
from inspector.kernels.silhouette import sample_bilinear
from inspector.model import Defect, DeviationStats, Evaluation, EvaluationSummary, RegionSummary, Rig
from inspector.params import param
from inspector.pipeline import InspectionContext, Tolerance
from inspector.registry import StageRegistry, StageSpec

if TYPE_CHECKING:
    from inspector.reference import Reference


#: Narrowest tolerance limit, in pixel footprints, a verdict can be trusted at: below it,
#: image noise alone rejects good parts (simulated cube30 at +-0.1 mm, 6 captures per rig: no
#: false reject at 0.5 px, i.e. 0.2 mm/px; 3 of 6 at 0.4 px; 4 of 6 at 0.33 px).
CAPABLE_LIMIT_PX = 0.5


def capability_warning(tol, footprint_mm: float) -> str | None:
    """A warning when a tolerance limit is narrower than :data:`CAPABLE_LIMIT_PX` pixel
    footprints at the rig centre (the measurement is not capable of that tolerance)."""
    bands = [("", tol.default)] + [(f" of region {r.name!r}", r.band) for r in tol.regions]
    where, band = min(bands, key=lambda wb: min(-wb[1].lower, wb[1].upper))
    narrow = abs(min(-band.lower, band.upper))  # >= 0 (recipes check lower <= 0 <= upper); abs: no -0.0
    if footprint_mm <= 0 or narrow / footprint_mm >= CAPABLE_LIMIT_PX - 1e-9:
        return None
    return (f"tolerance{where} [{band.lower:+.3g}, {band.upper:+.3g}] mm is {narrow / footprint_mm:.2f} px at this "
            f"rig's {footprint_mm:.3g} mm pixel footprint: below {CAPABLE_LIMIT_PX} px image noise alone can reject "
            "good parts; widen it or use a finer rig")


@dataclass(frozen=True)
class EvaluateParams:
    cluster_radius_mm: float = param(1.0, "out-of-tolerance points closer than this belong to one defect, mm", min=0.01, max=1000.0)
    min_points: int = param(3, "points a defect needs to reject the part", min=1, max=1_000_000)
    min_cameras: int = param(2, "cameras whose contours a defect's points must come from to reject the part", min=1, max=1024)
    health_px: float = param(
        0.3, "calibration health: a camera whose image is off from where the other cameras put the part by more than "
        "this (px; exact rigs: at most 0.13, a camera turned by 1 px: 0.79-1.03) is flagged: a warning names it, and a "
        "defect that rests on it is an error, not a fail; 0: not checked", min=0.0, max=100.0)
    health_rays: int = param(
        64, "calibration health: contour rays checked per camera, evenly spaced along its contour (the cost grows "
        "with them: 16 cameras x 64 rays, about 11 ms per part on 2 cores)", min=8, max=100_000)

    def rig_problem(self, rig: Rig) -> str | None:
        """Why these parameters could never reject a part measured with ``rig``, in one line
        naming the key and the rig; None when a rejection is possible.

        A defect needs ``min_cameras`` cameras' contours and ``min_points`` points. Each BCPS
        point comes from one contour point, and marching squares puts at most one contour
        point on each pixel edge of an image: a ``w`` x ``h`` camera gives at most
        ``(w - 1) h + w (h - 1)`` points, a bound no part can exceed (real parts give a few
        thousand per camera).
        """
        n = len(rig)
        if n == 0:
            return None  # no rig to judge by (a context built by hand)
        if self.min_cameras > n:
            return (f"min_cameras = {self.min_cameras} but the rig has {n} cameras: no defect could ever reject a part "
                    f"(it must lie on {self.min_cameras} cameras' contours); set min_cameras to at most {n}")
        most = sum((c.width - 1) * c.height + c.width * (c.height - 1) for c in rig.cameras)
        if self.min_points > most:
            sizes = sorted({f"{c.width}x{c.height}" for c in rig.cameras})
            return (f"min_points = {self.min_points} but the rig's {n} cameras ({', '.join(sizes)} px) can give at most "
                    f"{most} points (one per pixel edge): no defect could ever reject a part; lower min_points")
        return None


def evaluate(ctx: InspectionContext, p: EvaluateParams) -> InspectionContext:
    why = p.rig_problem(ctx.capture.rig)
    if why is not None:  # the recipe, not the part: the run is refused (exit 2), no verdict is made up
        raise RecipeError(f"capture '{ctx.capture.name}': evaluate.tolerance {why}")
    sel = ctx.need("bcps", "evaluate")
    pose = ctx.need("alignment", "evaluate").pose
    ref = ctx.need("reference", "evaluate")
    tol = ctx.tolerance
    dev = sel.deviation
    n = len(dev)
    lower, upper, region = _bands(ref, sel.points, pose, tol, n)
    names = [r.name for r in tol.regions]
    health = calibration_health(ctx, p)
    flagged = np.array(health["flagged_index"] if health is not None else [], int)
    missing = dev < lower
    excess = dev > upper
    # Per flagged camera, the points that rest on it (None: no camera flagged).
    leaning = _leaning(ctx, sel, np.flatnonzero(missing | excess), flagged, health) if len(flagged) else None
    defects, resting, isolated = _clusters(sel, p, missing, excess, leaning, region, names)
    out = missing | excess
    stats = _stats(ctx, sel, tol, health, dev, out, region, names, isolated)
    summary = _summary(tol, dev, out, region, stats["within_tolerance"])
    verdict, defects, error, unconfirmed = _verdict(ctx, p, health, defects, resting, n)
    if unconfirmed:
        stats["unconfirmed_defects"] = unconfirmed
    return ctx.evolve(evaluation=Evaluation(verdict, stats, tuple(defects), out, summary=summary, error=error))


def _bands(ref: Reference, points: np.ndarray, pose: np.ndarray, tol: Tolerance,
           n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each point's tolerance band: the default one, or that of the last named region
    (reference frame, ``ref`` placed at ``pose``) that holds it.

    Parameters
    ----------
    ref : Reference
    points : (N, 3) float
        BCPS points, world mm.
    pose : (4, 4) float
        Reference -> world.
    tol : Tolerance
    n : int
        ``N``.

    Returns
    -------
    lower, upper : (N,) float
        The band's limits, mm.
    region : (N,) int
        Index of the region in ``tol.regions`` (-1: the default band).
    """
    lower = np.full(n, tol.default.lower)
    upper = np.full(n, tol.default.upper)
    region = np.full(n, -1)
    if tol.regions:
        local = ref.to_reference_frame(points, pose)
        for k, r in enumerate(tol.regions):
            inside = r.contains(local)
            lower[inside], upper[inside], region[inside] = r.band.lower, r.band.upper, k
    return lower, upper, region


def _clusters(sel: Any, p: EvaluateParams, missing: np.ndarray, excess: np.ndarray,
              leaning: dict[int, np.ndarray] | None, region: np.ndarray,
              names: list[str]) -> tuple[list[Defect], list[tuple[Defect, list[int]]], int]:
    """The out-of-tolerance points clustered (``cluster_radius_mm``) into defects.

    Parameters
    ----------
    sel : BcpsSelection
        The points (N, 3) mm, their deviations (N,) mm and cameras (N,).
    missing, excess : (N,) bool
        Below / above their band.
    leaning : dict, optional
        Per flagged camera, (N,) bool: the points that rest on it (None: no camera flagged).
    region : (N,) int
        Each point's region (-1: the default band).
    names : list of str
        The regions' names.

    Returns
    -------
    defects : list of Defect
        The clusters that stand (``min_points`` points from ``min_cameras`` cameras) without
        the points resting on a flagged camera, worst first.
    resting : list of (Defect, list of int)
        The clusters that stand only with them, and the flagged cameras they rest on, worst
        first.
    isolated : int
        Out-of-tolerance points in clusters that do not stand.
    """
    dev = sel.deviation
    resting: list[tuple[Defect, list[int]]] = []  # (defect, the flagged cameras it rests on)
    defects: list[Defect] = []
    isolated = 0
    for kind, flag in (("missing", missing), ("excess", excess)):
        idx = np.flatnonzero(flag)
        if idx.size == 0:
            continue
        labels = cluster_points(sel.points[idx], p.cluster_radius_mm)
        for lab in np.unique(labels):
            members = idx[labels == lab]
            if not _stands(members, sel.camera, p):
                isolated += int(members.size)
                continue
            if leaning is None:
                defects.append(_defect(kind, members, sel.points, dev, region, names))
                continue
            # The points that rest on a flagged camera do not count: the defect must stand without them.
            on = {c: m[members] for c, m in leaning.items() if m[members].any()}
            sound = members[~np.any(list(on.values()), axis=0)] if on else members
            if _stands(sound, sel.camera, p):
                defects.append(_defect(kind, sound, sel.points, dev, region, names))
            else:
                resting.append((_defect(kind, members, sel.points, dev, region, names), sorted(on)))
    defects.sort(key=lambda d: -abs(d.worst_mm))
    resting.sort(key=lambda dc: -abs(dc[0].worst_mm))
    return defects, resting, isolated


def _stats(ctx: InspectionContext, sel: Any, tol: Tolerance, health: dict[str, Any] | None, dev: np.ndarray, out: np.ndarray,
           region: np.ndarray, names: list[str], isolated: int) -> dict[str, Any]:
    """The evaluation's ``stats`` (result.json): deviations, tolerance, footprint and its
    capability warning, calibration health, confidence and per-region statistics.

    Parameters
    ----------
    dev : (N,) float
        Deviations, mm.
    out : (N,) bool
        Out of tolerance.
    region : (N,) int
        Each point's region (-1: the default band).
    names : list of str
        The regions' names.
    isolated : int
        Out-of-tolerance points in clusters that do not stand.
    """
    n = len(dev)
    stats = {
        "n_points": int(n),
        "deviation_mm": deviation_stats(dev),
        "within_tolerance": float(1.0 - out.mean()) if n else 0.0,
        "out_of_tolerance_points": int(out.sum()),
        "isolated_out_of_tolerance": isolated,
        "tolerance_mm": {"lower": tol.default.lower, "upper": tol.default.upper},
        "bcps_method": sel.method,
        "segment_mm": {"median": float(np.median(sel.segment_mm)) if n else 0.0},
    }
    fp = ctx.capture.rig.footprint_mm() if len(ctx.capture.rig) else None
    warnings: list[str] = []
    if fp is not None:
        stats["footprint_mm"] = fp
        warning = capability_warning(tol, fp)
        if warning is not None:
            warnings.append(warning)
    if health is not None:
        stats["calibration"] = {k: v for k, v in health.items() if k not in ("flagged_index", "names")}
        cams = stats["calibration"]["cameras"]
        warnings += [f"{name} disagrees with the other cameras by {_px(cams[name]['off_px'])} px: check its "
                     "mounting or recalibrate" for name in stats["calibration"]["flagged"]]
        if health["not_judged"]:
            warnings.append(health["not_judged"])
    if warnings:
        stats["warnings"] = warnings
    if n and fp is not None:
        conf = confidence(sel.segment_mm, fp)
        stats["confidence"] = {
            "mean": float(conf.mean()),
            "p10": float(np.percentile(conf, 10)),
            "below_0.5": float((conf < 0.5).mean()),
            "defect_points_mean": float(conf[out].mean()) if out.any() else None,
        }
    if tol.regions:
        stats["regions"] = {
            name: {"n_points": int((region == k).sum()), "deviation_mm": deviation_stats(dev[region == k])}
            for k, name in enumerate(names)
        }
    return stats


def _summary(tol: Tolerance, dev: np.ndarray, out: np.ndarray, region: np.ndarray, within: float) -> EvaluationSummary:
    """The typed contract (what result.json's summary keys, the history and the CSV read):
    the default band's points first, then each named region's.

    Parameters
    ----------
    dev : (N,) float
        Deviations, mm.
    out : (N,) bool
        Out of tolerance.
    region : (N,) int
        Each point's region (-1: the default band).
    within : float
        Fraction of the points within tolerance (``stats.within_tolerance``).
    """
    n = len(dev)
    bands = [("default", tol.default)] + [(r.name, r.band) for r in tol.regions]
    regions = tuple(
        RegionSummary(name, band.lower, band.upper, int((region == k - 1).sum()), int(out[region == k - 1].sum()),
                      DeviationStats.of(dev[region == k - 1]))
        for k, (name, band) in enumerate(bands)
    )
    return EvaluationSummary(
        n_points=int(n),
        deviation_mm=DeviationStats.of(dev),
        tolerance_mm=(tol.default.lower, tol.default.upper),
        within_tolerance=within,
        out_of_tolerance_points=int(out.sum()),
        regions=regions,
        point_region=region + 1,
    )


def _verdict(ctx: InspectionContext, p: EvaluateParams, health: dict[str, Any] | None, defects: list[Defect],
             resting: list[tuple[Defect, list[int]]],
             n: int) -> tuple[str, list[Defect], str | None, list[dict[str, Any]]]:
    """The verdict (``pass``, ``fail`` or ``error``), the defects it stands on, the error and
    the unconfirmed defects (``stats.unconfirmed_defects``): defects on a turn the images do
    not fix (:func:`_unconfirmed`), or resting on a flagged camera, make no fail; a pass with
    fewer than ``min_points`` points (``n``) is an error."""
    verdict = "fail" if defects else "pass"
    error = _unconfirmed(ctx, defects)
    unconfirmed: list[dict[str, Any]] = []
    if error is not None:
        # The defects stand on a turn the images do not fix: report them as unconfirmed,
        # never as a defect list an operator would go looking for.
        unconfirmed = [{**d.to_json(), "reason": "pose uncertain"} for d in defects]
        verdict, defects = "error", []
    if resting:
        # Defects that only a camera disagreeing with the others makes: kept aside with the
        # camera named; the part is neither failed nor passed on its word.
        why = _camera_reason(health, resting)
        unconfirmed += [{**d.to_json(), "reason": f"rests on {', '.join(_names(health, c))}, which disagree"
                         f"{'s' if len(c) == 1 else ''} with the other cameras"} for d, c in resting]
        if not defects and error is None:
            verdict, error = "error", why
    if verdict == "pass" and n < p.min_points:
        # Not a pass: no defect of this part could have reached min_points.
        verdict, error = "error", (f"min_points = {p.min_points} is more than the {n} points measured on this part: "
                                   "no defect could reject it; lower min_points")
    return verdict, defects, error, unconfirmed


def _leaning(ctx: InspectionContext, sel: Any, idx: np.ndarray, flagged: np.ndarray,
             health: dict[str, Any] | None) -> dict[int, np.ndarray]:
    """Per flagged camera ``c``, which BCPS points (of ``idx``; (N,) bool) rest on it: its own
    contour's points, and the other cameras' points its silhouette holds in place.

    A camera that is off by ``k`` px carves the visual hull ``k`` px wrong along its
    contour, and the other cameras' rays select their points on that wrong hull there
    (cube, a camera turned by 2 px: a false reject on points of two other cameras, each
    0.05-0.2 px outside the turned camera's silhouette). So a point whose projection in
    ``c`` lies outside its silhouette, or within its 90th-percentile residual plus a pixel
    of its contour, rests on ``c`` too.
    """
    out: dict[int, np.ndarray] = {}
    rig = ctx.capture.rig
    sils = ctx.silhouettes or ()
    per = health["cameras"] if health is not None else {}
    for c in (int(c) for c in flagged):
        on = np.asarray(sel.camera) == c
        if idx.size and c < len(sils) and len(sils[c].contour):
            cam, sil = rig.cameras[c], sils[c]
            p90 = per.get(cam.name, {}).get("p90_px")
            reach = 1.0 + (float(p90) if p90 is not None else 1.0)
            uv, z = cam.project(sel.points[idx])
            h, w = sil.mask.shape
            ui = np.clip(np.round(uv[:, 0]).astype(np.int64), 0, w - 1)
            vi = np.clip(np.round(uv[:, 1]).astype(np.int64), 0, h - 1)
            seen = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
            outside = seen & ~sil.mask[vi, ui]
            contour = np.asarray(sil.contour, float)
            near = np.zeros(len(idx), bool)
            for k in range(0, len(idx), 256):  # (256, M) distances at a time
                d2 = ((uv[k:k + 256, None, :] - contour[None, :, :]) ** 2).sum(axis=2)
                near[k:k + 256] = d2.min(axis=1) <= reach**2
            on[idx] |= outside | (seen & near)
        out[c] = on
    return out


def _stands(members: np.ndarray, camera: np.ndarray, p: EvaluateParams) -> bool:
    """Whether the points ``members`` (indices) are enough to reject a part: ``min_points``
    of them, from ``min_cameras`` cameras."""
    return bool(members.size >= p.min_points and np.unique(camera[members]).size >= p.min_cameras)


def _defect(kind: str, members: np.ndarray, points: np.ndarray, dev: np.ndarray, region: np.ndarray,
            names: list[str]) -> Defect:
    """The defect cluster made of the points ``members`` (indices)."""
    pts = points[members]
    d = dev[members]
    regs = region[members]
    reg = names[np.bincount(regs[regs >= 0]).argmax()] if (regs >= 0).any() else "default"
    c, e = pts.mean(axis=0), pts.max(axis=0) - pts.min(axis=0)
    return Defect(
        kind=kind,
        position=(float(c[0]), float(c[1]), float(c[2])),
        extent=(float(e[0]), float(e[1]), float(e[2])),
        n_points=int(members.size),
        worst_mm=float(d.min() if kind == "missing" else d.max()),
        region=reg,
    )


def _names(health: dict[str, Any] | None, cams: list[int]) -> list[str]:
    names = health["names"] if health is not None else []
    return [names[c] if 0 <= c < len(names) else f"#{c}" for c in cams]


def _px(v: float) -> str:
    """A residual in pixels as the warnings say it: 1.9, 0.62."""
    return f"{v:.1f}" if v >= 0.95 else f"{v:.2f}"


def _camera_reason(health: dict[str, Any] | None, resting: list[tuple[Defect, list[int]]]) -> str:
    """The one-line error of a part whose defects rest on flagged cameras' points."""
    d, cams = resting[0]
    names = _names(health, cams)
    per = health["cameras"] if health is not None else {}
    by = " and ".join(_px(per[n]["off_px"]) for n in names if n in per)
    who, its = (f"{names[0]} disagrees", "its") if len(names) == 1 else (f"{' and '.join(names)} disagree", "their")
    at = ", ".join(f"{x:.1f}" for x in d.position)
    more = f" (and {len(resting) - 1} more defect{'s' if len(resting) > 2 else ''})" if len(resting) > 1 else ""
    what = "missing material" if d.kind == "missing" else "excess material"
    return (f"{who} with the other cameras by {by} px: the defect at ({at}) mm ({what}, {d.worst_mm:+.3f} mm){more} "
            f"rests on {its} points; check {its} mounting or recalibrate")


def _outward_normals(soft: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Outward unit normals (M, 2) of the silhouette at contour points ``uv`` (M, 2): minus
    the coverage's gradient (central differences of bilinear samples one pixel apart)."""
    u, v = uv[:, 0], uv[:, 1]
    g = np.stack([sample_bilinear(soft, u + 1.0, v) - sample_bilinear(soft, u - 1.0, v),
                  sample_bilinear(soft, u, v + 1.0) - sample_bilinear(soft, u, v - 1.0)], axis=1)
    norm = np.linalg.norm(g, axis=1, keepdims=True)
    return np.where(norm > 1e-9, -g / np.maximum(norm, 1e-9), np.nan)


def calibration_health(ctx: InspectionContext, p: EvaluateParams) -> dict[str, Any] | None:
    """Each camera's silhouette residual against the reference as the part was measured (its
    final pose, under the bcps stage's size model), ``stats.calibration``'s keys plus
    ``flagged_index`` (the flagged cameras' indices) and ``names``; None when not checked
    (``health_px`` 0), the context lacks what it needs (silhouettes, reconstruction,
    reference, pose) or the pose is not the one the silhouettes fix (``bcps.ray`` with
    ``refine_pose``). When most cameras are off, none is flagged: ``not_judged`` says why.

    The rays go through ``health_rays`` of each camera's sub-pixel contour points, searched
    across the reconstruction's bounds (with the margin of the bcps stage's ray ranges): a
    contour ray's smallest distance along its whole length is its graze.
    """
    from inspector.kernels.health import MIN_RAYS, flagged_cameras, silhouette_residuals

    rig = ctx.capture.rig
    sils, recon, ref, align = ctx.silhouettes, ctx.reconstruction, ctx.reference, ctx.alignment
    if (p.health_px <= 0 or sils is None or recon is None or ref is None or align is None or not len(rig)
            or len(sils) != len(rig) or not len(recon.points)):
        return None
    if ctx.bcps is None or ctx.bcps.method != "ray" or "bcps-refine" not in align.method:
        # Only the pose the silhouettes fix (bcps.ray with refine_pose) is good to a few
        # hundredths of a pixel; against the visual hull's (ICP) every camera is off by
        # about a pixel (6 cameras, 128 px, bcps.surface without refine_pose: 0.3-1 px).
        return None
    margin = max(1.0, 2.0 * float(recon.voxel_mm))
    lo, hi = bounds_of(recon.points)
    box = np.stack([lo - margin, hi + margin])
    centre = 0.5 * (lo + hi)
    rays, normals = [], []
    for cam, sil in zip(rig.cameras, sils):
        contour = np.asarray(sil.contour, float)
        contour = contour[:: max(1, -(-len(contour) // p.health_rays))]
        if not len(contour):
            rays.append((cam.centre, np.zeros((0, 3)), np.zeros(0), np.zeros(0)))
            normals.append(np.zeros((0, 2)))
            continue
        origin, dirs = cam.rays(contour)
        a, b = bk.ray_box(origin, dirs, box)
        rays.append((origin, dirs, a, b))
        normals.append(_outward_normals(sil.soft, contour))
    # The reference as the bcps stage left it: the final (rigid) pose times the size model's
    # scale about its centre (its rotation and shift are in the pose already).
    size = ctx.bcps.size if ctx.bcps is not None else None
    s = float(size.scale) if size is not None else 1.0
    c0 = np.asarray(size.centre, float) if size is not None else np.zeros(3)
    place = np.asarray(align.pose, float).copy()
    place[:3, 3] = place[:3, :3] @ (c0 - s * c0) + place[:3, 3]
    place[:3, :3] = place[:3, :3] * s
    inv = np.linalg.inv(place)
    near = ref.distance.near

    def sd(X: np.ndarray) -> np.ndarray:
        return s * near(X @ inv[:3, :3].T + inv[:3, 3])

    fp = [cam.footprint_mm(centre) for cam in rig.cameras]
    # Coarse samples every 2 mm, then 0.5 mm about the three lowest, refined to 8 um: the
    # figures of 1 mm / 0.25 mm to a few thousandths of a pixel, a quarter fewer distance queries.
    h = silhouette_residuals(rays, sd, fp, normals=normals, step_mm=0.5, levels=3)
    # A camera is off by its image's shift, or by a uniform offset of its own (a wrong distance
    # or focal length: every contour ray misses, or cuts, alike).
    off = np.fmax(h.shift_px, np.abs(h.signed_px))
    bad = flagged_cameras(off, h.rays, p.health_px)
    names = list(rig.names)
    judged = off[(h.rays >= MIN_RAYS) & np.isfinite(off)]
    wide = None
    if len(bad) and 2 * len(bad) > len(judged):
        # Most cameras off: not one camera's fault, but the pose, the part or the whole rig
        # (a rig.json of another cell). Nothing is flagged; the warning says so.
        wide = (f"the silhouettes disagree with the part's pose in {len(bad)} of {len(judged)} cameras (median "
                f"{_px(float(np.median(judged)))} px): the pose, the part or the whole rig, not one camera; "
                "calibration not judged")
        bad = bad[:0]

    def num(v: float) -> float | None:
        return round(float(v), 4) if np.isfinite(v) else None

    return {
        "cameras": {n: {"median_px": num(h.median_px[i]), "p90_px": num(h.p90_px[i]), "signed_px": num(h.signed_px[i]),
                        "shift_px": num(h.shift_px[i]), "off_px": num(off[i]), "rays": int(h.rays[i])}
                    for i, n in enumerate(names)},
        "flagged": [names[i] for i in bad],
        "threshold_px": float(p.health_px),
        "not_judged": wide,
        "offset_mm": num(h.offset_mm),
        "flagged_index": [int(i) for i in bad],
        "names": names,
    }


def _unconfirmed(ctx: InspectionContext, defects: list[Defect]) -> str | None:
    """Why ``defects`` cannot be trusted, or None: the pose's turn about the part's axis of
    near-symmetry is ambiguous (another turn fits the silhouettes about as well), so the defects
    could be the part turned, not damaged. A size error is still stated: it does not depend
    on the turn."""
    conf = ctx.alignment.confidence if ctx.alignment is not None else None
    if not defects or conf is None or not conf.ambiguous:
        return None
    size = ctx.bcps.size if ctx.bcps is not None else None
    sized = "" if size is None or size.is_identity else f"; the part measures {100 * (size.scale - 1):+.1f} % in size"
    return (f"pose uncertain: a turn of {conf.runner_up_deg:+.0f} deg about the part's axis fits the silhouettes about "
            f"as well (pinned by {conf.margin_points} contour points), so {len(defects)} defect(s) could be the part turned"
            f"{sized}; check the part's keying features are visible to the cameras")


@hookimpl
def inspector_register_stages(registry: StageRegistry) -> None:
    registry.add(
        StageSpec(
            name="evaluate.tolerance",
            run=evaluate,
            params=EvaluateParams,
            requires=("bcps",),
            doc="Signed deviations against tolerance bands (global and per region), defect clusters, verdict",
            summary=EvaluationSummary,
        )
    )
