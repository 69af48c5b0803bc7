"""Compiled residuals of the iterative fits (:mod:`inspector.kernels.fits`).

A cylinder fit evaluates its residual and Jacobian eight times or so (three damped
Gauss-Newton steps, each a trial and an accepted evaluation); on the few hundred points of a
bore, the numpy version of one evaluation is some twenty array operations whose call overhead
(~100 us) outweighs the arithmetic, and the characteristics stage fits a cylinder for every
bore and boss of every part (issue 28: 20 characteristics within 50 ms). Fused into one loop
over the points it costs a few microseconds. The numpy version stays in
:func:`inspector.kernels.fits.cylinder_residual_numpy`, the reference the tests hold this to.

Imported lazily by :mod:`inspector.kernels.fits` (the first cylinder fit), so
``import inspector`` stays free of Numba.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["cylinder_lm", "cylinder_residual"]


@numba.njit(cache=True, nogil=True)
def cylinder_residual(P, p, a, bu, bv, R, r, J, jac):  # pragma: no cover - compiled; see the module docstring
    """Orthogonal residuals of points to a cylinder and their Jacobian, in place.

    Parameters
    ----------
    P : (N, 3) float64
        Points, mm.
    p, a : (3,) float64
        A point on the axis (mm) and the unit axis direction.
    bu, bv : (3,) float64
        The local frame the Jacobian's shift and tilt columns refer to (the current axis's
        :func:`~inspector.kernels.fits.orthonormal_basis`).
    R : float
        Radius, mm.
    r : (N,) float64
        Out: ``|radial part of P - p| - R``.
    J : (N, 5) float64
        Out when ``jac``: columns d r / d (shift_u, shift_v, tilt_u, tilt_v, radius).
    jac : bool
        Whether to fill ``J``.
    """
    for i in range(P.shape[0]):
        dx, dy, dz = P[i, 0] - p[0], P[i, 1] - p[1], P[i, 2] - p[2]
        h = dx * a[0] + dy * a[1] + dz * a[2]
        rx, ry, rz = dx - h * a[0], dy - h * a[1], dz - h * a[2]
        rho = math.sqrt(rx * rx + ry * ry + rz * rz)
        r[i] = rho - R
        if jac:
            inv = 1.0 / max(rho, 1e-300)
            eu = (rx * bu[0] + ry * bu[1] + rz * bu[2]) * inv
            ev = (rx * bv[0] + ry * bv[1] + rz * bv[2]) * inv
            J[i, 0] = -eu
            J[i, 1] = -ev
            J[i, 2] = -h * eu
            J[i, 3] = -h * ev
            J[i, 4] = -1.0



@numba.njit(cache=True, nogil=True)
def _basis(a):  # pragma: no cover - compiled
    """:func:`inspector.kernels.fits.orthonormal_basis`, the same arithmetic."""
    a0, a1, a2 = a[0], a[1], a[2]
    b0, b1, b2 = abs(a0), abs(a1), abs(a2)
    if b0 <= b1 and b0 <= b2:
        u0, u1, u2 = 0.0, a2, -a1
    elif b1 <= b2:
        u0, u1, u2 = -a2, 0.0, a0
    else:
        u0, u1, u2 = a1, -a0, 0.0
    nu = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    u = np.array([u0 / nu, u1 / nu, u2 / nu])
    v = np.array([a1 * u[2] - a2 * u[1], a2 * u[0] - a0 * u[2], a0 * u[1] - a1 * u[0]])
    return u, v


@numba.njit(cache=True, nogil=True)
def _solve(M, b, x):  # pragma: no cover - compiled
    """``x = M^-1 b`` by Gaussian elimination with partial pivoting (M, b overwritten);
    False when a pivot is exactly 0 (where LAPACK's gesv reports a singular matrix)."""
    n = b.shape[0]
    for k in range(n):
        piv = k
        for i in range(k + 1, n):
            if abs(M[i, k]) > abs(M[piv, k]):
                piv = i
        if M[piv, k] == 0.0:
            return False
        if piv != k:
            for j in range(n):
                M[k, j], M[piv, j] = M[piv, j], M[k, j]
            b[k], b[piv] = b[piv], b[k]
        for i in range(k + 1, n):
            f = M[i, k] / M[k, k]
            for j in range(k, n):
                M[i, j] -= f * M[k, j]
            b[i] -= f * b[k]
    for k in range(n - 1, -1, -1):
        s = b[k]
        for j in range(k + 1, n):
            s -= M[k, j] * x[j]
        x[k] = s / M[k, k]
    return True


@numba.njit(cache=True, nogil=True)
def _moved(p, a, R, bu, bv, s):  # pragma: no cover - compiled
    """The cylinder moved by the local step ``s`` (5,): (point, unit axis, radius)."""
    p2 = p + s[0] * bu + s[1] * bv
    a2 = a + s[2] * bu + s[3] * bv
    a2 = a2 / math.sqrt(a2[0] * a2[0] + a2[1] * a2[1] + a2[2] * a2[2])
    return p2, a2, R + s[4]


@numba.njit(cache=True, nogil=True)
def cylinder_lm(P, w, cw, state, rtol, max_iter):  # pragma: no cover - compiled; see the module docstring
    """Levenberg-Marquardt cylinder fit, in place: the loop of
    :func:`inspector.kernels.fits._gauss_newton` on :func:`cylinder_residual`, with the axis
    point kept at the points' weighted mean along the axis.

    Parameters
    ----------
    P : (N, 3) float64
        Points, mm.
    w : (N,) float64
        Weights > 0.
    cw : (3,) float64
        The points' weighted centroid, mm.
    state : (7,) float64
        In: the start (axis point (3,), unit direction (3,), radius); out: the fit.
    rtol : float
        Stop when a step lowers the cost by at most this fraction.
    max_iter : int
        Most accepted steps.
    """
    n = P.shape[0]
    r = np.empty(n)
    r2 = np.empty(n)
    J = np.empty((n, 5))
    p, a, R = state[0:3].copy(), state[3:6].copy(), state[6]
    p = p + ((cw - p) @ a) * a
    bu, bv = _basis(a)
    cylinder_residual(P, p, a, bu, bv, R, r, J, True)
    cost = np.sum(w * r * r)
    lam = 1e-6
    A = np.empty((5, 5))
    g = np.empty(5)
    step = np.empty(5)
    for _ in range(max_iter):
        for i in range(5):
            g[i] = np.sum(J[:, i] * w * r)
            for j in range(i, 5):
                A[i, j] = A[j, i] = np.sum(J[:, i] * J[:, j] * w)
        tr = 0.0
        for i in range(5):
            tr += A[i, i]
        eps = 1e-12 * max(1.0, tr / 5.0)
        improved = False
        done = False
        for _ in range(30):
            M = A.copy()
            for i in range(5):
                M[i, i] += lam * (A[i, i] + eps)
            if not _solve(M, -g, step):
                lam *= 10.0
                continue
            p2, a2, R2 = _moved(p, a, R, bu, bv, step)
            cylinder_residual(P, p2, a2, bu, bv, R2, r2, J, False)
            cost2 = np.sum(w * r2 * r2)
            if np.isfinite(cost2) and cost2 <= cost:
                p, a, R = p2 + ((cw - p2) @ a2) * a2, a2, R2
                bu, bv = _basis(a)
                cylinder_residual(P, p, a, bu, bv, R, r, J, True)
                done = cost - cost2 <= rtol * max(cost, 1e-300) or cost2 == 0.0
                cost = np.sum(w * r * r)
                lam = max(lam / 10.0, 1e-12)
                improved = True
                break
            lam *= 10.0
        if not improved or done:
            break
    state[0:3] = p
    state[3:6] = a
    state[6] = R
