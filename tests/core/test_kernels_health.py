"""Calibration health kernel (``inspector.kernels.health``) on exact synthetic rays."""

from __future__ import annotations

import numpy as np
import pytest

from inspector.kernels import bcps as bk
from inspector.kernels.health import MIN_RAYS, flagged_cameras, image_shift, ray_min_distances, silhouette_residuals

R = 15.0  # the reference: a sphere of radius R about the origin


def _sphere(X: np.ndarray) -> np.ndarray:
    return np.linalg.norm(X, axis=1) - R


def _grazing(centre: np.ndarray, miss: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rays from ``centre`` (3,) whose closest point to the origin is at ``R + miss[i]``
    (M,), spread round the sphere's outline: (origin, dirs, t0, t1), the range 20 mm either
    side of the closest point."""
    C = np.asarray(centre, float)
    D = float(np.linalg.norm(C))
    w = -C / D  # towards the sphere
    a = np.cross(w, [0.0, 0.0, 1.0] if abs(w[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(w, a)
    phi = np.linspace(0.0, 2.0 * np.pi, len(miss), endpoint=False)
    rho = R + np.asarray(miss, float)
    # The foot Q of each ray: Q . (Q - C) = 0 with |Q| = rho: its component along C is rho^2 / D.
    along = rho**2 / D
    across = np.sqrt(rho**2 - along**2)
    Q = (along[:, None] * (C / D)[None, :] + across[:, None] * (np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b))
    d = Q - C
    t = np.linalg.norm(d, axis=1)
    return C, d / t[:, None], t - 20.0, t + 20.0


def _rig(misses: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    centres = [400.0 * np.array([np.cos(k), np.sin(k), 0.3 * (-1) ** k]) for k in range(len(misses))]
    return [_grazing(c, m) for c, m in zip(centres, misses)]


def test_grazing_rays_are_built_right():
    o, d, a, b = _grazing(np.array([0.0, -400.0, 50.0]), np.full(40, 0.1))
    assert np.allclose(bk.ray_min_distance(o, d, a, b, _sphere), 0.1, atol=1e-4)


def test_each_camera_is_measured_against_the_others_in_its_own_pixels():
    rng = np.random.default_rng(0)
    misses = [rng.normal(0.02, 0.001, 64) for _ in range(6)]  # every camera: 0.02 mm out (a size offset)
    misses[3] = misses[3] + 0.2  # one camera: its rays 0.2 mm farther out than the others'
    fp = np.array([0.1, 0.1, 0.1, 0.05, 0.1, 0.2])
    h = silhouette_residuals(_rig(misses), _sphere, fp)
    assert h.offset_mm == pytest.approx(0.02, abs=0.002)  # the common offset is not a camera's fault
    assert h.median_px[3] == pytest.approx(0.2 / 0.05, rel=0.02)  # 4 px at its 0.05 mm footprint
    assert h.signed_px[3] == pytest.approx(4.0, rel=0.02)
    others = np.delete(np.arange(6), 3)
    assert np.all(h.median_px[others] < 0.05) and np.all(h.p90_px[others] < 0.05)
    assert np.all(h.rays == 64) and np.all(np.isnan(h.shift_px))  # no normals: no shift
    assert list(flagged_cameras(h.median_px, h.rays, 0.5)) == [3]


def test_a_camera_without_rays_is_not_judged():
    misses = [np.zeros(32), np.zeros(0), np.zeros(MIN_RAYS - 1) + 0.5, np.zeros(32)]
    h = silhouette_residuals(_rig(misses), _sphere, [0.1] * 4)
    assert h.rays.tolist() == [32, 0, MIN_RAYS - 1, 32] and np.isnan(h.median_px[1])
    assert h.median_px[2] == pytest.approx(5.0, rel=0.01)
    assert flagged_cameras(h.median_px, h.rays, 0.3).tolist() == []  # too few rays to judge cam 2
    with pytest.raises(ValueError, match="one value per camera"):
        silhouette_residuals(_rig(misses), _sphere, [0.1] * 3)


def test_the_batched_search_is_ray_min_distance_ray_for_ray():
    rng = np.random.default_rng(1)
    rays = _rig([rng.uniform(-0.3, 0.5, 50) for _ in range(3)])
    rays[1] = (rays[1][0], rays[1][1], rays[1][2], rays[1][2] - 1.0)  # no range: NaN
    got = ray_min_distances(np.concatenate([np.broadcast_to(o, d.shape) for o, d, _, _ in rays]),
                            np.concatenate([d for _, d, _, _ in rays]), np.concatenate([a for *_, a, _ in rays]),
                            np.concatenate([b for *_, b in rays]), _sphere)
    want = np.concatenate([bk.ray_min_distance(o, d, a, b, _sphere) for o, d, a, b in rays])
    assert np.isnan(got[50:100]).all()
    np.testing.assert_allclose(got, want, atol=1e-9, equal_nan=True)


@pytest.mark.parametrize("shape", ["circle", "long rectangle"])
def test_the_image_shift_does_not_depend_on_the_silhouette_shape(shape):
    """A shift along a long straight contour moves only the short ends: most residuals stay 0,
    the median of |residual| misses it, the fitted shift does not."""
    rng = np.random.default_rng(2)
    if shape == "circle":
        a = np.linspace(0, 2 * np.pi, 64, endpoint=False)
        n = np.column_stack([np.cos(a), np.sin(a)])
    else:  # 200 x 20 px: 180 of 200 contour points on the long sides
        n = np.repeat([[0.0, 1.0], [0.0, -1.0], [1.0, 0.0], [-1.0, 0.0]], [29, 29, 3, 3], axis=0)
    s = np.array([1.0, 0.0])  # 1 px along x: along the rectangle's long sides
    r = n @ s + rng.normal(0, 0.03, len(n))
    assert image_shift(n, r) == pytest.approx(1.0, abs=0.05)
    assert image_shift(n, rng.normal(0, 0.03, len(n))) < 0.05
    if shape == "long rectangle":
        assert np.median(np.abs(r)) < 0.1
    assert np.isnan(image_shift(n[:MIN_RAYS - 1], r[:MIN_RAYS - 1]))


def test_the_shift_ignores_a_few_outliers():
    a = np.linspace(0, 2 * np.pi, 80, endpoint=False)
    n = np.column_stack([np.cos(a), np.sin(a)])
    r = n @ np.array([0.0, 0.8])
    r[:6] += 5.0  # a dent seen on six rays
    assert image_shift(n, r) == pytest.approx(0.8, abs=0.05)
