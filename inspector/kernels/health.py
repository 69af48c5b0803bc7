"""Calibration health: how well each camera's silhouette agrees with the others'.

Every contour ray of a part grazes it. With the reference sized and placed where all the
cameras together put it (the bcps stage's final pose and size model), each camera's contour
rays therefore graze the reference too, up to image noise: their smallest signed distance
to it along the ray (:func:`~inspector.kernels.bcps.ray_min_distance`, the *silhouette
residual*) is about zero. A camera whose rig entry is wrong (knocked, turned, a stale
calibration) sees the part where the rig does not expect it: its rays miss the reference
on one side of its silhouette and cut into it on the other, by about the error in pixels.

:func:`silhouette_residuals` turns the residuals into per-camera figures in pixels: each
ray's residual minus the median over every camera's rays (a size or offset error common to
all cameras is not a camera's fault), divided by that camera's pixel footprint at the part,
then per camera the median and 90th percentile of the absolute residual, the signed median
and the image shift that best explains the residuals (:func:`image_shift`: what a camera
turned by k px shows as k, whatever the silhouette's shape). Arrays in, arrays out; no I/O.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from inspector.kernels.ray_search import ray_min_search

__all__ = ["CameraRays", "SilhouetteHealth", "silhouette_residuals", "ray_min_distances", "image_shift",
           "flagged_cameras"]

#: One camera's contour rays: optical centre (3,), unit directions (M, 3), and the range
#: along each ray to search, t0 (M,) and t1 (M,) mm (``t0 > t1``: none).
CameraRays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

#: A camera needs at least this many residuals to be judged (flagged or cleared).
MIN_RAYS = 8


@dataclass(frozen=True, eq=False)
class SilhouetteHealth:
    """Per-camera silhouette residuals, in the cameras' order (NaN: not measured).

    Attributes
    ----------
    median_px : (C,) float
        Median of the absolute residuals, px.
    p90_px : (C,) float
        90th percentile of the absolute residuals, px.
    signed_px : (C,) float
        Median of the signed residuals, px (positive: its rays miss the reference, the part
        looks larger to it than to the others; negative: they cut into it).
    shift_px : (C,) float
        How far the camera's image is shifted from where the others put the part, px
        (:func:`image_shift`). Unlike ``median_px`` it does not depend on the silhouette's
        shape: a camera shifted along a long straight contour (a shaft seen from the side)
        moves only its ends, and most of its residuals stay near 0.
    rays : (C,) int
        Residuals each figure stands on (rays with a range and a finite residual).
    offset_mm : float
        The median residual over every camera's rays, mm, subtracted before the figures.
    """

    median_px: np.ndarray
    p90_px: np.ndarray
    signed_px: np.ndarray
    shift_px: np.ndarray
    rays: np.ndarray
    offset_mm: float


def silhouette_residuals(
    rays: Sequence[CameraRays],
    sd_fn: Callable[[np.ndarray], np.ndarray],
    footprint_mm: np.ndarray | Sequence[float],
    *,
    normals: Sequence[np.ndarray] | None = None,
    step_mm: float = 0.25,
    levels: int = 3,
) -> SilhouetteHealth:
    """Each camera's silhouette residuals against a reference, in pixels.

    Parameters
    ----------
    rays : sequence of (origin (3,), dirs (M, 3), t0 (M,), t1 (M,))
        Per camera, the contour rays to check (a subset: the cost grows with them) and
        where along them to look, mm (:func:`~inspector.kernels.bcps.ray_ranges`, or the
        part's box); ``M`` may be 0.
    sd_fn : callable
        ``(N, 3) world mm -> (N,)`` signed distance to the reference at the part's pose and
        size, mm (negative inside; NaN far from the surface counts as far outside).
    footprint_mm : (C,) float
        Each camera's pixel footprint at the part, mm per px (> 0).
    normals : sequence of (M, 2) float, optional
        Per camera, the contour's outward unit normals (image frame) at the points its rays
        go through: with them, ``shift_px`` is measured.
    step_mm, levels : float, int
        The search along each ray (:func:`ray_min_distances`).

    Returns
    -------
    SilhouetteHealth
    """
    fp = np.asarray(footprint_mm, float).reshape(-1)
    C = len(rays)
    if len(fp) != C:
        raise ValueError(f"footprint_mm must have one value per camera, got {len(fp)} for {C} cameras")
    if normals is not None and len(normals) != C:
        raise ValueError(f"normals: one (M, 2) array per camera, got {len(normals)} for {C} cameras")
    origins, dirs, t0, t1, cam = [], [], [], [], []
    for c, (o, d, a, b) in enumerate(rays):
        d = np.asarray(d, float).reshape(-1, 3)
        origins.append(np.broadcast_to(np.asarray(o, float).reshape(1, 3), d.shape))
        dirs.append(d)
        t0.append(np.asarray(a, float).reshape(-1))
        t1.append(np.asarray(b, float).reshape(-1))
        cam.append(np.full(len(d), c))
    camera = np.concatenate(cam) if cam else np.zeros(0, int)
    # One pass over every camera's rays: five distance queries in all (each a parallel
    # region of the Numba kernel), not five per camera.
    r = (ray_min_distances(np.concatenate(origins), np.concatenate(dirs), np.concatenate(t0), np.concatenate(t1),
                           sd_fn, step_mm=step_mm, levels=levels) if len(camera) else np.zeros(0))
    ok = np.isfinite(r)
    offset = float(np.median(r[ok])) if ok.any() else 0.0
    median, p90, signed, shift = (np.full(C, np.nan) for _ in range(4))
    count = np.bincount(camera[ok], minlength=C).astype(np.int64)[:C]
    start = 0
    for c in range(C):
        m = len(dirs[c])
        rc, okc = r[start:start + m], ok[start:start + m]
        start += m
        if not okc.any() or not fp[c] > 0:
            continue
        px = (rc[okc] - offset) / fp[c]
        a = np.abs(px)
        median[c], p90[c], signed[c] = float(np.median(a)), float(np.percentile(a, 90)), float(np.median(px))
        if normals is not None:
            shift[c] = image_shift(np.asarray(normals[c], float)[okc], px)
    return SilhouetteHealth(median, p90, signed, shift, count, offset)


def image_shift(normals: np.ndarray, residual_px: np.ndarray, *, iterations: int = 5,
                huber_px: float = 0.25) -> float:
    """How far a camera's image is shifted, px: the length of the shift ``s`` whose normal
    component ``n . s`` (plus a constant, the camera's own uniform offset) best explains its
    residuals (robust least squares, Huber weights at ``huber_px``). NaN with fewer than
    :data:`MIN_RAYS` residuals.

    A camera turned about an axis across its optical axis (knocked, or mounted loose) shifts
    its image; its residuals are then ``n . s``: full where the contour is across the shift,
    zero where it runs along it. A closed contour has normals in every direction, so ``s``
    is well determined whatever the silhouette's shape. (A turn about the optical axis, or a
    scale, would also fit, but not on a round silhouette: there they move the contour along
    itself, and a fit would turn noise into a turn of a third of a pixel.)

    Parameters
    ----------
    normals : (M, 2) float
        Outward unit normals of the contour at the rays' contour points (image frame).
    residual_px : (M,) float
        Their silhouette residuals, px.
    """
    n = np.asarray(normals, float).reshape(-1, 2)
    r = np.asarray(residual_px, float).reshape(-1)
    good = np.isfinite(n).all(axis=1) & np.isfinite(r)
    n, r = n[good], r[good]
    if len(r) < MIN_RAYS:
        return float("nan")
    A = np.column_stack([n[:, 0], n[:, 1], np.ones(len(r))])
    w = np.ones(len(r))
    x = np.zeros(3)
    for _ in range(int(iterations)):
        Aw = A * w[:, None]
        x = np.linalg.solve(Aw.T @ A + 1e-9 * np.eye(3), Aw.T @ r)
        e = np.abs(r - A @ x)
        w = np.where(e <= huber_px, 1.0, huber_px / np.maximum(e, 1e-12))
    return float(np.hypot(x[0], x[1]))


def ray_min_distances(
    origins: np.ndarray,
    dirs: np.ndarray,
    t0: np.ndarray,
    t1: np.ndarray,
    sd_fn: Callable[[np.ndarray], np.ndarray],
    *,
    step_mm: float = 0.25,
    levels: int = 3,
) -> np.ndarray:
    """:func:`~inspector.kernels.bcps.ray_min_distance` for rays of many cameras at once: one
    origin per ray (M, 3); the same search (every 4 steps, then every step about the
    ``RAY_SEEDS`` lowest samples, then ``levels`` refinements 4 times finer each) and the
    same result, ray for ray (mm; NaN for a ray without range)."""
    O = np.asarray(origins, float).reshape(-1, 3)
    if len(O) != len(np.asarray(dirs, float).reshape(-1, 3)):
        raise ValueError(f"origins, dirs, t0 and t1 must have one row per ray, got {len(O)}, "
                         f"{len(np.asarray(dirs).reshape(-1, 3))}, {len(np.ravel(t0))}, {len(np.ravel(t1))}")
    return ray_min_search(O, dirs, t0, t1, sd_fn, step_mm=step_mm, levels=levels)


def flagged_cameras(figure_px: np.ndarray, rays: np.ndarray, threshold_px: float, min_rays: int = MIN_RAYS) -> np.ndarray:
    """Indices (K,) of the cameras whose ``figure_px`` (C,) (e.g. :attr:`SilhouetteHealth.shift_px`)
    exceeds ``threshold_px``, judged on at least ``min_rays`` residuals (``rays`` (C,)), worst first."""
    m = np.where(np.asarray(rays) >= min_rays, np.asarray(figure_px, float), np.nan)
    idx = np.flatnonzero(np.nan_to_num(m, nan=-np.inf) > threshold_px)
    return idx[np.argsort(-m[idx], kind="stable")]
