"""Silhouette residuals with their grazing points, and their Jacobians: the model of a rig
refined from the silhouettes of the parts it inspects (``inspector calibrate --refine``).

Every contour ray of a part grazes it. For the reference placed where the part is, the
ray's *silhouette residual* is its smallest signed distance to the reference along the ray,
``r = min_t sd(C + t d)`` (0 for a ray that grazes it, positive where the ray misses it,
negative where it cuts into it; :func:`~inspector.kernels.bcps.ray_min_distance`). Here the
minimum's place is kept too: the *grazing point* ``q = C + t* d`` and the surface normal
``n`` there (the distance's gradient, unit, outward).

By the envelope theorem the residual's first-order change under a change of the ray or of
the reference is the change of ``sd`` at the fixed grazing point:

* the camera turned about its centre by a small world rotation ``dθ`` (every ray direction
  turns: ``dd = dθ × d``) and its centre moved by ``dC``:
  ``dr = n · dC + ((q - C) × n) · dθ`` (:func:`camera_jacobian`);
* the part moved by a small world twist (``X -> X + ω × X + τ``): the reference's distance at
  ``q`` becomes ``sd(q - ω × q - τ)``, so ``dr = -n · τ - (q × n) · ω`` (:func:`pose_jacobian`);
* a ray direction changed by ``dd`` (focal length, principal point):
  ``dr = t* n · dd`` (:func:`intrinsics_jacobian`, with :func:`direction_derivatives`).

Where the minimum sits on a crease of the distance (a ray cutting through a convex edge: the
distance to one face on one side of the deepest point, to the other face beyond), the
gradient jumps; the derivative of the min-max is then the combination ``n = λ g₋ + (1 - λ) g₊``
of the gradients on either side that is perpendicular to the ray (Danskin), which
:func:`grazes` returns. On a smooth surface both sides agree and ``n`` is the gradient.

Arrays in, arrays out: the distance and its gradient are callables (world mm); no file, no
mesh library.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from inspector.kernels import camera as camk
from inspector.kernels.ray_search import sampler, seed_minimum

__all__ = [
    "Grazes",
    "ray_argmin_distance",
    "grazes",
    "camera_jacobian",
    "pose_jacobian",
    "intrinsics_jacobian",
    "direction_derivatives",
    "rotation_matrix",
    "turn_camera",
    "twist_pose",
    "INTRINSICS",
]

SignedDistance = Callable[[np.ndarray], np.ndarray]
Normal = Callable[[np.ndarray], np.ndarray]

#: The intrinsic parameters :func:`direction_derivatives` differentiates, in its column order.
INTRINSICS = ("fx", "fy", "cx", "cy")

def rotation_matrix(w: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) (axis times angle, rad) -> rotation matrix (3, 3) (Rodrigues)."""
    w = np.asarray(w, float).reshape(3)
    a = float(np.linalg.norm(w))
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if a < 1e-12:
        return np.eye(3) + W
    return np.eye(3) + np.sin(a) / a * W + (1.0 - np.cos(a)) / (a * a) * (W @ W)


