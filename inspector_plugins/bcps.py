"""Stages ``bcps.ray`` and ``bcps.surface``: best-case coherent points, then pose refinement.

Both apply the signed-argmin rule (see :mod:`inspector.kernels.bcps`). With
``refine_pose`` the stage also finishes the alignment the paper's way round: select,
re-align the reference on the selected points, select again
(:func:`inspector.kernels.pose.search_pose`, which writes the refined alignment). This
module only adapts the inspection context to the kernels.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np

from inspector import hookimpl
from inspector.errors import StageError
from inspector.kernels import bcps as bk
from inspector.kernels.pose import search_pose
from inspector.kernels.prior import SizePrior
from inspector.model import BcpsPoints
from inspector.params import param
from inspector.pipeline import InspectionContext
from inspector.registry import StageRegistry, StageSpec
from inspector_plugins.bcps_rays import ContourRays


@dataclass(frozen=True)
class RayParams:
    step_mm: float = param(0.25, "coarse sampling step along each contour ray, mm", min=0.01, max=5.0)
    refine_levels: int = param(3, "refinement levels around the coarse minimum (each 5x finer: 2 um after 3)", min=0, max=6)
    refine_pose: bool = param(True, "re-align the reference on the selected points, then select again")
    refine_robust_mm: float = param(0.1, "robust scale of the re-alignment (points beyond are down-weighted), mm", min=0.001, max=100.0)
    refine_start_mm: float = param(1.0, "initial robust scale of the re-alignment, shrinking to refine_robust_mm, mm", min=0.001, max=100.0)
    refine_stride: int = param(3, "the selection that feeds the re-alignment uses every n-th contour point", min=1, max=1000)
    refine_rays: int = param(12000, "... and at most about this many in all (a larger n where the contours hold more: the re-alignment's cost stays flat as cameras are added)", min=100, max=100_000_000)
    tolerance_px: float = param(0.05, "hull tolerance of a strict candidate, px (contour noise)", min=0.0, max=2.0)
    accept_px: float = param(0.2, "largest hull violation of a selected point, px, plus the silhouettes' contour uncertainty (hard-edged images: 0.3 px; beyond: the ray has no point)", min=0.0, max=5.0)
    violation_weight: float = param(3.0, "cost of 1 px of hull violation, in pixel footprints of deviation", min=0.0, max=1000.0)
    backend: Literal["numba", "numpy"] = param("numba", "hull kernel: compiled (numba) or the numpy reference")
    margin_mm: float = param(2.0, "margin added around the reconstruction's bounds for the rays, mm", min=0.0, max=100.0)
    prior: Literal["size", "nominal"] = param(
        "size", "what the final selection is made against: the reference under the part's best-fit scale "
        "(size), or the nominal reference; deviations are always against the nominal", )

    @property
    def sized(self) -> bool:
        """Whether the pose search fits the part's size model (``prior = "size"``)."""
        return self.prior == "size"

    @property
    def compiled(self) -> bool:
        """Whether the rays use the compiled hull kernels."""
        return self.backend == "numba"


@dataclass(frozen=True)
class SurfaceParams:
    refine_pose: bool = param(True, "re-align the reference on the selected points, then select again")
    refine_robust_mm: float = param(0.3, "robust scale of the re-alignment, mm", min=0.001, max=100.0)
    refine_start_mm: float = param(1.0, "initial robust scale of the re-alignment, shrinking to refine_robust_mm, mm", min=0.001, max=100.0)

    #: The surface method selects against the nominal reference, and its turn judge samples
    #: the rays with the numpy kernels.
    sized: ClassVar[bool] = False
    compiled: ClassVar[bool] = False


def _placed_distance(index: Callable[[np.ndarray], np.ndarray], inv: np.ndarray, scale: float, X: np.ndarray) -> np.ndarray:
    """Signed distance, mm, of world points ``X`` (N, 3) to the reference that ``inv`` (4, 4,
    world -> its frame) places, times ``scale``."""
    return scale * index(X @ inv[:3, :3].T + inv[:3, 3])


