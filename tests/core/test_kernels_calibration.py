"""Calibration kernels on exact synthetic observations: derivatives, recovery, covariance,
rejection of a biased view, frames and the comparison of two rigs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from inspector.kernels import calibration as kc
from inspector.kernels import camera as camk
from inspector.model import Camera


def _look_at(centre: np.ndarray, roll: float) -> np.ndarray:
    z = -centre / np.linalg.norm(centre)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # world -> camera rows
    return Rotation.from_rotvec(z * 0 + np.array([0, 0, roll])).as_matrix() @ R


def _scene(n_cams=5, n_poses=8, noise=0.05, seed=0, f=2000.0, size=512):
    """Cameras on a sphere of 400 mm looking at the origin, a 3D target (points on three
    faces of a 30 mm cube) in random poses, observed with Gaussian noise (px)."""
    rng = np.random.default_rng(seed)
    g = np.linspace(-12.0, 12.0, 5)
    a, b = np.meshgrid(g, g)
    face = np.stack([a.ravel(), b.ravel()], 1)
    obj = np.concatenate([np.c_[face, np.full(25, 15.0)], np.c_[np.full(25, 15.0), face], np.c_[face[:, 0], np.full(25, 15.0), face[:, 1]]])
    cams = []
    for i in range(n_cams):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        C = 400.0 * d
        R = _look_at(C, rng.uniform(0, 6))
        K = np.array([[f * (1 + 0.01 * rng.normal()), 0, size / 2 + rng.normal() * 5], [0, f * (1 + 0.01 * rng.normal()), size / 2 + rng.normal() * 5],
                      [0, 0, 1]])
        dist = np.array([rng.uniform(0.05, 0.12), 0.0, rng.normal() * 1e-3, rng.normal() * 1e-3, 0.0])
        cams.append(Camera(f"c{i}", size, size, K, dist, R, -R @ C))
    poses = []
    for _ in range(n_poses):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        T[:3, 3] = rng.uniform(-5, 5, 3)
        poses.append(T)
    cam, pose, pt, uv = [], [], [], []
    for q, T in enumerate(poses):
        Xw = obj @ T[:3, :3].T + T[:3, 3]
        for c, cm in enumerate(cams):
            u, z = cm.project(Xw)
            # points on faces turned towards the camera only
            normals = np.repeat(np.array([[0, 0, 1.0], [1.0, 0, 0], [0, 1.0, 0]]) @ T[:3, :3].T, 25, axis=0)
            vis = np.einsum("ij,ij->i", normals, cm.centre - Xw) > 0.3 * np.linalg.norm(cm.centre - Xw, axis=1)
            cam += [c] * int(vis.sum())
            pose += [q] * int(vis.sum())
            pt += list(np.flatnonzero(vis))
            uv.append(u[vis] + rng.normal(size=(int(vis.sum()), 2)) * noise)
    return cams, poses, obj, np.array(cam), np.array(pose), np.array(pt), np.concatenate(uv)


def _params(cams, poses, rng=None, perturb=0.0):
    intr = np.array([[c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2], *c.dist] for c in cams])
    cr = np.array([kc.rotvec(c.R) for c in cams])
    ct = np.array([c.t for c in cams])
    pr = np.array([kc.rotvec(T[:3, :3]) for T in poses])
    pt = np.array([T[:3, 3] for T in poses])
    if perturb:
        intr[:, :2] *= 1 + rng.normal(size=(len(cams), 2)) * 0.01 * perturb
        intr[:, 2:4] += rng.normal(size=(len(cams), 2)) * 3 * perturb
        intr[:, 4] = 0.0
        cr = cr + rng.normal(size=cr.shape) * 2e-3 * perturb
        ct = ct + rng.normal(size=ct.shape) * 1.0 * perturb
        pr[1:] += rng.normal(size=pr[1:].shape) * 2e-3 * perturb
        pt[1:] += rng.normal(size=pt[1:].shape) * 0.5 * perturb
    return kc.BundleProblem.pack(intr, cr, ct, pr, pt)


def _free(n_cams, n_poses, fixed=("k2", "k3")):
    free = np.ones(n_cams * kc.N_CAM + n_poses * kc.N_POSE, bool)
    for c in range(n_cams):
        for k, name in enumerate(kc.INTRINSICS):
            if name in fixed:
                free[c * kc.N_CAM + k] = False
    free[n_cams * kc.N_CAM:n_cams * kc.N_CAM + kc.N_POSE] = False  # pose 0: the gauge
    return free


def _estimated(prob, params, cams):
    cb = prob.cam_block(params)
    out = []
    for j, c in enumerate(cams):
        K = np.array([[cb[j, 0], 0, cb[j, 2]], [0, cb[j, 1], cb[j, 3]], [0, 0, 1]])
        out.append(Camera(c.name, c.width, c.height, K, cb[j, 4:9], kc.rodrigues(cb[j, 9:12]), cb[j, 12:15]))
    return out


# --------------------------------------------------------------------------- derivatives


def test_rodrigues_matches_scipy_and_its_derivative_finite_differences():
    rng = np.random.default_rng(1)
    for r in [rng.normal(size=3), np.array([1e-10, 0, 0]), np.array([3.0, 0.1, -0.2])]:
        R, dR = kc.rodrigues_jacobian(r)
        assert np.allclose(R, Rotation.from_rotvec(r).as_matrix(), atol=1e-12)
        assert np.allclose(kc.rotvec(R), r, atol=1e-9)
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1e-6
            num = (kc.rodrigues(r + e) - kc.rodrigues(r - e)) / 2e-6
            assert np.allclose(dR[k], num, atol=1e-8)


def test_projection_matches_the_camera_model_and_jacobian_finite_differences():
    cams, poses, obj, cam, pose, pt, uv = _scene(n_cams=3, n_poses=3, noise=0.0)
    params = _params(cams, poses)
    # every intrinsic free, k3 and p1/p2 non-zero, weights not 1
    intr_i = [c * kc.N_CAM + k for c in range(3) for k in range(9)]
    params[intr_i] += np.tile([0, 0, 0, 0, 0, 0.3, 1e-3, -2e-3, 0.5], 3)
    free = _free(3, 3, fixed=())
    w = np.random.default_rng(0).uniform(0.5, 2.0, len(cam))
    prob = kc.BundleProblem(obj, cam, pose, pt, uv, 3, 3, params, free, w)
    # projection = the CONTRACT camera model
    est = _estimated(prob, params, cams)
    proj = prob.project()
    for c in range(3):
        sel = cam == c
        T = poses[0]
        for q in range(3):
            s = sel & (pose == q)
            T = poses[q]
            ref, _ = camk.project(obj[pt[s]] @ T[:3, :3].T + T[:3, 3], est[c].K, est[c].dist, est[c].R, est[c].t)
            assert np.allclose(proj[s], ref, atol=1e-9)
    x = prob.x0
    J = prob.jacobian(x).toarray()
    assert J.shape == (2 * len(cam), int(free.sum()))
    Jn = np.zeros_like(J)
    for i in range(x.size):
        h = 1e-6 * max(1.0, abs(x[i]))
        e = np.zeros_like(x)
        e[i] = h
        Jn[:, i] = (prob.residuals(x + e) - prob.residuals(x - e)) / (2 * h)
    assert np.abs(J - Jn).max() < 1e-5 * np.abs(J).max()


# --------------------------------------------------------------------------- adjustment


@pytest.fixture(scope="module")
def solved():
    cams, poses, obj, cam, pose, pt, uv = _scene(n_cams=5, n_poses=8, noise=0.05, seed=2)
    rng = np.random.default_rng(3)
    params = _params(cams, poses, rng, perturb=1.0)
    prob = kc.BundleProblem(obj, cam, pose, pt, uv, len(cams), len(poses), params, _free(len(cams), len(poses)))
    res = kc.bundle_adjust(prob)
    return cams, poses, prob, res


def test_bundle_adjustment_recovers_the_cameras(solved):
    cams, poses, prob, res = solved
    assert res.status > 0
    # residuals at the noise: RMS length of a 2D N(0, 0.05^2) error is 0.05 * sqrt(2)
    assert res.rms_px == pytest.approx(0.05 * np.sqrt(2), rel=0.1)
    est = _estimated(prob, res.params, cams)
    cmp = kc.compare_rigs(est, cams, radius_mm=20.0)
    assert cmp["rms_px"].max() < 0.05
    # focal lengths and k1 within 4 standard uncertainties of the covariance (f and distance
    # trade off at 400 mm: their uncertainty is large, ~0.5 % here)
    free = prob.free
    cov, _ = kc.normal_covariance(prob.jacobian(res.params[free]), res.residuals.ravel())
    col = np.cumsum(free) - 1
    for j, c in enumerate(cams):
        for k, true in ((0, c.K[0, 0]), (1, c.K[1, 1]), (4, c.dist[0])):
            i = col[j * kc.N_CAM + k]
            assert abs(prob.cam_block(res.params)[j, k] - true) < 4 * np.sqrt(cov[i, i])
    assert np.abs(cmp["f_err"]).max() < 0.03
    # the fixed pose fixes the frame and the target the scale
    assert abs(cmp["scale"] - 1.0) < 1e-3


def test_covariance_matches_the_errors_of_repeated_noise():
    """Predicted standard deviation of fx and of the camera centres against the spread over
    noise draws of the same scene (Monte Carlo, 12 draws)."""
    cams, poses, obj, cam, pose, pt, uv0 = _scene(n_cams=3, n_poses=5, noise=0.0, seed=4)
    params = _params(cams, poses)
    free = _free(3, 5)
    rng = np.random.default_rng(5)
    fx, centres, pred_f, pred_c = [], [], [], []
    for _ in range(12):
        uv = uv0 + rng.normal(size=uv0.shape) * 0.1
        prob = kc.BundleProblem(obj, cam, pose, pt, uv, 3, 5, params, free)
        res = kc.bundle_adjust(prob, loss="linear")
        J = prob.jacobian(res.params[free])
        cov, sigma = kc.normal_covariance(J, res.residuals.ravel())
        assert sigma == pytest.approx(0.1, rel=0.2)
        col = np.cumsum(free) - 1
        fx.append(prob.cam_block(res.params)[:, 0])
        pred_f.append(np.sqrt(cov[col[0], col[0]]))
        cb = prob.cam_block(res.params)
        ext = [int(col[j * kc.N_CAM + 9 + k]) for j in range(3) for k in range(6)]
        cen, ang, _ = kc.camera_uncertainty(cb[:, 9:12], cb[:, 12:15], cov[np.ix_(ext, ext)])
        assert np.all(np.isfinite(cen)) and np.all(cen > 0) and np.all(ang > 0)
        centres.append(-np.einsum("nji,nj->ni", kc.rodrigues(cb[:, 9:12]), cb[:, 12:15]))
        pred_c.append(cen)
    emp_f = np.std(np.array(fx)[:, 0], ddof=1)
    assert 0.5 < emp_f / np.mean(pred_f) < 2.0
    # centres: spread relative to their mean rigid position (the cameras' own datum)
    C = np.array(centres)
    spread = []
    for k in range(len(C)):
        s, R, t = kc.umeyama(C[k], C.mean(axis=0), with_scale=False)
        spread.append(np.linalg.norm(C[k] @ R.T + t - C.mean(axis=0), axis=1))
    emp_c = np.sqrt(np.mean(np.array(spread) ** 2, axis=0))
    assert np.all(emp_c / np.mean(pred_c, axis=0) < 2.5)
    assert np.all(emp_c / np.mean(pred_c, axis=0) > 0.3)


def test_camera_uncertainty_removes_a_rigid_motion_of_all_cameras():
    """A covariance that only moves the whole rig rigidly (a gauge change) leaves no
    uncertainty in the cameras' own datum."""
    rng = np.random.default_rng(6)
    C = 3
    rv = rng.normal(size=(C, 3)) * 0.5
    ts = rng.normal(size=(C, 3)) * 50 + np.array([0, 0, 400.0])
    # numerical derivative of the (r, t) parameters under a rigid motion of the world
    G = np.zeros((6 * C, 6))
    for k in range(6):
        eps = 1e-6
        om, tau = np.zeros(3), np.zeros(3)
        (om if k < 3 else tau)[k % 3] = eps
        Rw = kc.rodrigues(om)
        for c in range(C):
            R = kc.rodrigues(rv[c])
            # X' = Rw X + tau: camera R' = R Rw^T, t' = t - R Rw^T tau
            R2 = R @ Rw.T
            G[6 * c:6 * c + 3, k] = (kc.rotvec(R2) - rv[c]) / eps
            G[6 * c + 3:6 * c + 6, k] = (ts[c] - R2 @ tau - ts[c]) / eps
    A = rng.normal(size=(6, 6))
    cov = G @ (A @ A.T) @ G.T * 1e-4
    cen, ang, _ = kc.camera_uncertainty(rv, ts, cov)
    cov_free = np.eye(6 * C) * 1e-4
    cen2, ang2, _ = kc.camera_uncertainty(rv, ts, cov + cov_free)
    assert cen.max() < 1e-4 * cen2.min() + 1e-9
    assert ang.max() < 1e-3 * ang2.min() + 1e-9


