"""Silhouette kernels: grey levels -> object coverage, mask and sub-pixel contour.

The *coverage* image estimates, per pixel, the fraction of its area covered by the object
(0 background, 1 object) from the grey levels of an anti-aliased image; its 0.5 level is
the sub-pixel contour (found by marching squares, :func:`marching_squares`: the contours
of ``skimage.measure.find_contours``, compiled, then moved onto the edge by area
conservation, :func:`refine_contour_area`).

Speed: the object covers a small part of the image, so only the passes that must see every
pixel (denoising, histogram, threshold, connected components) run on the whole image, and
for 8-bit grey images they are uint8 OpenCV operations or 256-entry tables indexed by the
grey level (:func:`grey_u8`, :func:`histogram_u8`, :func:`otsu_level_from_histogram`,
:func:`levels_from_histogram`): exact, since the signal of an 8-bit image takes at most 256
values. Contouring and refinement work on a crop around the kept components
(:func:`grow_box`; ``origin`` of :func:`subpixel_contour` and :func:`refine_contour_area`)
and give the same points as on the whole image; both are compiled by Numba on first use
(cached on disk) and release the GIL, so cameras segment in parallel threads.
"""

from __future__ import annotations

import math
import mmap
import threading
from typing import NamedTuple

import numpy as np

__all__ = [
    "FAR_OUTSIDE",
    "InsideRegion",
    "inside_map",
    "inside_region",
    "refine_contour_area",
    "to_grey",
    "grey_u8",
    "median_denoise",
    "object_signal",
    "otsu_level",
    "otsu_level_from_histogram",
    "histogram_u8",
    "mask_from_table",
    "coverage",
    "coverage_levels",
    "coverage_ramp",
    "levels_from_histogram",
    "edge_pixel_count",
    "largest_components",
    "marching_squares",
    "kept_components",
    "Components",
    "grow_box",
    "subpixel_contour",
    "contour_bumps",
    "touches_border",
    "sample_bilinear",
    "edge_profile",
    "edge_half_width",
    "near_mask",
    "lazy_zeros",
]


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