def turn_camera(R: np.ndarray, t: np.ndarray, theta: np.ndarray, shift: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A camera (world -> camera ``R``, ``t``) turned about its optical centre by the world
    rotation vector ``theta`` (rad: every pixel's world ray direction ``d`` becomes
    ``exp(theta) d``) and its centre moved by ``shift`` (world mm); returns the new ``R``, ``t``."""
    R = np.asarray(R, float)
    C = camk.camera_centre(R, t) + np.asarray(shift, float).reshape(3)
    R2 = R @ rotation_matrix(theta).T
    return R2, -R2 @ C


def twist_pose(pose: np.ndarray, omega: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """A placement (4, 4, part -> world, maybe scaled) moved by the world rigid motion
    ``X -> exp(omega) X + tau`` (rad, mm): to first order ``X + omega × X + tau``."""
    M = np.eye(4)
    M[:3, :3] = rotation_matrix(omega)
    M[:3, 3] = np.asarray(tau, float).reshape(3)
    return M @ np.asarray(pose, float)


def ray_argmin_distance(
    origin: np.ndarray,
    dirs: np.ndarray,
    t0: np.ndarray,
    t1: np.ndarray,
    sd_fn: SignedDistance,
    *,
    step_mm: float = 0.25,
    levels: int = 5,
    guess: np.ndarray | None = None,
    window_mm: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Smallest signed distance along each ray and where it is (the search of
    :func:`~inspector.kernels.bcps.ray_min_distance`, which returns only the distance).

    The range is sampled every 4 steps, then every step about the 3 lowest samples (2 steps
    either side); the minimum is then bracketed by the steps either side of the lowest of
    those and narrowed by a golden-section search to ``step_mm / 4**levels`` (0.25 mm and 5
    levels: 0.24 um).

    Parameters
    ----------
    origin : (3,) or (M, 3) float
        Optical centre, mm (one for every ray, or one per ray: several cameras at once).
    dirs : (M, 3) float
        Unit ray directions.
    t0, t1 : (M,) float
        Where along each ray to look, mm from ``origin``; ``t0 > t1``: no range.
    sd_fn : callable
        ``(N, 3) world mm -> (N,)`` signed distance, mm (negative inside; NaN: far outside).
    step_mm, levels : float, int
        The search's coarse step and how many times 4 finer it ends.
    guess : (M,) float, optional
        Where each minimum was (e.g. before a small move of the ray or the surface; NaN: not
        known): the search is then only the golden section within ``window_mm`` of it (and
        the range), and the full search for the rays without one or whose minimum is at
        the window's edge.

    Returns
    -------
    r : (M,) float
        The smallest signed distance, mm; NaN for a ray without range or without a finite one.
    t : (M,) float
        Where along the ray it is, mm from ``origin``; NaN where ``r`` is.
    """
    d = np.asarray(dirs, float).reshape(-1, 3)
    a = np.asarray(t0, float).reshape(-1)
    b = np.asarray(t1, float).reshape(-1)
    if not (len(a) == len(b) == len(d)):
        raise ValueError(f"dirs, t0 and t1 must have one row per ray, got {len(d)}, {len(a)}, {len(b)}")
    if not step_mm > 0:
        raise ValueError(f"step_mm must be positive, got {step_mm!r}")
    r_out = np.full(len(d), np.nan)
    t_out = np.full(len(d), np.nan)
    has = np.isfinite(a) & np.isfinite(b) & (a <= b)
    o = _origins(origin, len(d))
    tol = step_mm / 4.0 ** int(levels)
    if guess is not None:
        gs = np.asarray(guess, float).reshape(-1)
        near = has & np.isfinite(gs)
        idx = np.flatnonzero(near)
        if len(idx):
            lo = np.maximum(gs[idx] - window_mm, a[idx])
            hi = np.minimum(gs[idx] + window_mm, b[idx])
            hi = np.maximum(hi, lo)
            t, s = _golden(o[idx], d[idx], lo, hi, sd_fn, tol)
            # A minimum at the window's edge (not the range's) moved farther: searched in full.
            edge = ((t <= lo + tol) & (lo > a[idx])) | ((t >= hi - tol) & (hi < b[idx]))
            fin = np.isfinite(s) & ~edge
            r_out[idx[fin]], t_out[idx[fin]] = s[fin], t[fin]
            near[idx[fin]] = True
            near[idx[~fin]] = False
        has &= ~near
    ok = np.flatnonzero(has)
    if not len(ok):
        return r_out, t_out
    o, d, a, b = o[ok], d[ok], a[ok], b[ok]
    tb, sb = seed_minimum(a, b, sampler(o, d, sd_fn), step_mm)
    t, s = _golden(o, d, np.maximum(tb - step_mm, a), np.minimum(tb + step_mm, b), sd_fn, tol)
    better = s < sb
    tb = np.where(better, t, tb)
    sb = np.where(better, s, sb)
    fin = np.isfinite(sb)
    r_out[ok[fin]] = sb[fin]
    t_out[ok[fin]] = tb[fin]
    return r_out, t_out


_INV_PHI = (np.sqrt(5.0) - 1.0) / 2.0


def _golden(o: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray, sd_fn: SignedDistance,
            tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Golden-section search of each ray's minimum in ``[lo, hi]`` (M,) to ``tol`` mm (rays
    from origins ``o`` (M, 3)); the best point seen, ends included: (t, sd), sd inf where
    none was finite."""
    lo, hi = np.asarray(lo, float).copy(), np.asarray(hi, float).copy()
    if not len(lo):
        return lo, np.zeros(0)

    def f(t: np.ndarray) -> np.ndarray:
        s = np.asarray(sd_fn(o + t[:, None] * d), float).reshape(-1)
        return np.where(np.isnan(s), np.inf, s)

    ends_t = np.stack([lo, hi], axis=1)
    ends_f = np.stack([f(lo), f(hi)], axis=1)
    x1 = hi - _INV_PHI * (hi - lo)
    x2 = lo + _INV_PHI * (hi - lo)
    f1, f2 = f(x1), f(x2)
    width = float(np.max(hi - lo))
    steps = int(np.ceil(np.log(width / tol) / -np.log(_INV_PHI))) if width > tol else 0
    for _ in range(steps):
        left = f1 <= f2  # the minimum is in [lo, x2]: x1 becomes the new x2
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        nx = np.where(left, hi - _INV_PHI * (hi - lo), lo + _INV_PHI * (hi - lo))
        fn = f(nx)
        x1, f1, x2, f2 = (np.where(left, nx, x2), np.where(left, fn, f2),
                          np.where(left, x1, nx), np.where(left, f1, fn))
    cand_t = np.concatenate([np.stack([x1, x2], axis=1), ends_t], axis=1)
    cand_f = np.concatenate([np.stack([f1, f2], axis=1), ends_f], axis=1)
    k = np.argmin(cand_f, axis=1)
    rows = np.arange(len(k))
    return cand_t[rows, k], cand_f[rows, k]


@dataclass(frozen=True, eq=False)
class Grazes:
    """Each ray's silhouette residual and where it is (NaN rows where ``ok`` is False).

    Attributes
    ----------
    r : (M,) float
        Smallest signed distance along the ray, mm.
    t : (M,) float
        Where along the ray, mm from the origin.
    q : (M, 3) float
        The grazing point, world mm.
    n : (M, 3) float
        The distance's (generalised) gradient there, perpendicular to the ray at a crease.
    ok : (M,) bool
        A finite minimum inside the range (one at either end of it is not a graze: the
        range cut the ray short).
    """

    r: np.ndarray
    t: np.ndarray
    q: np.ndarray
    n: np.ndarray
    ok: np.ndarray


def grazes(
    origin: np.ndarray,
    dirs: np.ndarray,
    t0: np.ndarray,
    t1: np.ndarray,
    sd_fn: SignedDistance,
    normal_fn: Normal,
    *,
    step_mm: float = 0.25,
    levels: int = 5,
    guess: np.ndarray | None = None,
    window_mm: float = 1.0,
) -> Grazes:
    """Each ray's silhouette residual, grazing point and normal (see the module docstring).

    Parameters
    ----------
    origin, dirs, t0, t1, sd_fn, step_mm, levels, guess, window_mm
        As :func:`ray_argmin_distance` (``origin`` (3,) or one per ray).
    normal_fn : callable
        ``(N, 3) world mm -> (N, 3)`` unit outward gradient of ``sd_fn`` (NaN: unknown).

    Returns
    -------
    Grazes
    """
    d = np.asarray(dirs, float).reshape(-1, 3)
    o = _origins(origin, len(d))
    r, t = ray_argmin_distance(o, d, t0, t1, sd_fn, step_mm=step_mm, levels=levels, guess=guess,
                               window_mm=window_mm)
    M = len(d)
    q = np.full((M, 3), np.nan)
    n = np.full((M, 3), np.nan)
    a = np.asarray(t0, float).reshape(-1)
    b = np.asarray(t1, float).reshape(-1)
    h = step_mm / 4.0 ** int(levels)
    ok = np.isfinite(r) & (t > a + 0.5 * h) & (t < b - 0.5 * h)
    idx = np.flatnonzero(ok)
    if len(idx):
        dd = d[idx]
        qq = o[idx] + t[idx, None] * dd
        # The gradient just before and just after the minimum (2 final steps: the crease,
        # if any, lies within one of it).
        g = np.asarray(normal_fn(np.concatenate([qq - 2.0 * h * dd, qq + 2.0 * h * dd, qq])), float).reshape(3, -1, 3)
        g_lo, g_hi, g_at = g
        s_lo = np.einsum("ij,ij->i", g_lo, dd)
        s_hi = np.einsum("ij,ij->i", g_hi, dd)
        span = s_hi - s_lo
        crease = (s_lo <= 0.0) & (s_hi >= 0.0) & (span > 1e-9)
        lam = np.where(crease, s_hi / np.where(crease, span, 1.0), 0.5)
        nn = np.where(crease[:, None], lam[:, None] * g_lo + (1.0 - lam[:, None]) * g_hi, g_at)
        good = np.isfinite(nn).all(axis=1)
        q[idx] = qq
        n[idx] = nn
        ok[idx[~good]] = False
    q[~ok] = np.nan
    n[~ok] = np.nan
    return Grazes(np.where(ok, r, np.nan), np.where(ok, t, np.nan), q, n, ok)


def camera_jacobian(origin: np.ndarray, q: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(M, 6) derivatives of the residuals of a camera's rays (``origin`` (3,), or (M, 3): each
    ray's camera centre) with respect to its turn about its centre (world rotation vector,
    rad; columns 0-2) and its centre's shift (world mm; columns 3-5): ``[(q - C) × n, n]``."""
    q = np.asarray(q, float).reshape(-1, 3)
    n = np.asarray(n, float).reshape(-1, 3)
    return np.concatenate([np.cross(q - _origins(origin, len(q)), n), n], axis=1)


def _origins(origin: np.ndarray, m: int) -> np.ndarray:
    """``origin`` (3,) or (m, 3) as (m, 3)."""
    o = np.asarray(origin, float)
    if o.shape == (3,):
        return np.broadcast_to(o, (m, 3))
    if o.shape != (m, 3):
        raise ValueError(f"origin must be (3,) or ({m}, 3), got {o.shape}")
    return o


def pose_jacobian(q: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(M, 6) derivatives of the residuals with respect to the part's world twist (rotation
    vector about the world origin, rad, columns 0-2; translation, mm, columns 3-5):
    ``[-(q × n), -n]``."""
    q = np.asarray(q, float).reshape(-1, 3)
    n = np.asarray(n, float).reshape(-1, 3)
    return -np.concatenate([np.cross(q, n), n], axis=1)


def intrinsics_jacobian(t: np.ndarray, n: np.ndarray, ddirs: np.ndarray) -> np.ndarray:
    """(M, P) derivatives of the residuals with respect to parameters of the ray directions:
    ``t* n · dd/dp``, with ``ddirs`` (M, 3, P) the unit directions' derivatives
    (:func:`direction_derivatives`)."""
    return np.asarray(t, float)[:, None] * np.einsum("ij,ijk->ik", np.asarray(n, float), np.asarray(ddirs, float))


def direction_derivatives(uv: np.ndarray, K: np.ndarray, dist: np.ndarray, R: np.ndarray,
                          rel_step: float = 1e-6) -> np.ndarray:
    """(M, 3, 4) derivatives of the unit world directions of the rays through pixels ``uv``
    (M, 2) with respect to ``fx, fy, cx, cy`` (:data:`INTRINSICS`; skew follows ``fx``'s
    ratio), by central differences of :func:`~inspector.kernels.camera.pixel_rays` (exact
    for the distortion too)."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    K = np.asarray(K, float)
    t = np.zeros(3)
    out = np.zeros((len(uv), 3, len(INTRINSICS)))
    scale = float(np.sqrt(K[0, 0] * K[1, 1]))
    for j, (row, col) in enumerate(((0, 0), (1, 1), (0, 2), (1, 2))):
        h = rel_step * scale
        Kp, Km = K.copy(), K.copy()
        Kp[row, col] += h
        Km[row, col] -= h
        _, dp = camk.pixel_rays(uv, Kp, dist, R, t)
        _, dm = camk.pixel_rays(uv, Km, dist, R, t)
        out[:, :, j] = (dp - dm) / (2.0 * h)
    return out