def test_a_biased_view_is_rejected_and_the_rest_recovers():
    cams, poses, obj, cam, pose, pt, uv = _scene(n_cams=5, n_poses=8, noise=0.05, seed=7)
    # one camera's view of one pose is off by a pixel, in a pattern (a biased detection)
    bad = (cam == 2) & (pose == 3)
    assert bad.sum() >= 10
    uv = uv.copy()
    uv[bad] += np.array([1.0, -0.6]) + 0.3 * (uv[bad] - uv[bad].mean(axis=0)) / 50.0
    group = cam * 100 + pose
    prob = kc.BundleProblem(obj, cam, pose, pt, uv, 5, 8, _params(cams, poses), _free(5, 8))
    res = kc.bundle_adjust(prob)
    rejected, thr = kc.reject_groups(res.residuals, group, factor=3.0)
    assert list(rejected) == [2 * 100 + 3]
    keep = ~np.isin(group, rejected)
    res2 = kc.bundle_adjust(prob.subset(keep))
    assert res2.rms_px < res.rms_px
    cmp_bad = kc.compare_rigs(_estimated(prob, res.params, cams), cams, radius_mm=20.0)
    cmp = kc.compare_rigs(_estimated(prob, res2.params, cams), cams, radius_mm=20.0)
    assert cmp["rms_px"][2] < cmp_bad["rms_px"][2]
    assert cmp["rms_px"].max() < 0.05
    ids, rms, counts = kc.group_rms(res2.residuals, group[keep])
    assert np.all(rms < thr) and counts.sum() == keep.sum()