def grey_u8(image: np.ndarray) -> np.ndarray | None:
    """The (H, W) uint8 grey levels of an 8-bit single-channel image, else ``None``.

    For such an image :func:`to_grey` is exactly ``grey_u8(image).astype(np.float32)``, so
    every grey-level computation can be done on 256-entry tables instead of float images.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8:
        return None
    if img.ndim == 2:
        return img
    if img.ndim == 3 and img.shape[2] == 1:
        return img[..., 0]
    return None


#: Bytes of the buffer :func:`median_denoise` works through (a band of rows, in cache).
DENOISE_BAND_BYTES = 1 << 18


def median_denoise(grey: np.ndarray, mode: str, impulse_threshold: float) -> np.ndarray:
    """3x3 median against impulse noise.

    Parameters
    ----------
    grey : (H, W) float32 (8-bit scale) or uint8
    mode : {"off", "impulse", "full"}
        ``"impulse"`` replaces only the pixels farther than ``impulse_threshold`` grey
        levels from their 3x3 median (keeps anti-aliased edges); ``"full"`` filters every
        pixel.

    Returns
    -------
    (H, W) array of the input's dtype
        For uint8 input, identical to filtering ``grey.astype(np.float32)`` (the median of
        integer levels is an integer level), with uint8 OpenCV operations only.
    """
    if mode == "off":
        return grey
    import cv2

    med = cv2.medianBlur(grey, 3)
    if mode == "full":
        return med
    if grey.dtype != np.uint8:
        return np.where(np.abs(grey - med) > impulse_threshold, med, grey)
    if impulse_threshold < 0:
        return med
    if impulse_threshold >= 255:
        return grey
    # Integer differences: |d| <= t  <=>  |d| <= floor(t). Keep those pixels, take the
    # median elsewhere: in place, band by band through one small buffer (fresh full-size
    # buffers cost page faults).
    grey = np.ascontiguousarray(grey)
    rows = max(1, DENOISE_BAND_BYTES // max(grey.shape[1], 1))
    calm = np.empty((min(rows, grey.shape[0]), grey.shape[1]), np.uint8)
    for y in range(0, grey.shape[0], rows):
        g, m = grey[y:y + rows], med[y:y + rows]
        c = calm[:len(g)]
        cv2.absdiff(g, m, dst=c)
        cv2.threshold(c, math.floor(impulse_threshold), 1, cv2.THRESH_BINARY_INV, dst=c)
        cv2.copyTo(g, c, m)
    return med


def lazy_zeros(shape: tuple[int, ...], dtype: np.dtype | type) -> np.ndarray:
    """Zeros of ``shape`` whose pages cost nothing until written: an anonymous memory map.

    A silhouette's full-size arrays (coverage, mask) are written only around the object;
    :func:`numpy.zeros` takes its memory from the heap once the allocator keeps freed blocks,
    and then clears every page (16 x 20 MB of float32 at 5 MP, more than the work on the
    object). An anonymous map is zero until touched, and unmapped with the array.
    """
    dt = np.dtype(dtype)
    n = math.prod(shape)
    if n * dt.itemsize < 1 << 20:  # small: the heap is as cheap
        return np.zeros(shape, dt)
    try:
        buf = mmap.mmap(-1, n * dt.itemsize)
    except OSError:  # no map left (vm.max_map_count): the heap's zeros are the same array
        return np.zeros(shape, dt)
    return np.frombuffer(buf, dt, count=n).reshape(shape)


def histogram_u8(grey: np.ndarray) -> np.ndarray:
    """Pixel count per grey level of a uint8 image, (256,) int64 (exact)."""
    if grey.size < 1 << 24:  # OpenCV counts in float32: exact below 2**24 per bin
        import cv2

        return cv2.calcHist([np.ascontiguousarray(grey)], [0], None, [256], [0, 256]).ravel().astype(np.int64)
    return np.bincount(grey.ravel(), minlength=256)


def mask_from_table(grey: np.ndarray, table: np.ndarray) -> np.ndarray:
    """``table[grey]`` for a boolean table per grey level, as a (H, W) uint8 0/1 image.

    Parameters
    ----------
    grey : (H, W) uint8
    table : (256,) bool

    A table that is a run of ``True`` from level 0 or up to level 255 (the threshold of a
    monotone signal) is one OpenCV threshold; any other table a lookup.
    """
    import cv2

    on = np.flatnonzero(table)
    if len(on) == 0:
        return np.zeros(grey.shape, np.uint8)
    if on[-1] - on[0] + 1 == len(on):  # one run
        if on[0] == 0:
            return cv2.threshold(grey, int(on[-1]), 1, cv2.THRESH_BINARY_INV)[1]  # grey <= last
        if on[-1] == 255:
            return cv2.threshold(grey, int(on[0]) - 1, 1, cv2.THRESH_BINARY)[1]  # grey >= first
    return cv2.LUT(grey, np.asarray(table, np.uint8))


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


def _otsu_u8(signal: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """The signal stretched from [lo, hi] to 0..255, uint8 (same shape)."""
    return np.clip((signal - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)


def otsu_level(signal: np.ndarray) -> float:
    """Otsu threshold of a float image (8-bit scale), via OpenCV on a 0..255 histogram."""
    import cv2

    lo, hi = float(signal.min()), float(signal.max())
    if hi - lo < 1e-6:
        return hi
    t, _ = cv2.threshold(_otsu_u8(signal, lo, hi), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return lo + (t + 0.5) * (hi - lo) / 255.0


def _otsu_threshold(hist: np.ndarray) -> float:
    """OpenCV's Otsu threshold of an 8-bit image (``cv2.threshold(..., THRESH_OTSU)``) from
    its 256-bin histogram: OpenCV's double-precision loop, operation for operation, so the
    same level (checked against OpenCV by the tests)."""
    h = [int(x) for x in hist]
    scale = 1.0 / sum(h)
    mu = 0.0
    for i in range(256):
        mu += i * float(h[i])
    mu *= scale
    mu1 = q1 = max_sigma = max_val = 0.0
    eps = float(np.finfo(np.float32).eps)  # FLT_EPSILON
    for i in range(256):
        p_i = h[i] * scale
        mu1 *= q1
        q1 += p_i
        q2 = 1.0 - q1
        if min(q1, q2) < eps or max(q1, q2) > 1.0 - eps:
            continue
        mu1 = (mu1 + i * p_i) / q1
        mu2 = (mu - q1 * mu1) / q2
        sigma = q1 * q2 * (mu1 - mu2) * (mu1 - mu2)
        if sigma > max_sigma:
            max_sigma = sigma
            max_val = float(i)
    return max_val


def otsu_level_from_histogram(values: np.ndarray, counts: np.ndarray) -> float:
    """:func:`otsu_level` of a signal given by its histogram, without any pixel pass.

    Parameters
    ----------
    values : (N,) float32
        Signal values (e.g. :func:`object_signal` of ``np.arange(256)``: per grey level).
    counts : (N,) int
        Pixels having each value (e.g. :func:`histogram_u8`).

    Returns
    -------
    float
        Identical to ``otsu_level(np.repeat(values, counts))``: the same stretch to 0..255,
        the histogram of the stretched levels, OpenCV's Otsu on it.
    """
    values = np.asarray(values, np.float32)
    counts = np.asarray(counts, np.int64)
    present = values[counts > 0]
    lo, hi = float(present.min()), float(present.max())
    if hi - lo < 1e-6:
        return hi
    hist = np.bincount(_otsu_u8(values, lo, hi), weights=counts, minlength=256)
    t = _otsu_threshold(hist)
    return lo + (t + 0.5) * (hi - lo) / 255.0


def _final_levels(bg: float | None, fg: float | None, level: float) -> tuple[float, float]:
    bg = float(level) - 1.0 if bg is None else bg
    fg = float(level) + 1.0 if fg is None else fg
    if fg - bg < 1e-6:
        fg = bg + 1e-6
    return bg, fg


def coverage_levels(signal: np.ndarray, level: float) -> tuple[float, float]:
    """Background and object levels: medians of the signal below / at or above ``level``.

    Returns
    -------
    background_level, object_level : float
        8-bit scale; ``level -/+ 1`` for an empty side; the object level is at least
        1e-6 above the background level.
    """
    below = signal[signal < level]
    above = signal[signal >= level]
    return _final_levels(
        float(np.median(below)) if below.size else None, float(np.median(above)) if above.size else None, level
    )


def levels_from_histogram(values: np.ndarray, counts: np.ndarray, level: float,
                          interpolate: bool = False) -> tuple[float, float]:
    """:func:`coverage_levels` from a histogram of the signal (exact, no pixel pass).

    Parameters
    ----------
    values : (N,) float32
        Signal values (any order, duplicates allowed), e.g. the signal per grey level.
    counts : (N,) int
        Pixels having each value.
    level : float

    interpolate : bool
        Each value stands for a bin of width 1 (an integer grey level, whose true level may
        lie anywhere within +-0.5): the median is interpolated linearly within its bin
        (the grouped-data median), not rounded to a value.

    Returns
    -------
    background_level, object_level : float
        Identical to ``coverage_levels(np.repeat(values, counts), level)``: the middle
        element(s) are picked from the cumulative counts and passed to ``np.median``
        (``interpolate``: the grouped median instead).
    """
    values = np.asarray(values, np.float32)
    counts = np.asarray(counts, np.int64)

    def median(sel: np.ndarray) -> float | None:
        v, c = values[sel], counts[sel]
        order = np.argsort(v, kind="stable")
        v, cum = v[order], np.cumsum(c[order])
        n = int(cum[-1]) if len(cum) else 0
        if n == 0:
            return None
        if interpolate:
            i = int(np.searchsorted(cum, 0.5 * n))  # the bin holding the middle
            below = float(cum[i - 1]) if i else 0.0
            return float(v[i]) - 0.5 + (0.5 * n - below) / float(c[order][i])
        ranks = [n // 2] if n % 2 else [n // 2 - 1, n // 2]
        return float(np.median(v[np.searchsorted(cum, ranks, side="right")]))

    below = values < level
    return _final_levels(median(below & (counts > 0)), median(~below & (counts > 0)), level)


def coverage_ramp(signal: np.ndarray, background_level: float, object_level: float) -> np.ndarray:
    """Linear coverage ramp, *not* clipped: 0 at the background level, 1 at the object level.

    Parameters
    ----------
    signal : float32 array, any shape (an image, or a table per grey level)

    Returns
    -------
    float32 array of the same shape
    """
    bg, fg = background_level, object_level
    return (signal - np.float32(bg)) * np.float32(1.0 / (fg - bg))


def coverage(signal: np.ndarray, level: float) -> tuple[np.ndarray, float, float]:
    """Normalise the signal to object coverage in [0, 1].

    The background and object levels are the medians of the signal on either side of
    ``level`` (:func:`coverage_levels`); coverage is the linear ramp between them (exact for
    an anti-aliased image whose grey level is linear in the covered area).

    Returns
    -------
    soft : (H, W) float32
    background_level, object_level : float
    """
    bg, fg = coverage_levels(signal, level)
    soft = coverage_ramp(signal, bg, fg)
    return np.clip(soft, 0.0, 1.0, out=soft), bg, fg


def edge_pixel_count(mask: np.ndarray) -> int:
    """Pixels that differ from their upper or left neighbour (cyclically), of a (H, W) mask
    (bool, or uint8 0/1).

    The same count as ``np.count_nonzero(m ^ np.roll(m, 1, 0) | m ^ np.roll(m, 1, 1))``
    without the rolled copies, and on the bounding box of the set pixels plus a 1 px
    frame when that fits in the image (no edge pixel lies outside it, none wraps round).
    """
    import cv2

    m = mask.view(bool) if mask.dtype == np.uint8 else np.asarray(mask, bool)  # uint8 0/1: no copy
    if m.size == 0:
        return 0
    x, y, w, h = cv2.boundingRect(m.view(np.uint8))
    if w == 0:
        return 0
    if y >= 1 and x >= 1 and y + h < m.shape[0] and x + w < m.shape[1]:
        m = m[y - 1 : y + h + 1, x - 1 : x + w + 1]
    e = np.empty(m.shape, bool)
    np.not_equal(m[1:], m[:-1], out=e[1:])
    np.not_equal(m[0], m[-1], out=e[0])
    h_ = np.empty(m.shape, bool)
    np.not_equal(m[:, 1:], m[:, :-1], out=h_[:, 1:])
    np.not_equal(m[:, 0], m[:, -1], out=h_[:, 0])
    e |= h_
    return int(np.count_nonzero(e))


class Components(NamedTuple):
    """Result of :func:`kept_components`.

    Attributes
    ----------
    mask : (H, W) bool
        Pixels of the kept components.
    box : (y0, y1, x0, x1) int or None
        Bounding box of the kept pixels, ends exclusive; None when none is kept.
    removed : (H, W) bool or None
        Pixels of the dropped components; None when none was dropped.
    """

    mask: np.ndarray
    box: tuple[int, int, int, int] | None
    removed: np.ndarray | None


def kept_components(binary: np.ndarray, min_area: int) -> Components:
    """Connected components (8-connected) of at least ``min_area`` px, with their box.

    Parameters
    ----------
    binary : (H, W) bool, uint8 0/1, or any dtype (non-zero = set)
    min_area : int

    Returns
    -------
    Components
        The labelling runs on the bounding box of the set pixels only (the components are
        the same: outside it there is nothing to label).
    """
    import cv2

    binary = np.asarray(binary)
    if binary.dtype == bool:
        b = binary.view(np.uint8)
    elif binary.dtype == np.uint8:
        b = binary
    else:
        b = (binary != 0).view(np.uint8)
    mask = lazy_zeros(b.shape, bool)
    x, y, w, h = cv2.boundingRect(b) if b.size else (0, 0, 0, 0)
    if w == 0 or h == 0:
        return Components(mask, None, None)
    sub = b[y : y + h, x : x + w]
    # 16-bit labels are faster; at most one 8-connected component per 2x2 block fits.
    ltype = cv2.CV_16U if ((h + 1) // 2) * ((w + 1) // 2) + 1 < 0xFFFF else cv2.CV_32S
    n, labels, stats, _ = cv2.connectedComponentsWithStats(sub, connectivity=8, ltype=ltype)
    keep = np.zeros(n, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_area
    removed = None
    if keep[1:].all():
        mask[y : y + h, x : x + w] = sub.view(bool)
    else:
        kept = keep[labels]
        mask[y : y + h, x : x + w] = kept
        removed = lazy_zeros(b.shape, bool)
        removed[y : y + h, x : x + w] = sub.view(bool) & ~kept
    if not keep.any():
        return Components(mask, None, removed)
    st = stats[keep]
    left, top = st[:, cv2.CC_STAT_LEFT], st[:, cv2.CC_STAT_TOP]
    box = (
        y + int(top.min()),
        y + int((top + st[:, cv2.CC_STAT_HEIGHT]).max()),
        x + int(left.min()),
        x + int((left + st[:, cv2.CC_STAT_WIDTH]).max()),
    )
    return Components(mask, box, removed)


def largest_components(mask: np.ndarray, min_area: int) -> np.ndarray:
    """Keep the connected components of ``mask`` (8-connected) of at least ``min_area`` px."""
    return kept_components(mask, min_area).mask


def grow_box(box: tuple[int, int, int, int], shape: tuple[int, ...], margin: int) -> tuple[int, int, int, int]:
    """``(y0, y1, x0, x1)`` grown by ``margin`` px on every side, clipped to an image of ``shape``."""
    y0, y1, x0, x1 = box
    h, w = shape[:2]
    return max(y0 - margin, 0), min(y1 + margin, h), max(x0 - margin, 0), min(x1 + margin, w)


def border_fraction(mask: np.ndarray, box: tuple[int, int, int, int] | None = None) -> float:
    """Fraction of the image's border pixels that are object pixels, of a (H, W) mask.

    ``box`` (y0, y1, x0, x1): rows and columns outside which the mask is False; only the
    border within it is read (a column of a large image touches every page of it).
    """
    h, w = mask.shape[:2]
    if h < 2 or w < 2:
        return float(np.count_nonzero(mask)) / max(mask.size, 1)
    y0, y1, x0, x1 = (0, h, 0, w) if box is None else box
    r0, r1 = max(y0, 1), min(y1, h - 1)  # the rows between the first and the last
    on = 0
    if y0 == 0:
        on += int(np.count_nonzero(mask[0, x0:x1]))
    if y1 == h:
        on += int(np.count_nonzero(mask[h - 1, x0:x1]))
    if x0 == 0 and r1 > r0:
        on += int(np.count_nonzero(mask[r0:r1, 0]))
    if x1 == w and r1 > r0:
        on += int(np.count_nonzero(mask[r0:r1, w - 1]))
    return on / (2 * w + 2 * (h - 2))


def touches_border(mask: np.ndarray) -> bool:
    """True when the mask has object pixels on the image border."""
    return border_fraction(mask) > 0.0


def _image_shape(crop_shape: tuple[int, ...], origin: tuple[int, int], image_shape: tuple[int, int] | None) -> tuple[int, int]:
    if image_shape is not None:
        return int(image_shape[0]), int(image_shape[1])
    if tuple(origin) != (0, 0):
        raise ValueError("image_shape is required with a non-zero origin")
    return int(crop_shape[0]), int(crop_shape[1])


def subpixel_contour(
    soft: np.ndarray,
    mask: np.ndarray,
    *,
    margin: float = 1.0,
    origin: tuple[int, int] = (0, 0),
    image_shape: tuple[int, int] | None = None,
    pieces: list[tuple[np.ndarray, bool]] | None = None,
) -> np.ndarray:
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
    origin : (x0, y0) int
        ``soft`` and ``mask`` may be a crop of the image whose pixel (0, 0) is the image's
        pixel ``(x0, y0)``; the points are then in image coordinates. The crop must hold
        the object's box plus 3 px (or reach the image border): the points are then the
        same as on the whole image.
    image_shape : (H, W), optional
        Size of the whole image; required with a non-zero ``origin``.
    pieces : list, optional
        When given, each contour is appended to it as ``(points, closed)``: its points
        ``(n, 2)`` in order along the contour (those returned, the same values) and whether
        it is a closed loop none of whose points was dropped at the border.

    Returns
    -------
    (M, 2) float
        ``(u, v)`` pixel coordinates (OpenCV convention).
    """
    import cv2

    h, w = _image_shape(mask.shape, origin, image_shape)
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if not len(rows):
        return np.zeros((0, 2))
    hc, wc = mask.shape
    y0, y1 = max(int(rows[0]) - 3, 0), min(int(rows[-1]) + 4, hc)
    x0, x1 = max(int(cols[0]) - 3, 0), min(int(cols[-1]) + 4, wc)
    m8 = mask[y0:y1, x0:x1]
    m8 = m8.view(np.uint8) if m8.dtype == bool else m8.astype(np.uint8)
    keep = cv2.dilate(m8, np.ones((3, 3), np.uint8)) != 0
    # Coverage near the kept pixels only, padded with zeros so that contours of objects
    # touching the crop edge close (border points are dropped below).
    padded = np.zeros((y1 - y0 + 2, x1 - x0 + 2), soft.dtype)
    np.copyto(padded[1:-1, 1:-1], soft[y0:y1, x0:x1], where=keep)
    pts = [c for c in marching_squares(padded, 0.5) if len(c) >= 3]
    if not pts:
        return np.zeros((0, 2))
    closed = [bool(np.allclose(c[0], c[-1])) for c in pts]
    loops = [c[:-1] if cl else c for c, cl in zip(pts, closed)]
    rc = np.concatenate(loops)
    # Integer offsets summed first: the same float operations as on the whole image.
    uv = np.stack([rc[:, 1] - 1 + (x0 + int(origin[0])), rc[:, 0] - 1 + (y0 + int(origin[1]))], axis=1)
    inside = (uv[:, 0] >= margin) & (uv[:, 0] <= w - 1 - margin) & (uv[:, 1] >= margin) & (uv[:, 1] <= h - 1 - margin)
    if pieces is not None:
        start = 0
        for c, cl in zip(loops, closed):
            part = slice(start, start + len(c))
            start += len(c)
            pieces.append((uv[part][inside[part]], cl and bool(inside[part].all())))
    return uv[inside]