def select_rays(ctx: InspectionContext, p: RayParams, rays: ContourRays, pose: np.ndarray, *, sparse: bool = False,
                prior: SizePrior | None = None) -> BcpsPoints:
    """Run the ``ray`` method on every camera for the reference placed at ``pose``.

    ``sparse``: every ``refine_stride``-th ray, one refinement level less (25 um steps), no
    ``segment_mm`` (NaN): a selection that only feeds a fit. With a ``prior`` the candidates
    are ranked by their signed distance to the sized reference; the deviations returned are
    against the nominal one placed on the part (:meth:`SizePrior.rigid`).
    """
    sils, ref = ctx.need("silhouettes", "bcps"), ctx.need("reference", "bcps")
    views, stack = rays.views()
    bounds = rays.bounds(p.margin_mm)
    prior = prior if prior is not None else SizePrior()
    sized = not prior.is_identity
    place = prior.placement(pose)  # = pose for the nominal reference
    nominal = prior.rigid(pose)
    sd_fn = functools.partial(_placed_distance, ref.distance, np.linalg.inv(place), prior.scale)
    # Hard-edged silhouettes are less exact than the hull tolerance assumes: a ray's true
    # point can lie a few tenths of a pixel outside them (shaft, binary images: 10 points
    # 1-1.8 px off in bulges at 0.2 px, a false reject).
    accept = p.accept_px + max(s.edge_px for s in sils)
    levels = p.refine_levels - 1 if sparse and p.refine_levels > 1 else p.refine_levels
    sub = slice(None, None, bk.sparse_stride([len(s.contour) for s in sils], p.refine_stride, p.refine_rays) if sparse else 1)
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("points", "deviation", "camera", "pixel", "segment")}
    cams = [i for i, sil in enumerate(sils) if len(sil.contour)]
    tables = rays.coarse(cams, bounds, p.step_mm, accept)  # the hull's part of every selection, once
    picked = bk.select_on_camera_rays(  # every camera's rays in one call
        [(i, rays.camera(i).take(sub)) for i in cams], views, sd_fn, bounds, stack=stack, step_mm=p.step_mm,
        refine_levels=levels, tolerance_px=p.tolerance_px, accept_px=accept, violation_weight=p.violation_weight,
        mesh=ref.distance if stack is not None else None, pose=place, sd_scale=prior.scale, segments=not sparse,
        coarse=None if tables is None else [t.take(sub) for t in tables],
    )
    for i, (pts, dev, seg, ok) in zip(cams, picked):
        out["points"].append(pts[ok])
        out["deviation"].append(dev[ok])
        out["camera"].append(np.full(int(ok.sum()), i, np.int32))
        out["pixel"].append(sils[i].contour[sub][ok])
        out["segment"].append(seg[ok])
    sel = _assemble(out, "ray")
    return dataclasses.replace(sel, deviation=ref.signed_distance(sel.points, nominal)) if sized else sel


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


def select_surface(ctx: InspectionContext, p: SurfaceParams, rays: ContourRays, pose: np.ndarray, *,
                   sparse: bool = False, prior: SizePrior | None = None) -> BcpsPoints:
    """Run the ``surface`` method (the paper's) for the reference placed at ``pose`` (the
    reconstruction's surface points: ``sparse`` and ``prior`` change nothing)."""
    import cv2

    sils = ctx.need("silhouettes", "bcps")
    ref = ctx.need("reference", "bcps")
    recon = ctx.need("reconstruction", "bcps")
    sd = ref.signed_distance(recon.points, pose)
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("points", "deviation", "camera", "pixel", "segment")}
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


def _stage(select: Callable[..., BcpsPoints], ctx: InspectionContext, p: RayParams | SurfaceParams) -> InspectionContext:
    """One stage run: the selection (with the pose search when ``refine_pose``) into the context."""
    alignment = ctx.need("alignment", "bcps")
    ref = ctx.need("reference", "bcps")
    rays = ContourRays(ctx, p.compiled)
    chosen = functools.partial(select, ctx, p, rays)
    if not p.refine_pose:
        return ctx.evolve(bcps=chosen(alignment.pose))
    hull = ctx.need("reconstruction", "bcps")
    refined, bcps = search_pose(chosen, ref, alignment, hull.points, hull.voxel_mm, rays.all, robust_mm=p.refine_robust_mm,
                                start_mm=p.refine_start_mm, sized=p.sized)
    return ctx.evolve(bcps=bcps, alignment=refined)


def _run(select: Callable[..., BcpsPoints]) -> Callable[[InspectionContext, RayParams | SurfaceParams], InspectionContext]:
    """The run of the stage whose selection rule is ``select`` (:func:`select_rays` or :func:`select_surface`)."""
    return functools.partial(_stage, select)


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
