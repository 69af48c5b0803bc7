"""Compiled kernels for :mod:`inspector.kernels.carving` (cell tests, Newton points, mesh grid).

Profiling ``carve`` at 0.1 mm showed its time in the numpy projection / bilinear
sampling of the cell tests and of the Newton steps (one temporary array per operation,
camera by camera). These Numba kernels fuse projection (OpenCV distortion continued by
the identity beyond the validity box), bilinear sampling of the signed distance and the
per-cell / per-point early exit, in parallel over cells / points. They repeat the numpy
reference (``backend="numpy"`` of :func:`carving.carve`) operation by operation, so the
same cells are kept and the points agree to rounding; where the order of the work
differs (the finest level's cells tested together with their Newton points, the mesh
grid's blocks depth first, cameras tried in another order) the results do not depend
on it.

Second round (0.1 mm on a 30 mm cube: 2.9 million finest cells, 1.5 million boundary
cells, 0.65 million points): the finest level is one pass over the boundary cells of the
level above (:func:`finest_points`, no child arrays; the hull function at a child's
centre comes from its cell test), the Newton chord of the 8 children is computed once at
their parent's centre, the steps are secant steps, and the Newton point is inlined in
the kernels (a call with some twenty array arguments cost about as much as the point).
The mesh grid's signs come from one depth-first kernel (:func:`mesh_signs`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numba
import numpy as np

# OpenMP (libgomp): the TBB found in some environments is too old (see hull_jit). Set
# before the first parallel kernel runs; this module is imported only by the numba backend
# of :func:`carving.carve` (lazily).
numba.config.THREADING_LAYER = "omp"

__all__ = ["ViewStack", "stack_views", "classify_cells", "f_all", "refine_points", "finest_points", "gather",
           "mesh_signs", "mesh_need"]


class ViewStack:
    """:class:`carving._View` objects packed into arrays (C cameras)."""

    def __init__(self, views: Sequence, sdt: np.ndarray | None = None) -> None:
        C = len(views)
        n = max(v.W * v.H for v in views)
        self.R = np.ascontiguousarray(np.stack([v.R for v in views]), dtype=np.float64)
        self.t = np.ascontiguousarray(np.stack([v.t for v in views]), dtype=np.float64)
        self.K2 = np.ascontiguousarray(np.stack([v.K2 for v in views]), dtype=np.float64)
        self.c = np.ascontiguousarray(np.stack([v.c for v in views]), dtype=np.float64)
        self.dist = np.ascontiguousarray(np.stack([v.dist for v in views]), dtype=np.float64)
        self.has_dist = np.array([v.has_dist for v in views], dtype=np.bool_)
        self.box = np.ascontiguousarray(np.stack([v.box for v in views]), dtype=np.float64)
        self.s_in = np.array([v.s_in for v in views], dtype=np.float64)
        self.s_out = np.array([v.s_out for v in views], dtype=np.float64)
        self.fgeo = np.array([v.fgeo for v in views], dtype=np.float64)
        self.size = np.array([[v.W, v.H] for v in views], dtype=np.int64)
        self.open = np.array([v.open for v in views], dtype=np.bool_)
        if sdt is not None and sdt.dtype == np.float32 and sdt.flags.c_contiguous and sdt.shape[0] == C and all(
                v.sdt.ctypes.data == sdt[i].ctypes.data for i, v in enumerate(views)):
            self.sdt = sdt  # the views' SDTs are already its rows (carve writes them there)
        else:
            self.sdt = np.zeros((C, n), dtype=np.float32)
            for i, v in enumerate(views):
                self.sdt[i, : v.sdt.size] = v.sdt

    def args(self) -> tuple:
        return (self.R, self.t, self.K2, self.c, self.dist, self.has_dist, self.box, self.s_in, self.s_out,
                self.fgeo, self.size, self.open, self.sdt)


def stack_views(views: Sequence, sdt: np.ndarray | None = None) -> ViewStack:
    """Pack the views; ``sdt`` (C, n) float32: a buffer whose row ``i`` starts with view
    ``i``'s SDT, used without copying."""
    return ViewStack(views, sdt)


#: Depth below which a point is "at or behind" the camera, mm (``carving._Z_MIN``).
Z_MIN = 1e-6
#: Hull-function value of points behind a camera, mm (``carving._BEHIND_MM``).
BEHIND = -1e9
#: Cells (parents) per parallel work item of the Newton kernels (their scratch arrays
#: are allocated once per item).
_BLOCK = 256
#: A Newton point farther than this from its cell's centre (max norm, cell edges) is
#: dropped at once (``carving._LEAVE``).
_LEAVE = 0.6