def contour_bumps(
    pieces: list[tuple[np.ndarray, bool]],
    soft: np.ndarray,
    *,
    origin: tuple[int, int] = (0, 0),
    side: tuple[int, int] = (8, 24),
    centre: int = 7,
    collinear_deg: float = 4.0,
    side_rms_px: float = 0.2,
    height_px: float = 0.5,
) -> np.ndarray:
    """Small outward bumps on otherwise straight stretches of contour: specks of dust on the
    edge, not the part's shape.

    At each point of a closed contour (:func:`subpixel_contour`'s ``pieces``) the points
    ``side[0]`` to ``side[1]`` steps before it and after it (about one per pixel) are fitted
    with a line each. Where both sides are straight (RMS within ``side_rms_px``) and
    collinear (within ``collinear_deg``), a point of the ``centre`` steps around it lying
    more than ``height_px`` beyond *both* lines, on the background's side, makes it a bump.
    A speck 1-4 px across on the edge bulges it by about its size; a corner of the part
    lies on both its sides' lines, a convex curve inside them, and a concave one (a hole's
    rim) turns its sides by more than ``collinear_deg`` unless its radius is above ~700 px,
    where it departs from them by less than 0.3 px: none qualifies. (The sides start
    ``side[0]`` points away so that a speck's bump, about 2 points per pixel of its size
    where the contour goes round it, stays out of them.)

    Parameters
    ----------
    pieces : list of ((n, 2) float, bool)
        Contours in order, image coordinates, and whether each is closed.
    soft : (h, w) float32
        Coverage (tells the background's side), a crop at ``origin`` (x0, y0).

    Returns
    -------
    (K, 2) float64
        The points ``(u, v)`` found on bumps.
    """
    out = []
    lo, hi = side
    mid = np.arange(-centre, centre + 1)
    cos_max = math.cos(math.radians(collinear_deg))
    m = hi - lo + 1  # points per side

    def lines(P: np.ndarray, first: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For every k, the line fitted to the points k + first .. k + first + m - 1 of the
        closed contour P (n, 2): centroid (n, 2), unit normal (n, 2), RMS distance (n,);
        window sums from cumulative sums (O(n))."""
        n = len(P)
        x, y = P[:, 0] - P[:, 0].mean(), P[:, 1] - P[:, 1].mean()  # centred: no cancellation
        idx = (np.arange(n)[:, None] + np.array([first, first + m])[None, :]) % n

        def wsum(a: np.ndarray) -> np.ndarray:
            c = np.concatenate([[0.0], np.cumsum(np.concatenate([a, a]))])
            start = idx[:, 0]
            return c[start + m] - c[start]

        sx, sy = wsum(x) / m, wsum(y) / m
        sxx, syy, sxy = wsum(x * x) / m - sx * sx, wsum(y * y) / m - sy * sy, wsum(x * y) / m - sx * sy
        a = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
        nrm = np.stack([-np.sin(a), np.cos(a)], axis=1)
        tr, det = sxx + syy, sxx * syy - sxy * sxy
        lam = 0.5 * tr - np.sqrt(np.maximum(0.25 * tr * tr - det, 0.0))  # the smaller eigenvalue
        cen = np.stack([sx + P[:, 0].mean(), sy + P[:, 1].mean()], axis=1)
        return cen, nrm, np.sqrt(np.maximum(lam, 0.0))

    for pts, closed in pieces:
        n = len(pts)
        if not closed or n < 2 * hi + 1:
            continue
        cl, nl, rl = lines(pts, -hi)
        cr, nr, rr = lines(pts, lo)
        dot = (nl * nr).sum(axis=1)
        cand = (np.abs(dot) >= cos_max) & (rl <= side_rms_px) & (rr <= side_rms_px)
        if not cand.any():
            continue
        k = np.flatnonzero(cand)
        cl, nl, cr = cl[k], nl[k], cr[k]
        nr = nr[k] * np.where(dot[k] < 0, -1.0, 1.0)[:, None]  # the same side as nl
        C = pts[(k[:, None] + mid[None, :]) % n]  # (K, 2 centre + 1, 2)
        dl = ((C - cl[:, None, :]) * nl[:, None, :]).sum(axis=2)
        dr = ((C - cr[:, None, :]) * nr[:, None, :]).sum(axis=2)
        beyond_plus = np.minimum(dl, dr).max(axis=1) > height_px  # beyond both lines on +nl's side
        beyond_minus = np.maximum(dl, dr).min(axis=1) < -height_px
        sel = beyond_plus | beyond_minus
        if not sel.any():
            continue
        k, cl, nl, cr, beyond_plus = k[sel], cl[sel], nl[sel], cr[sel], beyond_plus[sel]
        # The background's side of the lines: where the coverage, 3 px off them, is lower.
        c = 0.5 * (cl + cr) - np.asarray(origin, float)
        plus = sample_bilinear(soft, c[:, 0] + 3.0 * nl[:, 0], c[:, 1] + 3.0 * nl[:, 1], np.nan)
        minus = sample_bilinear(soft, c[:, 0] - 3.0 * nl[:, 0], c[:, 1] - 3.0 * nl[:, 1], np.nan)
        known = np.isfinite(plus) & np.isfinite(minus) & (np.abs(plus - minus) > 0.5)
        bump = known & np.where(beyond_plus, plus < minus, plus > minus)
        if bump.any():
            out.append(pts[k[bump]])
    return np.concatenate(out) if out else np.zeros((0, 2))


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


def edge_profile(
    raw: np.ndarray,
    uv: np.ndarray,
    *,
    reach: float = 10.0,
    step: float = 0.5,
    max_points: int = 200,
    origin: tuple[int, int] = (0, 0),
) -> tuple[np.ndarray, np.ndarray]:
    """The camera's measured edge profile: the median coverage across the contour.

    At up to ``max_points`` contour points, evenly spread, the coverage is sampled along the
    edge's normal (the coverage gradient's direction, towards the object) every ``step`` px
    out to ``reach`` px on both sides; the profile is the median over the points at each
    offset. A sharp anti-aliased edge goes from 0 to 1 within about 1.5 px of the contour;
    defocus, motion blur and blooming widen it (a Gaussian of sigma 1.5 px: about 4 px).

    Parameters
    ----------
    raw : (h, w) float32
        Coverage (not clipped), possibly a crop whose pixel (0, 0) is the image's ``origin``.
    uv : (M, 2) float
        Contour points, image coordinates.
    origin : (x0, y0) int

    Returns
    -------
    offsets : (K,) float64
        Signed distances along the normal, px (positive: towards the object).
    profile : (K,) float64
        Median coverage at each offset (a sample beyond ``raw`` counts as 0 outside, 1
        inside; NaN for all offsets when no point has a usable normal).
    """
    offsets = np.arange(-reach, reach + step / 2, step)
    if len(uv) == 0:
        return offsets, np.full(len(offsets), np.nan)
    pick = np.linspace(0, len(uv) - 1, min(len(uv), max_points)).round().astype(np.intp)
    u = np.asarray(uv, float)[pick, 0] - origin[0]
    v = np.asarray(uv, float)[pick, 1] - origin[1]
    c = np.clip(raw, 0.0, 1.0)
    gx = sample_bilinear(c, u + 1.0, v, np.nan) - sample_bilinear(c, u - 1.0, v, np.nan)
    gy = sample_bilinear(c, u, v + 1.0, np.nan) - sample_bilinear(c, u, v - 1.0, np.nan)
    norm = np.hypot(gx, gy)
    ok = np.isfinite(norm) & (norm > 1e-6)
    if not ok.any():
        return offsets, np.full(len(offsets), np.nan)
    nx, ny = gx[ok] / norm[ok], gy[ok] / norm[ok]
    su = u[ok, None] + offsets[None, :] * nx[:, None]
    sv = v[ok, None] + offsets[None, :] * ny[:, None]
    samples = sample_bilinear(raw, su, sv, np.nan)
    # A sample beyond ``raw`` (the image's border) counts as the far level of its side.
    samples = np.where(np.isnan(samples), (offsets > 0).astype(float)[None, :], samples)
    return offsets, np.median(samples, axis=0)


def edge_half_width(offsets: np.ndarray, profile: np.ndarray, tol: float = 0.02) -> float:
    """How far from the contour the edge profile still differs from a step, px.

    The largest ``|offset|`` at which ``profile`` (:func:`edge_profile`) is more than ``tol``
    from its far level (0 outside, 1 inside); offsets with no sample count as settled.
    """
    step = np.where(offsets > 0, 1.0, 0.0)
    off = np.abs(np.asarray(profile) - step) > tol
    off &= offsets != 0
    off &= np.isfinite(profile)
    return float(np.abs(offsets[off]).max()) if off.any() else 0.0


def near_mask(uv: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Which points ``uv`` (M, 2) fall on a set pixel of ``mask`` (H, W) bool (the pixel
    holding the point, rounded); points outside the image are not."""
    h, w = mask.shape
    j = np.rint(np.asarray(uv, float)[:, 0]).astype(np.intp)
    i = np.rint(np.asarray(uv, float)[:, 1]).astype(np.intp)
    inside = (j >= 0) & (j < w) & (i >= 0) & (i < h)
    out = np.zeros(len(j), bool)
    out[inside] = mask[i[inside], j[inside]]
    return out


