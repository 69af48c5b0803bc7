"""The search for the smallest signed distance along rays (kernels/ray_search.py), on a sphere
whose answer is known: a ray passing at distance p from the centre of a sphere of radius r
comes no closer than p - r (negative: it cuts through, as deep as r - p)."""

from __future__ import annotations

import numpy as np
import pytest

from inspector.kernels.ray_search import ray_min_search, refine_on_grid, sampler, seed_minimum

CENTRE = np.array([0.0, 0.0, 100.0])
RADIUS = 10.0


def sphere(X: np.ndarray) -> np.ndarray:
    return np.linalg.norm(X - CENTRE, axis=1) - RADIUS


def rays(p: np.ndarray, origin: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays from ``origin`` (default: 0) passing at ``p`` (M,) mm from the centre, and the range 60..140 mm."""
    origin = np.zeros(3) if origin is None else origin
    target = CENTRE + np.column_stack([p, np.zeros_like(p), np.zeros_like(p)])
    d = target - origin
    d /= np.linalg.norm(d, axis=1)[:, None]
    return d, np.full(len(p), 60.0), np.full(len(p), 140.0)


def passing_distance(origin: np.ndarray, d: np.ndarray) -> np.ndarray:
    v = CENTRE - origin
    return np.linalg.norm(v - (v @ d.T)[:, None] * d if d.ndim == 1 else v - (d @ v)[:, None] * d, axis=1)


def test_the_minimum_of_each_ray_is_the_passing_distance_minus_the_radius():
    p = np.array([0.0, 3.0, 9.5, 10.0, 10.7, 14.0])
    d, a, b = rays(p)
    got = ray_min_search(np.zeros(3), d, a, b, sphere, step_mm=0.25, levels=3)
    want = passing_distance(np.zeros(3), d) - RADIUS
    np.testing.assert_allclose(got, want, atol=2e-5)  # 0.25 mm / 4**3 = 4 um steps; the sphere is smooth


def test_one_origin_per_ray_gives_the_same_as_a_shared_one():
    p = np.linspace(0.0, 15.0, 31)
    d, a, b = rays(p)
    shared = ray_min_search(np.zeros(3), d, a, b, sphere)
    each = ray_min_search(np.zeros((len(p), 3)), d, a, b, sphere)
    np.testing.assert_array_equal(shared, each)


def test_no_range_and_far_rays_are_nan_and_shapes_are_checked():
    d, a, b = rays(np.array([2.0, 2.0]))
    b[1] = a[1] - 1.0  # no range
    far = ray_min_search(np.zeros(3), d, a, b, lambda X: np.full(len(X), np.nan))
    assert np.isnan(far).all()
    got = ray_min_search(np.zeros(3), d, a, b, sphere)
    assert np.isfinite(got[0]) and np.isnan(got[1])
    with pytest.raises(ValueError, match="one row per ray"):
        ray_min_search(np.zeros(3), d, a[:1], b, sphere)
    with pytest.raises(ValueError, match="origins must be"):
        ray_min_search(np.zeros((3, 3)), d, a, b, sphere)
    with pytest.raises(ValueError, match="step_mm"):
        ray_min_search(np.zeros(3), d, a, b, sphere, step_mm=0.0)


def test_seeds_then_the_grid_each_narrow_the_minimum():
    p = np.array([10.3, 12.0])
    d, a, b = rays(p)
    sample = sampler(np.zeros((2, 3)), d, sphere)
    t0, s0 = seed_minimum(a, b, sample, 0.25)
    want = passing_distance(np.zeros(3), d) - RADIUS
    assert (s0 >= want - 1e-12).all() and (s0 - want < 0.01).all()  # within a step's sag
    _, s1 = refine_on_grid(t0, s0, sample, 0.25, 3)
    assert (s1 <= s0).all() and np.abs(s1 - want).max() < np.abs(s0 - want).max()