@numba.njit(cache=True, inline="always")
def project(c, x0, x1, x2, R, t, K2, cc, dist, has_dist, box):
    xc = R[c, 0, 0] * x0 + R[c, 0, 1] * x1 + R[c, 0, 2] * x2 + t[c, 0]
    yc = R[c, 1, 0] * x0 + R[c, 1, 1] * x1 + R[c, 1, 2] * x2 + t[c, 1]
    z = R[c, 2, 0] * x0 + R[c, 2, 1] * x1 + R[c, 2, 2] * x2 + t[c, 2]
    inv = 1.0 / max(z, Z_MIN)
    xn = xc * inv
    yn = yc * inv
    if has_dist[c]:
        qx = min(max(xn, box[c, 0]), box[c, 1])
        qy = min(max(yn, box[c, 2]), box[c, 3])
        k1 = dist[c, 0]
        k2 = dist[c, 1]
        p1 = dist[c, 2]
        p2 = dist[c, 3]
        k3 = dist[c, 4]
        r2 = qx * qx + qy * qy
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dx = qx * radial + 2.0 * p1 * qx * qy + p2 * (r2 + 2.0 * qx * qx)
        dy = qy * radial + p1 * (r2 + 2.0 * qy * qy) + 2.0 * p2 * qx * qy
        xd = dx + (xn - qx)
        yd = dy + (yn - qy)
    else:
        xd = xn
        yd = yn
    u = K2[c, 0, 0] * xd + K2[c, 0, 1] * yd + cc[c, 0]
    w = K2[c, 1, 1] * yd + cc[c, 1]
    return u, w, z, xn, yn

@numba.njit(cache=True, inline="always")
def sample(c, u, w, size, sdt):
    W = size[c, 0]
    H = size[c, 1]
    qu = min(max(u, 0.0), W - 1.0)
    qv = min(max(w, 0.0), H - 1.0)
    iu = min(int(qu), W - 2)
    iv = min(int(qv), H - 2)
    au = qu - iu
    av = qv - iv
    i0 = iv * W + iu
    s00 = sdt[c, i0]
    s01 = sdt[c, i0 + 1]
    top = s00 + au * np.float32(s01 - s00)
    i0 += W
    s10 = sdt[c, i0]
    s11 = sdt[c, i0 + 1]
    bot = s10 + au * np.float32(s11 - s10)
    g = top + av * (bot - top)
    du = u - qu
    dv = w - qv
    e = np.hypot(du, dv) if (du != 0.0 or dv != 0.0) else 0.0  # most samples are in the window
    return g, e

@numba.njit(cache=True, inline="always")
def f_cam(c, x0, x1, x2, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt):
    u, w, z, _, _ = project(c, x0, x1, x2, R, t, K2, cc, dist, has_dist, box)
    g, e = sample(c, u, w, size, sdt)
    if opn[c]:
        g = g + e
    else:
        g = g - e
    f = g * (z / fgeo[c])
    if z > Z_MIN:
        return f
    return BEHIND

@numba.njit(cache=True, inline="always")
def ball_cam_uv(c, u, w, z, xn, yn, r, lipc, slack, has_dist, box, s_in, s_out, size, opn, sdt):
    """Conservative test of a ball of radius ``r`` mm against camera ``c``, its centre
    projected at ``u, w, z, xn, yn`` (:func:`project`), as :func:`carving._classify`:
    0 outside the cone, 1 strictly inside, 2 undecided; the upper and lower bounds of the
    SDT over the ball's disk, px; and :func:`sample` at the centre."""
    ok = z - r > Z_MIN
    zr = z - r if ok else 1.0
    rn = r * np.sqrt(1.0 + xn * xn + yn * yn) / zr
    if has_dist[c]:
        inbox = (xn - rn >= box[c, 0]) and (xn + rn <= box[c, 1]) and (yn - rn >= box[c, 2]) and (
            yn + rn <= box[c, 3])
        rho = rn * (s_in[c] if inbox else s_out[c])
    else:
        rho = rn * s_in[c]
    g, e = sample(c, u, w, size, sdt)
    W = size[c, 0]
    H = size[c, 1]
    exits = (u - rho < 0.0) or (u + rho > W - 1.0) or (w - rho < 0.0) or (w + rho > H - 1.0)
    ex = e + rho if exits else 0.0
    inner = max(e - rho, 0.0)
    lip = lipc * rho + slack
    if opn[c]:
        high = g + lip + ex
        low = g - lip + inner
    else:
        high = g + lip - inner
        low = g - lip - ex
    if (ok and high < 0.0) or (z + r <= 0.0):
        return 0, high, low, g, e
    if ok and low > 0.0:
        return 1, high, low, g, e
    return 2, high, low, g, e


@numba.njit(cache=True, inline="always")
def ball_cam(c, x0, x1, x2, r, lipc, slack, R, t, K2, cc, dist, has_dist, box, s_in, s_out, size, opn, sdt):
    """:func:`ball_cam_uv` of the ball centred on the world point ``x`` mm."""
    u, w, z, xn, yn = project(c, x0, x1, x2, R, t, K2, cc, dist, has_dist, box)
    return ball_cam_uv(c, u, w, z, xn, yn, r, lipc, slack, has_dist, box, s_in, s_out, size, opn, sdt)


