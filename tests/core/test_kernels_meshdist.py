"""Exact signed distance index against brute force and the winding number."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from trimesh.triangles import closest_point as closest_on_triangles

from inspector.kernels.meshdist import MeshDistance
from inspector.parts import load_reference


def _winding(V: np.ndarray, F: np.ndarray, p: np.ndarray) -> float:
    """Generalized winding number of a closed mesh at p (1 inside, 0 outside)."""
    a, b, c = V[F[:, 0]] - p, V[F[:, 1]] - p, V[F[:, 2]] - p
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    num = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", b, c) * la + np.einsum("ij,ij->i", c, a) * lb
    return float(np.sum(2 * np.arctan2(num, den)) / (4 * np.pi))


def _near_surface(mesh: trimesh.Trimesh, n: int, sigma: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    S, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    P = S + rng.normal(0.0, sigma, S.shape)
    P[: n // 4] = S[: n // 4] + rng.normal(0.0, 1e-4, (n // 4, 3))  # on the surface, either side
    return P


@pytest.mark.parametrize("part", ["bracket", "sphere30", "gauge"])
def test_exact_distance_and_sign(part):
    mesh = load_reference(f"builtin:{part}", recentre=False)
    V, F = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    md = MeshDistance(V, F)
    P = _near_surface(mesh, 300, 0.6, seed=1)
    d = md(P)
    inband = ~np.isnan(d)
    assert inband.mean() > 0.9
    tri = V[F]
    for p, di in zip(P[inband], d[inband]):
        q = closest_on_triangles(tri, np.repeat(p[None], len(tri), axis=0))
        brute = np.linalg.norm(q - p, axis=1).min()
        assert abs(abs(di) - brute) < 1e-9
        if brute > 1e-6:  # the sign of points on the surface is either
            assert (di < 0) == (_winding(V, F, p) > 0.5)


def test_band_fallback_and_closest():
    mesh = load_reference("builtin:cube30", recentre=False)
    V, F = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    md = MeshDistance(V, F, band_mm=1.0, cell_mm=0.5)
    r = 0.5 * np.sqrt(3) / 2
    P = np.array([[0.0, 0.0, 15.0 + (1.0 - r) * 0.99], [0.0, 0.0, 10.0], [0.0, 0.0, 40.0], [3.0, -2.0, -15.2]])
    d = md(P)
    assert d[0] == pytest.approx((1.0 - r) * 0.99) and d[3] == pytest.approx(0.2)
    assert np.isnan(d[1]) and np.isnan(d[2])  # deep inside, outside the grid: not in the band
    calls = []

    def fallback(X):
        calls.append(len(X))
        return np.full(len(X), 7.0)

    md.fallback = fallback
    assert np.allclose(md(P)[[1, 2]], 7.0) and calls == [2]
    q, tid = md.closest(P[[0, 3]])
    assert np.allclose(q, [[0.0, 0.0, 15.0], [3.0, -2.0, -15.0]])
    assert np.all(tid >= 0)
    assert np.all(np.abs(np.cross(V[F[tid, 1]] - V[F[tid, 0]], V[F[tid, 2]] - V[F[tid, 0]])[:, :2]) < 1e-9)  # a z face
    q, tid = md.closest(P[[1]])
    assert tid[0] == -1 and np.isnan(q).all()



def test_closest_on_one_thread_is_the_parallel_query():
    mesh = load_reference("builtin:bracket", recentre=False)
    md = MeshDistance(np.asarray(mesh.vertices, float), np.asarray(mesh.faces))
    P = _near_surface(mesh, 2000, 0.8, seed=4)
    q, tid = md.closest(P)
    q1, tid1 = md.closest(P, parallel=False)
    assert (tid >= 0).mean() > 0.9
    np.testing.assert_array_equal(tid1, tid)
    np.testing.assert_array_equal(q1, q)  # NaN where not in the band, in both

def test_rejects_bad_meshes():
    with pytest.raises(ValueError):
        MeshDistance(np.zeros((3, 2)), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError):
        MeshDistance(np.zeros((3, 3)), np.zeros((0, 3), int))


def test_near_is_the_exact_distance_within_the_band_and_nan_beyond():
    box = trimesh.creation.box((10.0, 10.0, 10.0))
    md = MeshDistance(box.vertices, box.faces, fallback=lambda P: np.full(len(P), -7.0), band_mm=1.0)
    P = np.array([[5.5, 0.0, 0.0], [0.0, 0.0, 4.2], [20.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    d = md.near(P)
    np.testing.assert_allclose(d[:2], [0.5, -0.8], atol=1e-12)
    assert np.isnan(d[2]) and np.isnan(d[3])  # beyond the band, with or without a fallback
    assert md(P)[2] == -7.0


@pytest.mark.parametrize("with_fallback", [False, True])
def test_residuals_in_one_pass_are_closest_and_numpy_bit_for_bit(with_fallback):
    """The fits' question in one compiled pass: in a frame offset by ``centre``, each point's
    closest point, its triangle's normal and its distance, to the bit what :meth:`closest`
    and numpy after it give; beyond the band the fallback answers (NaN without one)."""
    from inspector.kernels.rigid import RefMesh

    mesh = load_reference("builtin:bracket", recentre=False)
    mesh.apply_translation([3.3, -7.1, 11.7])  # a real offset between the two frames
    V, F = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    md = MeshDistance(V, F, band_mm=1.0)
    ref = RefMesh(V, F, index=md)
    assert np.abs(ref.centre).max() > 1.0
    P = _near_surface(mesh, 3000, 1.5, seed=7) - ref.centre  # some beyond the 1 mm band
    if with_fallback:
        md.fallback_closest = lambda X: ref.index.__class__(V, F, band_mm=40.0).closest(X)
    c, n, r = md.residuals(P, ref.centre, ref.face_normals)
    q, tid = md.closest(P + ref.centre)
    want_c = q - ref.centre
    d = P - want_c
    miss = tid < 0
    assert 0.05 < np.mean(np.isnan(want_c[:, 0])) < 0.5 if not with_fallback else not miss.any()
    np.testing.assert_array_equal(c, want_c)
    np.testing.assert_array_equal(n, ref.face_normals[tid])
    np.testing.assert_array_equal(r, np.sqrt(np.sum(d * d, axis=1)))
    K = P[:2400].reshape(2, 1200, 3)  # as the Gauss-Newton step asks: (K, N, 3)
    got = ref.residuals(K)
    assert [a.shape for a in got] == [(2, 1200, 3), (2, 1200, 3), (2, 1200)]
    for a, b in zip(got, (c[:2400].reshape(2, 1200, 3), n[:2400].reshape(2, 1200, 3), r[:2400].reshape(2, 1200))):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("with_fallback", [False, True])
def test_gradients_in_one_pass_are_the_distance_closest_and_numpy_bit_for_bit(with_fallback):
    """The size fit's question in one compiled pass: the signed distance, the closest point,
    the distance's unit gradient ((p - c) / sd, the face's normal on the surface) and the
    triangle, to the bit what ``index(p)``, :meth:`closest` and numpy after them give; beyond
    the band the fallbacks answer (NaN and -1 without them)."""
    mesh = load_reference("builtin:bracket", recentre=False)
    V, F = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    md = MeshDistance(V, F, band_mm=1.0)
    P = _near_surface(mesh, 3000, 1.5, seed=11)  # some beyond the 1 mm band
    P[:40] = mesh.vertices[mesh.faces[:40, 0]] * 0.5 + mesh.vertices[mesh.faces[:40, 1]] * 0.5  # on the surface
    if with_fallback:
        wide = MeshDistance(V, F, band_mm=40.0)
        md.fallback, md.fallback_closest = wide.near, wide.closest
    sd, c, g, tid = md.gradients(P)
    want_sd = md(P)
    want_c, want_t = md.closest(P)
    d = P - want_c
    far = np.linalg.norm(d, axis=1) > 1e-9
    want_g = np.where(far[:, None], d / np.where(far, want_sd, 1.0)[:, None], md.pn[np.maximum(want_t, 0), 0])
    miss = want_t < 0
    assert (not miss.any()) if with_fallback else 0.05 < miss.mean() < 0.5
    assert (~far).sum() >= 20  # the face-normal branch is exercised
    np.testing.assert_array_equal(tid, want_t)
    np.testing.assert_array_equal(sd, want_sd)
    np.testing.assert_array_equal(c, want_c)
    np.testing.assert_array_equal(g[~miss], want_g[~miss])
    assert np.isnan(g[miss]).all()
    np.testing.assert_allclose(np.linalg.norm(g[~miss], axis=1), 1.0, atol=1e-9)
