"""Silhouette residuals, grazing points and their Jacobians against finite differences,
on an exact sphere and an exact box (analytic signed distances)."""

from __future__ import annotations

import numpy as np
import pytest

from inspector.kernels import camera as camk
from inspector.kernels import silhouette_fit as sf

HALF = np.array([15.0, 10.0, 8.0])  # the box's half sides, mm
RADIUS = 12.0


def _sphere(X):
    return np.linalg.norm(X, axis=1) - RADIUS


def _sphere_normal(X):
    return X / np.linalg.norm(X, axis=1, keepdims=True)


def _box(X):
    q = np.abs(X) - HALF
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)


def _box_normal(X):
    q = np.abs(X) - HALF
    out = np.maximum(q, 0.0)
    norm = np.linalg.norm(out, axis=1)
    inside = norm <= 0.0
    k = np.argmax(q, axis=1)
    face = np.zeros_like(X)
    face[np.arange(len(X)), k] = 1.0
    g = np.where(inside[:, None], face, out / np.where(inside, 1.0, norm)[:, None])
    return g * np.sign(X)


def _placed(sd, normal, pose):
    """The shape placed by ``pose`` (part -> world, rigid)."""
    R, t = pose[:3, :3], pose[:3, 3]

    def sd_w(X):
        return sd((X - t) @ R)

    def n_w(X):
        return normal((X - t) @ R) @ R.T

    return sd_w, n_w


def _camera(direction, dist=300.0, f=3000.0, size=1024):
    z = -np.asarray(direction, float) / np.linalg.norm(direction)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    C = -z * dist
    K = np.array([[f, 0.0, (size - 1) / 2 + 7.0], [0.0, 1.01 * f, (size - 1) / 2 - 5.0], [0.0, 0.0, 1.0]])
    return K, R, -R @ C


def _near_grazing(sd, K, R, t, rng, n=4000, band=0.4):
    """Pixels whose rays come within ``band`` mm of grazing the shape (either side)."""
    C = camk.camera_centre(R, t)
    P = rng.uniform(-1.3, 1.3, size=(n, 3)) * max(HALF.max(), RADIUS)
    uv, _ = camk.project(P, K, np.zeros(5), R, t)
    _, d = camk.pixel_rays(uv, K, np.zeros(5), R, t)
    r, _ = sf.ray_argmin_distance(C, d, np.full(n, 250.0), np.full(n, 350.0), sd, step_mm=0.25, levels=8)
    keep = np.isfinite(r) & (np.abs(r) < band) & (np.abs(r) > 1e-3)
    return uv[keep]


def _residuals(sd, normal, K, R, t, uv):
    C, d = camk.pixel_rays(uv, K, np.zeros(5), R, t)
    m = len(d)
    return sf.grazes(C, d, np.full(m, 250.0), np.full(m, 350.0), sd, normal, step_mm=0.25, levels=9)


SHAPES = {"sphere": (_sphere, _sphere_normal), "box": (_box, _box_normal)}
POSE = np.eye(4)
POSE[:3, :3] = sf.rotation_matrix(np.array([0.3, -0.5, 0.2]))
POSE[:3, 3] = [2.0, -3.0, 1.5]


def _check(analytic, numeric, fwd, bwd, scale):
    """The analytic derivative matches the central difference where the residual is smooth
    (both one-sided differences agree), on nearly every ray."""
    smooth = np.abs(fwd - bwd) < 0.02 * scale
    assert smooth.mean() > 0.8, smooth.mean()
    err = np.abs(analytic[smooth] - numeric[smooth])
    assert np.percentile(err, 95) < 2e-3 * scale, (np.percentile(err, 95), scale)
    assert np.median(err) < 5e-4 * scale


@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_camera_jacobian_matches_finite_differences(shape):
    rng = np.random.default_rng(1)
    sd, normal = _placed(*SHAPES[shape], POSE)
    K, R, t = _camera([0.4, -0.7, 0.6])
    uv = _near_grazing(sd, K, R, t, rng)
    assert len(uv) > 100
    g = _residuals(sd, normal, K, R, t, uv)
    ok = g.ok
    C = camk.camera_centre(R, t)
    J = sf.camera_jacobian(C, g.q, g.n)
    for k in range(6):
        eps = 2e-5 if k < 3 else 5e-3  # rad, mm
        rs = []
        for s in (-1.0, 0.0, 1.0):
            v = np.zeros(6)
            v[k] = s * eps
            R2, t2 = sf.turn_camera(R, t, v[:3], v[3:])
            rs.append(_residuals(sd, normal, K, R2, t2, uv).r)
        ok2 = ok & np.isfinite(rs[0]) & np.isfinite(rs[2])
        num = (rs[2] - rs[0]) / (2 * eps)
        fwd, bwd = (rs[2] - rs[1]) / eps, (rs[1] - rs[0]) / eps
        scale = 300.0 if k < 3 else 1.0
        _check(J[ok2, k], num[ok2], fwd[ok2], bwd[ok2], scale)


