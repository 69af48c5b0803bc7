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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from inspector import hookimpl
from inspector.kernels.bcps import confidence
from inspector.kernels.deviation import cluster_points, deviation_stats
from inspector.model import Defect, DeviationStats, Evaluation, EvaluationSummary, RegionSummary
from inspector.params import param
from inspector.pipeline import InspectionContext
from inspector.registry import StageRegistry, StageSpec


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


def evaluate(ctx: InspectionContext, p: EvaluateParams) -> InspectionContext:
    sel = ctx.need("bcps", "evaluate")
    pose = ctx.need("alignment", "evaluate").pose
    ref = ctx.need("reference", "evaluate")
    tol = ctx.tolerance
    dev = sel.deviation
    n = len(dev)
    lower = np.full(n, tol.default.lower)
    upper = np.full(n, tol.default.upper)
    region = np.full(n, -1)
    if tol.regions:
        local = ref.to_reference_frame(sel.points, pose)
        for k, r in enumerate(tol.regions):
            inside = r.contains(local)
            lower[inside], upper[inside], region[inside] = r.band.lower, r.band.upper, k
    names = [r.name for r in tol.regions]
    missing = dev < lower
    excess = dev > upper
    defects: list[Defect] = []
    isolated = 0
    for kind, flag in (("missing", missing), ("excess", excess)):
        idx = np.flatnonzero(flag)
        if idx.size == 0:
            continue
        labels = cluster_points(sel.points[idx], p.cluster_radius_mm)
        for lab in np.unique(labels):
            members = idx[labels == lab]
            if members.size < p.min_points or np.unique(sel.camera[members]).size < p.min_cameras:
                isolated += int(members.size)
                continue
            pts = sel.points[members]
            d = dev[members]
            worst = float(d.min() if kind == "missing" else d.max())
            regs = region[members]
            reg = names[np.bincount(regs[regs >= 0]).argmax()] if (regs >= 0).any() else "default"
            defects.append(
                Defect(
                    kind=kind,
                    position=tuple(float(x) for x in pts.mean(axis=0)),
                    extent=tuple(float(x) for x in (pts.max(axis=0) - pts.min(axis=0))),
                    n_points=int(members.size),
                    worst_mm=worst,
                    region=reg,
                )
            )
    defects.sort(key=lambda d: -abs(d.worst_mm))
    out = missing | excess
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
    if fp is not None:
        stats["footprint_mm"] = fp
        warning = capability_warning(tol, fp)
        if warning is not None:
            stats["warnings"] = [warning]
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
    # The typed contract (what result.json's summary keys, the history and the CSV read):
    # the default band's points first, then each named region's.
    bands = [("default", tol.default)] + [(r.name, r.band) for r in tol.regions]
    regions = tuple(
        RegionSummary(name, band.lower, band.upper, int((region == k - 1).sum()), int(out[region == k - 1].sum()),
                      DeviationStats.of(dev[region == k - 1]))
        for k, (name, band) in enumerate(bands)
    )
    summary = EvaluationSummary(
        n_points=int(n),
        deviation_mm=DeviationStats.of(dev),
        tolerance_mm=(tol.default.lower, tol.default.upper),
        within_tolerance=stats["within_tolerance"],
        out_of_tolerance_points=int(out.sum()),
        regions=regions,
        point_region=region + 1,
    )
    verdict = "fail" if defects else "pass"
    error = _unconfirmed(ctx, defects)
    if error is not None:
        # The defects stand on a turn the images do not fix: report them as unconfirmed,
        # never as a defect list an operator would go looking for.
        stats["unconfirmed_defects"] = [d.to_json() for d in defects]
        verdict, defects = "error", []
    return ctx.evolve(evaluation=Evaluation(verdict, stats, tuple(defects), out, summary=summary, error=error))


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
