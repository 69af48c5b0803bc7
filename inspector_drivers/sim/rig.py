"""Geometry of the simulated rig: cameras spread over a sphere, all looking at the origin.

Design
------
Two cameras on opposite sides of the part (``d_j = -d_i``) see mirror-identical
silhouettes (same projection axis), so the second one adds no information. The rig
therefore spreads ``n`` *axes* (lines through the origin) over the projective plane —
repulsion between each direction and both ``+d_j`` and ``-d_j`` — and only then picks
one sign per axis so that the cameras are balanced over the whole sphere (smallest
resultant ``|sum d_i|``).

Consequences (checked by ``tests/drivers/test_sim_render.py``):

* the smallest angle between any camera direction and any *other* camera's antipode,
  ``min_{i != j} angle(d_i, -d_j)``, is at least the smallest angle between two axes;
  for the default ``n=16, seed=0`` it is about 37 degrees (see
  :func:`min_antipode_angle_deg`), far from the 0 degrees of an antipodal pair;
* the smallest angle between two cameras is bounded by the same number;
* the cameras are not all in one hemisphere (the resultant is small compared to
  ``n``), and for the default rig there are cameras on both sides of every coordinate
  plane.

Everything is deterministic for a given ``seed`` (NumPy ``default_rng``).
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import product

import numpy as np

from inspector.model import Camera, Rig

__all__ = [
    "sphere_directions",
    "sphere_rig",
    "min_antipode_angle_deg",
    "look_at_rotation",
]

_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))  # ~137.5 degrees


def _spread_axes(n: int, rng: np.random.Generator, iterations: int = 1500) -> np.ndarray:
    """``n`` unit vectors whose axes (±d) repel each other; signs are arbitrary."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    if n < 2:
        return d
    eye = np.eye(n, dtype=bool)
    # Riesz-like energy sum_{i<j} |d_i - d_j|^-p + |d_i + d_j|^-p with a growing
    # exponent: small p spreads globally, large p maximises the smallest separation.
    for it in range(iterations):
        p = 2.0 + 10.0 * it / max(iterations - 1, 1)
        grad = np.zeros_like(d)
        for sgn in (1.0, -1.0):
            diff = d[:, None, :] - sgn * d[None, :, :]  # (n, n, 3)
            dist = np.linalg.norm(diff, axis=2)
            dist[eye] = np.inf
            # d/dd_i of |diff|^-p = -p |diff|^-(p+2) diff ; the force pushes along +diff
            w = dist ** (-(p + 2.0))
            grad += (w[:, :, None] * diff).sum(axis=1)
        # keep only the tangential component, take a normalised step
        grad -= (grad * d).sum(axis=1, keepdims=True) * d
        gmax = np.max(np.linalg.norm(grad, axis=1))
        if gmax == 0.0:
            break
        step = 0.05 * (1.0 - it / iterations) + 1e-3
        d += step * grad / gmax
        d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d


def _balance_signs(d: np.ndarray) -> np.ndarray:
    """Choose ``s_i in {+1, -1}`` minimising ``|sum s_i d_i|`` (first sign fixed to +1).

    Exhaustive for ``n <= 20``; for larger ``n`` a greedy start refined by single
    flips. Ties are broken by the first pattern found (deterministic).
    """
    n = len(d)
    if n <= 1:
        return d.copy()
    if n <= 20:
        signs = np.array(list(product((1.0, -1.0), repeat=n - 1)))  # (2^(n-1), n-1)
        res = signs @ d[1:] + d[0]
        best = int(np.argmin(np.einsum("ij,ij->i", res, res)))
        s = np.concatenate([[1.0], signs[best]])
    else:
        s = np.ones(n)
        acc = d[0].copy()
        for i in range(1, n):
            s[i] = -1.0 if np.dot(acc, d[i]) > 0 else 1.0
            acc += s[i] * d[i]
        improved = True
        while improved:
            improved = False
            r = (s[:, None] * d).sum(axis=0)
            for i in range(1, n):
                r2 = r - 2.0 * s[i] * d[i]
                if r2 @ r2 < r @ r - 1e-12:
                    s[i] = -s[i]
                    r = r2
                    improved = True
    return s[:, None] * d


def sphere_directions(n: int = 16, *, seed: int = 0) -> np.ndarray:
    """Unit directions (origin -> camera) of ``n`` cameras, shape ``(n, 3)``.

    Axes are spread on the projective plane (no two cameras opposite, nor close to
    opposite), then one sign per axis is chosen so that the resultant is as small as
    possible (cameras balanced over the whole sphere). Deterministic for ``seed``.
    """
    if n < 1:
        raise ValueError("n must be >= 1")
    rng = np.random.default_rng(seed)
    d = _balance_signs(_spread_axes(int(n), rng))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def min_antipode_angle_deg(directions: np.ndarray) -> float:
    """``min_{i != j}`` angle between ``d_i`` and ``-d_j``, degrees (180 for one camera)."""
    d = np.asarray(directions, float)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    if len(d) < 2:
        return 180.0
    c = np.clip(d @ (-d).T, -1.0, 1.0)
    np.fill_diagonal(c, -1.0)  # exclude i == j (angle 180)
    return float(np.degrees(np.arccos(c.max())))


def look_at_rotation(direction: np.ndarray, roll: float = 0.0) -> np.ndarray:
    """World -> camera rotation of a camera at ``direction * r`` looking at the origin.

    The camera ``z`` axis is ``-direction``; ``x`` and ``y`` complete a right-handed
    frame, then are rotated by ``roll`` radians about ``z``. Returns a proper rotation.
    """
    z = -np.asarray(direction, float)
    z = z / np.linalg.norm(z)
    ref = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(ref, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = np.cos(roll), np.sin(roll)
    xr = c * x + s * y
    yr = -s * x + c * y
    return np.stack([xr, yr, z])


def sphere_rig(
    n: int = 16,
    *,
    radius_mm: float = 400.0,
    width: int = 1024,
    height: int = 1024,
    mm_per_px: float = 0.1,
    dist: Sequence[float] | None = None,
    seed: int = 0,
) -> Rig:
    """A rig of ``n`` cameras on a sphere of ``radius_mm`` around the origin.

    Each camera looks at the origin; its focal length is ``radius_mm / mm_per_px``
    pixels so one pixel covers ``mm_per_px`` mm at the origin; the principal point is
    the image centre ``((width - 1) / 2, (height - 1) / 2)`` (pixel ``(0, 0)`` is the
    centre of the top-left pixel). The roll about the optical axis is ``i`` times the
    golden angle (arbitrary but deterministic). ``dist`` (``[k1, k2, p1, p2, k3]``,
    default none; a shorter list is padded with zeros) is shared by all cameras. Names are ``cam00``, ``cam01``, ...
    """
    dirs = sphere_directions(n, seed=seed)
    f = float(radius_mm) / float(mm_per_px)
    K = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
    dvec = np.zeros(5)
    if dist is not None:
        dl = np.ravel(np.asarray(dist, float))
        if dl.size > 5:
            raise ValueError("dist has at most 5 coefficients [k1, k2, p1, p2, k3]")
        dvec[: dl.size] = dl  # missing trailing coefficients are zero (OpenCV)
    cams = []
    for i, d in enumerate(dirs):
        R = look_at_rotation(d, roll=i * _GOLDEN_ANGLE)
        C = float(radius_mm) * d
        t = -R @ C
        cams.append(Camera(name=f"cam{i:02d}", width=int(width), height=int(height), K=K, dist=dvec, R=R, t=t))
    return Rig(tuple(cams))
