"""Stage ``segment.threshold``: silhouettes with sub-pixel contours from grey levels."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from inspector import hookimpl
from inspector.errors import StageError
from inspector.kernels import background as bk
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
    min_area_px: int = param(50, "connected components smaller than this are noise (or specks of dust)", min=1, max=100_000_000)
    # Real optics (issue 26): an uneven background, dust, blooming and defocus.
    flat_field: Literal["auto", "ratio", "difference"] = param(
        "auto",
        "with background images: 'ratio' divides the image by the empty field (flat-field: vignetting, an uneven "
        "backlight and dust multiply the light), 'difference' subtracts it; auto: ratio unless the empty field is "
        "darker than 20 grey levels",
    )
    background_model: Literal["auto", "on", "off"] = param(
        "auto",
        "without background images: model the background's large-scale level from the image itself and divide by it; "
        "auto: when that level varies by more than uneven_pct over the image",
    )
    uneven_pct: float = param(3.0, "with background_model='auto': the background's variation, percent, above which it is modelled", min=0.0, max=100.0)
    speck_depth_pct: float = param(
        8.0, "a pixel of the empty field darker than the field's large-scale level by this many percent belongs to a speck", min=0.5, max=100.0
    )
    speck_margin_px: float = param(
        2.0, "contour points closer than this to a speck of the empty field are dropped (0: kept)", min=0.0, max=100.0
    )
    edge_window_px: int = param(
        0,
        "half width of the window the sub-pixel edge is integrated over, px; 0: from the camera's measured edge profile "
        "(2 for sharp edges, wider for defocus, motion blur or blooming)",
        min=0,
        max=16,
    )


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
#: half_window + 1 px beyond the contour (:data:`MAX_WINDOW_PX` + 1 at most), the edge
#: profile :data:`PROFILE_REACH_PX`. The points are then the whole image's.
CROP_MARGIN = 12

#: Edge profile (:func:`inspector.kernels.silhouette.edge_profile`): how far it is measured
#: on either side of the contour, px.
PROFILE_REACH_PX = 10.0
#: A measured edge half width up to this (px) is a sharp, anti-aliased edge: the sub-pixel
#: edge is integrated over +-2 px, as always. Wider (defocus, motion blur, blooming): over
#: the half width + 1 px, at most :data:`MAX_WINDOW_PX`.
SHARP_EDGE_PX = 2.0
MAX_WINDOW_PX = 10
#: Flat-field only a background at least this bright (grey levels): dividing by a darker one
#: (a bright object on a black background) would multiply its noise.
MIN_FLAT_LEVEL = 20.0
#: A background model from fewer blocks of background than this share is not trusted (the
#: background frames the part and covers most of the view; a model from less is more likely
#: that of the part itself, e.g. under an inverted polarity).
MIN_MODEL_BLOCKS = 0.3
#: Nor one that varies by more than this share of its highest level (a background at 25 %
#: of its centre's brightness at a corner is not vignetting but the part, or no backlight).
MAX_MODEL_SPREAD = 0.75


def _hard_edged(above: np.ndarray, partial: int) -> bool:
    """True when the image has (almost) no anti-aliased edge pixels: a binary silhouette.

    ``above``: (H, W) raw coverage >= 0.5; ``partial``: pixels of raw coverage in (0.2, 0.8).
    """
    return partial < 0.1 * max(sk.edge_pixel_count(above), 1)


#: Share of the image border above which the "object" is the background. A part is framed
#: by the background (a shaft across the view covers a few per cent of the border, a part
#: filling half the view a half); an inverted polarity gives the whole border.
INVERTED_BORDER_FRACTION = 0.75


def _polarity_check(camera: str, mask: np.ndarray, polarity: str, source: str,
                    box: tuple[int, int, int, int] | None = None) -> float:
    """The share of the image border the object covers (``mask`` False outside ``box``);
    StageError when it is the background."""
    share = sk.border_fraction(mask, box)
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


def _coverage_u8(grey: np.ndarray, polarity: str, p: SegmentParams, camera: str, levelled: bool = False):
    """Coverage of an 8-bit grey image (H, W) uint8, without background image.

    Every full-image pass is a uint8 OpenCV operation or a lookup in a 256-entry table (the
    signal of an 8-bit image takes at most 256 values): the same numbers as
    :func:`_coverage_float`, several times faster.

    Returns
    -------
    soft : (H, W) float32 or None
        Coverage clipped to [0, 1]; None when it is the unsmoothed ramp, which
        :func:`segment_camera` computes only around the object (``clip(raw, 0, 1)``).
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
    if levelled:
        # A flat-fielded image's levels fall anywhere between two grey levels: their medians
        # interpolated within the grey level (an integer median would be up to half a grey
        # level off: ~0.004 px of edge for a contrast of 140).
        bg_level, fg_level = sk.levels_from_histogram(table, counts, level, interpolate=True)
    else:
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
    return None, above, lambda y0, y1, x0, x1: cv2.LUT(grey[y0:y1, x0:x1], raw_t), 0.0


