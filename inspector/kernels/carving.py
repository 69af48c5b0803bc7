"""Coarse-to-fine visual hull of binary silhouettes (pure kernel: arrays in, arrays out).

Method
------
Each silhouette becomes a *signed distance transform* (SDT, pixels, positive inside,
see :func:`signed_distance`). Its bilinear interpolation ``g_c(u, v)`` is the continuous
silhouette function of camera ``c``; its zero level lies on the boundary of the mask
pixels. The *hull function*

    f(X) = min_c  g_c(project_c(X)) * footprint_c(X)        (mm, positive inside)

with ``footprint_c(X) = z_c(X) / sqrt(fx * fy)`` (mm per pixel at the depth of ``X``)
defines the visual hull as ``{X : f(X) >= 0}`` (see :func:`hull_function`).

:func:`carve` classifies cubic cells against each camera *conservatively*: the cell's
circumscribed sphere (radius ``r``) projects into a disk of radius ``rho`` pixels around
the projection of the centre (a rigorous bound: ``rho = S * r * sqrt(1 + |x|^2) / (z - r)``
with ``x`` the normalized image coordinates of the centre, ``z`` its depth and ``S`` an
upper bound of the lens's local scale, pixels per normalized unit). The interpolated
SDT is ``sqrt(2)``-Lipschitz, so ``g(p) + sqrt(2) * rho < 0`` proves the whole cell is
outside the silhouette (carve it), ``g(p) - sqrt(2) * rho > 0`` proves it is inside for
that camera (the camera is dropped for the cell and all its children). A cell inside for
every camera is kept without refinement; a cell neither carved nor fully inside is a
*boundary* cell and is split into 8 until the finest size ``voxel_mm``. Only cells
near the surface are ever refined, so memory and time scale with the surface area over
``voxel_mm**2``, not with the volume over ``voxel_mm**3``.

The carving never removes a cell containing a point where ``f >= 0``: the hull is
conservative with respect to the masks (the object's true contour lies within about half
a pixel of the mask boundary, so true object points have ``f >= -0.5`` pixel footprint,
down to about ``-0.9`` px at the sharp silhouette corners of a cube).

SDT windows
    :func:`carve` computes each closed silhouette's SDT only on a *window*: the bounding
    box of its object pixels grown by ``_WINDOW_MARGIN_PX`` (16) pixels, clipped to the
    image (an open silhouette keeps the whole image). Inside the window the values are
    those of the whole image's SDT (see :func:`_signed_distance_window`); beyond it the
    window is extended like a closed image border, ``G(p) = g(q) - |p - q|`` with ``q``
    the nearest point of the window's pixel-centre rectangle. This is still conservative
    for the whole image's SDT ``g``: the window's rim pixels are background, so ``G < 0``
    and ``g < 0`` (every object pixel is in the window) beyond the window, and
    ``{G >= 0} = {g >= 0}``: the hull is the same set. The classification keeps its
    proof (a window is an image with a closed border), and a cell whose disk (centre
    ``p`` beyond the window, radius ``rho``) reaches an object pixel centre is never
    carved: with ``D`` the distance to the nearest object pixel centre,
    ``D(p)**2 >= D(q)**2 + |p - q|**2`` (the object pixels lie in the rectangle, ``q``
    is ``p``'s projection onto it), so ``D(p) <= rho`` gives ``|p - q| <= rho`` and
    ``D(q) <= rho``; on the rectangle's edge ``g`` is linear between two pixel centres,
    where ``g >= 0.5 - D`` with ``D`` 1-Lipschitz, so ``g(q) >= -D(q)`` and the cell's
    upper bound ``g(q) + sqrt(2) * rho - max(|p - q| - rho, 0)`` is at least
    ``(sqrt(2) - 1) * rho > 0``. The margin keeps the samples of the finest cells, the
    Newton points and their gradients inside the window (where ``G = g``) for voxels up
    to about 5 pixel footprints (0.5 mm at 0.1 mm/px), so their points and normals are
    those of the whole images; beyond, only cells far from the surface see ``G < g``.

Surface points and normals
    Each finest boundary cell's centre is moved onto ``f = 0`` along a fixed *chord*: the
    gradient of the camera attaining the minimum (central differences over +-2 pixel
    footprints ``h``: a smaller step sees the pixel staircase of the masks, about 14 deg
    median normal error at 0.1 px against 5 deg at 2 px on a sphere's hull), taken at the
    centre, or at the parent cell's centre (once for its 8 children) when that lies
    within ``h`` of the cell's (voxels up to about 2 pixel footprints), and again at the
    current point if that camera changes. Along the chord the steps are secant steps
    (chord-slope Newton steps to start with or when the secant slope is implausible).
    A point is kept when it converges inside its own cell, so the surface is sampled
    about once per ``voxel_mm**2``. Its normal is the gradient of its camera taken within
    ``h`` of it (the chord or the parent's, else at the point): the gradient averages
    over +-h anyway. The accuracy is set by the silhouettes, not by the voxel: on a
    30 mm sphere seen by 16 cameras at 0.1 mm/px the points lie 0.017 mm on average
    (0.05 mm at most) from the exact visual hull at any voxel from 0.5 to 0.1 mm, and the
    normals 4.4 deg (median) from the exact hull's.

    With the numba backend the last two levels are tested together with the points: each
    cell of the level above the finest is classified and, when on the boundary, has its 8
    children classified and Newton-projected at once, the hull function at their centres
    coming from the cell tests.

Display mesh
    Marching cubes of ``f`` on a grid over the occupied cells. The sign of ``f`` on the
    grid comes from the conservative ball test of blocks of nodes (a block carved by a
    camera is negative, one inside every camera positive, others are split), the exact
    value only at the corners of the cubes with a sign change: the only values marching
    cubes reads, so the mesh is that of the exact ``f`` on the whole grid.

Outside an image
    With ``open_border[c]`` (the silhouette touches the image border: outside the image
    is unknown) camera ``c`` treats outside its image as inside the silhouette and never
    carves there. Otherwise outside the image is outside the silhouette. Either way the
    SDT is extended beyond the image by ``g(q) +- |p - q|`` with ``q`` the nearest point
    of the pixel-centre rectangle, and the zero level of an image-border pixel sits on the
    image edge. Points behind a camera (``z <= 0``) are always carved.

Lens distortion
    Projection uses the OpenCV model inside a box ``B`` of normalized coordinates that
    contains the image (its undistorted border, enlarged by 10 %); beyond ``B`` the
    distortion is continued by the identity (``D(q) + (x - q)``, ``q`` the nearest point
    of ``B``), so the polynomial can never fold far-away points back into the image. The
    local scale bound ``S`` is the largest singular value of ``K[:2, :2] @ dD/dx`` over
    ``B`` (sampled, +5 %), plus ``|K[:2, :2]|`` for disks leaving ``B``.

Conventions as :mod:`inspector.kernels.camera`: mm, ``x_cam = R @ x_world + t``, pixel
``(0, 0)`` the centre of the top-left pixel.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from inspector.kernels import camera as camk
from inspector.kernels import carving_jit
from inspector.kernels.extent import bounds_of
from inspector.kernels.threads import map_threads
from inspector.model import Camera, Reconstruction

__all__ = [
    "carve",
    "default_bounds",
    "signed_distance",
    "hull_function",
    "hull_gradient",
]

#: Lipschitz constant of the bilinear interpolation of a signed distance transform
#: (each axis derivative is at most 1 px/px, so the gradient is at most sqrt(2)).
_LIP = math.sqrt(2.0) * (1.0 + 1e-6)
#: Slack on the classification bounds, pixels (float32 SDT, rounding).
_SLACK_PX = 1e-3
#: Depth below which a point is "at or behind" the camera, mm.
_Z_MIN = 1e-6
#: Value standing for "infinitely far" in the SDT, pixels.
_BIG_PX = 1e6
#: Hull-function value of points behind a camera, mm.
_BEHIND_MM = -1e9
#: Background pixels kept around a closed silhouette's bounding box by the SDT window of
#: :func:`carve`, px: the cell tests of the finest cells, the Newton points and their
#: +-2 px gradient stencils then sample inside the window (where the SDT is the whole
#: image's) for voxels up to about 5 pixel footprints.
_WINDOW_MARGIN_PX = 16
#: Cells processed at once (bounds the temporaries to some tens of MB per camera).
_CHUNK = 1 << 18
#: Cells classified at once (the depth-first carving keeps about 8 such chunks per level).
_CELL_CHUNK = 1 << 16
#: Finite-difference step of the gradient (Newton steps, normals), pixel footprints: the
#: silhouettes' pixel staircase makes the gradient noisy at the pixel scale (about 14 deg
#: median normal error with a 0.1 px step, 5 deg with 2 px, on a sphere's hull).
_GRAD_STEP_PX = 2.0
#: A Newton point farther than this from its cell's centre (max norm, cell edges) is
#: dropped at once: on a sphere's hull at 0.1 mm, 0.6 loses 1 point in 3000 that 0.75
#: kept and stops a third more of the cells that end outside.
_LEAVE = 0.6
_CHILD_OFFSETS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=np.int32)


# --------------------------------------------------------------------------------------
# Silhouette fields
# --------------------------------------------------------------------------------------


def _sdt_padded(m: np.ndarray, outside: int, out: np.ndarray | None = None) -> np.ndarray:
    """Signed distance of ``m`` (h, w) bool framed by one pixel of value ``outside``.

    Returns the (h, w) float32 SDT of the pixels of ``m`` (the frame only takes part in
    the distances), as documented in :func:`signed_distance`, written into ``out``
    ((h, w) float32, C-contiguous) when given.
    """
    import cv2

    m8 = cv2.copyMakeBorder(m.view(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=outside)
    if out is None:
        out = np.empty(m.shape, dtype=np.float32)
    x, y, w, h = cv2.boundingRect(m8)  # the object pixels (the frame's too if outside = 1)
    if w == 0:
        out.fill(0.5 - _BIG_PX)
        return out
    # 0.5 - d_out, d_out the distance to the nearest object pixel (0 on the object)
    d_out = cv2.distanceTransform(np.bitwise_xor(m8, np.uint8(1)), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    np.subtract(np.float32(0.5), d_out[1:-1, 1:-1], out=out)
    # d_in - 0.5 on the object pixels, d_in from the object's bounding box grown by one
    # pixel (clipped to the frame): that ring is background, and the nearest background
    # pixel of an object pixel can be replaced by its projection onto the ring's
    # rectangle, a background pixel centre no farther.
    x0, y0 = max(x - 1, 0), max(y - 1, 0)
    x1, y1 = min(x + w + 1, m8.shape[1]), min(y + h + 1, m8.shape[0])
    sub = m8[y0:y1, x0:x1]
    d_in: np.ndarray
    if cv2.countNonZero(sub) == sub.size:  # no background pixel at all
        d_in = np.full(sub.shape, _BIG_PX, np.float32)
    else:
        d_in = cv2.distanceTransform(sub, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    # the same rectangle in the unframed coordinates of ``out``
    a0, b0 = max(x0 - 1, 0), max(y0 - 1, 0)
    a1, b1 = min(x1 - 1, m.shape[1]), min(y1 - 1, m.shape[0])
    np.subtract(
        d_in[b0 + 1 - y0 : b1 + 1 - y0, a0 + 1 - x0 : a1 + 1 - x0],
        np.float32(0.5),
        out=out[b0:b1, a0:a1],
        where=m[b0:b1, a0:a1],
    )
    return out


def signed_distance(mask: np.ndarray, *, open_border: bool = False) -> np.ndarray:
    """Half-pixel corrected signed distance transform of a silhouette.

    Parameters
    ----------
    mask : (H, W) bool
        True on the object.
    open_border : bool
        The silhouette continues beyond the image: pixels outside the image count as
        object (otherwise as background) for the distances of the pixels inside.

    Returns
    -------
    (H, W) float32
        Pixels, positive inside: ``d_in - 0.5`` on object pixels (``d_in`` the
        distance to the nearest background pixel centre, ``cv2.distanceTransform``,
        exact Euclidean), ``-(d_out - 0.5)`` on background pixels. Adjacent object and
        background pixels get ``+0.5`` and ``-0.5``, so the zero level of the bilinear
        interpolation lies on the boundary between them. Values are clipped to
        ``+-1e6`` (an image without any background / object pixel).
    """
    m = np.ascontiguousarray(mask, dtype=bool)
    if m.ndim != 2:
        raise ValueError(f"mask must be 2-D (H, W), got shape {m.shape}")
    return _sdt_padded(m, 1 if open_border else 0)


def _object_box(mask: np.ndarray, support: tuple[int, int, int, int] | None = None) -> tuple[int, int, int, int]:
    """Bounding box ``(x, y, w, h)`` px of the True pixels of ``mask`` (H, W) bool (w = 0:
    none), looked for only in rows ``y0:y1`` and columns ``x0:x1`` of ``support`` when given
    (the mask is False outside them)."""
    import cv2

    y0, x0 = 0, 0
    if support is not None:
        y0, y1, x0, x1 = support
        mask = mask[y0:y1, x0:x1]
    x, y, w, h = cv2.boundingRect(np.ascontiguousarray(mask, dtype=bool).view(np.uint8))
    return (int(x) + x0, int(y) + y0, int(w), int(h)) if w else (0, 0, 0, 0)


def _window(
    mask: np.ndarray, open_border: bool, margin: int, box: tuple[int, int, int, int] | None = None
) -> tuple[int, int, int, int]:
    """Window ``(u0, v0, w, h)`` px of :func:`_signed_distance_window` (at least 2x2).

    A closed silhouette (``open_border`` False) gets its object pixels' bounding box
    (``box``, from :func:`_object_box` by default) grown by ``margin`` pixels (>= 1),
    clipped to the image; an open one, whose object continues all around the image, the
    whole image.
    """
    H, W = mask.shape
    if open_border:
        return 0, 0, W, H
    x, y, w, h = _object_box(mask) if box is None else box
    if w == 0 or h == 0:  # no object: any window, the SDT is -1e6 everywhere
        x, y, w, h = 0, 0, 1, 1
    u0, v0 = max(x - margin, 0), max(y - margin, 0)
    u1, v1 = min(x + w + margin, W), min(y + h + margin, H)
    if u1 - u0 < 2:
        u0 = min(u0, W - 2)
        u1 = u0 + 2
    if v1 - v0 < 2:
        v0 = min(v0, H - 2)
        v1 = v0 + 2
    return u0, v0, u1 - u0, v1 - v0


def _signed_distance_window(
    mask: np.ndarray,
    open_border: bool,
    margin: int,
    out: np.ndarray | None = None,
    box: tuple[int, int, int, int] | None = None,
) -> tuple[np.ndarray, int, int]:
    """:func:`signed_distance` on a window of the image only (what :func:`carve` samples).

    Parameters
    ----------
    mask : (H, W) bool
    open_border : bool
    margin : int
        Pixels of background kept around a closed silhouette's bounding box (>= 1).
    out : (h * w,) float32, optional
        Where to write the window's SDT (``(w, h)`` from :func:`_window`).
    box : (4,) int, optional
        :func:`_object_box` of ``mask``, if known.

    Returns
    -------
    sdt : (h, w) float32
        Equal to ``signed_distance(mask)[v0:v0 + h, u0:u0 + w]`` bit for bit: the window
        holds every object pixel (an open silhouette gets the whole image), so the
        nearest object pixel of a window pixel is in the window; and its rim (one pixel,
        inside the image or the image's closed outside) is background, so the nearest
        background pixel of an object pixel can be replaced by its projection onto the
        rim's rectangle, a background pixel centre no farther.
    u0, v0 : int
        Pixel of the window's top-left corner in the image.
    """
    m = np.ascontiguousarray(mask, dtype=bool)
    u0, v0, w, h = _window(m, open_border, margin, box)
    o = None if out is None else out.reshape(h, w)
    return _sdt_padded(m[v0 : v0 + h, u0 : u0 + w], 1 if open_border else 0, o), u0, v0


def _undistort_normalized(xd: np.ndarray, dist: np.ndarray, iters: int = 30) -> np.ndarray:
    """Invert :func:`camk.distort_normalized` by Newton iterations, (N, 2) -> (N, 2)."""
    x = np.array(xd, float, copy=True)
    eps = 1e-7
    for _ in range(iters):
        r = camk.distort_normalized(x, dist) - xd
        jx = (camk.distort_normalized(x + [eps, 0.0], dist) - camk.distort_normalized(x - [eps, 0.0], dist)) / (2 * eps)
        jy = (camk.distort_normalized(x + [0.0, eps], dist) - camk.distort_normalized(x - [0.0, eps], dist)) / (2 * eps)
        a, c = jx[:, 0], jx[:, 1]
        b, d = jy[:, 0], jy[:, 1]
        det = a * d - b * c
        det = np.where(np.abs(det) > 1e-12, det, 1e-12)
        dx = (d * r[:, 0] - b * r[:, 1]) / det
        dy = (-c * r[:, 0] + a * r[:, 1]) / det
        step = np.stack([dx, dy], axis=1)
        x -= step
        if np.max(np.abs(step), initial=0.0) < 1e-13:
            break
    return x


def _sv_max_2x2(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Largest singular value of the 2x2 matrices [[a, b], [c, d]] (arrays)."""
    s1 = a * a + b * b + c * c + d * d
    det = a * d - b * c
    return np.sqrt(0.5 * (s1 + np.sqrt(np.maximum(s1 * s1 - 4 * det * det, 0.0))))


@dataclass(frozen=True, eq=False)
class _View:
    """One camera prepared for carving (internal)."""

    R: np.ndarray  # (3, 3)
    t: np.ndarray  # (3,)
    K2: np.ndarray  # (2, 2) K[:2, :2]
    c: np.ndarray  # (2,) principal point in the SDT window's pixels (the image's minus the window origin)
    dist: np.ndarray  # (5,)
    has_dist: bool
    box: np.ndarray  # (4,) xmin, xmax, ymin, ymax of the normalized validity box (distortion)
    s_in: float  # px per normalized unit, disks inside ``box``
    s_out: float  # px per normalized unit, disks leaving ``box``
    fgeo: float  # sqrt(fx * fy), px per normalized unit (footprint)
    sdt: np.ndarray  # (H*W,) float32, flattened
    W: int  # SDT window, px (the image, or the part of it :func:`_signed_distance_window` keeps)
    H: int
    open: bool

    @property
    def centre(self) -> np.ndarray:
        return camk.camera_centre(self.R, self.t)


def _prepare(camera: Camera, sdt: np.ndarray, open_border: bool, origin: tuple[int, int] | None = None) -> _View:
    """One camera and the SDT of its silhouette, ``(H, W)`` the camera's size or, with
    ``origin = (u0, v0)``, a window of the image starting at that pixel (closed border
    only: beyond the window the SDT is extended as beyond a closed image border)."""
    sdt = np.asarray(sdt, dtype=np.float32)
    H, W = sdt.shape
    Wi, Hi = int(camera.width), int(camera.height)
    if origin is None:
        u0 = v0 = 0
        if (H, W) != (Hi, Wi):
            raise ValueError(f"camera {camera.name}: mask is {W}x{H}, camera is {camera.width}x{camera.height}")
    else:
        u0, v0 = int(origin[0]), int(origin[1])
        if u0 < 0 or v0 < 0 or u0 + W > Wi or v0 + H > Hi or (open_border and (H, W) != (Hi, Wi)):
            raise ValueError(f"camera {camera.name}: SDT window {W}x{H} at ({u0}, {v0}) is not in the image")
    if H < 2 or W < 2:
        raise ValueError(f"camera {camera.name}: image must be at least 2x2 pixels")
    K = np.asarray(camera.K, float)
    K2 = K[:2, :2].copy()
    s_k = float(_sv_max_2x2(K2[0, 0], K2[0, 1], K2[1, 0], K2[1, 1]))
    dist = np.asarray(camera.dist, float)
    has_dist = bool(np.any(dist))
    box = np.array([-np.inf, np.inf, -np.inf, np.inf])
    s_in = s_out = s_k
    if has_dist:
        # Validity box: the undistorted image border, enlarged by 10 %.
        n = 64
        us = np.linspace(-0.5, Wi - 0.5, n)
        vs = np.linspace(-0.5, Hi - 0.5, n)
        border = np.concatenate(
            [
                np.stack([us, np.full(n, -0.5)], 1),
                np.stack([us, np.full(n, Hi - 0.5)], 1),
                np.stack([np.full(n, -0.5), vs], 1),
                np.stack([np.full(n, Wi - 0.5), vs], 1),
            ]
        )
        yd = (border[:, 1] - K[1, 2]) / K[1, 1]
        xd = (border[:, 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
        xu = _undistort_normalized(np.stack([xd, yd], 1), dist)
        lo, hi = xu.min(axis=0), xu.max(axis=0)
        pad = 0.1 * (hi - lo)
        lo, hi = lo - pad, hi + pad
        box = np.array([lo[0], hi[0], lo[1], hi[1]])
        gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], 65), np.linspace(lo[1], hi[1], 65))
        g = np.stack([gx.ravel(), gy.ravel()], 1)
        eps = 1e-6
        jx = (camk.distort_normalized(g + [eps, 0.0], dist) - camk.distort_normalized(g - [eps, 0.0], dist)) / (2 * eps)
        jy = (camk.distort_normalized(g + [0.0, eps], dist) - camk.distort_normalized(g - [0.0, eps], dist)) / (2 * eps)
        # A = K2 @ J with J = [[jx0, jy0], [jx1, jy1]]
        a = K2[0, 0] * jx[:, 0] + K2[0, 1] * jx[:, 1]
        b = K2[0, 0] * jy[:, 0] + K2[0, 1] * jy[:, 1]
        c = K2[1, 1] * jx[:, 1]
        d = K2[1, 1] * jy[:, 1]
        s_in = 1.05 * float(np.max(_sv_max_2x2(a, b, c, d)))
        s_out = s_in + s_k
    return _View(
        R=np.asarray(camera.R, float),
        t=np.asarray(camera.t, float),
        K2=K2,
        c=K[:2, 2] - np.array([u0, v0], float),
        dist=dist,
        has_dist=has_dist,
        box=box,
        s_in=s_in,
        s_out=s_out,
        fgeo=float(np.sqrt(K[0, 0] * K[1, 1])),
        sdt=np.ascontiguousarray(sdt).ravel(),
        W=int(W),
        H=int(H),
        open=bool(open_border),
    )


