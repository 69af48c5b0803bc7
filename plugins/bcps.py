"""Stages ``bcps.ray`` and ``bcps.surface``: best-case coherent points, then pose refinement.

Both apply the signed-argmin rule (see :mod:`inspector.kernels.bcps`). With
``refine_pose`` the stage also finishes the alignment the paper's way round: select,
re-align the reference on the selected points, select again.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import numpy as np

from inspector import hookimpl
from inspector.errors import StageError
from inspector.kernels import bcps as bk
from inspector.kernels.threads import map_threads
from inspector.kernels.prior import SizePrior, fit_size_prior
from inspector.kernels.robust import tukey_loss
from inspector.model import Alignment, BcpsPoints
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
    recon = ctx.need("reconstruction", "bcps")
    # Hard-edged silhouettes are less exact than the hull tolerance assumes: a ray's true
    # point can lie a few tenths of a pixel outside them (shaft, binary images: 10 points
    # 1-1.8 px off in bulges at 0.2 px, a false reject).
    accept = p.accept_px + max(s.edge_px for s in sils)
    out = {k: [] for k in ("points", "deviation", "camera", "pixel", "segment")}
    ranges = cache.setdefault("ranges", {})
    stride = cache.get("stride", 1)
    for i, (cam, sil) in enumerate(zip(rig.cameras, sils)):
        if len(sil.contour) == 0:
            continue
        if i not in ranges:
            origin, dirs = cam.rays(sil.contour)
            # Only where the ray passes near the reconstruction (the hull is conservative).
            # A pose update can move a grazing ray's optimum far along it: every pass
            # searches the whole range.
            ranges[i] = (origin, dirs, bk.ray_ranges(
                cam, sil.contour, origin, dirs, recon.points, max(1.0, 2.0 * recon.voxel_mm),
                compiled=cache.get("stack") is not None,
            ))
        origin, dirs, (r0, r1) = ranges[i]
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
                start: np.ndarray | None = None) -> SizePrior:
    """The part's best-fit size model, from a first selection (see :mod:`inspector.kernels.prior`)."""
    ref = ctx.need("reference", "bcps")
    V = ref.vertices
    return fit_size_prior(ref.to_reference_frame(sel.points, pose), ref.distance,
                          centre=0.5 * (V.min(axis=0) + V.max(axis=0)), robust_mm=p.refine_robust_mm,
                          start_mm=p.refine_start_mm, start=start)


#: Largest size error (relative) the pose search must tolerate.
_SIZE_RANGE = 0.035
#: The turn search: only where the hull allows turns beyond this either way (degrees);
#: candidates this far apart (degrees), at most this many; each judged on every n-th
#: contour ray; the winner must lower the mean loss by this share of the pose's and by this
#: much in all (fraction of points).
_OPEN_DEG = 10.0
_SEARCH_STEP_DEG = 15.0
_SEARCH_TURNS = 24
_SEARCH_STRIDE = 9
_SEARCH_GAIN = 0.25
_SEARCH_MARGIN = 0.0003
#: A re-fit that turns the pose by more than this (degrees) is followed by a new selection
#: and re-fit, at most this many times in all.
_RESELECT_DEG = 0.05
_ATTEMPTS = 4


def _turn_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle of the rotation between two poses (4, 4), degrees."""
    R = a[:3, :3].T @ b[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def _robust_loss(sel: BcpsPoints, cutoff_mm: float) -> float:
    """Mean Tukey loss (0..1) of a selection's deviations about their median."""
    return float(np.mean(tukey_loss(sel.deviation - np.median(sel.deviation), cutoff_mm)))


