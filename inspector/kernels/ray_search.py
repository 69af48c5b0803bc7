"""The smallest signed distance along rays: the search shared by the silhouette residual
(:func:`inspector.kernels.bcps.ray_min_distance`), the calibration health
(:func:`inspector.kernels.health.ray_min_distances`) and the silhouette fit
(:func:`inspector.kernels.silhouette_fit.ray_argmin_distance`).

A contour ray grazes the part, so the signed distance along it dips to (about) zero once, at
the grazing point, or has a sharp minimum at an edge. The search samples the range every 4
steps, then every step about the :data:`RAY_SEEDS` lowest samples (2 steps either side): the
distance changes by at most the distance moved, so the minimum lies near them. Its callers
then narrow the best sample (:func:`refine_on_grid`, or a golden section). Pure array code:
the signed distance is a callable ``(N, 3) world mm -> (N,) mm`` (negative inside, NaN far
outside, read as +inf).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["RAY_SEEDS", "Sampler", "sampler", "seed_minimum", "refine_on_grid", "ray_min_search"]

#: How many of the coarse samples along a ray are looked at more closely.
RAY_SEEDS = 3

#: ``(rows, t) -> sd``: the signed distance at ``t`` along rays ``rows`` (same shape), inf where NaN.
Sampler = Callable[[np.ndarray, np.ndarray], np.ndarray]


def sampler(origins: np.ndarray, dirs: np.ndarray, sd_fn: Callable[[np.ndarray], np.ndarray]) -> Sampler:
    """The :data:`Sampler` of rays from ``origins`` (M, 3) along ``dirs`` (M, 3), mm."""

    def sample(rows: np.ndarray, tt: np.ndarray) -> np.ndarray:
        flat = tt.reshape(-1)
        r = np.asarray(rows).reshape(-1)
        sd = np.asarray(sd_fn(origins[r] + flat[:, None] * dirs[r]), float).reshape(tt.shape)
        return np.where(np.isnan(sd), np.inf, sd)

    return sample


def seed_minimum(a: np.ndarray, b: np.ndarray, sample: Sampler, step_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """The lowest sample of each ray's range ``[a, b]`` (M,) (mm, ``a <= b`` finite): every 4
    steps, then every step about the :data:`RAY_SEEDS` lowest of those. Returns ``(t, sd)``
    (M,), sd inf where no sample was finite."""
    m = len(a)
    rows = np.arange(m)
    big = 4.0 * step_mm
    n = int(np.ceil(float(np.max(b - a)) / big)) + 1
    tt = a[:, None] + big * np.arange(n)[None, :]
    inside = tt <= b[:, None] + 1e-12  # ragged: only the samples inside each range
    sd = np.full(tt.shape, np.inf)
    sd[inside] = sample(np.broadcast_to(rows[:, None], tt.shape)[inside], tt[inside])
    k = min(RAY_SEEDS, n)
    seeds = np.argpartition(sd, k - 1, axis=1)[:, :k] if n > k else np.broadcast_to(np.arange(n), (m, n))
    ts = np.take_along_axis(tt, seeds, axis=1)[:, :, None] + step_mm * np.arange(-2, 3)[None, None, :]
    ts = np.clip(ts, a[:, None, None], b[:, None, None]).reshape(m, -1)
    sd = np.where(np.isfinite(np.take_along_axis(sd, seeds, axis=1)).repeat(5, axis=1),
                  sample(np.broadcast_to(rows[:, None], ts.shape), ts), np.inf)
    kbest = np.argmin(sd, axis=1)
    return ts[rows, kbest], sd[rows, kbest]


def refine_on_grid(tb: np.ndarray, sb: np.ndarray, sample: Sampler, step_mm: float,
                   levels: int) -> tuple[np.ndarray, np.ndarray]:
    """``levels`` times: 9 samples about each ray's best ``(tb, sb)`` (M,), each level 4
    times finer than the last (``step_mm / 4`` first); the best kept. Returns ``(t, sd)``."""
    rows = np.arange(len(tb))
    h = step_mm
    offsets = np.arange(-4, 5, dtype=float)
    for _ in range(int(levels)):
        h /= 4.0
        tt = tb[:, None] + h * offsets[None, :]
        sd = sample(np.broadcast_to(rows[:, None], tt.shape), tt)
        kbest = np.argmin(sd, axis=1)
        better = sd[rows, kbest] < sb
        tb = np.where(better, tt[rows, kbest], tb)
        sb = np.where(better, sd[rows, kbest], sb)
    return tb, sb


def ray_min_search(origins: np.ndarray, dirs: np.ndarray, t0: np.ndarray, t1: np.ndarray,
                   sd_fn: Callable[[np.ndarray], np.ndarray], *, step_mm: float = 0.25,
                   levels: int = 3) -> np.ndarray:
    """Smallest signed distance along each ray (:func:`seed_minimum`, then
    :func:`refine_on_grid`: 0.25 mm and 3 levels end at 4 um).

    Parameters
    ----------
    origins : (3,) or (M, 3) float
        Optical centre, mm: one for every ray, or one per ray (several cameras at once).
    dirs : (M, 3) float
        Unit ray directions.
    t0, t1 : (M,) float
        Where along each ray to look, mm from its origin; ``t0 > t1``: no range.
    sd_fn : callable
        ``(N, 3) world mm -> (N,)`` signed distance, mm (negative inside; NaN: far outside).
    step_mm, levels : float, int
        The coarse step and the number of refinements.

    Returns
    -------
    (M,) float
        mm; NaN for a ray without range or without a finite distance.
    """
    d = np.asarray(dirs, float).reshape(-1, 3)
    a = np.asarray(t0, float).reshape(-1)
    b = np.asarray(t1, float).reshape(-1)
    if not (len(a) == len(b) == len(d)):
        raise ValueError(f"dirs, t0 and t1 must have one row per ray, got {len(d)}, {len(a)}, {len(b)}")
    o = np.asarray(origins, float)
    if o.shape == (3,):
        o = np.broadcast_to(o, d.shape)
    elif o.shape != d.shape:
        raise ValueError(f"origins must be (3,) or ({len(d)}, 3), got {o.shape}")
    if not step_mm > 0:
        raise ValueError(f"step_mm must be positive, got {step_mm!r}")
    out = np.full(len(d), np.nan)
    ok = np.flatnonzero(a <= b)
    if not len(ok):
        return out
    sample = sampler(o[ok], d[ok], sd_fn)
    tb, sb = seed_minimum(a[ok], b[ok], sample, step_mm)
    _, sb = refine_on_grid(tb, sb, sample, step_mm, levels)
    out[ok] = np.where(np.isfinite(sb), sb, np.nan)
    return out
