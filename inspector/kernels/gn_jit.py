"""Compiled normal equations of the robust Gauss-Newton steps: the rigid fits'
(:class:`inspector.kernels.rigid.GaussNewtonStep`) and the size model's
(:func:`inspector.kernels.prior.fit_size_prior`, :func:`size_equations`: 7 to 14 steps an
inspection on 6000-7000 points, 20 ms of numpy on one core before).

Profiling the pose fits (issue 26: 45 steps an inspection, on one candidate and 6000
points in the BCPS re-fits, on 98 candidates and 82 points in the global alignment) left
55 ms an inspection in the numpy between the closest-point query and the 6 x 6 solve: some
twenty passes over (K, N, 3) arrays (residuals, weights, levers, the Jacobian and its
products), each a fresh temporary, on one core while the other waits. This kernel makes
them two passes over the points per candidate, with no temporary. Written by hand because
no library forms weighted point-to-surface normal equations in one pass; the sums run in
point order, so the figures differ from numpy's pairwise sums in the last bits only.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["normal_equations", "size_equations"]


@numba.njit(cache=True, nogil=True)
def _system(q, c, n, r, cutoff, R, normals, normal_cos, H, b, q0, scale, cost, sw_out, count):
    K, N = r.shape
    use_normals = normals.shape[0] == N
    w = np.empty(N)
    for k in range(K):
        ck = cutoff[k]
        sw = 0.0
        m0 = 0.0
        m1 = 0.0
        m2 = 0.0
        nz = 0
        wr2 = 0.0
        for i in range(N):
            u = r[k, i] / ck
            wi = (1.0 - u * u) ** 2 if abs(u) < 1.0 else 0.0
            if use_normals and wi != 0.0:
                # the point's normal turned by the candidate's rotation, against the match's
                a0 = R[k, 0, 0] * normals[i, 0] + R[k, 0, 1] * normals[i, 1] + R[k, 0, 2] * normals[i, 2]
                a1 = R[k, 1, 0] * normals[i, 0] + R[k, 1, 1] * normals[i, 1] + R[k, 1, 2] * normals[i, 2]
                a2 = R[k, 2, 0] * normals[i, 0] + R[k, 2, 1] * normals[i, 1] + R[k, 2, 2] * normals[i, 2]
                if not (a0 * n[k, i, 0] + a1 * n[k, i, 1] + a2 * n[k, i, 2] > normal_cos):
                    wi = 0.0
            w[i] = wi
            if wi != 0.0:
                nz += 1
            sw += wi
            m0 += wi * q[k, i, 0]
            m1 += wi * q[k, i, 1]
            m2 += wi * q[k, i, 2]
            wr2 += wi * r[k, i] * r[k, i]
        count[k] = nz
        if not sw > 0.0:
            sw = 1.0
        sw_out[k] = sw
        p0 = m0 / sw
        p1 = m1 / sw
        p2 = m2 / sw
        q0[k, 0] = p0
        q0[k, 1] = p1
        q0[k, 2] = p2
        cost[k] = wr2 / sw
        spread = 0.0
        for i in range(N):
            l0 = q[k, i, 0] - p0
            l1 = q[k, i, 1] - p1
            l2 = q[k, i, 2] - p2
            spread += w[i] * (l0 * l0 + l1 * l1 + l2 * l2)
        s = max(math.sqrt(spread / sw), 1e-9)
        scale[k] = s
        J = np.empty(6)
        for a in range(6):
            b[k, a] = 0.0
            for e in range(6):
                H[k, a, e] = 0.0
        for i in range(N):
            wi = w[i]
            if wi == 0.0:
                continue
            ri = r[k, i]
            # the distance's gradient: towards the closest point, or the triangle's normal on it
            if ri <= 1e-6:
                g0 = n[k, i, 0]
                g1 = n[k, i, 1]
                g2 = n[k, i, 2]
            else:
                g0 = (q[k, i, 0] - c[k, i, 0]) / ri
                g1 = (q[k, i, 1] - c[k, i, 1]) / ri
                g2 = (q[k, i, 2] - c[k, i, 2]) / ri
            l0 = q[k, i, 0] - p0
            l1 = q[k, i, 1] - p1
            l2 = q[k, i, 2] - p2
            J[0] = (l1 * g2 - l2 * g1) / s
            J[1] = (l2 * g0 - l0 * g2) / s
            J[2] = (l0 * g1 - l1 * g0) / s
            J[3] = g0
            J[4] = g1
            J[5] = g2
            for a in range(6):
                wa = wi * J[a]
                b[k, a] += wa * ri
                for e in range(a, 6):
                    H[k, a, e] += wa * J[e]
        for a in range(6):
            for e in range(a):
                H[k, a, e] = H[k, e, a]


def normal_equations(q: np.ndarray, c: np.ndarray, n: np.ndarray, r: np.ndarray, cutoff: np.ndarray,
                     R: np.ndarray, normals: np.ndarray | None, normal_cos: float):
    """The weighted Gauss-Newton system of K candidate poses on N points.

    Parameters
    ----------
    q : (K, N, 3) float
        The points under each candidate, mm (the reference's internal frame).
    c, n : (K, N, 3) float
        Their closest reference points, mm, and those points' unit triangle normals.
    r : (K, N) float
        ``|q - c|``, mm.
    cutoff : (K,) float
        Tukey cut-off of each candidate, mm (weights ``(1 - (r / cutoff)^2)^2`` within it).
    R : (K, 3, 3) float
        Each candidate's rotation (world -> internal), which turns ``normals``.
    normals : (N, 3) float or None
        World unit normals of the points: a match whose normal's cosine to the turned
        point normal is not above ``normal_cos`` gets no weight.

    Returns
    -------
    H : (K, 6, 6) float
        ``sum w J J^T`` with ``J = [(lever x g) / scale, g]`` (rotation about the weighted
        centroid, scaled by the points' weighted spread, then translation).
    b : (K, 6) float
        ``sum w J r``.
    q0 : (K, 3) float
        Weighted centroid, mm.
    scale : (K,) float
        Weighted RMS distance of the points from ``q0`` (at least 1e-9), mm.
    cost : (K,) float
        ``sum w r^2 / sum w``, mm^2.
    sw : (K,) float
        ``sum w`` (1 where it is 0).
    count : (K,) int
        Points with a non-zero weight.
    """
    K, N = r.shape
    H = np.empty((K, 6, 6))
    b = np.empty((K, 6))
    q0 = np.empty((K, 3))
    scale = np.empty(K)
    cost = np.empty(K)
    sw = np.empty(K)
    count = np.empty(K, np.int64)
    f8 = np.float64
    _system(np.ascontiguousarray(q, f8), np.ascontiguousarray(c, f8), np.ascontiguousarray(n, f8),
            np.ascontiguousarray(r, f8), np.ascontiguousarray(cutoff, f8), np.ascontiguousarray(R, f8),
            np.ascontiguousarray(normals, f8) if normals is not None else np.zeros((0, 3)), float(normal_cos),
            H, b, q0, scale, cost, sw, count)
    return H, b, q0, scale, cost, sw, count


@numba.njit(cache=True, nogil=True)
def _size_system(r, ok, g, c, c0, Q, s, cutoff, H, b):
    N = r.shape[0]
    for a in range(7):
        b[a] = 0.0
        for e in range(7):
            H[a, e] = 0.0
    sw = 0.0
    J = np.empty(7)
    for i in range(N):
        if not ok[i]:
            continue
        u = r[i] / cutoff
        if not abs(u) < 1.0:
            continue
        wi = (1.0 - u * u) ** 2
        sw += wi
        # the gradient and the lever (c - c0) mapped by Q to the world side
        e0 = c[i, 0] - c0[0]
        e1 = c[i, 1] - c0[1]
        e2 = c[i, 2] - c0[2]
        gw0 = g[i, 0] * Q[0, 0] + g[i, 1] * Q[0, 1] + g[i, 2] * Q[0, 2]
        gw1 = g[i, 0] * Q[1, 0] + g[i, 1] * Q[1, 1] + g[i, 2] * Q[1, 2]
        gw2 = g[i, 0] * Q[2, 0] + g[i, 1] * Q[2, 1] + g[i, 2] * Q[2, 2]
        cw0 = e0 * Q[0, 0] + e1 * Q[0, 1] + e2 * Q[0, 2]
        cw1 = e0 * Q[1, 0] + e1 * Q[1, 1] + e2 * Q[1, 2]
        cw2 = e0 * Q[2, 0] + e1 * Q[2, 1] + e2 * Q[2, 2]
        J[0] = gw0 * cw0 + gw1 * cw1 + gw2 * cw2
        J[1] = s * (cw1 * gw2 - cw2 * gw1)
        J[2] = s * (cw2 * gw0 - cw0 * gw2)
        J[3] = s * (cw0 * gw1 - cw1 * gw0)
        J[4] = gw0
        J[5] = gw1
        J[6] = gw2
        for a in range(7):
            wa = wi * J[a]
            b[a] += wa * r[i]
            for e in range(a, 7):
                H[a, e] += wa * J[e]
    for a in range(7):
        for e in range(a):
            H[a, e] = H[e, a]
    return sw


def size_equations(r: np.ndarray, ok: np.ndarray, g: np.ndarray, c: np.ndarray, c0: np.ndarray, Q: np.ndarray,
                   s: float, cutoff: float):
    """The weighted Gauss-Newton system of the size model ``(scale, rotation, shift)`` on N points.

    Parameters
    ----------
    r : (N,) float
        Residuals ``s * sd``, mm.
    ok : (N,) bool
        Points with a distance (the others get no weight).
    g, c : (N, 3) float
        The distance's unit gradient and the closest points, the reference's frame.
    c0 : (3,) float
        The scale centre, mm.
    Q : (3, 3) float
        The model's rotation.
    s, cutoff : float
        The scale and the Tukey cut-off, mm (weights ``(1 - (r / cutoff)^2)^2`` within it).

    Returns
    -------
    H : (7, 7) float
        ``sum w J J^T`` with ``J = [g_w . c_w, s (c_w x g_w), g_w]`` (``g_w``, ``c_w``: ``g``
        and ``c - c0`` turned by ``Q``): the change of ``r`` with the scale, the rotation and
        the shift.
    b : (7,) float
        ``sum w J r``.
    sw : float
        ``sum w``.
    """
    H = np.empty((7, 7))
    b = np.empty(7)
    f8 = np.float64
    sw = _size_system(np.ascontiguousarray(r, f8), np.ascontiguousarray(ok, np.bool_), np.ascontiguousarray(g, f8),
                      np.ascontiguousarray(c, f8), np.ascontiguousarray(c0, f8), np.ascontiguousarray(Q, f8), float(s),
                      float(cutoff), H, b)
    return H, b, float(sw)
