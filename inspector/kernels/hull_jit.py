"""Compiled kernel for the hot loop of BCPS: how far points lie outside the visual hull.

Profiling the ``ray`` selection showed ~70 % of its time in projecting samples and
interpolating silhouettes camera by camera with numpy (one temporary array per step, no
early exit). This Numba kernel fuses projection (with distortion), bilinear sampling and
the early exit per point, in parallel over points. :func:`hull_violation` in
:mod:`inspector.kernels.bcps` is the reference implementation it must match.
"""

from __future__ import annotations

from collections.abc import Sequence

import numba
import numpy as np

from inspector.kernels.silhouette import InsideRegion
from inspector.kernels.threads import map_threads

__all__ = ["CameraStack", "stack_views", "violation"]


class CameraStack:
    """Cameras and inside-maps packed into arrays for the compiled kernel.

    Attributes
    ----------
    K, R : (C, 3, 3) float64
    t : (C, 3) float64
    dist : (C, 5) float64
    maps : (C, h, w) float32
        Inside-maps, each cropped to the region around its silhouette where the map holds
        anything but its constant far-outside value (padded to the largest crop), with
        the depth inside the silhouette restored where the inside-map clips it (pixels
        more than 2 px inside: ``distance to the background - 1.5``, >= 0.5): the same
        violations everywhere, and :mod:`inspector.kernels.bcps_jit` can tell how far a
        point is from leaving a silhouette.
    sizes : (C, 7) int64
        Per camera: the image's width and height (px), the crop's origin (x0, y0) and
        size (w, h) in the image, and the value ``-fill`` of every pixel outside the crop
        (:data:`CLAMP_PX` or less, whole px: see :func:`_with_depth`). The crop holds
        only the silhouette's neighbourhood (issue 26: on 16 cameras of 5 MP, 13 MB of
        maps instead of 320 MB, read from the cache instead of memory); the values read
        are exactly those of the whole map.
    open_border : (C,) bool
    speed_cache : (bytes, (C,) float) or None
        The last per-camera projection speed bound (px / mm) computed on this stack and the
        bounds it holds for (:func:`inspector.kernels.bcps_jit.camera_speed`): the same
        bounds for every camera of a pass.
    """

    def __init__(self, K, R, t, dist, maps, sizes, open_border):
        self.K, self.R, self.t, self.dist = K, R, t, dist
        self.maps, self.sizes, self.open_border = maps, sizes, open_border
        self.speed_cache: tuple[bytes, np.ndarray] | None = None


#: Outside values are clamped at minus this, px (see :func:`_with_depth`).
CLAMP_PX = 8.0


def _with_depth(inside: np.ndarray, out: np.ndarray) -> None:
    """Write the inside-map as the compiled kernels use it, a Lipschitz signed distance,
    into ``out`` (same shape).

    * Inside: the depth is restored where the inside-map clips it (pixels more than 2 px
      from the background: ``distance - 1.5``, >= 0.5). A 2x2 block of pixels touching
      such a pixel holds only object pixels, whose values were >= 0 and stay >= 0, so
      no bilinear sample that was negative (a violation) changes.
    * Outside: values are clamped at ``-m`` with ``m = min(CLAMP_PX, margin)``, the
      margin being how far the inside-map's computed region extends beyond the
      silhouette (it stores -1e6 beyond, not a distance). Points there are at least ``m``
      px outside, so the clamped map is ``max(signed distance, -m)``: still Lipschitz,
      and every violation within ``m`` px (all that any tolerance uses) is unchanged.
    """
    H, W = inside.shape
    box = _known_box(inside)
    if box is None or _with_depth_box(inside[box[0]:box[1], box[2]:box[3]], box, (H, W), (0, H, 0, W), out) is None:
        out[...] = inside  # nothing computed, or no inside pixel: the map as it is