# --------------------------------------------------------------------------- frames and comparison


def test_nearest_point_to_lines_and_umeyama():
    rng = np.random.default_rng(8)
    p = np.array([3.0, -2.0, 5.0])
    d = rng.normal(size=(6, 3))
    o = p + d * rng.uniform(-50, 50, size=(6, 1))
    assert np.allclose(kc.nearest_point_to_lines(o, d), p)
    X = rng.normal(size=(10, 3)) * 100
    R = Rotation.random(random_state=rng).as_matrix()
    s, R2, t = kc.umeyama(X, 1.01 * X @ R.T + [1, 2, 3])
    assert s == pytest.approx(1.01) and np.allclose(R2, R) and np.allclose(t, [1, 2, 3])


def test_compare_rigs_sees_through_a_similarity_and_finds_a_turned_camera():
    cams = _scene(n_cams=8, n_poses=1)[0]
    R = Rotation.from_rotvec([0.1, -0.2, 0.05]).as_matrix()
    s, t = 1.002, np.array([5.0, -3.0, 2.0])
    # the same rig in another frame: X' = s R X + t (camera frames keep their size: t scales)
    moved = [Camera(c.name, c.width, c.height, c.K, c.dist, c.R @ R.T, s * c.t - c.R @ R.T @ t) for c in cams]
    cmp = kc.compare_rigs(moved, cams)
    assert cmp["rms_px"].max() < 1e-6
    assert cmp["scale"] == pytest.approx(1 / s)
    assert cmp["centre_err_mm"].max() < 1e-6 and np.abs(cmp["f_err"]).max() == 0.0
    # one camera turned by 1 px: it is by far the worst (the alignment spreads a little of it)
    turned = list(cams)
    c = cams[1]
    dR = Rotation.from_rotvec([1.0 / c.K[0, 0], 0, 0]).as_matrix()
    turned[1] = Camera(c.name, c.width, c.height, c.K, c.dist, dR @ c.R, dR @ c.t)
    cmp = kc.compare_rigs(turned, cams)
    assert cmp["rms_px"][1] > 0.5 and cmp["rms_px"][1] > 2 * np.delete(cmp["rms_px"], 1).max()
    assert kc.compare_rigs(turned, cams, align="centres")["centre_err_mm"].max() < 1e-6