def _turn_search(ctx: InspectionContext, pose: np.ndarray, scan, p, cache: dict) -> np.ndarray | None:
    """A better pose among the turns about the reference's axis that its visual hull allows,
    each judged by its own (sparse) selection; None when the pose stays.

    Only for a reference with an axis of near-symmetry whose hull leaves more than
    ``_OPEN_DEG`` of turn either way. Candidates every ``_SEARCH_STEP_DEG`` (at most
    ``_SEARCH_TURNS``), skipping the reference's own symmetries, then half a step either
    side of the best; the winner must fit clearly better than the pose (its mean robust loss
    lower by ``_SEARCH_GAIN`` of the pose's and by ``_SEARCH_MARGIN``). ``scan``: the
    :class:`~inspector.kernels.registration.AxisScan` about ``pose`` (with hull points).

    Measured on a keyed shaft (16 cameras, grey): at the true pose the loss at 0.3 mm is
    0.46e-3, 5 / 10 / 20 / 45 / 180 degrees off 1.5 / 2.6 / 4.7 / 9.6 / 2.6e-3 (every ninth
    ray, 10 um steps): the keyway moves about 55 contour points by 0.1 mm.
    """
    if scan is None:
        return None
    inside = scan.inside_hull & scan.distinct(_OPEN_DEG)
    if not inside.any():
        return None
    k = max(1, int(np.ceil(len(scan.angles_deg) * _SEARCH_STEP_DEG / 360.0)))
    angles = list(scan.angles_deg[inside][::k][:_SEARCH_TURNS])
    cutoff = 3.0 * p.refine_robust_mm
    saved = {key: cache.get(key) for key in ("stride", "refine_levels")}
    cache["stride"], cache["refine_levels"] = _SEARCH_STRIDE, min(2, getattr(p, "refine_levels", 0))

    def loss(angle: float) -> float:
        return _robust_loss(cache["select"](ctx, pose @ _turn(scan.axis, scan.centre, angle), p, cache), cutoff)

    try:
        base = loss(0.0)
        losses = [loss(a) for a in angles]
        best = int(np.argmin(losses))
        for a in (angles[best] - _SEARCH_STEP_DEG / 2, angles[best] + _SEARCH_STEP_DEG / 2):
            angles.append(a)
            losses.append(loss(a))
    finally:
        for key, v in saved.items():
            if v is None:
                cache.pop(key, None)
            else:
                cache[key] = v
    best = int(np.argmin(losses))
    if losses[best] < (1.0 - _SEARCH_GAIN) * base and losses[best] < base - _SEARCH_MARGIN:
        return pose @ _turn(scan.axis, scan.centre, angles[best])
    return None


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
        # Where the hull leaves the turn open (a keyway, a flat: features a fraction of a
        # millimetre deep), the points selected against a pose agree with it; the turns
        # the hull allows are each judged by a selection of their own.
        def scan_at(pose: np.ndarray, sel: BcpsPoints):
            return scan_about_axis(sel.points, ref.vertices, ref.faces, pose, cutoff_mm=p.refine_start_mm,
                                   index=ref.distance, hull_points=hull.points, hull_mm=hull_mm)

        scan = scan_at(refined.pose, sel)
        turned = _turn_search(ctx, refined.pose, scan, p, cache)
        if turned is not None:
            refined, sel = settle(turned, sparse(turned), False)
            scan = scan_at(refined.pose, sel)
        # How firmly the points fix the turn about the axis of near-symmetry (the scan of the
        # settled pose: the size fit below corrects it by hundredths of a degree).
        confidence = pose_confidence(scan)
        alignment = Alignment(refined.pose, refined.fitness, refined.rmse_mm, f"{alignment.method}+bcps-refine")
        if getattr(p, "prior", "nominal") != "size":
            return ctx.evolve(bcps=select(ctx, alignment.pose, p, cache),
                              alignment=dataclasses.replace(alignment, confidence=confidence))
        prior = _size_prior(ctx, sel, alignment.pose, p)
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
                refit = _size_prior(ctx, sparse(alignment.pose, prior=prior), alignment.pose, p, prior.rigid())
                if refit.is_identity:
                    break
                turned = _turn_deg(prior.rigid(alignment.pose), refit.rigid(alignment.pose))
                prior = refit
                if turned < _RESELECT_DEG:
                    break
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