def _views(cameras: Sequence[Camera], sdts: Sequence[np.ndarray], open_border: Sequence[bool] | None) -> list[_View]:
    if len(cameras) != len(sdts):
        raise ValueError(f"{len(cameras)} cameras but {len(sdts)} silhouettes")
    ob = [False] * len(cameras) if open_border is None else [bool(b) for b in open_border]
    if len(ob) != len(cameras):
        raise ValueError(f"{len(cameras)} cameras but {len(ob)} open_border flags")
    return [_prepare(c, s, o) for c, s, o in zip(cameras, sdts, ob)]


# --------------------------------------------------------------------------------------
# Projection and sampling (internal arrays are structure-of-arrays: X is (3, N))
# --------------------------------------------------------------------------------------


def _distort_soa(x: np.ndarray, y: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`camk.distort_normalized` on separate coordinate arrays."""
    k1, k2, p1, p2, k3 = (float(d) for d in dist)
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return xd, yd


def _project(v: _View, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """World points (3, N) mm -> ``u, v`` px, depth ``z`` mm, undistorted normalized ``x, y``.

    All outputs (N,). Points at or behind the camera get meaningless finite pixels; test ``z``.
    """
    R, t = v.R, v.t
    x0, x1, x2 = X[0], X[1], X[2]
    xc = R[0, 0] * x0 + R[0, 1] * x1 + R[0, 2] * x2 + t[0]
    yc = R[1, 0] * x0 + R[1, 1] * x1 + R[1, 2] * x2 + t[1]
    z = R[2, 0] * x0 + R[2, 1] * x1 + R[2, 2] * x2 + t[2]
    inv = 1.0 / np.maximum(z, _Z_MIN)
    xn = xc * inv
    yn = yc * inv
    if v.has_dist:
        qx = np.clip(xn, v.box[0], v.box[1])
        qy = np.clip(yn, v.box[2], v.box[3])
        dx, dy = _distort_soa(qx, qy, v.dist)
        xd = dx + (xn - qx)
        yd = dy + (yn - qy)
    else:
        xd, yd = xn, yn
    K2, c = v.K2, v.c
    u = K2[0, 0] * xd + K2[0, 1] * yd + c[0]
    w = K2[1, 1] * yd + c[1]
    return u, w, z, xn, yn


def _sample(v: _View, u: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """SDT at the clamped pixel ``q`` (bilinear) and the distance ``|(u, v) - q|``, both (N,) px."""
    qu = np.clip(u, 0.0, v.W - 1.0)
    qv = np.clip(w, 0.0, v.H - 1.0)
    iu = np.minimum(qu.astype(np.intp), v.W - 2)
    iv = np.minimum(qv.astype(np.intp), v.H - 2)
    au = qu - iu
    av = qv - iv
    i00 = iv * v.W + iu
    s = v.sdt
    top = s[i00] + au * (s[i00 + 1] - s[i00])
    i00 += v.W
    bot = s[i00] + au * (s[i00 + 1] - s[i00])
    g = top + av * (bot - top)
    e = np.hypot(u - qu, w - qv)
    return g, e


def _f_camera(v: _View, X: np.ndarray) -> np.ndarray:
    """Hull function of one camera, (3, N) -> (N,) mm (positive inside its cone)."""
    u, w, z, _, _ = _project(v, X)
    g, e = _sample(v, u, w)
    g = g + e if v.open else g - e
    f = g * (z / v.fgeo)
    return np.where(z > _Z_MIN, f, _BEHIND_MM)


def _f_all(
    views: Sequence[_View], X: np.ndarray, active: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Hull function (N,) mm and the index (N,) of the camera attaining the minimum.

    With ``active`` (N, C) bool only the flagged cameras are evaluated for each point.
    """
    n = X.shape[1]
    f = np.full(n, np.inf)
    arg = np.zeros(n, dtype=np.intp)
    for i, v in enumerate(views):
        if active is None:
            fc = _f_camera(v, X)
            better = fc < f
            f[better] = fc[better]
            arg[better] = i
        else:
            idx = np.flatnonzero(active[:, i])
            if idx.size == 0:
                continue
            fc = _f_camera(v, X[:, idx])
            better = fc < f[idx]
            f[idx[better]] = fc[better]
            arg[idx[better]] = i
    return f, arg


def _grad_argmin(views: Sequence[_View], X: np.ndarray, arg: np.ndarray, h: float) -> np.ndarray:
    """Central-difference gradient (3, N) of the attaining camera's hull function, mm/mm."""
    grad = np.zeros_like(X)
    for i in np.unique(arg):
        idx = np.flatnonzero(arg == i)
        Xi = X[:, idx]
        m = idx.size
        P = np.tile(Xi, (1, 6))
        for a in range(3):
            P[a, a * m : (a + 1) * m] += h
            P[a, (a + 3) * m : (a + 4) * m] -= h
        fv = _f_camera(views[int(i)], P).reshape(6, m)
        grad[:, idx] = (fv[:3] - fv[3:]) / (2.0 * h)
    return grad


def _footprint(views: Sequence[_View], X: np.ndarray) -> float:
    """Median pixel footprint (mm) of the cameras at the world point ``X`` (3,)."""
    return float(np.median([max(float(np.linalg.norm(v.centre - X)), 1e-9) / v.fgeo for v in views]))


def hull_function(
    cameras: Sequence[Camera],
    sdts: Sequence[np.ndarray],
    X: np.ndarray,
    *,
    open_border: Sequence[bool] | None = None,
) -> np.ndarray:
    """Continuous visual-hull function at world points.

    Parameters
    ----------
    cameras : sequence of Camera
    sdts : sequence of (H, W) float
        :func:`signed_distance` of each camera's mask (same order; computed with the
        same ``open_border`` flags).
    X : (N, 3) float
        World points, mm.
    open_border : sequence of bool, optional
        Per camera: outside the image counts as inside the silhouette.

    Returns
    -------
    (N,) float
        ``min_c g_c(X) * footprint_c(X)``, mm: positive inside the hull and, near the
        surface, about the distance to the nearest silhouette cone; ``-1e9`` behind a
        camera.
    """
    views = _views(cameras, sdts, open_border)
    X = np.asarray(X, float).reshape(-1, 3)
    out = np.empty(len(X))
    for s in range(0, len(X), _CHUNK):
        out[s : s + _CHUNK] = _f_all(views, np.ascontiguousarray(X[s : s + _CHUNK].T))[0]
    return out


def hull_gradient(
    cameras: Sequence[Camera],
    sdts: Sequence[np.ndarray],
    X: np.ndarray,
    *,
    open_border: Sequence[bool] | None = None,
    h_mm: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Hull function and its numerical gradient at world points (N, 3) mm.

    Parameters
    ----------
    h_mm : float, optional
        Finite-difference step, mm (default: 2 pixel footprints at the points' centroid,
        which averages out the pixel staircase of the silhouettes, as :func:`carve`).

    Returns
    -------
    f : (N,) float
        :func:`hull_function`, mm.
    grad : (N, 3) float
        Central differences of the hull function of the camera attaining the minimum
        (well defined on the hull's creases too); the outward normal is
        ``-grad / |grad|``.
    """
    views = _views(cameras, sdts, open_border)
    X = np.ascontiguousarray(np.asarray(X, float).reshape(-1, 3).T)
    if h_mm is None:
        h_mm = _GRAD_STEP_PX * _footprint(views, X.mean(axis=1) if X.shape[1] else np.zeros(3))
    f, arg = _f_all(views, X)
    return f, _grad_argmin(views, X, arg, float(h_mm)).T.copy()


# --------------------------------------------------------------------------------------
# Conservative cell classification
# --------------------------------------------------------------------------------------


def _classify(v: _View, P: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Classify balls (centres ``P`` (3, N) mm, radius ``r`` mm) against one camera.

    Returns
    -------
    outside : (N,) bool
        Every point of the ball is outside the silhouette cone (or behind the camera).
    inside : (N,) bool
        Every point of the ball is strictly inside the silhouette cone.
    """
    u, w, z, xn, yn = _project(v, P)
    ok = z - r > _Z_MIN
    zr = np.where(ok, z - r, 1.0)
    rn = r * np.sqrt(1.0 + xn * xn + yn * yn) / zr  # radius in the normalized plane
    if v.has_dist:
        inbox = (xn - rn >= v.box[0]) & (xn + rn <= v.box[1]) & (yn - rn >= v.box[2]) & (yn + rn <= v.box[3])
        rho = rn * np.where(inbox, v.s_in, v.s_out)
    else:
        rho = rn * v.s_in
    g, e = _sample(v, u, w)
    exits = (u - rho < 0.0) | (u + rho > v.W - 1.0) | (w - rho < 0.0) | (w + rho > v.H - 1.0)
    ex = np.where(exits, e + rho, 0.0)  # upper bound of |p' - q'| over the disk
    inner = np.maximum(e - rho, 0.0)  # lower bound of |p' - q'| over the disk
    lip = _LIP * rho + _SLACK_PX
    if v.open:
        high = g + lip + ex
        low = g - lip + inner
    else:
        high = g + lip - inner
        low = g - lip - ex
    outside = (ok & (high < 0.0)) | (z + r <= 0.0)
    inside = ok & (low > 0.0)
    return outside, inside


# --------------------------------------------------------------------------------------
# Bounds
# --------------------------------------------------------------------------------------


def _silhouette_polygon(
    camera: Camera, mask: np.ndarray, margin_px: float, box: tuple[int, int, int, int] | None = None
) -> np.ndarray:
    """Convex polygon (M, 2) in undistorted normalized coordinates containing the
    silhouette's pixel squares grown by ``margin_px`` (``box``: :func:`_object_box`)."""
    import cv2

    m = np.ascontiguousarray(mask, dtype=bool)
    # contours of the object's bounding box grown by one pixel (findContours sees the
    # array's edge pixels as background: the same contours as in the whole image)
    x, y, w, h = _object_box(m) if box is None else box
    x0, y0 = max(x - 1, 0), max(y - 1, 0)
    m8 = np.ascontiguousarray(m[y0 : y + h + 1, x0 : x + w + 1]).view(np.uint8)
    contours, _ = cv2.findContours(m8, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE, offset=(x0, y0))
    pts = np.concatenate([c.reshape(-1, 2) for c in contours]).astype(np.float32)
    hull = cv2.convexHull(pts).reshape(-1, 2).astype(float)
    grow = 0.5 + margin_px
    corners = (hull[:, None, :] + np.array([[-grow, -grow], [grow, -grow], [grow, grow], [-grow, grow]])[None]).reshape(-1, 2)
    poly = cv2.convexHull(corners.astype(np.float32)).reshape(-1, 2).astype(float)
    K = np.asarray(camera.K, float)
    if camera.has_distortion:
        # densify the edges (a straight pixel edge is curved in the normalized plane)
        nxt = np.roll(poly, -1, axis=0)
        seg = []
        for a, b in zip(poly, nxt):
            k = max(1, int(np.ceil(np.linalg.norm(b - a) / 4.0)))
            s = np.arange(k)[:, None] / k
            seg.append(a + s * (b - a))
        dense = np.concatenate(seg)
        yd = (dense[:, 1] - K[1, 2]) / K[1, 1]
        xd = (dense[:, 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
        return _undistort_normalized(np.stack([xd, yd], 1), np.asarray(camera.dist, float))
    y = (poly[:, 1] - K[1, 2]) / K[1, 1]
    x = (poly[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return np.stack([x, y], 1)


def _polytope_box(A: np.ndarray, b: np.ndarray, cap: np.ndarray) -> np.ndarray | None:
    """Bounding box (2, 3) of ``{x : A x <= b} & cap`` (rows of ``A`` unit vectors, ``cap``
    a (2, 3) box) from its vertices: one linear program for a point deep inside (the
    centre of the largest inscribed ball), then Qhull's halfspace intersection. None when
    that ball is too small for Qhull to be reliable (then solve one program per side).

    Raises
    ------
    ValueError
        The set is empty.
    """
    from scipy.optimize import linprog
    from scipy.spatial import HalfspaceIntersection, QhullError

    eye = np.eye(3)
    A = np.concatenate([A, eye, -eye])
    b = np.concatenate([b, cap[1], -cap[0]])
    res = linprog(
        np.array([0.0, 0.0, 0.0, -1.0]),
        A_ub=np.hstack([A, np.ones((len(A), 1))]),
        b_ub=b,
        bounds=[(float(lo), float(hi)) for lo, hi in zip(cap[0], cap[1])] + [(0.0, None)],
        method="highs",
    )
    if res.status == 2:
        raise ValueError("the silhouette cones have no common point (check the calibration)")
    if res.status != 0 or not res.x[3] > 1e-3:  # mm
        return None
    try:
        V = HalfspaceIntersection(np.hstack([A, -b[:, None]]), res.x[:3]).intersections
    except (QhullError, ValueError):
        return None
    if not (len(V) >= 4 and np.all(np.isfinite(V))):
        return None
    return np.array([V.min(axis=0), V.max(axis=0)])


def default_bounds(
    cameras: Sequence[Camera],
    masks: Sequence[np.ndarray],
    *,
    open_border: Sequence[bool] | None = None,
    margin_px: float = 1.0,
    margin_mm: float | None = None,
) -> np.ndarray:
    """Axis-aligned box containing the intersection of the silhouette cones.

    Each camera whose silhouette does not touch the border (``open_border[c]`` False)
    contributes the half-spaces of the cone over the convex hull of its silhouette (pixel
    squares grown by ``margin_px``), in front of the camera; the vertices of the
    intersection of these convex cones (Qhull, or six small linear programs in
    near-degenerate cases) give its exact bounding box. Cameras with
    an open border do not constrain it. When the cones leave the box unbounded (too few
    closed cameras), the box is capped at 4 times the rig's radius around its centre.

    Parameters
    ----------
    cameras : sequence of Camera
    masks : sequence of (H, W) bool
    open_border : sequence of bool, optional
    margin_px : float
        Growth of each silhouette, pixels.
    margin_mm : float, optional
        Growth of the box, mm (default 2 % of its largest extent).

    Returns
    -------
    (2, 3) float
        ``[min, max]`` corners, world mm.

    Raises
    ------
    ValueError
        A closed camera sees no object, or the cones have no common point.
    """
    return _default_bounds(cameras, masks, open_border, margin_px, margin_mm)


def _default_bounds(
    cameras: Sequence[Camera],
    masks: Sequence[np.ndarray],
    open_border: Sequence[bool] | None,
    margin_px: float,
    margin_mm: float | None,
    boxes: Sequence[tuple[int, int, int, int]] | None = None,
) -> np.ndarray:
    """:func:`default_bounds`, with the masks' :func:`_object_box` if known."""
    from scipy.optimize import linprog
    from scipy.spatial import ConvexHull

    if len(cameras) != len(masks):
        raise ValueError(f"{len(cameras)} cameras but {len(masks)} masks")
    ob = [False] * len(cameras) if open_border is None else [bool(b) for b in open_border]
    A: list[np.ndarray] = []
    b: list[np.ndarray] = []
    for i, (cam, mask, o) in enumerate(zip(cameras, masks, ob)):
        if o:
            continue
        m = np.ascontiguousarray(mask, dtype=bool)
        box = _object_box(m) if boxes is None else boxes[i]
        if box[2] == 0:
            raise ValueError(f"camera {cam.name}: empty silhouette, the visual hull is empty")
        poly = _silhouette_polygon(cam, m, margin_px, box)
        hull = ConvexHull(poly)
        eq = hull.equations.copy()  # n . x + d <= 0 inside
        if cam.has_distortion:
            eq[:, 2] -= 0.5 / float(min(cam.K[0, 0], cam.K[1, 1]))  # chord sagitta slack
        R = np.asarray(cam.R, float)
        t = np.asarray(cam.t, float)
        # n . (R_xy X + t_xy) + d (R_z X + t_z) <= 0
        A.append(eq[:, :2] @ R[:2] + eq[:, 2:3] * R[2][None, :])
        b.append(-(eq[:, :2] @ t[:2] + eq[:, 2] * t[2]))
        A.append(-R[2][None, :])  # z >= 1 mm
        b.append(np.array([t[2] - 1.0]))
    centres = np.array([c.centre for c in cameras])
    mid = centres.mean(axis=0)
    rad = float(np.max(np.linalg.norm(centres - mid, axis=1))) + 1.0
    var_bounds = [(float(mid[i] - 4 * rad), float(mid[i] + 4 * rad)) for i in range(3)]
    bounds = np.array([mid - 4 * rad, mid + 4 * rad])
    if A:
        A_ub = np.concatenate(A)
        b_ub = np.concatenate(b)
        scale = np.linalg.norm(A_ub, axis=1)
        A_ub = A_ub / scale[:, None]
        b_ub = b_ub / scale
        ext = _polytope_box(A_ub, b_ub, bounds)
        if ext is not None:
            bounds = ext
        else:
            for i in range(3):
                for k, sgn in enumerate((1.0, -1.0)):
                    c = np.zeros(3)
                    c[i] = sgn
                    res = linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=var_bounds, method="highs")
                    if res.status == 2:
                        raise ValueError("the silhouette cones have no common point (check the calibration)")
                    if res.status != 0:
                        continue  # keep the rig cap on that side
                    bounds[k, i] = res.x[i]
    if margin_mm is None:
        margin_mm = 0.02 * float(np.max(bounds[1] - bounds[0]))
    bounds[0] -= margin_mm
    bounds[1] += margin_mm
    return bounds


# --------------------------------------------------------------------------------------
# Carving
# --------------------------------------------------------------------------------------


def _empty(voxel_mm: float) -> Reconstruction:
    return Reconstruction(
        points=np.zeros((0, 3)),
        normals=np.zeros((0, 3)),
        vertices=np.zeros((0, 3)),
        faces=np.zeros((0, 3), dtype=np.int64),
        voxel_mm=float(voxel_mm),
    )


def _refine_points(
    views: Sequence[_View],
    C: np.ndarray,
    Pc: np.ndarray | None,
    active: np.ndarray,
    size: float,
    h: float,
    max_iter: int = 6,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Newton-project finest boundary cell centres onto ``f = 0``.

    Each point moves along a fixed *chord* direction, the gradient of the camera attaining
    the minimum of ``f``, taken again when that camera changes: at the current point or,
    with ``Pc``, at the centre of the cell's parent (computed once for its 8 children).
    Along that line the steps are secant steps (Newton steps with the chord slope while
    fewer than two values are known, or when the secant slope is not within a factor 4
    of it). The normal is a gradient of the final camera taken within the finite-difference
    step ``h`` of the final point (the gradient averages over +-h anyway): the chord if
    it is one, else the one at the parent's centre (with ``Pc``), else the one at the
    point.

    Parameters
    ----------
    C : (3, N) float
        Cell centres, mm.
    Pc : (3, N) float, optional
        Centres of the cells' parents (edge ``2 * size``), mm (:func:`carve` gives them
        when they lie within ``h`` of the cell centres: voxels up to about 2 pixel
        footprints).
    active : (N, C) bool
        Cameras not proven "inside" for each cell; the others are > 0 by about the cell's
        size everywhere in it, so they cannot attain the minimum of ``f`` near 0.
    size : float
        Cell edge, mm.
    h : float
        Finite-difference step, mm.
    max_iter : int
        Steps at most (a point stops once ``|f| <= 1e-3 * size``).

    Returns
    -------
    points (M, 3), outward unit normals (M, 3), residual ``f`` (M,) mm: the points that
    land inside their own cell (so the surface is sampled about once per ``size**2``) and
    converged (``|f| <= 0.02 * size``); points leaving their cell by more than a tenth
    of its edge are dropped at once (they end outside it all but never).
    """
    n = C.shape[1]
    Xout = C.copy()
    fout = np.full(n, np.inf)
    argout = np.zeros(n, dtype=np.intp)
    grad_all = np.zeros((3, n))
    anchor = np.zeros((3, n))  # where each chord was taken
    arg_prev = np.full(n, -1, dtype=np.intp)  # and for which camera
    S = C.copy()  # start of each point's line X = S - tau * grad
    tau = np.zeros(n)
    tau_p = np.zeros(n)
    f_p = np.zeros(n)
    have_p = np.zeros(n, dtype=bool)
    todo = np.arange(n)
    X = C.copy()
    for it in range(max_iter + 1):
        f, arg = _f_all(views, X, active[todo])
        done = np.abs(f) <= 1e-3 * size
        if it == max_iter:
            done[:] = True
        d = todo[done]
        Xout[:, d] = X[:, done]
        fout[d] = f[done]
        argout[d] = arg[done]
        nd = ~done
        todo, X, f, arg = todo[nd], X[:, nd], f[nd], arg[nd]
        if todo.size == 0:
            break
        new = arg != arg_prev[todo]
        if new.any():
            tn = todo[new]
            at = X[:, new] if Pc is None or it > 0 else Pc[:, tn]
            grad_all[:, tn] = _grad_argmin(views, at, arg[new], h)
            anchor[:, tn] = at
            arg_prev[tn] = arg[new]
            S[:, tn] = X[:, new]
            tau[tn] = 0.0
            have_p[tn] = False
        grad = grad_all[:, todo]
        gn2 = np.einsum("ij,ij->j", grad, grad)
        t, tp, fp, hp = tau[todo], tau_p[todo], f_p[todo], have_p[todo]
        slope = _secant_slope(gn2, f, t, tp, fp, hp)
        step = gn2 > 1e-12
        ts = todo[step]
        f_p[ts] = f[step]
        tau_p[ts] = t[step]
        have_p[ts] = True
        tau[ts] = t[step] - f[step] / slope[step]
        X = S[:, todo] - tau[todo] * grad
        ok = np.max(np.abs(X - C[:, todo]), axis=0) <= _LEAVE * size  # drop those leaving their cell early
        todo, X = todo[ok], X[:, ok]
        if todo.size == 0:
            break
    return _kept_points(views, C, Pc, size, h, Xout, fout, argout, arg_prev, anchor, grad_all)


def _secant_slope(
    gn2: np.ndarray, f: np.ndarray, t: np.ndarray, tp: np.ndarray, fp: np.ndarray, hp: np.ndarray
) -> np.ndarray:
    """Slope of ``f`` along each point's chord for its next step (:func:`_refine_points`).

    Parameters
    ----------
    gn2 : (N,) float
        Squared norm of each chord's gradient, mm**2 / mm**2 (``-gn2``: the chord slope).
    f : (N,) float
        ``f`` at the current points, mm.
    t, tp : (N,) float
        Current and previous positions along the chord (``X = S - tau * grad``).
    fp : (N,) float
        ``f`` at the previous position, mm.
    hp : (N,) bool
        A previous position is known.

    Returns
    -------
    (N,) float
        The secant slope where two positions are known and it lies within a factor 4 of the
        chord slope, else the chord slope ``-gn2``.
    """
    slope = -gn2
    use = hp & (t != tp)
    if use.any():
        sec = (f[use] - fp[use]) / (t[use] - tp[use])
        g2 = gn2[use]
        slope[use] = np.where((sec >= -4.0 * g2) & (sec <= -0.25 * g2), sec, slope[use])
    return slope


def _kept_points(
    views: Sequence[_View], C: np.ndarray, Pc: np.ndarray | None, size: float, h: float, Xout: np.ndarray,
    fout: np.ndarray, argout: np.ndarray, arg_prev: np.ndarray, anchor: np.ndarray, grad_all: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Newton points of :func:`_refine_points` that are kept, with their normals.

    Parameters
    ----------
    C : (3, N) float
        Cell centres, mm.
    Pc : (3, N) float, optional
        Centres of the cells' parents, mm.
    size : float
        Cell edge, mm.
    h : float
        Finite-difference step, mm.
    Xout : (3, N) float
        Final points, mm.
    fout : (N,) float
        ``f`` at them, mm.
    argout : (N,) intp
        Camera attaining the minimum there.
    arg_prev : (N,) intp
        Camera of each point's last chord (-1: none).
    anchor : (3, N) float
        Where each last chord was taken, mm.
    grad_all : (3, N) float
        Each last chord's gradient (mm / mm).

    Returns
    -------
    points (M, 3), outward unit normals (M, 3), residual ``f`` (M,) mm: the points inside
    their own cell with ``|f| <= 0.02 * size``, the normal a gradient of their camera taken
    within ``h`` of them (the chord, or at the parent's centre), else at the point.
    """
    ok = np.flatnonzero((np.max(np.abs(Xout - C), axis=0) <= 0.5 * size * (1.0 + 1e-9)) & (np.abs(fout) <= 0.02 * size))
    X, f, a = Xout[:, ok], fout[ok], argout[ok]
    # the normal: a gradient of camera a taken within h of the point (the chord, or at the
    # parent's centre), else at the point
    chord_ok = (arg_prev[ok] == a) & (np.sum((X - anchor[:, ok]) ** 2, axis=0) <= h * h)
    at_parent = ~chord_ok
    if Pc is None:
        at_parent[:] = False
    else:
        at_parent &= np.sum((X - Pc[:, ok]) ** 2, axis=0) <= h * h
    at_point = ~chord_ok & ~at_parent
    grad = np.empty_like(X)
    grad[:, chord_ok] = grad_all[:, ok[chord_ok]]
    if Pc is not None and at_parent.any():
        grad[:, at_parent] = _grad_argmin(views, Pc[:, ok[at_parent]], a[at_parent], h)
    grad[:, at_point] = _grad_argmin(views, X[:, at_point], a[at_point], h)
    gn = np.sqrt(np.einsum("ij,ij->j", grad, grad))
    good = gn > 1e-9
    return X[:, good].T.copy(), (-grad[:, good] / gn[good]).T.copy(), f[good]


def _mesh_signs(views: Sequence[_View], n: np.ndarray, lo: np.ndarray, mv: float, B: int) -> tuple[np.ndarray, int]:
    """Sign of the hull function on the mesh grid, by blocks (numpy reference).

    Blocks of ``B**3`` nodes (``B`` a power of 2; clipped at the grid's end) are tested
    like the carving's cells, their ball being centred on the block with the half
    diagonal of its nodes as radius: carved by a camera -> every node is negative;
    inside every camera -> every node is positive (cameras proven inside are dropped for
    the sub-blocks); otherwise the block is split into 8. Single nodes get the sign of
    ``f``.

    Returns
    -------
    vals : (n0, n1, n2) float32
        ``+1`` where ``f > 0``, ``-1`` elsewhere.
    n_eval : int
        Blocks and nodes evaluated.
    """
    vals = np.empty(tuple(int(k) for k in n), dtype=np.float32)
    nm1 = (n - 1)[:, None]
    gi = np.meshgrid(*[np.arange(0, k, B) for k in n], indexing="ij")
    starts = np.stack([g.ravel() for g in gi])  # (3, M) node indices
    act = np.ones((starts.shape[1], len(views)), dtype=bool)
    n_eval = 0
    while starts.shape[1]:
        ends = np.minimum(starts + B - 1, nm1)
        n_eval += starts.shape[1]
        node = np.all(ends == starts, axis=0)
        if node.any():
            s = starts[:, node]
            f = _f_all(views, lo[:, None] + s * mv)[0]
            vals[s[0], s[1], s[2]] = np.where(f > 0.0, np.float32(1.0), np.float32(-1.0))
        blk = ~node
        s, e, a = starts[:, blk], ends[:, blk], act[blk]
        P = lo[:, None] + 0.5 * (s + e) * mv
        hd = 0.5 * mv * np.sqrt(np.sum((e - s) ** 2.0, axis=0))
        carved = np.zeros(s.shape[1], dtype=bool)
        for c, v in enumerate(views):
            sel = np.flatnonzero(a[:, c] & ~carved)
            if sel.size == 0:
                continue
            out, inn = _classify(v, P[:, sel], hd[sel])
            carved[sel[out]] = True
            a[sel[inn], c] = False
        inside = ~carved & ~a.any(axis=1)
        for sign, sel in ((-1.0, carved), (1.0, inside)):
            if sel.any():
                # blocks of one level start at multiples of B: fill through a coarse grid
                coarse = np.zeros([-(-int(k) // B) for k in n], dtype=np.float32)
                coarse[s[0, sel] // B, s[1, sel] // B, s[2, sel] // B] = sign
                up = coarse.repeat(B, 0).repeat(B, 1).repeat(B, 2)[: n[0], : n[1], : n[2]]
                np.copyto(vals, up, where=up != 0)
        split = ~carved & ~inside
        B //= 2
        starts = (s[:, split][:, :, None] + _CHILD_OFFSETS.T[:, None, :] * B).reshape(3, -1)
        act = np.repeat(a[split], 8, axis=0)
        keep = np.all(starts <= nm1, axis=0)
        starts, act = starts[:, keep], act[keep]
    return vals, n_eval


def _mixed_cubes(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cubes of the grid with corners of both signs, and their corners.

    Parameters
    ----------
    pos : (n0, n1, n2) bool

    Returns
    -------
    mixed : (n0 - 1, n1 - 1, n2 - 1) bool
        Cube ``(i, j, k)`` (corners ``(i..i+1, j..j+1, k..k+1)``) has both signs.
    corners : (n0, n1, n2) bool
        Corner of a mixed cube.
    """
    shifts = [(slice(a, a + pos.shape[0] - 1), slice(b, b + pos.shape[1] - 1), slice(c, c + pos.shape[2] - 1))
              for a in (0, 1) for b in (0, 1) for c in (0, 1)]
    any_pos = np.zeros([k - 1 for k in pos.shape], dtype=bool)
    all_pos = np.ones_like(any_pos)
    for sl in shifts:
        any_pos |= pos[sl]
        all_pos &= pos[sl]
    mixed = any_pos & ~all_pos
    corners = np.zeros_like(pos)
    for sl in shifts:
        corners[sl] |= mixed
    return mixed, corners


#: Most nodes of the display mesh's grid (its signs are a float32 volume: 256 MiB).
MAX_MESH_NODES = 1 << 26


def _mesh_pitch(lo: np.ndarray, hi: np.ndarray, mv: float) -> float:
    """The display mesh's pitch, mm: ``mv``, coarsened so that its grid over [lo, hi] (plus
    one cell on each side) has at most :data:`MAX_MESH_NODES` nodes. A reconstruction that
    large is a wrong segmentation or calibration; it must not exhaust the memory."""
    ext = np.asarray(hi, float) - np.asarray(lo, float) + 2.0 * mv
    while float(np.prod(np.ceil(ext / mv) + 1.0)) > MAX_MESH_NODES:
        mv *= 1.25
        ext = np.asarray(hi, float) - np.asarray(lo, float) + 2.0 * mv
    return mv


def _mesh(
    views: Sequence[_View], lo: np.ndarray, hi: np.ndarray, mv: float, jit: Any = None, stack: Any = None
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Marching cubes of the hull function on a grid of pitch ``mv`` over [lo, hi].

    The grid is evaluated in a narrow band only: the sign of ``f`` comes from the
    conservative ball test of blocks of nodes (:func:`_mesh_signs`), exact values only at
    the corners of the cubes with a sign change, the only values marching cubes reads
    (edge interpolation and Lewiner's face / interior tests), so the mesh is that of the
    exact ``f`` on the whole grid. With ``jit`` (:mod:`carving_jit`) and its ``stack`` the
    signs and values come from the compiled kernels.
    """
    from skimage.measure import marching_cubes

    n = np.maximum(np.ceil((hi - lo) / mv - 1e-9).astype(np.int64) + 1, 2)
    B = 1
    while B * 8 < n.max():
        B *= 2
    info: dict[str, Any] = dict(mesh_grid=int(np.prod(n)))
    if jit is not None:
        vol, exact, n_eval = jit.mesh_signs(stack, n, lo, mv, B, _LIP, _SLACK_PX)
        if not (vol.max() > 0.0):
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), dict(info, mesh_evaluated=n_eval)
        cube, m = jit.mesh_fill(stack, vol, exact, lo, mv)
        n_eval += m
    else:
        vals, n_eval = _mesh_signs(views, n, lo, mv, B)
        if not (vals.max() > 0.0):
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), dict(info, mesh_evaluated=n_eval)
        vol = np.pad(vals, 1, constant_values=-1.0)  # closed by a negative layer
        mixed, need = _mixed_cubes(vol > 0.0)
        ii = np.nonzero(need[1:-1, 1:-1, 1:-1])
        # only the mixed cubes make triangles: skip the others (skimage reads the mask at
        # each cube's last corner, (i + 1, j + 1, k + 1) for the cube at (i, j, k))
        cube = np.zeros(vol.shape, dtype=bool)
        cube[1:, 1:, 1:] = mixed
        if len(ii[0]):
            P = lo[:, None] + np.stack(ii) * mv
            f = _f_all(views, P)[0]
            vol[ii[0] + 1, ii[1] + 1, ii[2] + 1] = np.clip(f, -1e3, 1e3)
            n_eval += len(f)
    info["mesh_evaluated"] = n_eval
    verts, faces, _, _ = marching_cubes(vol, level=0.0, spacing=(mv, mv, mv), mask=cube)
    verts = verts + (lo - mv)
    faces = faces.astype(np.int64)
    # outward faces: positive enclosed volume (sum of the signed tetrahedra on the centroid)
    v = verts - verts.mean(0)
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    vol6 = np.sum(a[:, 0] * (b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1]) + a[:, 1] * (b[:, 2] * c[:, 0] - b[:, 0] * c[:, 2])
                  + a[:, 2] * (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0]))
    if vol6 < 0:
        faces = faces[:, ::-1].copy()
    return verts, faces, info


def _resolve_backend(backend: str) -> str:
    """The carving backend: ``backend`` checked, ``"auto"`` resolved to ``"numba"`` when numba
    can be imported, else ``"numpy"``.

    Raises
    ------
    ValueError
        ``backend`` is not one of ``"auto"``, ``"numba"``, ``"numpy"``.
    """
    if backend not in ("auto", "numba", "numpy"):
        raise ValueError(f"backend must be 'auto', 'numba' or 'numpy', got {backend!r}")
    if backend == "auto":
        try:
            import numba  # noqa: F401

            backend = "numba"
        except ImportError:  # pragma: no cover - numba is a dependency
            backend = "numpy"
    return backend


def _checked_inputs(
    cameras: Sequence[Camera], masks: Sequence[np.ndarray], voxel_mm: float, open_border: Sequence[bool] | None
) -> tuple[float, list[bool], list[np.ndarray]]:
    """:func:`carve`'s arguments checked: ``voxel_mm`` (mm, float), the open-border flags (one
    per camera) and the masks as C-contiguous (H, W) bool arrays.

    Raises
    ------
    ValueError
        ``voxel_mm <= 0`` or not finite, no cameras, or counts that do not match.
    """
    voxel_mm = float(voxel_mm)
    if not (voxel_mm > 0 and np.isfinite(voxel_mm)):
        raise ValueError(f"voxel_mm must be > 0, got {voxel_mm}")
    if len(cameras) != len(masks):
        raise ValueError(f"{len(cameras)} cameras but {len(masks)} masks")
    if len(cameras) == 0:
        raise ValueError("no cameras")
    ob = [False] * len(cameras) if open_border is None else [bool(b) for b in open_border]
    if len(ob) != len(cameras):
        raise ValueError(f"{len(cameras)} cameras but {len(ob)} open_border flags")
    return voxel_mm, ob, [np.ascontiguousarray(m, dtype=bool) for m in masks]


def _carve_bounds(
    cameras: Sequence[Camera], masks: Sequence[np.ndarray], ob: Sequence[bool], bounds: np.ndarray | None,
    st: dict[str, Any], supports: Sequence[tuple[int, int, int, int] | None] | None = None,
) -> tuple[list[tuple[int, int, int, int]], np.ndarray | None]:
    """The masks' object boxes (:func:`_object_box`, within ``supports``) and the (2, 3) ``[min, max]`` world box to
    carve, mm (``bounds``, checked, or :func:`default_bounds`); ``None`` for the box when the
    hull is empty, with ``n_points`` and ``empty_reason`` in ``st``.

    Raises
    ------
    ValueError
        A mask not of its camera's size, or malformed ``bounds``.
    """
    for cam, m in zip(cameras, masks):
        if m.shape != (int(cam.height), int(cam.width)):
            raise ValueError(f"camera {cam.name}: mask shape {m.shape}, camera is {cam.width}x{cam.height}")
    boxes = [_object_box(m, None if supports is None else supports[i]) for i, m in enumerate(masks)]
    if any((not o) and box[2] == 0 for box, o in zip(boxes, ob)):
        st.update(n_points=0, empty_reason="a closed camera sees no object")
        return boxes, None
    if bounds is None:
        try:
            bounds = _default_bounds(cameras, masks, ob, 1.0, None, boxes)
        except ValueError as exc:
            st.update(n_points=0, empty_reason=str(exc))
            return boxes, None
    bounds = np.asarray(bounds, float)
    if bounds.shape != (2, 3) or not np.all(np.isfinite(bounds)) or not np.all(bounds[1] > bounds[0]):
        raise ValueError(f"bounds must be (2, 3) [min, max], got {bounds!r}")
    return boxes, bounds


def _silhouette_views(
    cameras: Sequence[Camera], masks: Sequence[np.ndarray], ob: Sequence[bool],
    boxes: Sequence[tuple[int, int, int, int]], backend: str,
) -> tuple[list[_View], np.ndarray]:
    """Each camera's :class:`_View` of its silhouette's signed distances on a window around it
    (:func:`_signed_distance_window`), each written straight into its row of one buffer that
    the compiled kernels share.

    Returns
    -------
    views : list of _View
        One per camera, same order.
    buf : (C, max window pixels) float32
        The windows' signed distances, px, row ``c`` holding camera ``c``'s (row-major).
    """
    rects = [_window(m, o, _WINDOW_MARGIN_PX, box) for m, o, box in zip(masks, ob, boxes)]
    buf = np.zeros((len(masks), max(w * h for _, _, w, h in rects)), dtype=np.float32)

    def sdt_job(i: int) -> np.ndarray:
        w, h = rects[i][2], rects[i][3]
        return _signed_distance_window(masks[i], ob[i], _WINDOW_MARGIN_PX, buf[i, : w * h], boxes[i])[0]

    if backend == "numba" and len(cameras) > 1:
        # the distance transforms release the GIL: one thread per core
        sdts = map_threads(sdt_job, range(len(masks)))
    else:
        sdts = [sdt_job(i) for i in range(len(masks))]
    return [_prepare(c, sd, o, r[:2]) for c, sd, o, r in zip(cameras, sdts, ob, rects)], buf


@dataclass(eq=False)
class _Carving:
    """The depth-first carving of :func:`carve`: its grid, its diagnostics and its points.

    Attributes
    ----------
    views : sequence of _View
    jit, stack
        :mod:`carving_jit` and its :class:`carving_jit.ViewStack` of the views (numba
        backend), else ``None``.
    levels : int
        Levels below the coarse cells (level ``levels`` has cells of ``voxel_mm``).
    coarse : float
        Edge of the level-0 cells, mm (``voxel_mm * 2**levels``).
    n0 : (3,) int64
        Level-0 cells along each axis.
    origin : (3,) float
        World position of the grid's corner, mm.
    voxel_mm : float
        Edge of the finest cells, mm.
    h : float
        Finite-difference step of the gradient, mm.
    use_parent : bool
        Newton chords from the parent cells' centres (they lie within ``h`` of the finest
        cells' centres).
    level_stats : list of dict
        Per level: ``level``, ``cell_mm``, ``evaluated``, ``carved``, ``inside``, ``boundary``.
    occ_lo, occ_hi : (3,) float
        Box of the kept cells, mm (``+inf`` / ``-inf`` while none).
    pts, nrm, res : list of arrays
        Surface points (M, 3) mm, outward unit normals (M, 3), residuals ``f`` (M,) mm, by
        chunk.
    t_points : float
        Seconds spent on the points (with the numba backend, with the last two levels'
        cell tests).
    """

    views: Sequence[_View]
    jit: Any
    stack: Any
    levels: int
    coarse: float
    n0: np.ndarray
    origin: np.ndarray
    voxel_mm: float
    h: float
    use_parent: bool
    level_stats: list[dict[str, Any]]
    occ_lo: np.ndarray = field(default_factory=lambda: np.full(3, np.inf))
    occ_hi: np.ndarray = field(default_factory=lambda: np.full(3, -np.inf))
    pts: list[np.ndarray] = field(default_factory=list)
    nrm: list[np.ndarray] = field(default_factory=list)
    res: list[np.ndarray] = field(default_factory=list)
    t_points: float = 0.0

    def occupy(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """Grow the occupied box to hold ``[lo, hi]`` (mm)."""
        self.occ_lo = np.minimum(self.occ_lo, lo)
        self.occ_hi = np.maximum(self.occ_hi, hi)

    def add_points(self, X: np.ndarray, N: np.ndarray, f: np.ndarray) -> None:
        """Keep a chunk of surface points (M, 3) mm, normals (M, 3) and residuals (M,) mm."""
        self.pts.append(X)
        self.nrm.append(N)
        self.res.append(f)

    def count(self, level: int, evaluated: int, carved: int, inside: int, boundary: int) -> None:
        """Add cell counts to ``level``'s diagnostics."""
        ls = self.level_stats[level]
        ls["evaluated"] += evaluated
        ls["carved"] += carved
        ls["inside"] += inside
        ls["boundary"] += boundary


def _start_carving(
    views: Sequence[_View], jit: Any, stack: Any, bounds: np.ndarray, voxel_mm: float, coarse_mm: float | None
) -> _Carving:
    """The coarse grid over ``bounds`` ((2, 3) mm): ``coarse_mm`` (default 1/16 of the largest
    extent) rounded up to ``voxel_mm * 2**k``, centred on the box.

    Raises
    ------
    ValueError
        Too many cells (more than 2**24 coarse cells, or 2**30 finest along an axis).
    """
    extent = bounds[1] - bounds[0]
    target = float(coarse_mm) if coarse_mm else float(np.max(extent)) / 16.0
    levels = max(0, int(math.ceil(math.log2(max(target / voxel_mm, 1.0)) - 1e-9)))
    coarse = voxel_mm * 2**levels
    n0 = np.maximum(np.ceil(extent / coarse - 1e-9).astype(np.int64), 1)
    if int(np.prod(n0)) > 1 << 24 or levels + math.log2(float(n0.max())) > 30:
        raise ValueError(f"too many cells: voxel_mm={voxel_mm}, coarse_mm={coarse_mm} for bounds {bounds.tolist()}")
    origin = 0.5 * (bounds[0] + bounds[1]) - 0.5 * n0 * coarse
    level_stats = [
        dict(level=k, cell_mm=coarse / 2**k, evaluated=0, carved=0, inside=0, boundary=0) for k in range(levels + 1)
    ]
    h = _GRAD_STEP_PX * _footprint(views, 0.5 * (bounds[0] + bounds[1]))
    # Newton chords from the parent cells' centres when they lie within the gradient's
    # finite-difference step of the finest cells' centres (the gradient averages over it).
    use_parent = voxel_mm * math.sqrt(3.0) / 2.0 <= h
    return _Carving(views, jit, stack, levels, coarse, n0, origin, voxel_mm, h, use_parent, level_stats)


def _carve_cells(run: _Carving) -> None:
    """Classify the grid's cells depth first over chunks, from the coarse level to the finest,
    and Newton-project the finest boundary cells: memory stays bounded (about 8 chunks per
    level) whatever the voxel size and the part's surface."""
    gi = np.meshgrid(*[np.arange(k, dtype=np.int32) for k in run.n0], indexing="ij")
    cells0 = np.stack([g.ravel() for g in gi], axis=1)  # (N, 3) integer cell coordinates
    active0 = np.ones((len(cells0), len(run.views)), dtype=bool)  # cameras not yet proven "inside"
    todo: list[tuple[int, np.ndarray, np.ndarray]] = [(0, cells0, active0)]
    while todo:
        level, cells, active = todo.pop()
        if len(cells) > _CELL_CHUNK:
            for s in reversed(range(0, len(cells), _CELL_CHUNK)):
                todo.append((level, cells[s : s + _CELL_CHUNK], active[s : s + _CELL_CHUNK]))
            continue
        if run.jit is not None and level == run.levels - 1:
            _jit_last_levels(run, level, cells, active)
        elif run.jit is not None:
            _jit_level(run, todo, level, cells, active)
        else:
            _numpy_level(run, todo, level, cells, active)


def _jit_last_levels(run: _Carving, level: int, cells: np.ndarray, active: np.ndarray) -> None:
    """The last two levels with the points, in one compiled pass from ``level``'s cells.

    Parameters
    ----------
    level : int
        ``run.levels - 1``.
    cells : (N, 3) int32
        Integer cell coordinates at ``level``.
    active : (N, C) bool
        Cameras not yet proven "inside" for each cell.
    """
    size = run.coarse / 2**level
    r = size * math.sqrt(3.0) / 2.0
    voxel_mm = run.voxel_mm
    tp = time.perf_counter()
    cnt_f, lohi_f, X, N, f = run.jit.finest_points(
        run.stack, cells, active, run.origin, voxel_mm, r, voxel_mm * math.sqrt(3.0) / 2.0, _LIP, _SLACK_PX, run.h,
        run.use_parent
    )
    for k, (lv, sz) in enumerate(((level, size), (run.levels, voxel_mm))):
        run.count(lv, len(cells) if k == 0 else 8 * int(cnt_f[0, 2]), int(cnt_f[k, 0]), int(cnt_f[k, 1]),
                  int(cnt_f[k, 2]))
        if np.all(lohi_f[k, 1] > lohi_f[k, 0]):
            run.occupy(run.origin + lohi_f[k, 0] * sz, run.origin + lohi_f[k, 1] * sz)
    run.add_points(X, N, f)
    run.t_points += time.perf_counter() - tp


def _jit_level(
    run: _Carving, todo: list[tuple[int, np.ndarray, np.ndarray]], level: int, cells: np.ndarray, active: np.ndarray
) -> None:
    """Classify one chunk of ``level``'s cells with the compiled kernels: the boundary cells'
    children go on ``todo``, or, at the finest level, their centres are Newton-projected.

    Parameters
    ----------
    cells : (N, 3) int32
        Integer cell coordinates at ``level``.
    active : (N, C) bool
        Cameras not yet proven "inside" for each cell.
    """
    size = run.coarse / 2**level
    r = size * math.sqrt(3.0) / 2.0
    finest = level == run.levels
    status, act, bcount = run.jit.classify_cells(run.stack, cells, active, run.origin, size, r, _LIP, _SLACK_PX)
    cnt = bcount.sum(axis=0)
    nb = int(cnt[2])
    run.count(level, len(cells), int(cnt[0]), int(cnt[1]), nb)
    if cnt[1] == 0 and nb == 0:
        return
    lohi, *rest = run.jit.gather(cells, act, status, bcount, 1 if finest else 0, run.origin, size)
    if np.all(lohi[1] > lohi[0]):
        run.occupy(run.origin + lohi[0] * size, run.origin + lohi[1] * size)
    if nb == 0:
        return
    if finest:
        tp = time.perf_counter()
        A, Pc, B = rest
        run.add_points(*run.jit.refine_points(run.stack, A, Pc if run.use_parent else None, B, run.voxel_mm, run.h))
        run.t_points += time.perf_counter() - tp
    else:
        todo.append((level + 1, *rest))


def _numpy_level(
    run: _Carving, todo: list[tuple[int, np.ndarray, np.ndarray]], level: int, cells: np.ndarray, active: np.ndarray
) -> None:
    """:func:`_jit_level` with numpy (the reference): classify one chunk of ``level``'s cells
    against each camera (:func:`_classify`); the boundary cells' children go on ``todo``, or,
    at the finest level, their centres are Newton-projected (:func:`_refine_points`).

    Parameters
    ----------
    cells : (N, 3) int32
        Integer cell coordinates at ``level``.
    active : (N, C) bool
        Cameras not yet proven "inside" for each cell.
    """
    size = run.coarse / 2**level
    r = size * math.sqrt(3.0) / 2.0
    finest = level == run.levels
    origin = run.origin
    act = active.copy()
    P = origin[:, None] + (cells.T + 0.5) * size  # (3, n) centres
    carved = np.zeros(len(cells), dtype=bool)
    for c, v in enumerate(run.views):
        sel = np.flatnonzero(act[:, c] & ~carved)
        if sel.size == 0:
            continue
        out, inn = _classify(v, P[:, sel], r)
        carved[sel[out]] = True
        act[sel[inn], c] = False
    undecided = act.any(axis=1)
    inside = ~carved & ~undecided
    bnd = ~carved & undecided
    run.count(level, len(cells), int(carved.sum()), int(inside.sum()), int(bnd.sum()))
    kept = inside | bnd if finest else inside
    if kept.any():
        lo, hi = bounds_of(cells[kept])
        run.occupy(origin + lo * size, origin + (hi + 1) * size)
    if not bnd.any():
        return
    if finest:
        # surface points, Newton-projected onto f = 0
        tp = time.perf_counter()
        Pc = origin[:, None] + ((cells[bnd].T >> 1) + 0.5) * (2.0 * size) if run.use_parent else None
        run.add_points(*_refine_points(run.views, P[:, bnd], Pc, act[bnd], run.voxel_mm, run.h))
        run.t_points += time.perf_counter() - tp
    else:
        b = cells[bnd]
        todo.append(
            (
                level + 1,
                (b[:, None, :] * 2 + _CHILD_OFFSETS[None]).reshape(-1, 3),
                np.repeat(act[bnd], 8, axis=0),
            )
        )


def _finish(
    run: _Carving, bounds: np.ndarray, mesh_voxel_mm: float | None, st: dict[str, Any], t0: float, mesh: bool = True
) -> Reconstruction:
    """The carving's points gathered, its display mesh over the occupied cells
    (:func:`_mesh`; none without ``mesh``) and its diagnostics in ``st`` (``t0``: the start,
    :func:`time.perf_counter` seconds)."""
    points = np.concatenate(run.pts) if run.pts else np.zeros((0, 3))
    normals = np.concatenate(run.nrm) if run.nrm else np.zeros((0, 3))
    resid = np.concatenate(run.res) if run.res else np.zeros(0)
    t2 = time.perf_counter()
    t1 = t2 - run.t_points
    level_stats = run.level_stats
    st.update(
        levels=level_stats,
        bounds=bounds.copy(),
        coarse_mm=run.coarse,
        n_finest_evaluated=level_stats[-1]["evaluated"],
        n_dense_finest=int(np.prod(run.n0 * 2**run.levels)),
        n_boundary_finest=level_stats[-1]["boundary"],
    )

    # Display mesh over the occupied cells.
    voxel_mm, occ_lo, occ_hi = run.voxel_mm, run.occ_lo, run.occ_hi
    mv = float(mesh_voxel_mm) if mesh_voxel_mm else max(voxel_mm, 0.5)
    info: dict[str, Any] = dict(mesh_grid=0, mesh_evaluated=0)
    if mesh and np.all(np.isfinite(occ_lo)) and len(points):
        mv = _mesh_pitch(occ_lo, occ_hi, mv)
        verts, faces, info = _mesh(run.views, occ_lo - mv, occ_hi + mv, mv, run.jit, run.stack)
    else:
        verts, faces = np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    t3 = time.perf_counter()
    st.update(
        n_points=len(points),
        residual_mm_max=float(np.max(np.abs(resid), initial=0.0)),
        occupied_bounds=np.array([occ_lo, occ_hi]),
        mesh_voxel_mm=mv if mesh else None,
        time_s=dict(carve=t1 - t0, points=t2 - t1, mesh=t3 - t2, total=t3 - t0),
        **info,
    )
    return Reconstruction(points=points, normals=normals, vertices=verts, faces=faces, voxel_mm=voxel_mm)


def carve(
    cameras: Sequence[Camera],
    masks: Sequence[np.ndarray],
    *,
    voxel_mm: float,
    bounds: np.ndarray | None = None,
    open_border: Sequence[bool] | None = None,
    coarse_mm: float | None = None,
    mesh_voxel_mm: float | None = None,
    mesh: bool = True,
    stats: dict[str, Any] | None = None,
    backend: str = "auto",
    supports: Sequence[tuple[int, int, int, int] | None] | None = None,
) -> Reconstruction:
    """Coarse-to-fine visual hull of binary silhouettes.

    Parameters
    ----------
    cameras : sequence of Camera
    masks : sequence of (H, W) bool
        Silhouettes (True = object), one per camera, same order, each the camera's size.
    voxel_mm : float
        Edge of the finest cells, mm (> 0). Only cells near the surface are refined:
        0.1 mm on a 30 mm part tests about 2 million finest cells, not a dense 300**3 grid.
    bounds : (2, 3) float, optional
        ``[min, max]`` world box to carve, mm; must contain the object (default
        :func:`default_bounds`).
    open_border : sequence of bool, optional
        Per camera: the silhouette touches the image border, outside the image is
        unknown and that camera does not carve there. Otherwise (default) outside the
        image is outside the silhouette: the part of the object the camera does not see
        is carved away. Points behind a camera are always carved.
    coarse_mm : float, optional
        Edge of the starting cells, mm; rounded up to ``voxel_mm * 2**k`` (default:
        about 1/16 of the largest extent of ``bounds``).
    mesh_voxel_mm : float, optional
        Pitch of the display mesh grid, mm (default ``max(voxel_mm, 0.5)``).
    mesh : bool, optional
        Make the display mesh (default True); without it ``vertices`` and ``faces`` are
        empty and ``mesh_voxel_mm`` in ``stats`` is None.
    stats : dict, optional
        Cleared, then filled in place with diagnostics: ``levels`` (one dict per level:
        ``cell_mm``, ``evaluated``, ``carved``, ``inside``, ``boundary`` cell counts),
        ``n_finest_evaluated`` (cells tested at ``voxel_mm``), ``n_dense_finest`` (cells
        of a dense ``voxel_mm`` grid over the same box), ``n_boundary_finest``,
        ``n_points``, ``residual_mm_max`` (largest ``|f|`` at the points), ``bounds``,
        ``coarse_mm``, ``occupied_bounds``, ``mesh_voxel_mm``, ``mesh_grid``,
        ``mesh_evaluated``, ``time_s`` (``carve``: distance transforms, bounds and cell
        tests; ``points``: Newton projection, with the numba backend together with the
        cell tests of the last two levels (one pass); ``mesh``; ``total``, seconds); for an
        empty hull only ``n_points`` = 0 and ``empty_reason``.
    backend : {"auto", "numba", "numpy"}
        ``"numba"``: compiled kernels for the cell tests, the Newton points and the mesh
        grid (:mod:`inspector.kernels.carving_jit`); ``"numpy"``: the pure-numpy
        reference (same cells, same points to rounding); ``"auto"`` (default): numba
        when it can be imported.
    supports : sequence of (y0, y1, x0, x1) int or None, optional
        Per camera, the rows and columns outside which its mask is False
        (:attr:`~inspector.model.Silhouette.support`): its object is looked for there only.
        None (default, or for a camera): anywhere.

    Returns
    -------
    Reconstruction
        ``points`` (N, 3) mm: surface points, about one per ``voxel_mm**2`` of hull
        surface: each finest boundary cell's centre moved onto ``f = 0`` of
        :func:`hull_function` by secant / Newton steps along its numerical gradient
        (see the module notes), kept when it lands inside its own cell (``|f|`` below
        0.1 % of a voxel, 2 % at worst).
        ``normals`` (N, 3): outward unit normals ``-grad f / |grad f|`` (central
        differences over +-2 pixel footprints, taken within that step of the point).
        ``vertices`` (V, 3) / ``faces`` (F, 3): marching-cubes mesh of ``f`` over the
        occupied cells, faces oriented outward (empty without ``mesh``). All empty when the
        hull is empty (a closed camera sees nothing, or the cones do not meet).

    Raises
    ------
    ValueError
        Bad arguments (sizes, ``voxel_mm <= 0``, malformed ``bounds``).
    """
    backend = _resolve_backend(backend)
    voxel_mm, ob, masks = _checked_inputs(cameras, masks, voxel_mm, open_border)
    st: dict[str, Any] = stats if stats is not None else {}
    st.clear()
    t0 = time.perf_counter()
    if supports is not None and len(supports) != len(masks):
        raise ValueError(f"{len(supports)} supports for {len(masks)} masks")
    boxes, box = _carve_bounds(cameras, masks, ob, bounds, st, supports)
    if box is None:
        return _empty(voxel_mm)
    views, buf = _silhouette_views(cameras, masks, ob, boxes, backend)
    jit: Any = None
    stack: Any = None
    if backend == "numba":
        jit = carving_jit
        stack = jit.stack_views(views, buf)
    run = _start_carving(views, jit, stack, box, voxel_mm, coarse_mm)
    _carve_cells(run)
    return _finish(run, box, mesh_voxel_mm, st, t0, mesh)