#: The value of an inside-map beyond its computed region (far outside the silhouette).
FAR_OUTSIDE = -1e6


class InsideRegion(NamedTuple):
    """The computed part of an inside-map (:func:`inside_region`): ``values`` at rows
    ``y0:y0 + h`` and columns ``x0:x0 + w`` of an image of ``shape`` (H, W), whose every
    other pixel is :data:`FAR_OUTSIDE`. ``values`` is (0, 0) when the silhouette is empty.
    On 16 cameras of 5 MP the whole maps are 320 MB of float32 written for each inspection;
    the regions about 13 MB."""

    values: np.ndarray
    y0: int
    x0: int
    shape: tuple[int, int]

    def full(self) -> np.ndarray:
        """The whole map, (H, W) float32."""
        out = np.full(self.shape, FAR_OUTSIDE, np.float32)
        h, w = self.values.shape
        out[self.y0:self.y0 + h, self.x0:self.x0 + w] = self.values
        return out


def inside_region(soft: np.ndarray, margin: int = 16, support: tuple[int, int, int, int] | None = None) -> InsideRegion:
    """Signed "inside-ness" of the pixels around the silhouette, in pixels: >= 0 inside it.

    Near the contour it is ``soft - 0.5`` (the coverage ramp, whose 0.5 level is the
    sub-pixel contour); farther out it is minus the distance to the object (Euclidean
    distance transform), so bilinear samples of it tell how far outside a projected point
    lies. Inside it is clipped at +0.5 (only the outside distance is ever needed). Only a
    band around the object matters (farther is "far outside" for every use): the region is
    the silhouette's bounding box plus ``margin`` pixels (clipped to the image).

    Parameters
    ----------
    soft : (H, W) float32
        Coverage in [0, 1].
    margin : int
        px.
    support : (y0, y1, x0, x1) int, optional
        Rows and columns outside which ``soft`` is below 0.5
        (:attr:`~inspector.model.Silhouette.support`): the object is looked for there only.

    Returns
    -------
    InsideRegion
    """
    import cv2

    sy, sy1, sx, sx1 = (0, soft.shape[0], 0, soft.shape[1]) if support is None else support
    mask = soft[sy:sy1, sx:sx1] >= 0.5
    rows, cols = np.flatnonzero(mask.any(axis=1)) + sy, np.flatnonzero(mask.any(axis=0)) + sx
    if not len(rows):
        return InsideRegion(np.zeros((0, 0), np.float32), 0, 0, soft.shape)
    y0, y1 = max(rows[0] - margin, 0), min(rows[-1] + margin + 1, soft.shape[0])
    x0, x1 = max(cols[0] - margin, 0), min(cols[-1] + margin + 1, soft.shape[1])
    crop = soft[y0:y1, x0:x1]
    # Written in place into the distance transform's own array (a bool array is 0/1 bytes):
    # every temporary of the crop's size is a fresh allocation, most of this function's cost.
    values = cv2.distanceTransform((crop < 0.5).view(np.uint8), cv2.DIST_L2, 5)
    near = values <= 1.0
    np.subtract(np.float32(0.5), values, out=values)
    np.subtract(crop, np.float32(0.5), out=values, where=near)
    return InsideRegion(values, int(y0), int(x0), soft.shape)


