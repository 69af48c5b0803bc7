"""The compiled Gauss-Newton normal equations against the same system written in numpy."""

from __future__ import annotations

import numpy as np
import pytest

from inspector.kernels.gn_jit import normal_equations, size_equations
from inspector.kernels.robust import tukey


def numpy_system(q, c, n, r, cutoff, R, normals, normal_cos):
    """The weighted point-to-surface system, array by array (what the kernel sums point by point)."""
    d = q - c
    on_surface = r <= 1e-6
    g = np.where(on_surface[..., None], n, d / np.where(on_surface, 1.0, r)[..., None])
    w = tukey(r, cutoff[:, None])
    if normals is not None:
        nq = np.matmul(normals[None], R.transpose(0, 2, 1))
        w = w * (np.sum(nq * n, axis=2) > normal_cos)
    count = np.count_nonzero(w, axis=1)
    sw = w.sum(axis=1)
    sw = np.where(sw > 0, sw, 1.0)
    q0 = np.matmul(w[:, None, :], q)[:, 0] / sw[:, None]
    lever = q - q0[:, None, :]
    scale = np.maximum(np.sqrt(np.sum(w * np.sum(lever * lever, axis=2), axis=1) / sw), 1e-9)
    J = np.concatenate([np.cross(lever, g) / scale[:, None, None], g], axis=2)
    Jw = J * w[..., None]
    H = np.matmul(Jw.transpose(0, 2, 1), J)
    b = np.matmul(Jw.transpose(0, 2, 1), r[..., None])[..., 0]
    return H, b, q0, scale, np.sum(w * r * r, axis=1) / sw, sw, count


def _case(K, N, seed, on_surface=0):
    rng = np.random.default_rng(seed)
    q = rng.normal(scale=10.0, size=(K, N, 3)) + [3.0, -2.0, 1.0]
    n = rng.normal(size=(K, N, 3))
    n /= np.linalg.norm(n, axis=2, keepdims=True)
    c = q - rng.exponential(0.3, size=(K, N, 1)) * n * rng.choice([-1.0, 1.0], size=(K, N, 1))
    c[:, :on_surface] = q[:, :on_surface]  # some points on the surface: the gradient is the normal
    r = np.linalg.norm(q - c, axis=2)
    R = np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(K)])
    normals = rng.normal(size=(N, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    cutoff = rng.uniform(0.3, 1.5, size=K)
    return q, c, n, r, cutoff, R, normals


@pytest.mark.parametrize(("K", "N", "use_normals"), [(1, 6000, False), (1, 500, True), (98, 82, True), (4, 571, False)])
def test_normal_equations_equal_the_numpy_system(K, N, use_normals):
    q, c, n, r, cutoff, R, normals = _case(K, N, seed=K * 1000 + N, on_surface=5)
    normals = normals if use_normals else None
    got = normal_equations(q, c, n, r, cutoff, R, normals, -0.5)
    want = numpy_system(q, c, n, r, cutoff, R, normals, -0.5)
    for name, a, b in zip(("H", "b", "q0", "scale", "cost", "sw"), got[:6], want[:6]):
        np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-12, err_msg=name)
    np.testing.assert_array_equal(got[6], want[6])
    assert (want[6] > 0).all() and (want[6] < N).all()  # some points weighted, some cut off


def test_no_weighted_point_gives_an_empty_system():
    q, c, n, r, cutoff, R, normals = _case(2, 50, seed=3)
    cutoff[:] = 1e-6  # every point beyond the cut-off
    H, b, q0, scale, cost, sw, count = normal_equations(q, c, n, r, cutoff, R, None, -0.5)
    assert (count == 0).all() and (sw == 1.0).all() and (scale == 1e-9).all()
    assert not H.any() and not b.any() and not q0.any() and not cost.any()


def numpy_size_system(r, ok, g, c, c0, Q, s, cutoff):
    """The size model's system array by array (the numpy the kernel replaced in
    :func:`inspector.kernels.prior.fit_size_prior`)."""
    w = np.where(ok, tukey(np.where(ok, r, 0.0), cutoff), 0.0)
    gw, cw = g @ Q.T, (c - c0) @ Q.T
    J = np.column_stack([np.einsum("ij,ij->i", gw, cw), s * np.cross(cw, gw), gw])
    JW = J * w[:, None]
    return JW.T @ J, JW.T @ np.where(ok, r, 0.0), w.sum()


@pytest.mark.parametrize("N, seed", [(7000, 1), (300, 2)])
def test_size_system_is_numpys(N, seed):
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    g = rng.normal(size=(N, 3))
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    c = rng.normal(scale=12.0, size=(N, 3)) + [1.0, 2.0, -3.0]
    r = rng.normal(scale=0.08, size=N)
    r[:N // 10] = 0.5  # beyond the cut-off: no weight
    ok = rng.random(N) > 0.05
    g[~ok] = np.nan  # a point without a distance must not spoil the sums
    c0 = np.array([0.5, -0.2, 0.1])
    Q = Rotation.from_rotvec([0.1, -0.3, 0.2]).as_matrix()
    H, b, sw = size_equations(r, ok, g, c, c0, Q, 0.98, 0.2)
    ok_rows = ok.copy()
    want_H, want_b, want_sw = numpy_size_system(r[ok_rows], ok[ok_rows], g[ok_rows], c[ok_rows], c0, Q, 0.98, 0.2)
    assert np.array_equal(H, H.T) and np.isfinite(H).all()
    np.testing.assert_allclose(H, want_H, rtol=1e-11, atol=1e-9)
    np.testing.assert_allclose(b, want_b, rtol=1e-11, atol=1e-12)
    assert sw == pytest.approx(want_sw, rel=1e-12)
    none = size_equations(r, np.zeros(N, bool), g, c, c0, Q, 0.98, 0.2)
    assert none[2] == 0.0 and not none[0].any() and not none[1].any()
