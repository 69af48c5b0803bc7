"""Stage ``segment.threshold``: silhouettes with sub-pixel contours from grey levels."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from inspector import hookimpl
from inspector.errors import StageError
from inspector.kernels import silhouette as sk
from inspector.kernels.threads import map_threads
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
    impulse_threshold: float = param(60.0, "grey-level difference to the 3x3 median above which a pixel is an impulse (255: none is)", min=1.0, max=255.0)
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
    min_area_px: int = param(50, "connected components smaller than this are noise", min=1, max=100_000_000)


def _denoise(grey: np.ndarray, p: SegmentParams) -> np.ndarray:
    return sk.median_denoise(grey, p.median, p.impulse_threshold)


#: Smoothing of hard-edged images, px (binary cube: mean error 0.25 px unsmoothed, 0.13 px at 1.0, 0.12 at 1.5 with more outliers).
AUTO_SMOOTH_PX = 1.0

#: Contour uncertainty of a smoothed (hard-edged) image, px: what is left of the pixel
#: staircase after smoothing (binary images: contour errors up to about half a pixel,
#: against a few hundredths for anti-aliased ones). BCPS widens its hull acceptance by it.
SMOOTHED_EDGE_PX = 0.3

#: Crop around the kept components for the contour work, px: the contour lies within 1 px
#: of them; subpixel_contour works on their box + 3 px, refine_contour_area reads up to
#: half_window + 1 = 3 px beyond the contour. The points are then the whole image's.
CROP_MARGIN = 4


def _hard_edged(above: np.ndarray, partial: int) -> bool:
    """True when the image has (almost) no anti-aliased edge pixels: a binary silhouette.

    ``above``: (H, W) raw coverage >= 0.5; ``partial``: pixels of raw coverage in (0.2, 0.8).
    """
    return partial < 0.1 * max(sk.edge_pixel_count(above), 1)


#: Share of the image border above which the "object" is the background. A part is framed
#: by the background (a shaft across the view covers a few per cent of the border, a part
#: filling half the view a half); an inverted polarity gives the whole border.
INVERTED_BORDER_FRACTION = 0.75


def _polarity_check(camera: str, mask: np.ndarray, polarity: str, source: str) -> float:
    """The share of the image border the object covers; StageError when it is the background."""
    share = sk.border_fraction(mask)
    if share > INVERTED_BORDER_FRACTION:
        other = "bright-object" if polarity == "dark-object" else "dark-object"
        raise StageError(
            f"camera {camera}: the object covers {share:.0%} of the image border, so it is the background: "
            f"the polarity looks inverted: {polarity}, from {source}; the image looks {other}"
        )
    return share


def _contrast_check(camera: str, bg_level: float, fg_level: float) -> None:
    if fg_level - bg_level < 10.0:
        raise StageError(f"camera {camera}: empty silhouette (no contrast between object and background)")


def _coverage_u8(grey: np.ndarray, polarity: str, p: SegmentParams, camera: str):
    """Coverage of an 8-bit grey image (H, W) uint8, without background image.

    Every full-image pass is a uint8 OpenCV operation or a lookup in a 256-entry table (the
    signal of an 8-bit image takes at most 256 values): the same numbers as
    :func:`_coverage_float`, several times faster.

    Returns
    -------
    soft : (H, W) float32
        Coverage clipped to [0, 1].
    above : (H, W) uint8
        1 where the coverage is >= 0.5.
    raw : callable
        ``raw(y0, y1, x0, x1)`` -> the unclipped coverage of that box, float32.
    sigma : float
        Smoothing applied to the coverage, px (0: the image's own anti-aliasing).
    """
    import cv2

    grey = _denoise(grey, p)
    counts = sk.histogram_u8(grey)
    table = sk.object_signal(np.arange(256, dtype=np.float32), polarity)
    level = sk.otsu_level_from_histogram(table, counts) if p.threshold == "otsu" else p.level
    bg_level, fg_level = sk.levels_from_histogram(table, counts, level)
    _contrast_check(camera, bg_level, fg_level)
    raw_t = sk.coverage_ramp(table, bg_level, fg_level)
    above = sk.mask_from_table(grey, raw_t >= 0.5)
    sigma = p.smooth_px
    if sigma < 0:
        partial = int(counts[(raw_t > 0.2) & (raw_t < 0.8)].sum())
        sigma = AUTO_SMOOTH_PX if _hard_edged(above, partial) else 0.0
    if sigma > 0:
        return (*_smoothed(cv2.LUT(grey, raw_t), sigma), sigma)
    soft = cv2.LUT(grey, np.clip(raw_t, 0.0, 1.0))
    return soft, above, lambda y0, y1, x0, x1: cv2.LUT(grey[y0:y1, x0:x1], raw_t), 0.0


def _coverage_float(image, background, polarity: str, p: SegmentParams, camera: str):
    """Coverage of any image (16-bit, colour, with background subtraction) from float32
    grey levels; returns what :func:`_coverage_u8` returns."""
    grey = _denoise(sk.to_grey(image), p)
    bg = _denoise(sk.to_grey(background), p) if background is not None else None
    signal = sk.object_signal(grey, polarity, bg)
    level = sk.otsu_level(signal) if p.threshold == "otsu" else p.level
    bg_level, fg_level = sk.coverage_levels(signal, level)
    _contrast_check(camera, bg_level, fg_level)
    raw = sk.coverage_ramp(signal, bg_level, fg_level)
    sigma = p.smooth_px
    if sigma < 0:
        partial = int(np.count_nonzero((raw > 0.2) & (raw < 0.8)))
        sigma = AUTO_SMOOTH_PX if _hard_edged(raw >= 0.5, partial) else 0.0
    if sigma > 0:
        return (*_smoothed(raw, sigma), sigma)
    soft = np.clip(raw, 0.0, 1.0)
    return soft, (soft >= 0.5).view(np.uint8), lambda y0, y1, x0, x1: raw[y0:y1, x0:x1], 0.0


def _smoothed(raw: np.ndarray, sigma: float):
    """Coverage of a hard-edged image: the raw coverage (H, W) float32 blurred by ``sigma`` px."""
    import cv2

    raw = cv2.GaussianBlur(raw, (0, 0), sigma)
    soft = np.clip(raw, 0.0, 1.0)
    return soft, (soft >= 0.5).view(np.uint8), lambda y0, y1, x0, x1: raw[y0:y1, x0:x1]


def segment_image(
    image: np.ndarray,
    background: np.ndarray | None,
    polarity: str,
    p: SegmentParams,
    camera: str,
    polarity_source: str = "the segment stage",
) -> Silhouette:
    """One camera image -> :class:`Silhouette` (pure function of its inputs).

    ``polarity_source`` names where ``polarity`` came from, for the message when the
    image's background comes out as the object (an inverted polarity).

    Full-image passes find the coverage, its 0.5 threshold and the components; the
    contour work runs on a crop around the kept components (same points as on the whole
    image: :data:`CROP_MARGIN`).
    """
    grey8 = sk.grey_u8(image) if background is None else None
    if grey8 is not None:
        soft, above, raw_in, sigma = _coverage_u8(grey8, polarity, p, camera)
    else:
        soft, above, raw_in, sigma = _coverage_float(image, background, polarity, p, camera)
    comps = sk.kept_components(above, p.min_area_px)
    if comps.box is None:
        raise StageError(f"camera {camera}: empty silhouette (no object region of {p.min_area_px} px or more)")
    mask = comps.mask
    border = _polarity_check(camera, mask, polarity, polarity_source) > 0.0
    if comps.removed is not None:
        soft[comps.removed] = 0.0  # coverage >= 0.5 only on the kept components
    y0, y1, x0, x1 = sk.grow_box(comps.box, mask.shape, CROP_MARGIN)
    crop = dict(origin=(x0, y0), image_shape=mask.shape)
    m = mask[y0:y1, x0:x1]
    contour = sk.subpixel_contour(soft[y0:y1, x0:x1], m, margin=1.0, **crop)
    if p.subpixel == "area":
        raw = raw_in(y0, y1, x0, x1)
        if comps.removed is not None:  # raw >= 0.5 outside the mask: the dropped components
            raw = np.where(comps.removed[y0:y1, x0:x1], np.float32(0.0), raw)
        contour = sk.refine_contour_area(contour, raw, **crop)
        h, w = mask.shape
        keep = (contour[:, 0] >= 1) & (contour[:, 0] <= w - 2) & (contour[:, 1] >= 1) & (contour[:, 1] <= h - 2)
        contour = contour[keep]
    return Silhouette(camera=camera, mask=mask, soft=soft, contour=contour, touches_border=border,
                      edge_px=SMOOTHED_EDGE_PX if sigma > 0 else 0.0)


def run_segment(ctx: InspectionContext, p: SegmentParams) -> InspectionContext:
    cap = ctx.capture
    polarity = cap.polarity if p.polarity == "auto" else p.polarity
    source = "the recipe's segment stage" if p.polarity != "auto" else "capture.json (dark-object when it has none)"
    use_bg = p.background == "on" or (p.background == "auto" and bool(cap.backgrounds))
    for cam in cap.rig:
        if use_bg and cap.backgrounds.get(cam.name) is None:
            raise StageError(f"camera {cam.name}: no background image (background/{cam.name}.png)")

    def one(cam):
        bg = cap.backgrounds.get(cam.name) if use_bg else None
        return segment_image(cap.images[cam.name], bg, polarity, p, cam.name, source)

    # OpenCV, the compiled contouring and numpy on whole images release the GIL: cameras
    # in parallel threads.
    sils = map_threads(one, cap.rig.cameras)
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