def _known_box(inside: np.ndarray) -> tuple[int, int, int, int] | None:
    """Rows ``y0:y1`` and columns ``x0:x1`` of the inside-map's computed region (values
    above -1e5), or None when it has none (one threshold and OpenCV's bounding box)."""
    import cv2

    known = (inside > -1e5).view(np.uint8)
    x, y, w, h = cv2.boundingRect(known)
    if w == 0 or h == 0:
        return None
    return y, y + h, x, x + w


_Plan = tuple[np.ndarray, tuple[int, int, int, int], tuple[int, int], tuple[int, int, int, int]]


def _crop_plan(inside: np.ndarray | InsideRegion) -> _Plan | None:
    """Where :func:`_with_depth_crop` writes ``inside``: ``(known values, known box, image
    shape, crop box)`` (boxes as y0, y1, x0, x1; the crop is the known region grown by 1 px,
    clipped to the image), or None when the map has no inside pixel (it is kept whole)."""
    if isinstance(inside, InsideRegion):
        h, w = inside.values.shape
        box = (inside.y0, inside.y0 + h, inside.x0, inside.x0 + w)
        known, (H, W) = inside.values, inside.shape
    else:
        (H, W), found = inside.shape, _known_box(inside)
        if found is None:
            return None
        box, known = found, inside[found[0]:found[1], found[2]:found[3]]
    if not (known >= 0.0).any():
        return None
    ky0, ky1, kx0, kx1 = box
    return known, box, (H, W), (max(ky0 - 1, 0), min(ky1 + 1, H), max(kx0 - 1, 0), min(kx1 + 1, W))


def _write_crop(inside: np.ndarray | InsideRegion, plan: _Plan | None, out: np.ndarray) -> int:
    """Write :func:`_with_depth` of ``inside`` for ``plan``'s crop into ``out`` (crop-sized;
    the whole map's size when ``plan`` is None) and return the whole number ``fill`` (the
    value beyond the crop is ``-fill``; 0 for a whole map)."""
    if plan is None:
        _with_depth(inside.full() if isinstance(inside, InsideRegion) else inside, out)
        return 0
    # The same numbers as _with_depth on the whole map: written for the grown crop, whose
    # outside margin is the whole map's (the crop's own ring is outside the computed
    # region, as is everything beyond it). The clamp is a whole number of px: CLAMP_PX or
    # the computed region's margin beyond the silhouette.
    known, box, shape, crop = plan
    return int(_with_depth_box(known, box, shape, crop, out))  # type: ignore[arg-type]  # not None: it has an inside pixel


def _with_depth_crop(inside: np.ndarray | InsideRegion) -> tuple[np.ndarray, int, int, int]:
    """:func:`_with_depth` of ``inside`` (a whole (H, W) map, or its computed region: an
    :class:`~inspector.kernels.silhouette.InsideRegion`), on the region that differs from its
    constant outside value only: ``(crop, y0, x0, fill)`` where the whole map would be
    ``crop`` at rows ``y0:y0 + h``, columns ``x0:x0 + w`` and ``-fill`` everywhere else
    (``fill`` a whole number of px). The crop is the computed region grown by 1 px (clipped
    to the image), so a bilinear sample that reads any pixel outside it reads ``-fill`` at
    all four corners. A map without an inside pixel is returned whole (``fill`` 0, unused)."""
    plan = _crop_plan(inside)
    y0, y1, x0, x1 = plan[3] if plan is not None else (0, inside.shape[0], 0, inside.shape[1])
    out = np.empty((y1 - y0, x1 - x0), np.float32)
    return out, y0, x0, _write_crop(inside, plan, out)