@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_pose_jacobian_matches_finite_differences(shape):
    rng = np.random.default_rng(2)
    base_sd, base_n = SHAPES[shape]
    sd, normal = _placed(base_sd, base_n, POSE)
    K, R, t = _camera([-0.5, 0.2, 0.8])
    uv = _near_grazing(sd, K, R, t, rng)
    g = _residuals(sd, normal, K, R, t, uv)
    J = sf.pose_jacobian(g.q, g.n)
    for k in range(6):
        eps = 2e-5 if k < 3 else 5e-3
        rs = []
        for s in (-1.0, 0.0, 1.0):
            v = np.zeros(6)
            v[k] = s * eps
            sd2, n2 = _placed(base_sd, base_n, sf.twist_pose(POSE, v[:3], v[3:]))
            rs.append(_residuals(sd2, n2, K, R, t, uv).r)
        ok = g.ok & np.isfinite(rs[0]) & np.isfinite(rs[2])
        num = (rs[2] - rs[0]) / (2 * eps)
        _check(J[ok, k], num[ok], ((rs[2] - rs[1]) / eps)[ok], ((rs[1] - rs[0]) / eps)[ok], 30.0 if k < 3 else 1.0)


@pytest.mark.parametrize("dist", [np.zeros(5), np.array([-0.08, 0.05, 0.001, -0.002, 0.0])])
def test_intrinsics_jacobian_matches_finite_differences(dist):
    rng = np.random.default_rng(3)
    sd, normal = _placed(_box, _box_normal, POSE)
    K, R, t = _camera([0.1, 0.9, -0.3])
    uv = _near_grazing(sd, K, R, t, rng)
    C, d = camk.pixel_rays(uv, K, dist, R, t)
    m = len(d)
    lo, hi = np.full(m, 250.0), np.full(m, 350.0)
    g = sf.grazes(C, d, lo, hi, sd, normal, step_mm=0.25, levels=9)
    J = sf.intrinsics_jacobian(g.t, g.n, sf.direction_derivatives(uv, K, dist, R))
    for k, (row, col) in enumerate(((0, 0), (1, 1), (0, 2), (1, 2))):
        eps = 0.05  # px
        rs = []
        for s in (-1.0, 0.0, 1.0):
            K2 = K.copy()
            K2[row, col] += s * eps
            _, d2 = camk.pixel_rays(uv, K2, dist, R, t)
            rs.append(sf.ray_argmin_distance(C, d2, lo, hi, sd, step_mm=0.25, levels=9)[0])
        ok = g.ok & np.isfinite(rs[0]) & np.isfinite(rs[2])
        num = (rs[2] - rs[0]) / (2 * eps)
        _check(J[ok, k], num[ok], ((rs[2] - rs[1]) / eps)[ok], ((rs[1] - rs[0]) / eps)[ok], 0.1)


def test_grazes_on_a_sphere_are_exact():
    """For a sphere the residual is the ray's distance to the centre minus the radius, the
    grazing point the closest point of the ray and the normal the radial direction."""
    rng = np.random.default_rng(4)
    C = np.array([0.0, -300.0, 20.0])
    target = rng.uniform(-14.0, 14.0, size=(500, 3))
    d = target - C
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    m = len(d)
    g = sf.grazes(C, d, np.full(m, 250.0), np.full(m, 350.0), _sphere, _sphere_normal, levels=6)
    tc = -(C @ d.T)
    closest = C + tc[:, None] * d
    expect = np.linalg.norm(closest, axis=1) - RADIUS
    outside = expect > 0.0  # inside, the minimum is the deepest point: the same point here
    assert g.ok.all()
    assert np.abs(g.r - expect).max() < 1e-6
    assert np.abs(g.t - tc)[outside].max() < 1e-3
    np.testing.assert_allclose(g.n, closest / np.linalg.norm(closest, axis=1, keepdims=True), atol=1e-3)


def test_a_crease_normal_is_perpendicular_to_the_ray():
    """A ray cutting through the box's edge: the deepest point is on the bisector, and the
    normal returned is the combination of the two faces' perpendicular to the ray."""
    C = np.array([0.0, -300.0, 0.0])
    # Through the edge x = 15, y = -10, a little inside, slanted.
    aim = np.array([15.0 - 0.2, -10.0 + 0.1, 0.0])
    d = (aim - C) / np.linalg.norm(aim - C)
    g = sf.grazes(C, d[None], np.array([250.0]), np.array([350.0]), _box, _box_normal, levels=8)
    assert g.ok[0] and g.r[0] < 0
    assert abs(float(g.n[0] @ d)) < 1e-6
    assert g.n[0][0] > 0 and g.n[0][1] < 0


