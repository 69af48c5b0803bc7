"""Stage ``segment.threshold``: silhouettes with sub-pixel contours from grey levels."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Literal

import numpy as np

from inspector import hookimpl
from inspector.errors import StageError
from inspector.kernels import silhouette as sk
from inspector.model import Silhouette
from inspector.params import param
from inspector.pipeline import InspectionContext
from inspector.registry import StageRegistry, StageSpec


@dataclass(frozen=True)
class SegmentParams:
    polarity: Literal["auto", "dark-object", "bright-object"] = param(
        "auto", "object darker or brighter than the background; auto: the capture's polarity (capture.json, default dark-object)"
    )
    threshold: Literal["otsu", "fixed"] = param("otsu", "how the object/background level is chosen")
    level: float = param(
        128.0,
        "with threshold='fixed': level on the object signal, 8-bit scale (255 - grey for dark objects; the difference to the background when subtracting)",
        min=0.0,
        max=255.0,
    )
    background: Literal["auto", "on", "off"] = param("auto", "subtract background images: auto uses them when the capture has them")
    median: Literal["off", "impulse", "full"] = param(
        "impulse",
        "3x3 median against impulse noise: 'impulse' replaces only outlier pixels (keeps anti-aliased edges), 'full' filters every pixel",
    )
    impulse_threshold: float = param(60.0, "grey-level difference to the 3x3 median above which a pixel is an impulse", min=1.0)
    subpixel: Literal["area", "linear"] = param(
        "area", "sub-pixel contour: 'area' (coverage summed across the edge, exact for straight edges) or 'linear' (marching squares)"
    )
    smooth_px: float = param(
        -1.0,
        "Gaussian smoothing of the coverage before contouring, px; hard-edged (binary) images need ~1-2 px to "
        "turn their pixel staircase into a straight edge; -1: automatic (smooths only images without anti-aliasing)",
        min=-1.0,
        max=10.0,
    )
    min_area_px: int = param(50, "connected components smaller than this are noise", min=1)


def _denoise(grey: np.ndarray, p: SegmentParams) -> np.ndarray:
    if p.median == "off":
        return grey
    import cv2

    med = cv2.medianBlur(grey, 3)
    if p.median == "full":
        return med
    return np.where(np.abs(grey - med) > p.impulse_threshold, med, grey)


#: Smoothing of hard-edged images, px (binary cube: mean error 0.25 px unsmoothed, 0.13 px at 1.0, 0.12 at 1.5 with more outliers).
AUTO_SMOOTH_PX = 1.0


def _hard_edged(raw: np.ndarray) -> bool:
    """True when the image has (almost) no anti-aliased edge pixels: a binary silhouette."""
    mask = raw >= 0.5
    edge = mask ^ np.roll(mask, 1, axis=0) | mask ^ np.roll(mask, 1, axis=1)
    partial = np.count_nonzero((raw > 0.2) & (raw < 0.8))
    return partial < 0.1 * max(np.count_nonzero(edge), 1)


def segment_image(
    image: np.ndarray,
    background: np.ndarray | None,
    polarity: str,
    p: SegmentParams,
    camera: str,
) -> Silhouette:
    """One camera image -> :class:`Silhouette` (pure function of its inputs)."""
    grey = _denoise(sk.to_grey(image), p)
    bg = _denoise(sk.to_grey(background), p) if background is not None else None
    signal = sk.object_signal(grey, polarity, bg)
    level = sk.otsu_level(signal) if p.threshold == "otsu" else p.level
    soft, bg_level, fg_level = sk.coverage(signal, level)
    raw = (signal - np.float32(bg_level)) * np.float32(1.0 / max(fg_level - bg_level, 1e-6))
    sigma = p.smooth_px if p.smooth_px >= 0 else (AUTO_SMOOTH_PX if _hard_edged(raw) else 0.0)
    if sigma > 0:
        import cv2

        raw = cv2.GaussianBlur(raw, (0, 0), sigma)
        soft = np.clip(raw, 0.0, 1.0)
    if fg_level - bg_level < 10.0:
        raise StageError(f"camera {camera}: empty silhouette (no contrast between object and background)")
    mask = sk.largest_components(soft >= 0.5, p.min_area_px)
    if not mask.any():
        raise StageError(f"camera {camera}: empty silhouette (no object region of {p.min_area_px} px or more)")
    soft = np.where(mask | (soft < 0.5), soft, 0.0).astype(np.float32)
    border = sk.touches_border(mask)
    contour = sk.subpixel_contour(soft, mask, margin=1.0)
    if p.subpixel == "area":
        contour = sk.refine_contour_area(contour, np.where(mask | (raw < 0.5), raw, 0.0).astype(np.float32))
        h, w = mask.shape
        m = (contour[:, 0] >= 1) & (contour[:, 0] <= w - 2) & (contour[:, 1] >= 1) & (contour[:, 1] <= h - 2)
        contour = contour[m]
    return Silhouette(camera=camera, mask=mask, soft=soft, contour=contour, touches_border=border)


def run_segment(ctx: InspectionContext, p: SegmentParams) -> InspectionContext:
    cap = ctx.capture
    polarity = cap.polarity if p.polarity == "auto" else p.polarity
    use_bg = p.background == "on" or (p.background == "auto" and bool(cap.backgrounds))
    for cam in cap.rig:
        if use_bg and cap.backgrounds.get(cam.name) is None:
            raise StageError(f"camera {cam.name}: no background image (background/{cam.name}.png)")

    def one(cam):
        bg = cap.backgrounds.get(cam.name) if use_bg else None
        return segment_image(cap.images[cam.name], bg, polarity, p, cam.name)

    # OpenCV and most numpy kernels release the GIL: cameras in parallel threads.
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=min(len(cap.rig), os.cpu_count() or 1) or 1) as pool:
        sils = list(pool.map(one, cap.rig.cameras))
    return ctx.evolve(silhouettes=tuple(sils))


@hookimpl
def inspector_register_stages(registry: StageRegistry) -> None:
    registry.add(
        StageSpec(
            name="segment.threshold",
            run=run_segment,
            params=SegmentParams,
            doc="Silhouette per camera: threshold, impulse filtering, coverage from grey levels, sub-pixel contour",
        )
    )
