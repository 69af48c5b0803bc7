"""Silhouette kernels: grey levels -> object coverage, mask and sub-pixel contour.

The *coverage* image estimates, per pixel, the fraction of its area covered by the object
(0 background, 1 object) from the grey levels of an anti-aliased image; its 0.5 level is
the sub-pixel contour (found by marching squares, ``skimage.measure.find_contours``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["inside_map", "refine_contour_area", "to_grey", "object_signal", "coverage", "largest_components", "subpixel_contour", "touches_border", "sample_bilinear"]


def to_grey(image: np.ndarray) -> np.ndarray:
    """Image (H, W) or (H, W, C), uint8/uint16 -> float32 (H, W) grey on the 8-bit scale.

    Colour images are converted with the usual luma weights (channels in RGB order); an
    alpha channel is ignored. 16-bit levels are divided by 257 so that thresholds and noise
    figures read the same for both depths.
    """
    img = np.asarray(image)
    scale = 1.0 / 257.0 if img.dtype == np.uint16 else 1.0
    img = img.astype(np.float32)
    if img.ndim == 3:
        c = img.shape[2]
        if c == 1:
            img = img[..., 0]
        else:
            img = 0.299 * img[..., 0] + 0.587 * img[..., 1] + 0.114 * img[..., 2]
    return img * np.float32(scale)


def object_signal(grey: np.ndarray, polarity: str, background: np.ndarray | None = None) -> np.ndarray:
    """Grey levels -> a signal that is high on the object, float32 (H, W), 8-bit scale.

    Parameters
    ----------
    grey : (H, W) float32
    polarity : {"dark-object", "bright-object"}
    background : (H, W) float32, optional
        Grey image of the empty rig: the signal is then the difference to it, signed by
        the polarity (robust to uneven lighting).
    """
    sign = -1.0 if polarity == "dark-object" else 1.0
    if background is not None:
        return np.float32(sign) * (grey - background)
    return grey if sign > 0 else np.float32(255.0) - grey


def otsu_level(signal: np.ndarray) -> float:
    """Otsu threshold of a float image (8-bit scale), via OpenCV on a 0..255 histogram."""
    import cv2

    lo, hi = float(signal.min()), float(signal.max())
    if hi - lo < 1e-6:
        return hi
    u8 = np.clip((signal - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)
    t, _ = cv2.threshold(u8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return lo + (t + 0.5) * (hi - lo) / 255.0


def coverage(signal: np.ndarray, level: float) -> tuple[np.ndarray, float, float]:
    """Normalise the signal to object coverage in [0, 1].

    The background and object levels are the medians of the signal on either side of
    ``level``; coverage is the linear ramp between them (exact for an anti-aliased image
    whose grey level is linear in the covered area).

    Returns
    -------
    soft : (H, W) float32
    background_level, object_level : float
    """
    below = signal[signal < level]
    above = signal[signal >= level]
    bg = float(np.median(below)) if below.size else float(level) - 1.0
    fg = float(np.median(above)) if above.size else float(level) + 1.0
    if fg - bg < 1e-6:
        fg = bg + 1e-6
    soft = (signal - np.float32(bg)) * np.float32(1.0 / (fg - bg))
    return np.clip(soft, 0.0, 1.0, out=soft), bg, fg


def largest_components(mask: np.ndarray, min_area: int) -> np.ndarray:
    """Keep the connected components of ``mask`` (8-connected) of at least ``min_area`` px."""
    import cv2

    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = np.zeros(n, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_area
    return keep[labels]


def touches_border(mask: np.ndarray) -> bool:
    """True when the mask has object pixels on the image border."""
    return bool(mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())


def subpixel_contour(soft: np.ndarray, mask: np.ndarray, *, margin: float = 1.0) -> np.ndarray:
    """Sub-pixel contour points of the object, about one per contour pixel.

    Parameters
    ----------
    soft : (H, W) float32
        Coverage in [0, 1].
    mask : (H, W) bool
        The kept object pixels; contours of anything else are ignored.
    margin : float
        Points closer than this to the image border (px) are dropped: there the border,
        not the object, makes the contour.

    Returns
    -------
    (M, 2) float
        ``(u, v)`` pixel coordinates (OpenCV convention).
    """
    from skimage.measure import find_contours

    import cv2

    if not mask.any():
        return np.zeros((0, 2))
    h, w = mask.shape
    ys, xs = np.nonzero(mask)
    y0, y1 = max(ys.min() - 3, 0), min(ys.max() + 4, h)
    x0, x1 = max(xs.min() - 3, 0), min(xs.max() + 4, w)
    keep = cv2.dilate(mask[y0:y1, x0:x1].astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    crop = np.where(keep, soft[y0:y1, x0:x1], 0.0)
    # Pad so contours of objects touching the crop edge close; border points are dropped below.
    padded = np.pad(crop, 1)
    pts = [c for c in find_contours(padded, 0.5) if len(c) >= 3]
    if not pts:
        return np.zeros((0, 2))
    rc = np.concatenate([c[:-1] if np.allclose(c[0], c[-1]) else c for c in pts])
    uv = np.stack([rc[:, 1] - 1 + x0, rc[:, 0] - 1 + y0], axis=1)
    inside = (uv[:, 0] >= margin) & (uv[:, 0] <= w - 1 - margin) & (uv[:, 1] >= margin) & (uv[:, 1] <= h - 1 - margin)
    return uv[inside]


def sample_bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray, outside: float | np.ndarray = 0.0) -> np.ndarray:
    """Bilinear interpolation of ``image`` (H, W) at pixel coordinates ``u, v`` (any shape).

    Points outside the pixel-centre grid get ``outside``.
    """
    h, w = image.shape
    valid = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1) & np.isfinite(u) & np.isfinite(v)
    uc = np.where(valid, u, 0.0)
    vc = np.where(valid, v, 0.0)
    x0 = np.minimum(uc.astype(np.intp), w - 2)
    y0 = np.minimum(vc.astype(np.intp), h - 2)
    fx = uc - x0
    fy = vc - y0
    flat = image.ravel()
    i00 = y0 * w + x0
    a = flat[i00]
    b = flat[i00 + 1]
    c = flat[i00 + w]
    d = flat[i00 + w + 1]
    val = (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy
    return np.where(valid, val, outside)


def inside_map(soft: np.ndarray, margin: int = 16) -> np.ndarray:
    """Signed "inside-ness" of every pixel, in pixels: >= 0 inside the silhouette.

    Near the contour it is ``soft - 0.5`` (the coverage ramp, whose 0.5 level is the
    sub-pixel contour); farther out it is minus the distance to the object (Euclidean
    distance transform), so bilinear samples of it tell how far outside a projected point
    lies. Inside it is clipped at +0.5 (only the outside distance is ever needed).

    Parameters
    ----------
    soft : (H, W) float32
        Coverage in [0, 1].

    Returns
    -------
    (H, W) float32
    """
    import cv2

    mask = soft >= 0.5
    out = np.full(soft.shape, -1e6, np.float32)
    if not mask.any():
        return out
    # Only a band around the object matters (farther is "far outside" for every use):
    # work on its bounding box plus ``margin`` pixels.
    ys, xs = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    y0, y1 = max(ys[0] - margin, 0), min(ys[-1] + margin + 1, soft.shape[0])
    x0, x1 = max(xs[0] - margin, 0), min(xs[-1] + margin + 1, soft.shape[1])
    m = mask[y0:y1, x0:x1]
    edt = cv2.distanceTransform((~m).astype(np.uint8), cv2.DIST_L2, 5)
    out[y0:y1, x0:x1] = np.where(edt <= 1.0, soft[y0:y1, x0:x1] - 0.5, 0.5 - edt)
    return out


def refine_contour_area(uv: np.ndarray, raw: np.ndarray, *, half_window: int = 2) -> np.ndarray:
    """Move marching-squares contour points onto the edge by area conservation.

    Linear interpolation of coverage between pixel centres misplaces an edge by up to
    0.08 px depending on its sub-pixel phase. Along a pixel row (for edges steeper than
    45 degrees; columns otherwise) the summed coverage of the pixels crossing the edge is
    exactly the length of object in that row strip, i.e. the edge position at the row's
    centre, whatever the edge's angle. Only marching-squares vertices lying on the row
    (column) lines are kept, so the result has one point per row (column) crossed.

    Parameters
    ----------
    uv : (M, 2) float
        Contour points from :func:`subpixel_contour`.
    raw : (H, W) float32
        Coverage *not* clipped to [0, 1] (clipping would bias noisy sums).
    half_window : int
        Pixels summed on either side of the edge pixel.

    Returns
    -------
    (P, 2) float
        Refined ``(u, v)`` points. Points whose window is not clean (another edge inside,
        e.g. at a corner or a thin part) keep their marching-squares position.
    """
    h, w = raw.shape
    if len(uv) == 0:
        return uv
    clipped = np.clip(raw, 0.0, 1.0)
    gy, gx = np.gradient(clipped)
    gxs = sample_bilinear(gx, uv[:, 0], uv[:, 1])
    gys = sample_bilinear(gy, uv[:, 0], uv[:, 1])
    on_row = np.abs(uv[:, 1] - np.rint(uv[:, 1])) < 1e-9
    on_col = np.abs(uv[:, 0] - np.rint(uv[:, 0])) < 1e-9
    steep = np.abs(gxs) >= np.abs(gys)
    out = []
    offs = np.arange(-half_window, half_window + 1)
    for along_u, keep in ((True, steep & on_row), (False, ~steep & on_col)):
        pts = uv[keep]
        if len(pts) == 0:
            continue
        g = gxs[keep] if along_u else gys[keep]
        line = np.rint(pts[:, 1] if along_u else pts[:, 0]).astype(np.intp)
        pos = pts[:, 0] if along_u else pts[:, 1]
        centre = np.rint(pos).astype(np.intp)
        idx = centre[:, None] + offs[None, :]
        n = w if along_u else h
        inside_img = (idx.min(axis=1) >= 0) & (idx.max(axis=1) < n)
        idx = np.clip(idx, 0, n - 1)
        vals = raw[line[:, None], idx] if along_u else raw[idx, line[:, None]]
        cl = np.clip(vals, 0.0, 1.0)
        obj_low = g < 0  # coverage decreases with the coordinate: object on the low side
        first = np.where(obj_low, cl[:, 0], cl[:, -1])
        last = np.where(obj_low, cl[:, -1], cl[:, 0])
        # A clean window: saturated at both ends and monotone (one edge only).
        d = np.diff(cl, axis=1) * np.where(obj_low, 1.0, -1.0)[:, None]
        clean = inside_img & (first > 0.85) & (last < 0.15) & np.all(d < 0.1, axis=1)
        total = vals.sum(axis=1)
        edge = np.where(obj_low, centre - half_window - 0.5 + total, centre + half_window + 0.5 - total)
        edge = np.where(clean, edge, pos)
        out.append(np.stack([edge, line.astype(float)], axis=1) if along_u else np.stack([line.astype(float), edge], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 2))