def inside_map(soft: np.ndarray, margin: int = 16) -> np.ndarray:
    """The whole inside-map, (H, W) float32: :func:`inside_region` and :data:`FAR_OUTSIDE`
    everywhere else (the numpy reference kernels read it whole)."""
    return inside_region(soft, margin).full()


# Marching squares (skimage.measure.find_contours' algorithm), compiled by Numba on first
# use: these functions are plain Python until _compiled_march_squares() compiles them.

#: Segments (from edge, to edge) of each square case, as skimage draws them with
#: fully_connected="low"; edges 0 top, 1 bottom, 2 left, 3 right; -1: none.
_SQUARE_SEGMENTS = np.array(
    [
        [-1, -1, -1, -1], [0, 2, -1, -1], [3, 0, -1, -1], [3, 2, -1, -1],
        [2, 1, -1, -1], [0, 1, -1, -1], [3, 0, 2, 1], [3, 1, -1, -1],
        [1, 3, -1, -1], [0, 2, 1, 3], [1, 0, -1, -1], [1, 2, -1, -1],
        [2, 3, -1, -1], [0, 3, -1, -1], [2, 0, -1, -1], [-1, -1, -1, -1],
    ],
    np.int64,
)  # fmt: skip


def _hash_slot(keys, key, mask):
    """Slot of ``key`` in an open-addressing table (linear probing, Fibonacci hashing), or
    the first free one where it would go (-1: empty, -2: deleted)."""
    i = np.int64((np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(40)) & mask
    free = -1
    while True:
        k = keys[i]
        if k == key:
            return i
        if k == -1:
            return free if free >= 0 else i
        if k == -2 and free < 0:
            free = i
        i = (i + 1) & mask


def _table_pop(keys, values, key, mask):
    """``dict.pop(key, -1)`` on a table of :func:`_hash_slot`."""
    i = _hash_slot(keys, key, mask)
    if keys[i] != key:
        return -1
    keys[i] = -2
    return values[i]


def _table_set(keys, values, key, value, mask):
    """``dict[key] = value`` on a table of :func:`_hash_slot`."""
    i = _hash_slot(keys, key, mask)
    keys[i] = key
    values[i] = value


def _march_squares(a, level, segments):
    """Compiled body of :func:`marching_squares`: skimage's ``_get_contour_segments`` then
    ``_assemble_contours``, operation for operation.

    A segment end point is keyed by what it lies on (a pixel when both its coordinates
    are integers, else the row or column edge holding it): the same identity as skimage's
    dictionaries keyed by the coordinates. Those ``starts`` / ``ends`` dictionaries are
    hash tables here; a contour is a linked list of nodes.

    Returns
    -------
    points : (P, 2) float64
        The contours' ``(row, col)`` points, one contour after the other.
    lengths : (K,) int64
        Points per contour, in skimage's order.
    """
    H, W = a.shape
    cap = 1024
    seg = np.empty((cap, 2, 2))  # segment, from/to, (row, col)
    seg_key = np.empty((cap, 2), np.int64)
    pt = np.empty((4, 2))
    key = np.empty(4, np.int64)
    n_seg = 0
    for r0 in range(H - 1):
        for c0 in range(W - 1):
            ul = np.float64(a[r0, c0])
            ur = np.float64(a[r0, c0 + 1])
            ll = np.float64(a[r0 + 1, c0])
            lr = np.float64(a[r0 + 1, c0 + 1])
            case = (ul > level) + 2 * (ur > level) + 4 * (ll > level) + 8 * (lr > level)
            if case == 0 or case == 15:
                continue
            if np.isnan(ul) or np.isnan(ur) or np.isnan(ll) or np.isnan(lr):
                continue
            if n_seg + 2 > cap:
                cap *= 2
                grown = np.empty((cap, 2, 2))
                grown[:n_seg] = seg[:n_seg]
                seg = grown
                grown_key = np.empty((cap, 2), np.int64)
                grown_key[:n_seg] = seg_key[:n_seg]
                seg_key = grown_key
            # Crossing points on the top, bottom, left and right edges (skimage's formula).
            pt[0, 0] = r0
            pt[0, 1] = c0 + (0.0 if ur == ul else (level - ul) / (ur - ul))
            pt[1, 0] = r0 + 1
            pt[1, 1] = c0 + (0.0 if lr == ll else (level - ll) / (lr - ll))
            pt[2, 0] = r0 + (0.0 if ll == ul else (level - ul) / (ll - ul))
            pt[2, 1] = c0
            pt[3, 0] = r0 + (0.0 if lr == ur else (level - ur) / (lr - ur))
            pt[3, 1] = c0 + 1
            for j in range(4):
                ri, ci = np.floor(pt[j, 0]), np.floor(pt[j, 1])
                cell = 3 * (np.int64(ri) * W + np.int64(ci))
                if pt[j, 0] == ri and pt[j, 1] == ci:
                    key[j] = cell + 2  # on a pixel
                elif pt[j, 0] == ri:
                    key[j] = cell  # inside a row edge
                else:
                    key[j] = cell + 1  # inside a column edge
            for j in range(0, 4, 2):
                e0, e1 = segments[case, j], segments[case, j + 1]
                if e0 < 0:
                    break
                seg[n_seg, 0] = pt[e0]
                seg[n_seg, 1] = pt[e1]
                seg_key[n_seg, 0] = key[e0]
                seg_key[n_seg, 1] = key[e1]
                n_seg += 1
    # Assembly (skimage's _assemble_contours): contour number -> first / last node.
    node = np.empty((2 * n_seg + 1, 2))
    node_key = np.empty(2 * n_seg + 1, np.int64)
    nxt = np.full(2 * n_seg + 1, -1, np.int64)
    first = np.empty(n_seg + 1, np.int64)
    last = np.empty(n_seg + 1, np.int64)
    alive = np.zeros(n_seg + 1, np.bool_)
    size = 16
    while size < 4 * n_seg + 8:  # at most 2 insertions per segment: load <= 1/2
        size *= 2
    mask = size - 1
    starts_k = np.full(size, -1, np.int64)
    starts_v = np.empty(size, np.int64)
    ends_k = np.full(size, -1, np.int64)
    ends_v = np.empty(size, np.int64)
    n_node = 0
    n_cont = 0
    for s in range(n_seg):
        fk, tk = seg_key[s, 0], seg_key[s, 1]
        if fk == tk:
            continue  # degenerate: a pixel exactly at the level
        tail = _table_pop(starts_k, starts_v, tk, mask)
        head = _table_pop(ends_k, ends_v, fk, mask)
        if tail >= 0 and head >= 0:
            if tail == head:  # close the contour
                node[n_node] = seg[s, 1]
                node_key[n_node] = tk
                nxt[last[head]] = n_node
                last[head] = n_node
                n_node += 1
            elif tail > head:  # head.extend(tail)
                nxt[last[head]] = first[tail]
                last[head] = last[tail]
                alive[tail] = False
                _table_set(starts_k, starts_v, node_key[first[head]], head, mask)
                _table_set(ends_k, ends_v, node_key[last[head]], head, mask)
            else:  # tail.extendleft(reversed(head))
                _table_pop(starts_k, starts_v, node_key[first[head]], mask)
                nxt[last[head]] = first[tail]
                first[tail] = first[head]
                alive[head] = False
                _table_set(starts_k, starts_v, node_key[first[tail]], tail, mask)
                _table_set(ends_k, ends_v, node_key[last[tail]], tail, mask)
        elif tail < 0 and head < 0:  # a new contour
            node[n_node] = seg[s, 0]
            node[n_node + 1] = seg[s, 1]
            node_key[n_node] = fk
            node_key[n_node + 1] = tk
            nxt[n_node] = n_node + 1
            first[n_cont] = n_node
            last[n_cont] = n_node + 1
            alive[n_cont] = True
            _table_set(starts_k, starts_v, fk, n_cont, mask)
            _table_set(ends_k, ends_v, tk, n_cont, mask)
            n_node += 2
            n_cont += 1
        elif head < 0:  # tail.appendleft(from_point)
            node[n_node] = seg[s, 0]
            node_key[n_node] = fk
            nxt[n_node] = first[tail]
            first[tail] = n_node
            n_node += 1
            _table_set(starts_k, starts_v, fk, tail, mask)
        else:  # head.append(to_point)
            node[n_node] = seg[s, 1]
            node_key[n_node] = tk
            nxt[last[head]] = n_node
            last[head] = n_node
            n_node += 1
            _table_set(ends_k, ends_v, tk, head, mask)
    # The contours in creation order, each from its first node to its last.
    out = np.empty((n_node, 2))
    lengths = np.zeros(n_cont, np.int64)
    m = 0
    for c in range(n_cont):
        if not alive[c]:
            continue
        j = first[c]
        start = m
        while True:
            out[m] = node[j]
            m += 1
            if j == last[c]:
                break
            j = nxt[j]
        lengths[c] = m - start
    return out[:m], lengths[alive[:n_cont]]


_MARCH_JIT = None
_JIT_LOCK = threading.Lock()


def _compiled_march_squares():
    """:func:`_march_squares` compiled by Numba (on first use; cached on disk)."""
    global _MARCH_JIT
    with _JIT_LOCK:
        if _MARCH_JIT is None:
            import numba

            # A compiled function resolves the helpers it calls by their module-level
            # names: compile those first, in call order, and rebind the names.
            g = globals()
            for name in ("_hash_slot", "_table_pop", "_table_set"):
                if not isinstance(g[name], numba.core.dispatcher.Dispatcher):
                    g[name] = numba.njit(cache=True, nogil=True)(g[name])
            _MARCH_JIT = numba.njit(cache=True, nogil=True)(_march_squares)
    return _MARCH_JIT


def marching_squares(image: np.ndarray, level: float) -> list[np.ndarray]:
    """Iso-contours of ``image`` at ``level``: ``skimage.measure.find_contours(image, level)``.

    The same contours, point for point and in the same order (default options:
    ``fully_connected="low"``, ``positive_orientation="low"``, no mask; NaN cells are
    skipped), computed in one compiled pass that releases the GIL (skimage assembles the
    contours in Python, several times slower, holding the GIL).

    Parameters
    ----------
    image : (H, W) float32 or float64
        Other dtypes are converted to float64, as skimage does.
    level : float

    Returns
    -------
    list of (n, 2) float64
        ``(row, col)`` points of each contour; a closed contour repeats its first point.
    """
    a = np.asarray(image)
    if a.ndim != 2:
        raise ValueError("Only 2D arrays are supported.")
    if a.shape[0] < 2 or a.shape[1] < 2:
        raise ValueError("Input array must be at least 2x2.")
    if a.dtype not in (np.float32, np.float64):
        a = a.astype(np.float64)
    pts, lengths = _compiled_march_squares()(np.ascontiguousarray(a), float(level), _SQUARE_SEGMENTS)
    return np.split(pts, np.cumsum(lengths)[:-1]) if len(lengths) else []


def _refine_points(uv, raw, ox, oy, h, w, half_window, hi, lo, zero, one):
    """Compiled body of :func:`refine_contour_area` (numpy's float operations, in order).

    ``raw`` is the crop at ``(ox, oy)`` of an (h, w) image; ``hi``, ``lo``, ``zero``,
    ``one`` are 0.85, 0.15, 0 and 1 in raw's dtype (numpy compares and clips in it).

    Returns
    -------
    out : (P, 2) float64
        The refined points.
    ok : bool
        False when a pixel needed lies outside the crop.
    """
    hc, wc = raw.shape
    M = uv.shape[0]
    gx = np.zeros(M)
    gy = np.zeros(M)
    # The coverage gradient at the points: bilinear samples of np.gradient(np.clip(image,
    # 0, 1)), central differences inside the image, one-sided on its border.
    for i in range(M):
        u, v = uv[i, 0], uv[i, 1]
        if not (u >= 0 and u <= w - 1 and v >= 0 and v <= h - 1 and np.isfinite(u) and np.isfinite(v)):
            continue  # outside the image: 0
        x0 = min(np.int64(u), w - 2)
        y0 = min(np.int64(v), h - 2)
        fx = u - x0
        fy = v - y0
        corner_x = np.empty(4, raw.dtype)
        corner_y = np.empty(4, raw.dtype)
        for k in range(4):
            yy = y0 + k // 2
            xx = x0 + k % 2
            xl, xh = max(xx - 1, 0), min(xx + 1, w - 1)
            yl, yh = max(yy - 1, 0), min(yy + 1, h - 1)
            if min(yl - oy, xl - ox) < 0 or yh - oy >= hc or xh - ox >= wc:
                return np.empty((0, 2)), False
            dx = min(max(raw[yy - oy, xh - ox], zero), one) - min(max(raw[yy - oy, xl - ox], zero), one)
            dy = min(max(raw[yh - oy, xx - ox], zero), one) - min(max(raw[yl - oy, xx - ox], zero), one)
            corner_x[k] = dx / (one + one) if 0 < xx < w - 1 else dx
            corner_y[k] = dy / (one + one) if 0 < yy < h - 1 else dy
        for g, c in ((gx, corner_x), (gy, corner_y)):
            g[i] = (c[0] * (1 - fx) + c[1] * fx) * (1 - fy) + (c[2] * (1 - fx) + c[3] * fx) * fy
    out = np.empty((M, 2))
    n_out = 0
    n_win = 2 * half_window + 1
    vals = np.empty(n_win, raw.dtype)
    for along_u in (True, False):
        for i in range(M):
            u, v = uv[i, 0], uv[i, 1]
            steep = abs(gx[i]) >= abs(gy[i])
            if along_u:
                if not (steep and abs(v - np.rint(v)) < 1e-9):
                    continue
                g, line, pos, n = gx[i], np.int64(np.rint(v)), u, w
            else:
                if steep or not abs(u - np.rint(u)) < 1e-9:
                    continue
                g, line, pos, n = gy[i], np.int64(np.rint(u)), v, h
            centre = np.int64(np.rint(pos))
            inside = centre - half_window >= 0 and centre + half_window < n
            total = -zero  # numpy's sum: from -0.0, left to right
            for k in range(n_win):
                j = min(max(centre - half_window + k, 0), n - 1)
                r, c = (line - oy, j - ox) if along_u else (j - oy, line - ox)
                if r < 0 or r >= hc or c < 0 or c >= wc:
                    return np.empty((0, 2)), False
                vals[k] = raw[r, c]
                total += vals[k]
            obj_low = g < 0  # coverage decreases with the coordinate: object on the low side
            first = min(max(vals[0 if obj_low else n_win - 1], zero), one)
            last = min(max(vals[n_win - 1 if obj_low else 0], zero), one)
            # A clean window: saturated at both ends and monotone (one edge only).
            clean = inside and first > hi and last < lo
            sign = 1.0 if obj_low else -1.0
            for k in range(n_win - 1):
                d = min(max(vals[k + 1], zero), one) - min(max(vals[k], zero), one)
                if not d * sign < 0.1:
                    clean = False
            if not clean:
                edge = pos
            elif obj_low:
                edge = centre - half_window - 0.5 + total
            else:
                edge = centre + half_window + 0.5 - total
            if along_u:
                out[n_out, 0] = edge
                out[n_out, 1] = line
            else:
                out[n_out, 0] = line
                out[n_out, 1] = edge
            n_out += 1
    return out[:n_out], True


_REFINE_JIT = None


def _compiled_refine_points():
    """:func:`_refine_points` compiled by Numba (on first use; cached on disk)."""
    global _REFINE_JIT
    with _JIT_LOCK:
        if _REFINE_JIT is None:
            import numba

            _REFINE_JIT = numba.njit(cache=True, nogil=True)(_refine_points)
    return _REFINE_JIT


def refine_contour_area(
    uv: np.ndarray,
    raw: np.ndarray,
    *,
    half_window: int = 2,
    origin: tuple[int, int] = (0, 0),
    image_shape: tuple[int, int] | None = None,
) -> np.ndarray:
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
        Contour points from :func:`subpixel_contour`: image pixel coordinates, inside the
        image.
    raw : (H, W) float32
        Coverage *not* clipped to [0, 1] (clipping would bias noisy sums).
    half_window : int
        Pixels summed on either side of the edge pixel.
    origin : (x0, y0) int
        ``raw`` may be a crop of the image whose pixel (0, 0) is the image's pixel
        ``(x0, y0)``; it must hold every point plus ``half_window + 1`` px (or reach the
        image border), else ``ValueError``. The result is the same as on the whole image.
    image_shape : (H, W), optional
        Size of the whole image; required with a non-zero ``origin``.

    Returns
    -------
    (P, 2) float
        Refined ``(u, v)`` points. Points whose window is not clean (another edge inside,
        e.g. at a corner or a thin part) keep their marching-squares position.
    """
    h, w = _image_shape(raw.shape, origin, image_shape)
    if len(uv) == 0:
        return uv
    if h < 2 or w < 2:
        raise ValueError("refine_contour_area: the image must be at least 2x2 pixels")
    if raw.dtype not in (np.float32, np.float64):
        raw = raw.astype(np.float64)  # as np.gradient does for integers
    t = raw.dtype.type
    out, ok = _compiled_refine_points()(
        np.ascontiguousarray(uv, np.float64), np.ascontiguousarray(raw), int(origin[0]), int(origin[1]), h, w,
        int(half_window), t(0.85), t(0.15), t(0.0), t(1.0),
    )
    if not ok:
        raise ValueError("refine_contour_area: raw does not cover the contour's neighbourhood (crop too small)")
    return out