def _coverage_float(grey: np.ndarray, background, polarity: str, p: SegmentParams, camera: str):
    """Coverage of float32 grey levels (H, W) (16-bit or colour images, flat-fielded ones, or
    with a background subtracted: ``background`` (H, W) float32 grey levels); returns what
    :func:`_coverage_u8` returns."""
    grey = _denoise(grey, p)
    bg = _denoise(background, p) if background is not None else None
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


def _level(grey: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """Grey levels times a gain per pixel: uint8 stays uint8 (rounded, one OpenCV pass)."""
    if grey.dtype == np.uint8:
        return bk.flat_field_u8(grey, gain)
    return (grey * gain).astype(np.float32)


def _levelled(image: np.ndarray, background: np.ndarray | None, polarity: str, p: SegmentParams,
              report: dict[str, Any]) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """The image levelled for segmentation, and what the flat-field found.

    Returns
    -------
    grey : (H, W) uint8 or float32, or None
        Grey levels to segment (uint8 for an 8-bit image: the fast path); None: segment the
        image with ``background`` subtracted (``difference``), as :func:`_coverage_float`.
    background : (H, W) float32 or None
        The grey background to subtract (``difference`` only).
    specks : (H, W) bool or None
        The empty field's specks (with a background image).
    """
    grey8 = sk.grey_u8(image)
    grey = grey8 if grey8 is not None else sk.to_grey(image)
    if background is not None:
        bg = sk.to_grey(background)
        field = bk.background_level(_denoise(bg, p), polarity)
        mode = p.flat_field
        if mode == "auto":
            mode = "ratio" if field.reference >= MIN_FLAT_LEVEL else "difference"
        specks = bk.speck_mask(_denoise(bg, p), field.level, polarity, p.speck_depth_pct / 100.0)
        report.update(background="image", flat_field=mode, background_range=[field.low, field.high],
                      specks=bk.count_blobs(specks))
        if mode == "difference":
            return None, bg, specks
        gain = np.float32(field.reference) / np.maximum(_denoise(bg, p), np.float32(1.0))
        return _level(grey, gain), None, specks
    if p.background_model == "off":
        return grey, None, None
    field = bk.background_level(grey, polarity)
    report.update(background_range=[field.low, field.high])
    trusted = field.blocks >= MIN_MODEL_BLOCKS * field.blocks_level.size and field.spread <= MAX_MODEL_SPREAD
    wanted = p.background_model == "on" or 100.0 * field.spread > p.uneven_pct
    if wanted and trusted and field.reference >= MIN_FLAT_LEVEL:
        report.update(background="model", flat_field="ratio")
        return _level(grey, (np.float32(field.reference) / np.maximum(field.level, np.float32(1.0)))), None, None
    report.update(background="even" if not wanted else "model refused")
    return grey, None, None


#: Slope of a sharp, anti-aliased edge's measured profile across its contour (the coverage
#: gained from 0.5 px outside to 0.5 px inside, measured: 0.63 on the 1024² foreign captures).
SHARP_SLOPE = 0.63


def _resharpen(soft: np.ndarray, offsets: np.ndarray, profile: np.ndarray) -> float:
    """Steepen a wide edge's coverage (h, w) float32 (the crop around the object: a view,
    written in place) about its 0.5 level (mask and contour unchanged) to a sharp edge's
    slope, so that ``coverage - 0.5`` near the contour reads as a distance in px as for a
    sharp edge (the BCPS inside maps take it so); returns the gain (1: unchanged)."""
    import cv2

    i0, i1 = np.searchsorted(offsets, [-0.5 - 1e-9, 0.5 - 1e-9])
    slope = float(profile[i1] - profile[i0]) if 0 <= i0 < i1 < len(profile) else 0.0
    if not slope > 0.05:
        return 1.0
    gain = SHARP_SLOPE / slope
    if gain <= 1.0:
        return 1.0
    # soft = clip(0.5 + (soft - 0.5) * gain, 0, 1), in two OpenCV passes on a contiguous
    # copy (OpenCV would not write a strided view back).
    c = np.ascontiguousarray(soft)
    cv2.addWeighted(c, gain, c, 0.0, 0.5 * (1.0 - gain), dst=c)
    np.clip(c, 0.0, 1.0, out=soft)
    return gain


#: Without an empty field: contour points within this (px, plus speck_margin_px) of a bump
#: found on the edge (:func:`inspector.kernels.silhouette.contour_bumps`) are dropped.
BUMP_ZONE_PX = 2


def cv2_dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """A (h, w) bool mask dilated by a disc of ``radius`` px."""
    import cv2

    if radius <= 0:
        return mask
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    return cv2.dilate(mask.view(np.uint8), disc).view(bool)


def segment_camera(
    image: np.ndarray,
    background: np.ndarray | None,
    polarity: str,
    p: SegmentParams,
    camera: str,
    polarity_source: str = "the segment stage",
) -> tuple[Silhouette, dict[str, Any]]:
    """One camera image -> :class:`Silhouette` and what the segmentation concluded (pure
    function of its inputs).

    ``polarity_source`` names where ``polarity`` came from, for the message when the
    image's background comes out as the object (an inverted polarity).

    Real optics (issue 26): the image is first levelled, by the empty field ``background``
    (``flat_field``; its specks are found) or by a model of its own background's large-scale
    level when that is uneven (``background_model``), so one pair of levels holds everywhere;
    the edge profile measured across the contour sets the window the sub-pixel edge is
    integrated over (defocus, motion blur and blooming widen it: the whole profile is
    integrated, so its 50 % position between the dark and bright levels on either side is
    found whatever its shape); contour points on a speck of the empty field are dropped.

    Full-image passes find the coverage, its 0.5 threshold and the components; the
    contour work runs on a crop around the kept components (same points as on the whole
    image: :data:`CROP_MARGIN`).

    Returns
    -------
    Silhouette
    dict
        ``background`` ("image", "model", "even", "model refused"), ``flat_field``,
        ``background_range`` (grey levels: the background's large-scale level, lowest and
        highest), ``specks`` (of the empty field), ``specks_ignored`` (small blobs dropped as
        noise or dust), ``points_dropped`` (contour points on specks), ``edge_px`` (the
        measured edge profile's half width, px), ``window_px`` (the integration window's
        half width) and ``optics`` (whether any of it changed the segmentation).
    """
    report: dict[str, Any] = {"background": "even"}
    grey, sub_bg, specks = _levelled(image, background, polarity, p, report)
    if grey is not None and grey.dtype == np.uint8:
        levelled = report["background"] in ("image", "model")
        soft, above, raw_in, sigma = _coverage_u8(grey, polarity, p, camera, levelled)
    else:
        soft, above, raw_in, sigma = _coverage_float(sk.to_grey(image) if grey is None else grey, sub_bg, polarity, p,
                                                     camera)
    comps = sk.kept_components(above, p.min_area_px)
    if comps.box is None:
        raise StageError(f"camera {camera}: empty silhouette (no object region of {p.min_area_px} px or more)")
    mask = comps.mask
    border = _polarity_check(camera, mask, polarity, polarity_source, comps.box) > 0.0
    y0, y1, x0, x1 = sk.grow_box(comps.box, mask.shape, CROP_MARGIN)
    crop = dict(origin=(x0, y0), image_shape=mask.shape)
    raw = raw_in(y0, y1, x0, x1)
    if comps.removed is not None:
        # coverage >= 0.5 only on the kept components
        raw = np.where(comps.removed[y0:y1, x0:x1], np.float32(0.0), raw)
        if soft is not None:
            soft[comps.removed] = 0.0
        report["specks_ignored"] = bk.count_blobs(comps.removed)
    if soft is None:  # the coverage only where it is read: the crop (zero beyond: no page touched)
        soft = sk.lazy_zeros(mask.shape, np.float32)
        np.clip(raw, 0.0, 1.0, out=soft[y0:y1, x0:x1])
    m = mask[y0:y1, x0:x1]
    # Without an empty field, specks on the edge are found by their shape: a small bump on a
    # straight stretch of contour (the zone around it is dropped below); looked for on a
    # camera that shows dust (specks away from the part, dropped as small blobs).
    look = specks is None and p.speck_margin_px > 0 and bool(report.get("specks_ignored"))
    pieces: list[tuple[np.ndarray, bool]] | None = [] if look else None
    contour = sk.subpixel_contour(soft[y0:y1, x0:x1], m, margin=1.0, pieces=pieces, **crop)
    bumps = sk.contour_bumps(pieces, soft[y0:y1, x0:x1], origin=(x0, y0)) if pieces else np.zeros((0, 2))
    window = 2
    if p.subpixel == "area":
        if p.edge_window_px:
            window = int(p.edge_window_px)
        elif sigma == 0:  # anti-aliased: the profile is the optics' (a smoothed hard edge's is ours)
            offsets, profile = sk.edge_profile(raw, contour, reach=PROFILE_REACH_PX, origin=(x0, y0))
            width = sk.edge_half_width(offsets, profile)
            report["edge_px"] = round(width, 2)
            if width > SHARP_EDGE_PX:
                window = min(int(math.ceil(width)) + 1, MAX_WINDOW_PX)
                gain = _resharpen(soft[y0:y1, x0:x1], offsets, profile)
                if gain > 1.0:
                    report["edge_gain"] = round(gain, 2)
        contour = sk.refine_contour_area(contour, raw, half_window=window, **crop)
        h, w = mask.shape
        keep = (contour[:, 0] >= 1) & (contour[:, 0] <= w - 2) & (contour[:, 1] >= 1) & (contour[:, 1] <= h - 2)
        contour = contour[keep]
    report["window_px"] = window
    contour = _off_specks(contour, specks, bumps, (y0, y1, x0, x1), m.shape, p, report)
    report["optics"] = bool(report["background"] in ("image", "model") or report.get("specks_ignored")
                            or report.get("points_dropped") or window != 2)
    sil = Silhouette(camera=camera, mask=mask, soft=soft, contour=contour, touches_border=border,
                     edge_px=SMOOTHED_EDGE_PX if sigma > 0 else 0.0, support=(y0, y1, x0, x1))
    return sil, report


def _off_specks(contour: np.ndarray, specks: np.ndarray | None, bumps: np.ndarray, box: tuple[int, int, int, int],
               shape: tuple[int, ...], p: SegmentParams, report: dict[str, Any]) -> np.ndarray:
    """The contour points that do not lie on a speck: of the empty field (within
    ``speck_margin_px``), or, without one, of the bumps found on the edge (within
    ``speck_margin_px`` plus :data:`BUMP_ZONE_PX`); ``report`` gets ``edge_specks`` and
    ``points_dropped``.

    Parameters
    ----------
    contour : (M, 2) float
        Sub-pixel contour points, image px.
    specks : (H, W) bool or None
        The empty field's specks.
    bumps : (K, 2) float
        Bumps found on the edge, image px.
    box : (y0, y1, x0, x1)
        The crop the contour work runs on, image px.
    shape : (h, w)
        The crop's shape (the mask's crop).

    Returns
    -------
    (M', 2) float
    """
    y0, y1, x0, x1 = box
    zone = None
    if specks is not None and report.get("specks") and p.speck_margin_px > 0:
        zone = specks[y0:y1, x0:x1].copy()
    elif len(bumps):
        zone = np.zeros(shape, bool)
        j = np.clip(np.rint(bumps[:, 0] - x0).astype(np.intp), 0, shape[1] - 1)
        i = np.clip(np.rint(bumps[:, 1] - y0).astype(np.intp), 0, shape[0] - 1)
        zone[i, j] = True
        report["edge_specks"] = bk.count_blobs(cv2_dilate(zone, BUMP_ZONE_PX))
    if zone is not None:
        r = int(math.ceil(p.speck_margin_px)) + (BUMP_ZONE_PX if specks is None else 0)
        on = sk.near_mask(contour - np.array([x0, y0]), cv2_dilate(zone, r))
        report["points_dropped"] = int(on.sum())
        contour = contour[~on]
    return contour


def segment_image(
    image: np.ndarray,
    background: np.ndarray | None,
    polarity: str,
    p: SegmentParams,
    camera: str,
    polarity_source: str = "the segment stage",
) -> Silhouette:
    """One camera image -> :class:`Silhouette` (pure function of its inputs): the silhouette of
    :func:`segment_camera`."""
    return segment_camera(image, background, polarity, p, camera, polarity_source)[0]


#: ``context.extras`` key of what the segmentation concluded per camera, when real optics
#: changed it for some camera (result.json ``extras``): camera -> :func:`segment_camera`'s dict.
EXTRAS_KEY = "segment.optics"


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
        return segment_camera(cap.images[cam.name], bg, polarity, p, cam.name, source)

    # OpenCV, the compiled contouring and numpy on whole images release the GIL: cameras
    # in parallel threads.
    out = map_threads(one, cap.rig.cameras)
    sils = tuple(s for s, _ in out)
    reports = {cam.name: r for cam, (_, r) in zip(cap.rig.cameras, out)}
    if not any(r["optics"] for r in reports.values()):
        return ctx.evolve(silhouettes=sils)
    return ctx.evolve(silhouettes=sils, extras={**ctx.extras, EXTRAS_KEY: reports})


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