def _with_depth_box(kcrop: np.ndarray, known: tuple[int, int, int, int], shape: tuple[int, int],
                    crop: tuple[int, int, int, int], out: np.ndarray) -> float | None:
    """:func:`_with_depth` written only for the rows and columns ``crop`` (y0, y1, x0, x1)
    of the whole map (of ``shape`` (H, W)) into ``out`` (crop-sized), ``kcrop`` the values of
    its computed region ``known`` (y0, y1, x0, x1); returns the clamp ``m`` (the value
    outside is ``-m``), or None when the map has no inside pixel."""
    import cv2

    H, W = shape
    ky0, ky1, kx0, kx1 = known
    mask = kcrop >= 0.0
    if not mask.any():
        return None
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    hk, wk = kcrop.shape
    sides = [y0 if ky0 > 0 else np.inf, hk - y1 if ky1 < H else np.inf, x0 if kx0 > 0 else np.inf, wk - x1 if kx1 < W else np.inf]
    m = min(CLAMP_PX, float(min(sides)))
    out.fill(-m)
    sub = np.maximum(kcrop, -m)
    mm = mask[y0:y1, x0:x1]
    d = cv2.distanceTransform(np.pad(mm, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]
    deep = mm & (d > 2.0)
    inner = sub[y0:y1, x0:x1]
    inner[deep] = d[deep] - 1.5
    cy0, _, cx0, _ = crop
    out[ky0 - cy0:ky1 - cy0, kx0 - cx0:kx1 - cx0] = sub
    return m


def stack_views(views: Sequence) -> CameraStack:
    """Pack :class:`inspector.kernels.bcps.View` objects (maps as :func:`_with_depth`,
    each cropped to its silhouette's neighbourhood: :class:`CameraStack`), each crop
    written straight into the stack (as :func:`_with_depth_crop`)."""
    C = len(views)
    plans = [_crop_plan(v.inside) for v in views]
    boxes = [p[3] if p is not None else (0, v.inside.shape[0], 0, v.inside.shape[1]) for v, p in zip(views, plans)]
    maps = np.empty((C, max(b[1] - b[0] for b in boxes), max(b[3] - b[2] for b in boxes)), np.float32)
    sizes = np.zeros((C, 7), np.int64)

    def one(i: int) -> None:
        y0, y1, x0, x1 = boxes[i]
        h, w = y1 - y0, x1 - x0
        fill = _write_crop(views[i].inside, plans[i], maps[i, :h, :w])
        maps[i, h:, :] = -float(fill)
        maps[i, :h, w:] = -float(fill)
        H, W = views[i].inside.shape
        sizes[i] = (W, H, x0, y0, w, h, fill)

    # OpenCV and numpy release the GIL on these arrays: cameras in parallel
    map_threads(one, range(C))
    return CameraStack(
        np.stack([v.camera.K for v in views]).astype(np.float64),
        np.stack([v.camera.R for v in views]).astype(np.float64),
        np.stack([v.camera.t for v in views]).astype(np.float64),
        np.stack([v.camera.dist for v in views]).astype(np.float64),
        maps,
        sizes,
        np.array([v.open_border for v in views], bool),
    )


# OpenMP (libgomp, a system prerequisite): the TBB found in some environments is too old
# and numba would warn about it on every run. This module is imported lazily (by the
# bcps stage), so ``import inspector`` stays free of Numba.
numba.config.THREADING_LAYER = "omp"  # type: ignore[attr-defined]  # set at run time


@numba.njit(cache=True, inline="always")
def map_value(c, x0, x1, x2, K, R, t, dist, maps, sizes, open_border):
    """Bilinear map value of camera ``c`` at the projection of a world point.

    Returns ``(code, g)``: code 0 with the value ``g`` (px), 1 when the point falls outside
    an open-border image (unknown: no constraint), 2 when it is behind the camera or
    outside a closed image (rejected).
    """
    xc = R[c, 0, 0] * x0 + R[c, 0, 1] * x1 + R[c, 0, 2] * x2 + t[c, 0]
    yc = R[c, 1, 0] * x0 + R[c, 1, 1] * x1 + R[c, 1, 2] * x2 + t[c, 1]
    zc = R[c, 2, 0] * x0 + R[c, 2, 1] * x1 + R[c, 2, 2] * x2 + t[c, 2]
    if zc <= 0.0:
        return 2, 0.0
    xn = xc / zc
    yn = yc / zc
    k1 = dist[c, 0]
    k2 = dist[c, 1]
    p1 = dist[c, 2]
    p2 = dist[c, 3]
    k3 = dist[c, 4]
    if k1 != 0.0 or k2 != 0.0 or p1 != 0.0 or p2 != 0.0 or k3 != 0.0:
        r2 = xn * xn + yn * yn
        rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = xn * rad + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
        yd = yn * rad + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
        xn = xd
        yn = yd
    u = K[c, 0, 0] * xn + K[c, 0, 1] * yn + K[c, 0, 2]
    v = K[c, 1, 1] * yn + K[c, 1, 2]
    w = sizes[c, 0]
    h = sizes[c, 1]
    if not (u >= 0.0 and u <= w - 1 and v >= 0.0 and v <= h - 1):
        return (1 if open_border[c] else 2), 0.0
    iu = min(int(u), w - 2)
    iv = min(int(v), h - 2)
    fu = u - iu
    fv = v - iv
    # The map is stored cropped (CameraStack.sizes): pixels outside the crop are -fill.
    ju = iu - sizes[c, 2]
    jv = iv - sizes[c, 3]
    if ju >= 0 and jv >= 0 and ju + 1 < sizes[c, 4] and jv + 1 < sizes[c, 5]:
        m00 = maps[c, jv, ju]
        m01 = maps[c, jv, ju + 1]
        m10 = maps[c, jv + 1, ju]
        m11 = maps[c, jv + 1, ju + 1]
    else:
        # outside the crop, or on its ring: every corner is the outside value (the crop
        # is the computed region grown by 1 px), read as the whole map would hold it
        f = np.float32(-sizes[c, 6])
        m00 = f
        m01 = f
        m10 = f
        m11 = f
        if ju >= 0 and jv >= 0 and ju < sizes[c, 4] and jv < sizes[c, 5]:
            m00 = maps[c, jv, ju]
        if ju + 1 >= 0 and jv >= 0 and ju + 1 < sizes[c, 4] and jv < sizes[c, 5]:
            m01 = maps[c, jv, ju + 1]
        if ju >= 0 and jv + 1 >= 0 and ju < sizes[c, 4] and jv + 1 < sizes[c, 5]:
            m10 = maps[c, jv + 1, ju]
        if ju + 1 >= 0 and jv + 1 >= 0 and ju + 1 < sizes[c, 4] and jv + 1 < sizes[c, 5]:
            m11 = maps[c, jv + 1, ju + 1]
    g = (m00 * (1.0 - fu) + m01 * fu) * (1.0 - fv) + (m10 * (1.0 - fu) + m11 * fu) * fv
    return 0, g


@numba.njit(parallel=True, cache=True, nogil=True)
def _kernel(X, K, R, t, dist, maps, sizes, open_border, limit, skip, out):
    N = X.shape[0]
    C = K.shape[0]
    for n in numba.prange(N):
        worst = 0.0
        for c in range(C):
            if c == skip:
                continue
            code, g = map_value(c, X[n, 0], X[n, 1], X[n, 2], K, R, t, dist, maps, sizes, open_border)
            if code == 1:
                continue
            if code == 2:
                worst = 1e6
                break
            if -g > worst:
                worst = -g
                if worst > limit:
                    break
        out[n] = worst


def violation(X: np.ndarray, stack: CameraStack, limit: float = np.inf, skip: int = -1) -> np.ndarray:
    """Hull violation (px) of world points ``X`` (N, 3) mm; see ``bcps.hull_violation``.

    Camera ``skip`` is ignored; values beyond ``limit`` are only known to exceed it.
    Values below ``CLAMP_PX - 1.5`` are exact; larger ones are only known to be at least
    that (the maps are clamped, see :func:`_with_depth`).
    """
    X = np.ascontiguousarray(X, dtype=np.float64)
    out = np.empty(len(X))
    _kernel(X, stack.K, stack.R, stack.t, stack.dist, stack.maps, stack.sizes, stack.open_border, float(min(limit, 1e300)), int(skip), out)
    return out