@numba.njit(parallel=True, cache=True, nogil=True)
def _classify_kernel(cells, act, origin, size_mm, r, lipc, slack,
                   R, t, K2, cc, dist, has_dist, box, s_in, s_out, fgeo, size, opn, sdt, act_out, status):
    N = cells.shape[0]
    C = R.shape[0]
    for n in numba.prange(N):
        x0 = origin[0] + (cells[n, 0] + 0.5) * size_mm
        x1 = origin[1] + (cells[n, 1] + 0.5) * size_mm
        x2 = origin[2] + (cells[n, 2] + 0.5) * size_mm
        cv = False
        und = False
        for c in range(C):
            act_out[n, c] = act[n, c]
        for c in range(C):
            if not act[n, c]:
                continue
            st, _, _, _, _ = ball_cam(c, x0, x1, x2, r, lipc, slack, R, t, K2, cc, dist, has_dist, box, s_in, s_out,
                                      size, opn, sdt)
            if st == 0:
                cv = True
                break
            if st == 1:
                act_out[n, c] = False
            else:
                und = True
        status[n] = 0 if cv else (2 if und else 1)

@numba.njit(parallel=True, cache=True, nogil=True)
def _f_all_kernel(X, act, use_act, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt, fout, argout):
    N = X.shape[0]
    C = R.shape[0]
    for n in numba.prange(N):
        f = np.inf
        a = 0
        for c in range(C):
            if use_act and not act[n, c]:
                continue
            fc = f_cam(c, X[n, 0], X[n, 1], X[n, 2], R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
            if fc < f:
                f = fc
                a = c
        fout[n] = f
        argout[n] = a

@numba.njit(cache=True, nogil=True)
def grad_cam(c, x0, x1, x2, h, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt):
    fp0 = f_cam(c, x0 + h, x1, x2, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
    fp1 = f_cam(c, x0, x1 + h, x2, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
    fp2 = f_cam(c, x0, x1, x2 + h, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
    fm0 = f_cam(c, x0 - h, x1, x2, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
    fm1 = f_cam(c, x0, x1 - h, x2, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
    fm2 = f_cam(c, x0, x1, x2 - h, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
    h2 = 2.0 * h
    return (fp0 - fm0) / h2, (fp1 - fm1) / h2, (fp2 - fm2) / h2


@numba.njit(cache=True, inline="always")
def chord(a, p0, p1, p2, h, gcache, gflag, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt):
    """Gradient of camera ``a`` at the parent centre ``p``, computed once per parent."""
    if not gflag[a]:
        g0, g1, g2 = grad_cam(a, p0, p1, p2, h, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
        gcache[a, 0] = g0
        gcache[a, 1] = g1
        gcache[a, 2] = g2
        gflag[a] = True
    return gcache[a, 0], gcache[a, 1], gcache[a, 2]


@numba.njit(cache=True, inline="always")
def newton_point(c0, c1, c2, p0, p1, p2, use_parent, f, a, act, size_mm, h, max_iter, gcache, gflag, out,
                 R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt):
    """:func:`carving._refine_points` for one cell: centre ``c``, parent centre ``p``
    (used if ``use_parent``), ``f`` and ``a`` the hull function and its camera at ``c``
    over the flagged cameras ``act`` (C,); ``gcache`` / ``gflag`` the parent's chord
    gradients. Writes point, normal and residual to ``out`` (7,); True if kept."""
    C = R.shape[0]
    x0 = c0
    x1 = c1
    x2 = c2
    aprev = -1  # camera of the chord g, taken at the anchor point n
    g0 = g1 = g2 = 0.0
    n0 = n1 = n2 = 0.0
    s0 = s1 = s2 = 0.0  # start of the current line x = s - tau * g
    tau = 0.0
    tau_p = 0.0
    f_p = 0.0
    have_p = False
    for it in range(max_iter + 1):
        if it > 0:
            f = np.inf
            a = 0
            for c in range(C):
                if not act[c]:
                    continue
                fc = f_cam(c, x0, x1, x2, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
                if fc < f:
                    f = fc
                    a = c
        if abs(f) <= 1e-3 * size_mm or it == max_iter:
            if (max(abs(x0 - c0), max(abs(x1 - c1), abs(x2 - c2))) > 0.5 * size_mm * (1.0 + 1e-9)) or (
                    abs(f) > 0.02 * size_mm):
                return False
            # the normal: a gradient of camera a taken within h of the point
            q0 = x0 - n0
            q1 = x1 - n1
            q2 = x2 - n2
            r0 = x0 - p0
            r1 = x1 - p1
            r2 = x2 - p2
            if a == aprev and q0 * q0 + q1 * q1 + q2 * q2 <= h * h:
                d0, d1, d2 = g0, g1, g2
            elif use_parent and r0 * r0 + r1 * r1 + r2 * r2 <= h * h:
                d0, d1, d2 = chord(a, p0, p1, p2, h, gcache, gflag, R, t, K2, cc, dist, has_dist, box, fgeo, size,
                                   opn, sdt)
            else:
                d0, d1, d2 = grad_cam(a, x0, x1, x2, h, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
            gn = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            if not gn > 1e-9:
                return False
            out[0] = x0
            out[1] = x1
            out[2] = x2
            out[3] = -d0 / gn
            out[4] = -d1 / gn
            out[5] = -d2 / gn
            out[6] = f
            return True
        if a != aprev:
            if use_parent and it == 0:
                g0, g1, g2 = chord(a, p0, p1, p2, h, gcache, gflag, R, t, K2, cc, dist, has_dist, box, fgeo, size,
                                   opn, sdt)
                n0, n1, n2 = p0, p1, p2
            else:
                g0, g1, g2 = grad_cam(a, x0, x1, x2, h, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
                n0, n1, n2 = x0, x1, x2
            aprev = a
            s0 = x0
            s1 = x1
            s2 = x2
            tau = 0.0
            have_p = False
        gn2 = g0 * g0 + g1 * g1 + g2 * g2
        if gn2 > 1e-12:
            slope = -gn2  # chord
            if have_p and tau != tau_p:
                sec = (f - f_p) / (tau - tau_p)
                if -4.0 * gn2 <= sec <= -0.25 * gn2:
                    slope = sec
            f_p = f
            tau_p = tau
            have_p = True
            tau = tau - f / slope
        x0 = s0 - tau * g0
        x1 = s1 - tau * g1
        x2 = s2 - tau * g2
        if max(abs(x0 - c0), max(abs(x1 - c1), abs(x2 - c2))) > _LEAVE * size_mm:
            return False
    return False


@numba.njit(parallel=True, cache=True, nogil=True)
def _refine_kernel(Cn, Pn, use_parent, act, size_mm, h, max_iter, R, t, K2, cc, dist, has_dist, box, fgeo, size,
                   opn, sdt, out, good):
    N = Cn.shape[0]
    C = R.shape[0]
    for b in numba.prange((N + _BLOCK - 1) // _BLOCK):
        gcache = np.empty((C, 3))
        gflag = np.zeros(C, dtype=np.bool_)
        for n in range(b * _BLOCK, min(N, (b + 1) * _BLOCK)):
            f = np.inf
            a = 0
            for c in range(C):
                gflag[c] = False
                if not act[n, c]:
                    continue
                fc = f_cam(c, Cn[n, 0], Cn[n, 1], Cn[n, 2], R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
                if fc < f:
                    f = fc
                    a = c
                good[n] = newton_point(Cn[n, 0], Cn[n, 1], Cn[n, 2], Pn[n, 0], Pn[n, 1], Pn[n, 2], use_parent, f, a,
                                   act[n], size_mm, h, max_iter, gcache, gflag, out[n], R, t, K2, cc, dist, has_dist,
                                   box, fgeo, size, opn, sdt)


@numba.njit(parallel=True, cache=True, nogil=True)
def _finest_kernel(parents, pact, origin, size_mm, r, lipc, slack, h, use_parent, max_iter,
                   R, t, K2, cc, dist, has_dist, box, s_in, s_out, fgeo, size, opn, sdt, counts, lohi, npts, out):
    """The finest level in one pass: the 8 children of each boundary parent cell are
    classified (as :func:`_classify_kernel`) and each boundary child is Newton-projected
    at once (as :func:`_refine_kernel`), reusing the hull function at its centre from the
    cell tests and the chord gradients of its parent. Per block of ``_BLOCK`` parents:
    children carved / inside / boundary (``counts``), integer bounds of the kept children
    (``lohi``), and its ``npts`` points first in its ``8 * _BLOCK`` rows of ``out``."""
    M = parents.shape[0]
    C = R.shape[0]
    for b in numba.prange((M + _BLOCK - 1) // _BLOCK):
        act = np.empty(C, dtype=np.bool_)
        gcache = np.empty((C, 3))
        gflag = np.empty(C, dtype=np.bool_)
        lo0 = lo1 = lo2 = np.iinfo(np.int64).max
        hi0 = hi1 = hi2 = np.iinfo(np.int64).min
        n_carved = 0
        n_inside = 0
        n_bnd = 0
        j = b * 8 * _BLOCK
        for m in range(b * _BLOCK, min(M, (b + 1) * _BLOCK)):
            gflag[:] = False
            p0 = origin[0] + (parents[m, 0] + 0.5) * (2.0 * size_mm)
            p1 = origin[1] + (parents[m, 1] + 0.5) * (2.0 * size_mm)
            p2 = origin[2] + (parents[m, 2] + 0.5) * (2.0 * size_mm)
            for i0 in range(2):
                for i1 in range(2):
                    for i2 in range(2):
                        k0 = parents[m, 0] * 2 + i0
                        k1 = parents[m, 1] * 2 + i1
                        k2 = parents[m, 2] * 2 + i2
                        x0 = origin[0] + (k0 + 0.5) * size_mm
                        x1 = origin[1] + (k1 + 0.5) * size_mm
                        x2 = origin[2] + (k2 + 0.5) * size_mm
                        cv = False
                        und = False
                        f = np.inf
                        fa = 0
                        for c in range(C):
                            act[c] = pact[m, c]
                        for c in range(C):
                            if not act[c]:
                                continue
                            u, w, z, xn, yn = project(c, x0, x1, x2, R, t, K2, cc, dist, has_dist, box)
                            st, _, _, g, e = ball_cam_uv(c, u, w, z, xn, yn, r, lipc, slack, has_dist, box, s_in,
                                                         s_out, size, opn, sdt)
                            if st == 0:
                                cv = True
                                break
                            if st == 1:
                                act[c] = False
                                continue
                            und = True
                            # the hull function of camera c at the centre (as f_cam), for the Newton start
                            g = g + e if opn[c] else g - e
                            fc = g * (z / fgeo[c]) if z > Z_MIN else BEHIND
                            if fc < f:
                                f = fc
                                fa = c
                        if cv:
                            n_carved += 1
                            continue
                        lo0 = min(lo0, k0)
                        lo1 = min(lo1, k1)
                        lo2 = min(lo2, k2)
                        hi0 = max(hi0, k0 + 1)
                        hi1 = max(hi1, k1 + 1)
                        hi2 = max(hi2, k2 + 1)
                        if not und:
                            n_inside += 1
                            continue
                        n_bnd += 1
                        if newton_point(x0, x1, x2, p0, p1, p2, use_parent, f, fa, act, size_mm, h, max_iter, gcache,
                                        gflag, out[j], R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt):
                            j += 1
        counts[b, 0] = n_carved
        counts[b, 1] = n_inside
        counts[b, 2] = n_bnd
        lohi[b, 0, 0] = lo0
        lohi[b, 0, 1] = lo1
        lohi[b, 0, 2] = lo2
        lohi[b, 1, 0] = hi0
        lohi[b, 1, 1] = hi1
        lohi[b, 1, 2] = hi2
        npts[b] = j - b * 8 * _BLOCK


@numba.njit(parallel=True, cache=True, nogil=True)
def _compact_kernel(out, npts, start, X, N, f):
    """Rows ``[b * 8 * _BLOCK, b * 8 * _BLOCK + npts[b])`` of ``out`` (point, normal,
    residual) to ``X``, ``N`` and ``f`` from ``start[b]``, for every block ``b``."""
    for b in numba.prange(npts.shape[0]):
        for i in range(npts[b]):
            j = start[b] + i
            r = b * 8 * _BLOCK + i
            for k in range(3):
                X[j, k] = out[r, k]
                N[j, k] = out[r, 3 + k]
            f[j] = out[r, 6]


@numba.njit(cache=True, nogil=True)
def _gather_kernel(cells, act, status, mode, origin, size_mm, lohi, centres, pcentres, bact, child_cells,
                   child_act):
    N = cells.shape[0]
    C = act.shape[1]
    finest = mode == 1
    j = 0
    for n in range(N):
        s = status[n]
        if s == 0:
            continue
        if s == 1 or finest:
            for a in range(3):
                v = cells[n, a]
                if v < lohi[0, a]:
                    lohi[0, a] = v
                if v + 1 > lohi[1, a]:
                    lohi[1, a] = v + 1
        if s != 2:
            continue
        if finest:
            for a in range(3):
                centres[j, a] = origin[a] + (cells[n, a] + 0.5) * size_mm
                pcentres[j, a] = origin[a] + ((cells[n, a] >> 1) + 0.5) * (2.0 * size_mm)
            for c in range(C):
                bact[j, c] = act[n, c]
            j += 1
        elif mode == 2:
            for a in range(3):
                child_cells[j, a] = cells[n, a]
            for c in range(C):
                child_act[j, c] = act[n, c]
            j += 1
        else:
            for i0 in range(2):
                for i1 in range(2):
                    for i2 in range(2):
                        child_cells[j, 0] = cells[n, 0] * 2 + i0
                        child_cells[j, 1] = cells[n, 1] * 2 + i1
                        child_cells[j, 2] = cells[n, 2] * 2 + i2
                        for c in range(C):
                            child_act[j, c] = act[n, c]
                        j += 1


_K = dict(classify=_classify_kernel, f_all=_f_all_kernel, refine=_refine_kernel, gather=_gather_kernel,
          finest=_finest_kernel)


def _compile() -> dict:
    return _K


def classify_cells(stack: ViewStack, cells: np.ndarray, act: np.ndarray, origin: np.ndarray, size_mm: float,
                   r: float, lipc: float, slack: float) -> tuple[np.ndarray, np.ndarray]:
    """Classify integer cells (N, 3) of edge ``size_mm`` against the cameras flagged in
    ``act`` (N, C) bool. Returns the status (N,) int8 (0 carved, 1 inside, 2 boundary) and
    the new flags (N, C) (cameras proven "inside" cleared; carved cells' rows meaningless)."""
    k = _compile()["classify"]
    status = np.empty(len(cells), dtype=np.int8)
    act_out = np.empty(act.shape, dtype=np.bool_)
    act = np.ascontiguousarray(act, dtype=np.bool_)
    if len(cells):
        s = stack
        k(np.ascontiguousarray(cells), act, np.ascontiguousarray(origin, dtype=np.float64), float(size_mm), float(r),
          float(lipc), float(slack), s.R, s.t, s.K2, s.c, s.dist, s.has_dist, s.box, s.s_in, s.s_out, s.fgeo,
          s.size, s.open, s.sdt, act_out, status)
    return status, act_out


def f_all(stack: ViewStack, X: np.ndarray, active: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Hull function (N,) and attaining camera (N,) at points ``X`` (N, 3)."""
    k = _compile()["f_all"]
    X = np.ascontiguousarray(X, dtype=np.float64)
    n = len(X)
    f = np.empty(n)
    arg = np.empty(n, dtype=np.intp)
    if n:
        s = stack
        act = np.zeros((1, 1), np.bool_) if active is None else np.ascontiguousarray(active, dtype=np.bool_)
        k(X, act, active is not None, s.R, s.t, s.K2, s.c, s.dist, s.has_dist, s.box, s.fgeo, s.size, s.open, s.sdt,
          f, arg)
    return f, arg


def refine_points(stack: ViewStack, C: np.ndarray, P: np.ndarray | None, active: np.ndarray, size_mm: float,
                  h: float, max_iter: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Compiled :func:`carving._refine_points`; ``C`` (N, 3) cell centres, ``P`` (N, 3)
    their parent cells' centres or None."""
    k = _compile()["refine"]
    C = np.ascontiguousarray(C, dtype=np.float64)
    n = len(C)
    out = np.empty((n, 7))
    good = np.zeros(n, dtype=np.bool_)
    if n:
        s = stack
        k(C, C if P is None else np.ascontiguousarray(P, dtype=np.float64), P is not None,
          np.ascontiguousarray(active, dtype=np.bool_), float(size_mm), float(h), int(max_iter), s.R, s.t, s.K2, s.c,
          s.dist, s.has_dist, s.box, s.fgeo, s.size, s.open, s.sdt, out, good)
    o = out[good]
    return o[:, :3].copy(), o[:, 3:6].copy(), o[:, 6].copy()


def finest_points(stack: ViewStack, parents: np.ndarray, act: np.ndarray, origin: np.ndarray, size_mm: float,
                  r: float, lipc: float, slack: float, h: float, use_parent: bool, max_iter: int = 6) -> tuple:
    """The finest level from its boundary parents: :func:`classify_cells` of their 8
    children each (``size_mm`` the children's edge, ``r`` their radius), then
    :func:`refine_points` of the boundary children (the parents' centres as ``P`` if
    ``use_parent``), in one pass without materializing the children.

    Returns
    -------
    counts : (3,) int
        Children carved, inside, boundary.
    lohi : (2, 3) int
        Integer bounds ``[lo, hi)`` of the kept children (lo > hi when none).
    points, normals : (M, 3) float
    residual : (M,) float
        As :func:`refine_points`, in the order of the children (parents in order, each
        one's children in ``carving._CHILD_OFFSETS`` order).
    """
    k = _compile()["finest"]
    parents = np.ascontiguousarray(parents)
    n = len(parents)
    nb = (n + _BLOCK - 1) // _BLOCK
    counts = np.zeros((nb, 3), dtype=np.int64)
    lohi = np.empty((nb, 2, 3), dtype=np.int64)
    npts = np.zeros(nb, dtype=np.int64)
    # only the first rows of each block's part are written (np.empty: pages never touched
    # are never allocated)
    out = np.empty((8 * _BLOCK * nb, 7))
    if n:
        s = stack
        k(parents, np.ascontiguousarray(act, dtype=np.bool_), np.ascontiguousarray(origin, dtype=np.float64),
          float(size_mm), float(r), float(lipc), float(slack), float(h), bool(use_parent), int(max_iter), s.R, s.t,
          s.K2, s.c, s.dist, s.has_dist, s.box, s.s_in, s.s_out, s.fgeo, s.size, s.open, s.sdt, counts, lohi, npts, out)
    start = np.zeros(nb, dtype=np.int64)
    np.cumsum(npts[:-1], out=start[1:])
    m = int(npts.sum())
    X, N, f = np.empty((m, 3)), np.empty((m, 3)), np.empty(m)
    if nb:
        _compact_kernel(out, npts, start, X, N, f)
    lh = np.array([lohi[:, 0].min(axis=0), lohi[:, 1].max(axis=0)]) if nb else np.array(
        [[np.iinfo(np.int64).max] * 3, [np.iinfo(np.int64).min] * 3])
    return counts.sum(axis=0), lh, X, N, f


def gather(cells: np.ndarray, act: np.ndarray, status: np.ndarray, n_boundary: int, mode: int,
           origin: np.ndarray, size_mm: float) -> tuple:
    """After :func:`classify_cells`: integer bounds ``[lo, hi)`` (2, 3) of the kept cells
    (inside, plus boundary at the finest level; lo > hi when none), and in the numpy
    order, with ``mode`` 0: the boundary cells' 8 children's integer coordinates (8 nb, 3)
    and flags (8 nb, C); 1 (finest level): the boundary cells' centres (nb, 3) mm, their
    parents' centres (nb, 3) mm and flags (nb, C); 2: the boundary cells themselves
    (nb, 3) and their flags (nb, C)."""
    k = _compile()["gather"]
    C = act.shape[1]
    lohi = np.array([[np.iinfo(np.int64).max] * 3, [np.iinfo(np.int64).min] * 3], dtype=np.int64)
    nf = n_boundary if mode == 1 else 0
    centres = np.empty((nf, 3))
    pcentres = np.empty((nf, 3))
    bact = np.empty((nf, C), dtype=np.bool_)
    nc = {0: 8 * n_boundary, 1: 0, 2: n_boundary}[mode]
    cc = np.empty((nc, 3), dtype=cells.dtype)
    ca = np.empty((nc, C), dtype=np.bool_)
    k(np.ascontiguousarray(cells), act, status, int(mode), np.ascontiguousarray(origin, dtype=np.float64),
      float(size_mm), lohi, centres, pcentres, bact, cc, ca)
    if mode == 1:
        return lohi, centres, pcentres, bact
    return lohi, cc, ca


@numba.njit(parallel=True, cache=True, nogil=True)
def _mesh_signs_kernel(tops, B0, nmax, lo, mv, lipc, slack, R, t, K2, cc, dist, has_dist, box, s_in, s_out, fgeo,
                       size, opn, sdt, vals, exact, n_eval):
    """:func:`carving._mesh_signs`, depth first from each top block (parallel over them),
    trying first the camera that came closest to carving the parent block; nodes also
    get their exact ``f`` (clipped to +-1e3, ``exact`` set)."""
    M = tops.shape[0]
    C = R.shape[0]
    depth = 1
    b = B0
    while b > 1:
        b //= 2
        depth += 1
    for m in numba.prange(M):
        cap = 8 * depth + 1
        sblk = np.empty((cap, 5), dtype=np.int64)  # i, j, k, B, hint camera
        sact = np.empty((cap, C), dtype=np.bool_)
        slb = np.empty(cap)  # lower bound of f over the dropped cameras, mm
        act = np.empty(C, dtype=np.bool_)
        sblk[0, 0] = tops[m, 0]
        sblk[0, 1] = tops[m, 1]
        sblk[0, 2] = tops[m, 2]
        sblk[0, 3] = B0
        sblk[0, 4] = 0
        sact[0, :] = True
        slb[0] = np.inf
        top = 0
        cnt = 0
        while top >= 0:
            i0 = sblk[top, 0]
            i1 = sblk[top, 1]
            i2 = sblk[top, 2]
            B = sblk[top, 3]
            hint = sblk[top, 4]
            for c in range(C):
                act[c] = sact[top, c]
            lb = slb[top]
            top -= 1
            e0 = min(i0 + B - 1, nmax[0])
            e1 = min(i1 + B - 1, nmax[1])
            e2 = min(i2 + B - 1, nmax[2])
            cnt += 1
            if e0 == i0 and e1 == i1 and e2 == i2:
                # A node, its exact f: the cameras proven inside are above lb there, so the
                # minimum over the others is f when it is <= lb (when <= 0 in particular).
                x0 = lo[0] + i0 * mv
                x1 = lo[1] + i1 * mv
                x2 = lo[2] + i2 * mv
                fm = np.inf
                dropped = False
                for c in range(C):
                    if not act[c]:
                        dropped = True
                        continue
                    fc = f_cam(c, x0, x1, x2, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
                    if fc < fm:
                        fm = fc
                if fm > lb and dropped:
                    # the cameras proven inside may attain the minimum
                    for c in range(C):
                        if not act[c]:
                            fc = f_cam(c, x0, x1, x2, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
                            if fc < fm:
                                fm = fc
                vals[i0, i1, i2] = min(max(fm, -1e3), 1e3)
                exact[i0, i1, i2] = True
                continue
            x0 = lo[0] + 0.5 * (i0 + e0) * mv
            x1 = lo[1] + 0.5 * (i1 + e1) * mv
            x2 = lo[2] + 0.5 * (i2 + e2) * mv
            d0 = e0 - i0
            d1 = e1 - i1
            d2 = e2 - i2
            hd = 0.5 * mv * np.sqrt(d0 * d0 * 1.0 + d1 * d1 * 1.0 + d2 * d2 * 1.0)
            carved = False
            und = False
            best = np.inf
            nh = hint
            for q in range(C):
                c = (hint + q) % C
                if not act[c]:
                    continue
                st, high, low, _, _ = ball_cam(c, x0, x1, x2, hd, lipc, slack, R, t, K2, cc, dist, has_dist, box, s_in,
                                         s_out, size, opn, sdt)
                if st == 0:
                    carved = True
                    break
                if st == 1:
                    act[c] = False
                    # f of camera c over the ball: G >= low > 0 at depth >= z - hd
                    zc = R[c, 2, 0] * x0 + R[c, 2, 1] * x1 + R[c, 2, 2] * x2 + t[c, 2]
                    lb = min(lb, low * ((zc - hd) / fgeo[c]))
                else:
                    und = True
                    if high < best:
                        best = high
                        nh = c
            if carved or not und:
                sign = -1.0 if carved else 1.0
                for a0 in range(i0, e0 + 1):
                    for a1 in range(i1, e1 + 1):
                        for a2 in range(i2, e2 + 1):
                            vals[a0, a1, a2] = sign
                continue
            h = B // 2
            for k0 in range(2):
                for k1 in range(2):
                    for k2 in range(2):
                        c0 = i0 + k0 * h
                        c1 = i1 + k1 * h
                        c2 = i2 + k2 * h
                        if c0 > nmax[0] or c1 > nmax[1] or c2 > nmax[2]:
                            continue
                        top += 1
                        sblk[top, 0] = c0
                        sblk[top, 1] = c1
                        sblk[top, 2] = c2
                        sblk[top, 3] = h
                        sblk[top, 4] = nh
                        for c in range(C):
                            sact[top, c] = act[c]
                        slb[top] = lb
        n_eval[m] = cnt


def mesh_signs(stack: ViewStack, n: np.ndarray, lo: np.ndarray, mv: float, B: int, lipc: float,
               slack: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Compiled :func:`carving._mesh_signs` on the grid ``lo + index * mv`` (n0, n1, n2).

    Returns ``vol`` (n0 + 2, n1 + 2, n2 + 2) float32, the grid framed by a layer of -1
    (> 0 exactly where ``f > 0``; the exact ``f``, clipped to +-1e3, where ``exact``,
    otherwise +-1), ``exact`` (n0, n1, n2) bool and the number of blocks and nodes
    tested."""
    n = np.asarray(n, dtype=np.int64)
    vol = np.empty(tuple(int(k) + 2 for k in n), dtype=np.float32)
    vol[0], vol[-1], vol[:, 0], vol[:, -1], vol[:, :, 0], vol[:, :, -1] = (-1.0,) * 6
    exact = np.zeros(tuple(int(k) for k in n), dtype=np.bool_)
    gi = np.meshgrid(*[np.arange(0, k, B) for k in n], indexing="ij")
    tops = np.ascontiguousarray(np.stack([g.ravel() for g in gi], axis=1), dtype=np.int64)
    cnt = np.zeros(len(tops), dtype=np.int64)
    s = stack
    _mesh_signs_kernel(tops, int(B), n - 1, np.ascontiguousarray(lo, dtype=np.float64), float(mv), float(lipc),
                       float(slack), s.R, s.t, s.K2, s.c, s.dist, s.has_dist, s.box, s.s_in, s.s_out, s.fgeo, s.size,
                       s.open, s.sdt, vol[1:-1, 1:-1, 1:-1], exact, cnt)
    return vol, exact, int(cnt.sum())


@numba.njit(cache=True, inline="always")
def _touches_sign_change(cube, i, j, k):
    """Inner node (i, j, k) -- vol's (i + 1, j + 1, k + 1) -- is a corner of a flagged cube
    (the cubes at vol's (i..i+1, j..j+1, k..k+1), flagged at (i+1..i+2, ...) in ``cube``)."""
    for a in range(1, 3):
        for b in range(1, 3):
            for c in range(1, 3):
                if cube[i + a, j + b, k + c]:
                    return True
    return False


@numba.njit(parallel=True, cache=True, nogil=True)
def _need_kernel(vol, exact, cube, count):
    """``cube[i + 1, j + 1, k + 1]``: the cube at ``(i, j, k)`` of ``vol`` has both signs;
    ``count[i]``: nodes of plane ``i`` of the inner grid, corners of such a cube and not
    ``exact``."""
    n0, n1, n2 = vol.shape
    for i in numba.prange(n0):
        for j in range(n1):
            for k in range(n2):
                if i == 0 or j == 0 or k == 0:
                    cube[i, j, k] = False
                    continue
                npos = 0
                for a in range(2):
                    for b in range(2):
                        for c in range(2):
                            if vol[i - 1 + a, j - 1 + b, k - 1 + c] > 0.0:
                                npos += 1
                cube[i, j, k] = 0 < npos < 8
    for i in numba.prange(n0 - 2):
        m = 0
        for j in range(n1 - 2):
            for k in range(n2 - 2):
                if exact[i, j, k]:
                    continue
                if _touches_sign_change(cube, i, j, k):
                    m += 1
        count[i] = m


@numba.njit(parallel=True, cache=True, nogil=True)
def _need_list_kernel(exact, cube, start, idx):
    n0, n1, n2 = exact.shape
    for i in numba.prange(n0):
        m = start[i]
        for j in range(n1):
            for k in range(n2):
                if exact[i, j, k]:
                    continue
                if _touches_sign_change(cube, i, j, k):
                    idx[m, 0] = i
                    idx[m, 1] = j
                    idx[m, 2] = k
                    m += 1


def mesh_need(vol: np.ndarray, exact: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """After :func:`mesh_signs`: the marching-cubes mask (vol's shape; True at the last
    corner of each cube with both signs, as skimage reads it) and the inner-grid indices
    (M, 3) of the corners of those cubes whose value is not yet exact (in C order)."""
    cube = np.empty(vol.shape, dtype=np.bool_)
    count = np.zeros(exact.shape[0], dtype=np.int64)
    _need_kernel(vol, exact, cube, count)
    start = np.zeros(exact.shape[0], dtype=np.int64)
    np.cumsum(count[:-1], out=start[1:])
    idx = np.empty((int(count.sum()), 3), dtype=np.int64)
    _need_list_kernel(exact, cube, start, idx)
    return cube, idx