def test_no_range_and_range_end_are_not_grazes():
    C = np.array([0.0, -300.0, 0.0])
    d = np.array([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    g = sf.grazes(C, d, np.array([1.0, 250.0, 250.0]), np.array([0.0, 280.0, 350.0]), _box, _box_normal)
    assert list(g.ok) == [False, False, True]
    assert np.isnan(g.r[:2]).all() and abs(g.r[2] + 8.0) < 1e-6  # the ray through the centre


def test_turn_camera_and_twist_pose_conventions():
    K, R, t = _camera([0.3, 0.4, 0.5])
    theta = np.array([1e-3, -2e-3, 5e-4])
    R2, t2 = sf.turn_camera(R, t, theta, np.zeros(3))
    np.testing.assert_allclose(camk.camera_centre(R2, t2), camk.camera_centre(R, t), atol=1e-9)
    uv = np.array([[100.0, 200.0], [700.0, 400.0]])
    _, d = camk.pixel_rays(uv, K, np.zeros(5), R, t)
    _, d2 = camk.pixel_rays(uv, K, np.zeros(5), R2, t2)
    np.testing.assert_allclose(d2, d @ sf.rotation_matrix(theta).T, atol=1e-12)
    P = sf.twist_pose(np.eye(4), theta, np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(P[:3, :3], sf.rotation_matrix(theta))
    assert sf.rotation_matrix(np.zeros(3)).tolist() == np.eye(3).tolist()


def test_a_search_near_a_guess_finds_the_full_search_minimum():
    """After a small move, each ray is searched near its last minimum; a minimum that left the
    window is searched in full again."""
    rng = np.random.default_rng(5)
    sd, normal = _placed(_box, _box_normal, POSE)
    K, R, t = _camera([0.3, -0.4, 0.7])
    uv = _near_grazing(sd, K, R, t, rng)
    C, d = camk.pixel_rays(uv, K, np.zeros(5), R, t)
    m = len(d)
    lo, hi = np.full(m, 250.0), np.full(m, 350.0)
    r, tt = sf.ray_argmin_distance(C, d, lo, hi, sd, levels=6)
    R2, t2 = sf.turn_camera(R, t, np.array([2e-4, -1e-4, 0.0]), np.zeros(3))
    C2, d2 = camk.pixel_rays(uv, K, np.zeros(5), R2, t2)
    full, _ = sf.ray_argmin_distance(C2, d2, lo, hi, sd, levels=6)
    near, _ = sf.ray_argmin_distance(C2, d2, lo, hi, sd, levels=6, guess=tt, window_mm=0.75)
    ok = np.isfinite(full)
    assert np.isfinite(near[ok]).all()
    assert np.abs(near[ok] - full[ok]).max() < 1e-4
    # A guess far from the minimum (beyond the window): found by the full search all the same.
    far, _ = sf.ray_argmin_distance(C2, d2, lo, hi, sd, levels=6, guess=tt + 20.0, window_mm=0.75)
    assert np.abs(far[ok] - full[ok]).max() < 1e-4


def test_several_cameras_in_one_search():
    """One origin per ray (rays of several cameras at once) gives each camera's own result."""
    rng = np.random.default_rng(6)
    sd, normal = _placed(_sphere, _sphere_normal, POSE)
    parts = []
    for direction in ([0.3, -0.4, 0.7], [-0.8, 0.1, 0.2]):
        K, R, t = _camera(direction)
        uv = _near_grazing(sd, K, R, t, rng, n=1000)
        C, d = camk.pixel_rays(uv, K, np.zeros(5), R, t)
        parts.append((C, d))
    one = [sf.grazes(C, d, np.full(len(d), 250.0), np.full(len(d), 350.0), sd, normal) for C, d in parts]
    origins = np.concatenate([np.broadcast_to(C, d.shape) for C, d in parts])
    dirs = np.concatenate([d for _, d in parts])
    both = sf.grazes(origins, dirs, np.full(len(dirs), 250.0), np.full(len(dirs), 350.0), sd, normal)
    np.testing.assert_allclose(both.r, np.concatenate([g.r for g in one]), atol=1e-9)
    J = sf.camera_jacobian(origins, both.q, both.n)
    np.testing.assert_allclose(J[: len(parts[0][1])], sf.camera_jacobian(parts[0][0], one[0].q, one[0].n), atol=1e-9)
    with pytest.raises(ValueError):
        sf.ray_argmin_distance(np.zeros((2, 3)), dirs, np.full(len(dirs), 250.0), np.full(len(dirs), 350.0), sd)
