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

Third round (same cube, 2 cores): the kernels' inlined helpers took some fifteen array
arguments, and Numba increments and decrements the reference count of each array
argument of an inlined call (atomic operations, shared by the threads): those calls
cost more than the projection and the sampling themselves. The helpers now take one
array of camera parameters (:class:`ViewStack`), the window sizes and the SDTs, with
no reference counting left in the loops (-30 % for the cell tests and the points, the
arithmetic unchanged: the same results bit for bit). :func:`finest_points` also
classifies the level above the finest (no separate cell tests, gather and flag copies
for it), the cell tests hand their per-block counts to a parallel
:func:`gather`, the mesh values come with the marching-cubes mask
(:func:`mesh_fill`), and the parallel loops take their work items one at a time from
an atomic counter (:func:`_next_item`) instead of Numba's static split of a
``prange`` (2-thread speedup of the cell tests 1.35 -> 1.65, of the mesh signs 1.5 ->
1.8, and a thread slowed down by another job no longer holds the other back).

Compile time (issue 15): with every helper inlined into the Numba IR, the Newton point
(about 25 copies of :func:`f_cam` through :func:`grad_cam` and :func:`chord`) made
:func:`_finest_kernel` take 278 s of CPU to compile, three quarters of the first run.
:func:`grad_cam` and :func:`newton_point` are now ordinary calls, compiled once each
(27 s for the kernel with them); the small leaves stay inlined. The per-stage CPU time
and the points are unchanged (bit for bit on the demo cube): the call costs nothing
beside the Newton iterations it runs, whereas un-inlining the leaves (``project``,
``sample``, ``f_cam``) made ``carve`` 40 % slower.
"""

from __future__ import annotations

from collections.abc import Sequence

import numba
import numpy as np
from numba import types
from numba.extending import intrinsic

# OpenMP (libgomp): the TBB found in some environments is too old (see hull_jit). Set
# before the first parallel kernel runs; this module is imported with :mod:`carving` (its
# numba backend).
numba.config.THREADING_LAYER = "omp"  # type: ignore[attr-defined]  # set at run time

__all__ = ["ViewStack", "stack_views", "classify_cells", "f_all", "refine_points", "finest_points", "gather",
            "mesh_signs", "mesh_fill"]


class ViewStack:
    """:class:`carving._View` objects packed into arrays (C cameras): ``cam`` (C, _NP)
    float64, every camera's parameters in one row (the kernels' helpers take this one
    array instead of a dozen: Numba reference-counts each array argument of an inlined
    helper, which cost more than the projection itself); ``size`` (C, 2) int64, the SDT
    windows' W, H; ``sdt`` (C, n) float32."""

    def __init__(self, views: Sequence, sdt: np.ndarray | None = None) -> None:
        C = len(views)
        n = max(v.W * v.H for v in views)
        cam = np.zeros((C, _NP), dtype=np.float64)
        for i, v in enumerate(views):
            cam[i, _R : _R + 9] = np.asarray(v.R, dtype=np.float64).ravel()
            cam[i, _T : _T + 3] = v.t
            cam[i, _K00] = v.K2[0, 0]
            cam[i, _K01] = v.K2[0, 1]
            cam[i, _K11] = v.K2[1, 1]
            cam[i, _CC : _CC + 2] = v.c
            cam[i, _DIST : _DIST + 5] = v.dist
            cam[i, _HAS_DIST] = 1.0 if v.has_dist else 0.0
            cam[i, _BOX : _BOX + 4] = v.box
            cam[i, _S_IN] = v.s_in
            cam[i, _S_OUT] = v.s_out
            cam[i, _FGEO] = v.fgeo
            cam[i, _OPEN] = 1.0 if v.open else 0.0
            cam[i, _WM1] = v.W - 1.0
            cam[i, _HM1] = v.H - 1.0
        self.cam = cam
        self.size = np.array([[v.W, v.H] for v in views], dtype=np.int64)
        if sdt is not None and sdt.dtype == np.float32 and sdt.flags.c_contiguous and sdt.shape[0] == C and all(
                v.sdt.ctypes.data == sdt[i].ctypes.data for i, v in enumerate(views)):
            self.sdt = sdt  # the views' SDTs are already its rows (carve writes them there)
        else:
            self.sdt = np.zeros((C, n), dtype=np.float32)
            for i, v in enumerate(views):
                self.sdt[i, : v.sdt.size] = v.sdt

    def args(self) -> tuple:
        return self.cam, self.size, self.sdt


def stack_views(views: Sequence, sdt: np.ndarray | None = None) -> ViewStack:
    """Pack the views; ``sdt`` (C, n) float32: a buffer whose row ``i`` starts with view
    ``i``'s SDT, used without copying."""
    return ViewStack(views, sdt)


# Columns of ViewStack.cam: R (row major), t, K[:2, :2] (00, 01, 11), principal point (in
# the SDT window), distortion (k1, k2, p1, p2, k3), has_dist (0 / 1), validity box
# (xmin, xmax, ymin, ymax), s_in, s_out, fgeo, open (0 / 1), W - 1, H - 1 (the SDT window's
# last pixel centre); see carving._View.
_R = 0
_T = 9
_K00 = 12
_K01 = 13
_K11 = 14
_CC = 15
_DIST = 17
_HAS_DIST = 22
_BOX = 23
_S_IN = 27
_S_OUT = 28
_FGEO = 29
_OPEN = 30
_WM1 = 31
_HM1 = 32
_NP = 33

#: Depth below which a point is "at or behind" the camera, mm (``carving._Z_MIN``).
Z_MIN = 1e-6
#: Hull-function value of points behind a camera, mm (``carving._BEHIND_MM``).
BEHIND = -1e9
#: Cells (parents) per parallel work item of the Newton kernels.
_BLOCK = 256
#: Cells per parallel work item of the cell tests.
_CBLOCK = 1024
#: A Newton point farther than this from its cell's centre (max norm, cell edges) is
#: dropped at once (``carving._LEAVE``).
_LEAVE = 0.6


@intrinsic
def _next_item(typingctx, counter):
    """Atomically increment ``counter[0]`` (1-D int64 array), returning its old value:
    the kernels' work items are handed out one by one to the threads that ask, so a
    thread slowed down (another job on its core, a denser part of the surface) does not
    hold the others back at the end of the parallel loop (Numba's OpenMP layer splits a
    ``prange`` statically)."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64 and counter.ndim == 1):
        return None
    sig = types.int64(counter)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        return builder.atomic_rmw("add", ary.data, context.get_constant(types.int64, 1), "monotonic")

    return sig, codegen


def _workers() -> tuple[int, np.ndarray]:
    """``prange`` width (the threads) and a fresh counter for :func:`_next_item`."""
    return numba.get_num_threads(), np.zeros(1, dtype=np.int64)


@numba.njit(cache=True, inline="always")
def project(c, x0, x1, x2, cam):
    xc = cam[c, _R + 0] * x0 + cam[c, _R + 1] * x1 + cam[c, _R + 2] * x2 + cam[c, _T + 0]
    yc = cam[c, _R + 3] * x0 + cam[c, _R + 4] * x1 + cam[c, _R + 5] * x2 + cam[c, _T + 1]
    z = cam[c, _R + 6] * x0 + cam[c, _R + 7] * x1 + cam[c, _R + 8] * x2 + cam[c, _T + 2]
    inv = 1.0 / max(z, Z_MIN)
    xn = xc * inv
    yn = yc * inv
    if cam[c, _HAS_DIST] != 0.0:
        qx = min(max(xn, cam[c, _BOX + 0]), cam[c, _BOX + 1])
        qy = min(max(yn, cam[c, _BOX + 2]), cam[c, _BOX + 3])
        k1 = cam[c, _DIST + 0]
        k2 = cam[c, _DIST + 1]
        p1 = cam[c, _DIST + 2]
        p2 = cam[c, _DIST + 3]
        k3 = cam[c, _DIST + 4]
        r2 = qx * qx + qy * qy
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dx = qx * radial + 2.0 * p1 * qx * qy + p2 * (r2 + 2.0 * qx * qx)
        dy = qy * radial + p1 * (r2 + 2.0 * qy * qy) + 2.0 * p2 * qx * qy
        xd = dx + (xn - qx)
        yd = dy + (yn - qy)
    else:
        xd = xn
        yd = yn
    u = cam[c, _K00] * xd + cam[c, _K01] * yd + cam[c, _CC + 0]
    w = cam[c, _K11] * yd + cam[c, _CC + 1]
    return u, w, z, xn, yn

@numba.njit(cache=True, inline="always")
def sample(c, u, w, cam, size, sdt):
    W = size[c, 0]
    H = size[c, 1]
    qu = min(max(u, 0.0), cam[c, _WM1])
    qv = min(max(w, 0.0), cam[c, _HM1])
    iu = min(int(qu), W - 2)
    iv = min(int(qv), H - 2)
    au = qu - iu
    av = qv - iv
    i0 = np.uint64(iv * W + iu)  # >= 0 (unsigned: no negative-index wraparound code)
    s00 = sdt[c, i0]
    s01 = sdt[c, i0 + np.uint64(1)]
    top = s00 + au * np.float32(s01 - s00)
    i0 += np.uint64(W)
    s10 = sdt[c, i0]
    s11 = sdt[c, i0 + np.uint64(1)]
    bot = s10 + au * np.float32(s11 - s10)
    g = top + av * (bot - top)
    du = u - qu
    dv = w - qv
    e = np.hypot(du, dv) if (du != 0.0 or dv != 0.0) else 0.0  # most samples are in the window
    return g, e

@numba.njit(cache=True, inline="always")
def f_cam(c, x0, x1, x2, cam, size, sdt):
    u, w, z, _, _ = project(c, x0, x1, x2, cam)
    g, e = sample(c, u, w, cam, size, sdt)
    if cam[c, _OPEN] != 0.0:
        g = g + e
    else:
        g = g - e
    f = g * (z / cam[c, _FGEO])
    if z > Z_MIN:
        return f
    return BEHIND

@numba.njit(cache=True, inline="always")
def ball_cam_uv(c, u, w, z, xn, yn, r, lipc, slack, cam, size, sdt):
    """Conservative test of a ball of radius ``r`` mm against camera ``c``, its centre
    projected at ``u, w, z, xn, yn`` (:func:`project`), as :func:`carving._classify`:
    0 outside the cone, 1 strictly inside, 2 undecided; the upper and lower bounds of the
    SDT over the ball's disk, px; and :func:`sample` at the centre."""
    ok = z - r > Z_MIN
    zr = z - r if ok else 1.0
    rn = r * np.sqrt(1.0 + xn * xn + yn * yn) / zr
    if cam[c, _HAS_DIST] != 0.0:
        inbox = (xn - rn >= cam[c, _BOX + 0]) and (xn + rn <= cam[c, _BOX + 1]) and (
            yn - rn >= cam[c, _BOX + 2]) and (yn + rn <= cam[c, _BOX + 3])
        rho = rn * (cam[c, _S_IN] if inbox else cam[c, _S_OUT])
    else:
        rho = rn * cam[c, _S_IN]
    g, e = sample(c, u, w, cam, size, sdt)
    exits = (u - rho < 0.0) | (u + rho > cam[c, _WM1]) | (w - rho < 0.0) | (w + rho > cam[c, _HM1])
    ex = e + rho if exits else 0.0
    inner = max(e - rho, 0.0)
    lip = lipc * rho + slack
    if cam[c, _OPEN] != 0.0:
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
def ball_cam(c, x0, x1, x2, r, lipc, slack, cam, size, sdt):
    """:func:`ball_cam_uv` of the ball centred on the world point ``x`` mm."""
    u, w, z, xn, yn = project(c, x0, x1, x2, cam)
    return ball_cam_uv(c, u, w, z, xn, yn, r, lipc, slack, cam, size, sdt)


@numba.njit(parallel=True, cache=True, nogil=True)
def _classify_kernel(cells, act, origin, size_mm, r, lipc, slack, cam, size, sdt, act_out, status, bcount, nw, ctr):
    N = cells.shape[0]
    C = cam.shape[0]
    nb = (N + _CBLOCK - 1) // _CBLOCK
    for _wk in numba.prange(nw):  # one work loop per thread
        while True:
            b = _next_item(ctr)
            if b >= nb:
                break
            bcount[b, 0] = 0
            bcount[b, 1] = 0
            bcount[b, 2] = 0
            for n in range(b * _CBLOCK, min(N, (b + 1) * _CBLOCK)):
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
                    st, _, _, _, _ = ball_cam(c, x0, x1, x2, r, lipc, slack, cam, size, sdt)
                    if st == 0:
                        cv = True
                        break
                    if st == 1:
                        act_out[n, c] = False
                    else:
                        und = True
                s = 0 if cv else (2 if und else 1)
                status[n] = s
                bcount[b, s] += 1

@numba.njit(parallel=True, cache=True, nogil=True)
def _f_all_kernel(X, act, use_act, cam, size, sdt, fout, argout):
    N = X.shape[0]
    C = cam.shape[0]
    for n in numba.prange(N):
        f = np.inf
        a = 0
        for c in range(C):
            if use_act and not act[n, c]:
                continue
            fc = f_cam(c, X[n, 0], X[n, 1], X[n, 2], cam, size, sdt)
            if fc < f:
                f = fc
                a = c
        fout[n] = f
        argout[n] = a

@numba.njit(cache=True)
def grad_cam(c, x0, x1, x2, h, cam, size, sdt):
    fp0 = f_cam(c, x0 + h, x1, x2, cam, size, sdt)
    fp1 = f_cam(c, x0, x1 + h, x2, cam, size, sdt)
    fp2 = f_cam(c, x0, x1, x2 + h, cam, size, sdt)
    fm0 = f_cam(c, x0 - h, x1, x2, cam, size, sdt)
    fm1 = f_cam(c, x0, x1 - h, x2, cam, size, sdt)
    fm2 = f_cam(c, x0, x1, x2 - h, cam, size, sdt)
    h2 = 2.0 * h
    return (fp0 - fm0) / h2, (fp1 - fm1) / h2, (fp2 - fm2) / h2


@numba.njit(cache=True, inline="always")
def chord(a, p0, p1, p2, h, gcache, cam, size, sdt):
    """Gradient of camera ``a`` at the parent centre ``p``, computed once per parent
    (``gcache[a, 3]`` != 0: ``gcache[a, :3]`` holds it)."""
    if gcache[a, 3] == 0.0:
        g0, g1, g2 = grad_cam(a, p0, p1, p2, h, cam, size, sdt)
        gcache[a, 0] = g0
        gcache[a, 1] = g1
        gcache[a, 2] = g2
        gcache[a, 3] = 1.0
    return gcache[a, 0], gcache[a, 1], gcache[a, 2]


@numba.njit(cache=True)
def newton_point(c0, c1, c2, p0, p1, p2, use_parent, f, a, cl, na, und, size_mm, h, max_iter, gcache, cam, size, sdt):
    """:func:`carving._refine_points` for one cell: centre ``c``, parent centre ``p``
    (used if ``use_parent``), ``f`` and ``a`` the hull function and its camera at ``c``
    over the flagged cameras: ``cl[k]`` where ``und[k]`` for ``k < na`` (``cl[:na]`` camera
    indices in increasing order); ``gcache`` the parent's chord gradients
    (:func:`chord`). Returns (kept, point, normal, residual)."""
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
            a = np.int64(0)  # not a literal (Numba would compile grad_cam for Literal[int](0) too)
            for k in range(na):
                if not und[k]:
                    continue
                c = cl[k]
                fc = f_cam(c, x0, x1, x2, cam, size, sdt)
                if fc < f:
                    f = fc
                    a = c
        if abs(f) <= 1e-3 * size_mm or it == max_iter:
            if (max(abs(x0 - c0), max(abs(x1 - c1), abs(x2 - c2))) > 0.5 * size_mm * (1.0 + 1e-9)) or (
                    abs(f) > 0.02 * size_mm):
                break
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
                d0, d1, d2 = chord(a, p0, p1, p2, h, gcache, cam, size, sdt)
            else:
                d0, d1, d2 = grad_cam(a, x0, x1, x2, h, cam, size, sdt)
            gn = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            if not gn > 1e-9:
                break
            return True, x0, x1, x2, -d0 / gn, -d1 / gn, -d2 / gn, f
        if a != aprev:
            if use_parent and it == 0:
                g0, g1, g2 = chord(a, p0, p1, p2, h, gcache, cam, size, sdt)
                n0, n1, n2 = p0, p1, p2
            else:
                g0, g1, g2 = grad_cam(a, x0, x1, x2, h, cam, size, sdt)
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
            break
    return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0


@numba.njit(parallel=True, cache=True, nogil=True)
def _refine_kernel(Cn, Pn, use_parent, act, size_mm, h, max_iter, cam, size, sdt, out, good):
    N = Cn.shape[0]
    C = cam.shape[0]
    for b in numba.prange((N + _BLOCK - 1) // _BLOCK):
        gcache = np.empty((C, 4))
        cl = np.empty(C, dtype=np.int64)
        und = np.ones(C, dtype=np.bool_)
        for n in range(b * _BLOCK, min(N, (b + 1) * _BLOCK)):
            f = np.inf
            a = np.int64(0)  # not a literal: one specialisation of newton_point
            na = 0
            for c in range(C):
                gcache[c, 3] = 0.0
                if not act[n, c]:
                    continue
                cl[na] = c
                na += 1
                fc = f_cam(c, Cn[n, 0], Cn[n, 1], Cn[n, 2], cam, size, sdt)
                if fc < f:
                    f = fc
                    a = c
            ok, y0, y1, y2, m0, m1, m2, fr = newton_point(Cn[n, 0], Cn[n, 1], Cn[n, 2], Pn[n, 0], Pn[n, 1], Pn[n, 2],
                                                          use_parent, f, a, cl, na, und, size_mm, h, max_iter,
                                                          gcache, cam, size, sdt)
            good[n] = ok
            if ok:
                out[n, 0] = y0
                out[n, 1] = y1
                out[n, 2] = y2
                out[n, 3] = m0
                out[n, 4] = m1
                out[n, 5] = m2
                out[n, 6] = fr


@numba.njit(parallel=True, cache=True, nogil=True)
def _finest_kernel(parents, pact, origin, size_mm, rp, r, lipc, slack, h, use_parent, max_iter, cam, size, sdt,
                   counts, lohi, npts, out, nw, ctr):
    """The last two levels in one pass: each cell of the level above the finest (edge
    ``2 * size_mm``, radius ``rp``) is classified (as :func:`_classify_kernel`), then the 8
    children (radius ``r``) of a boundary one are classified against its undecided
    cameras and each boundary child is Newton-projected at once (as
    :func:`_refine_kernel`), reusing the hull function at its centre from the cell tests
    and the chord gradients of its parent. Per block of ``_BLOCK`` cells: cells carved /
    inside / boundary and children carved / inside / boundary (``counts``), integer
    bounds of the inside cells and of the kept children (``lohi``), and its ``npts``
    points first in its ``8 * _BLOCK`` rows of ``out``."""
    M = parents.shape[0]
    C = cam.shape[0]
    psize = 2.0 * size_mm
    nb = (M + _BLOCK - 1) // _BLOCK
    for _wk in numba.prange(nw):  # one work loop per thread
        cl = np.empty(C, dtype=np.int64)  # the cell's undecided cameras
        und = np.empty(C, dtype=np.bool_)  # cl[k] undecided for the child
        gcache = np.empty((C, 4))
        while True:
            b = _next_item(ctr)
            if b >= nb:
                break
            plo0 = plo1 = plo2 = lo0 = lo1 = lo2 = np.iinfo(np.int64).max
            phi0 = phi1 = phi2 = hi0 = hi1 = hi2 = np.iinfo(np.int64).min
            p_carved = 0
            p_inside = 0
            p_bnd = 0
            n_carved = 0
            n_inside = 0
            n_bnd = 0
            j = b * 8 * _BLOCK
            for m in range(b * _BLOCK, min(M, (b + 1) * _BLOCK)):
                p0 = origin[0] + (parents[m, 0] + 0.5) * psize
                p1 = origin[1] + (parents[m, 1] + 0.5) * psize
                p2 = origin[2] + (parents[m, 2] + 0.5) * psize
                cv = False
                na = 0
                for c in range(C):
                    if not pact[m, c]:
                        continue
                    st, _, _, _, _ = ball_cam(c, p0, p1, p2, rp, lipc, slack, cam, size, sdt)
                    if st == 0:
                        cv = True
                        break
                    if st == 2:
                        cl[na] = c
                        na += 1
                if cv:
                    p_carved += 1
                    continue
                if na == 0:
                    p_inside += 1
                    plo0 = min(plo0, parents[m, 0])
                    plo1 = min(plo1, parents[m, 1])
                    plo2 = min(plo2, parents[m, 2])
                    phi0 = max(phi0, parents[m, 0] + 1)
                    phi1 = max(phi1, parents[m, 1] + 1)
                    phi2 = max(phi2, parents[m, 2] + 1)
                    continue
                p_bnd += 1
                for k in range(na):
                    gcache[cl[k], 3] = 0.0
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
                            nu = 0
                            f = np.inf
                            fa = np.int64(0)  # not a literal: one specialisation of newton_point
                            for k in range(na):
                                c = cl[k]
                                u, w, z, xn, yn = project(c, x0, x1, x2, cam)
                                st, _, _, g, e = ball_cam_uv(c, u, w, z, xn, yn, r, lipc, slack, cam, size, sdt)
                                und[k] = st == 2
                                if st == 0:
                                    cv = True
                                    break
                                if st == 1:
                                    continue
                                nu += 1
                                # the hull function of camera c at the centre (as f_cam), for the Newton start
                                g = g + e if cam[c, _OPEN] != 0.0 else g - e
                                fc = g * (z / cam[c, _FGEO]) if z > Z_MIN else BEHIND
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
                            if nu == 0:
                                n_inside += 1
                                continue
                            n_bnd += 1
                            ok, y0, y1, y2, m0, m1, m2, fr = newton_point(x0, x1, x2, p0, p1, p2, use_parent, f, fa, cl, na,
                                                                          und, size_mm, h, max_iter, gcache, cam, size, sdt)
                            if ok:
                                out[j, 0] = y0
                                out[j, 1] = y1
                                out[j, 2] = y2
                                out[j, 3] = m0
                                out[j, 4] = m1
                                out[j, 5] = m2
                                out[j, 6] = fr
                                j += 1
            counts[b, 0] = p_carved
            counts[b, 1] = p_inside
            counts[b, 2] = p_bnd
            counts[b, 3] = n_carved
            counts[b, 4] = n_inside
            counts[b, 5] = n_bnd
            lohi[b, 0, 0, 0] = plo0
            lohi[b, 0, 0, 1] = plo1
            lohi[b, 0, 0, 2] = plo2
            lohi[b, 0, 1, 0] = phi0
            lohi[b, 0, 1, 1] = phi1
            lohi[b, 0, 1, 2] = phi2
            lohi[b, 1, 0, 0] = lo0
            lohi[b, 1, 0, 1] = lo1
            lohi[b, 1, 0, 2] = lo2
            lohi[b, 1, 1, 0] = hi0
            lohi[b, 1, 1, 1] = hi1
            lohi[b, 1, 1, 2] = hi2
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


@numba.njit(parallel=True, cache=True, nogil=True)
def _gather_kernel(cells, act, status, mode, origin, size_mm, bstart, lohi, centres, pcentres, bact, child_cells,
                   child_act, nw, ctr):
    """:func:`gather` by blocks of ``_CBLOCK`` cells, block ``b``'s boundary cells going
    to ``bstart[b]`` onwards (times 8 with ``mode`` 0), its bounds to ``lohi[b]``."""
    N = cells.shape[0]
    C = act.shape[1]
    finest = mode == 1
    nb = (N + _CBLOCK - 1) // _CBLOCK
    for _wk in numba.prange(nw):  # one work loop per thread
        while True:
            b = _next_item(ctr)
            if b >= nb:
                break
            for a in range(3):
                lohi[b, 0, a] = np.iinfo(np.int64).max
                lohi[b, 1, a] = np.iinfo(np.int64).min
            j = bstart[b] * (1 if finest else 8)
            for n in range(b * _CBLOCK, min(N, (b + 1) * _CBLOCK)):
                s = status[n]
                if s == 0:
                    continue
                if s == 1 or finest:
                    for a in range(3):
                        v = cells[n, a]
                        if v < lohi[b, 0, a]:
                            lohi[b, 0, a] = v
                        if v + 1 > lohi[b, 1, a]:
                            lohi[b, 1, a] = v + 1
                if s != 2:
                    continue
                if finest:
                    for a in range(3):
                        centres[j, a] = origin[a] + (cells[n, a] + 0.5) * size_mm
                        pcentres[j, a] = origin[a] + ((cells[n, a] >> 1) + 0.5) * (2.0 * size_mm)
                    for c in range(C):
                        bact[j, c] = act[n, c]
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
                   r: float, lipc: float, slack: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Classify integer cells (N, 3) of edge ``size_mm`` against the cameras flagged in
    ``act`` (N, C) bool. Returns the status (N,) int8 (0 carved, 1 inside, 2 boundary),
    the new flags (N, C) (cameras proven "inside" cleared; carved cells' rows meaningless)
    and the cells carved, inside and boundary per block of ``_CBLOCK`` cells (for
    :func:`gather`)."""
    k = _compile()["classify"]
    n = len(cells)
    status = np.empty(n, dtype=np.int8)
    act_out = np.empty(act.shape, dtype=np.bool_)
    bcount = np.zeros(((n + _CBLOCK - 1) // _CBLOCK, 3), dtype=np.int64)
    act = np.ascontiguousarray(act, dtype=np.bool_)
    if n:
        s = stack
        k(np.ascontiguousarray(cells), act, np.ascontiguousarray(origin, dtype=np.float64), float(size_mm), float(r),
          float(lipc), float(slack), s.cam, s.size, s.sdt, act_out, status, bcount, *_workers())
    return status, act_out, bcount


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
        k(X, act, active is not None, s.cam, s.size, s.sdt, f, arg)
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
          np.ascontiguousarray(active, dtype=np.bool_), float(size_mm), float(h), int(max_iter), s.cam, s.size, s.sdt,
          out, good)
    o = out[good]
    return o[:, :3].copy(), o[:, 3:6].copy(), o[:, 6].copy()


def finest_points(stack: ViewStack, parents: np.ndarray, act: np.ndarray, origin: np.ndarray, size_mm: float,
                  rp: float, r: float, lipc: float, slack: float, h: float, use_parent: bool,
                  max_iter: int = 6) -> tuple:
    """The last two levels from the cells of the level above the finest (``parents``
    (M, 3) integer, edge ``2 * size_mm``, radius ``rp``, flags ``act`` (M, C)):
    :func:`classify_cells` of them, then of the 8 children (``size_mm`` the children's
    edge, ``r`` their radius) of the boundary ones, and :func:`refine_points` of the
    boundary children (the parents' centres as ``P`` if ``use_parent``), in one pass
    without materializing the children.

    Returns
    -------
    counts : (2, 3) int
        Cells, then children: carved, inside, boundary.
    lohi : (2, 2, 3) int
        Integer bounds ``[lo, hi)`` of the inside cells, then of the kept children (lo > hi
        when none).
    points, normals : (M, 3) float
    residual : (M,) float
        As :func:`refine_points`, in the order of the children (boundary cells in order,
        each one's children in ``carving._CHILD_OFFSETS`` order).
    """
    k = _compile()["finest"]
    parents = np.ascontiguousarray(parents)
    n = len(parents)
    nb = (n + _BLOCK - 1) // _BLOCK
    counts = np.zeros((nb, 6), dtype=np.int64)
    lohi = np.empty((nb, 2, 2, 3), dtype=np.int64)
    npts = np.zeros(nb, dtype=np.int64)
    # only the first rows of each block's part are written (np.empty: pages never touched
    # are never allocated; freed on return, the next call reuses them)
    out = np.empty((8 * _BLOCK * nb, 7))
    if n:
        s = stack
        k(parents, np.ascontiguousarray(act, dtype=np.bool_), np.ascontiguousarray(origin, dtype=np.float64),
          float(size_mm), float(rp), float(r), float(lipc), float(slack), float(h), bool(use_parent), int(max_iter),
          s.cam, s.size, s.sdt, counts, lohi, npts, out, *_workers())
    start = np.zeros(nb, dtype=np.int64)
    np.cumsum(npts[:-1], out=start[1:])
    m = int(npts.sum())
    X, N, f = np.empty((m, 3)), np.empty((m, 3)), np.empty(m)
    if nb:
        _compact_kernel(out, npts, start, X, N, f)
    lh = np.array([lohi[:, :, 0].min(axis=0), lohi[:, :, 1].max(axis=0)]).transpose(1, 0, 2) if nb else np.array(
        [[[np.iinfo(np.int64).max] * 3, [np.iinfo(np.int64).min] * 3]] * 2)
    return counts.sum(axis=0).reshape(2, 3), lh, X, N, f


def gather(cells: np.ndarray, act: np.ndarray, status: np.ndarray, bcount: np.ndarray, mode: int,
           origin: np.ndarray, size_mm: float) -> tuple:
    """After :func:`classify_cells` (``bcount`` its counts per block): integer bounds
    ``[lo, hi)`` (2, 3) of the kept cells (inside, plus boundary at the finest level; lo >
    hi when none), and in the numpy order, with ``mode`` 0: the boundary cells' 8
    children's integer coordinates (8 nb, 3) and flags (8 nb, C); 1 (finest level): the
    boundary cells' centres (nb, 3) mm, their parents' centres (nb, 3) mm and flags
    (nb, C)."""
    k = _compile()["gather"]
    C = act.shape[1]
    nblk = len(bcount)
    bstart = np.zeros(nblk, dtype=np.int64)
    np.cumsum(bcount[:-1, 2], out=bstart[1:])
    n_boundary = int(bcount[:, 2].sum())
    lohi = np.empty((nblk, 2, 3), dtype=np.int64)
    nf = n_boundary if mode == 1 else 0
    centres = np.empty((nf, 3))
    pcentres = np.empty((nf, 3))
    bact = np.empty((nf, C), dtype=np.bool_)
    nc = 8 * n_boundary if mode == 0 else 0
    cc = np.empty((nc, 3), dtype=cells.dtype)
    ca = np.empty((nc, C), dtype=np.bool_)
    if nblk:
        k(np.ascontiguousarray(cells), act, status, int(mode), np.ascontiguousarray(origin, dtype=np.float64),
          float(size_mm), bstart, lohi, centres, pcentres, bact, cc, ca, *_workers())
        lh = np.array([lohi[:, 0].min(axis=0), lohi[:, 1].max(axis=0)])
    else:
        lh = np.array([[np.iinfo(np.int64).max] * 3, [np.iinfo(np.int64).min] * 3], dtype=np.int64)
    if mode == 1:
        return lh, centres, pcentres, bact
    return lh, cc, ca


@numba.njit(parallel=True, cache=True, nogil=True)
def _mesh_signs_kernel(tops, B0, nmax, lo, mv, lipc, slack, cam, size, sdt, vals, exact, n_eval, nw, ctr):
    """:func:`carving._mesh_signs`, depth first from each top block (parallel over them),
    trying first the camera that came closest to carving the parent block; nodes also
    get their exact ``f`` (clipped to +-1e3, ``exact`` set)."""
    M = tops.shape[0]
    C = cam.shape[0]
    depth = 1
    b = B0
    while b > 1:
        b //= 2
        depth += 1
    cap = 8 * depth + 1
    for _wk in numba.prange(nw):  # one work loop per thread
        sblk = np.empty((cap, 5), dtype=np.int64)  # i, j, k, B, hint camera
        sact = np.empty((cap, C), dtype=np.bool_)
        slb = np.empty(cap)  # lower bound of f over the dropped cameras, mm
        act = np.empty(C, dtype=np.bool_)
        while True:
            m = _next_item(ctr)
            if m >= M:
                break
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
                        fc = f_cam(c, x0, x1, x2, cam, size, sdt)
                        if fc < fm:
                            fm = fc
                    if fm > lb and dropped:
                        # the cameras proven inside may attain the minimum
                        for c in range(C):
                            if not act[c]:
                                fc = f_cam(c, x0, x1, x2, cam, size, sdt)
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
                    st, high, low, _, _ = ball_cam(c, x0, x1, x2, hd, lipc, slack, cam, size, sdt)
                    if st == 0:
                        carved = True
                        break
                    if st == 1:
                        act[c] = False
                        # f of camera c over the ball: G >= low > 0 at depth >= z - hd
                        zc = cam[c, _R + 6] * x0 + cam[c, _R + 7] * x1 + cam[c, _R + 8] * x2 + cam[c, _T + 2]
                        lb = min(lb, low * ((zc - hd) / cam[c, _FGEO]))
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
                       float(slack), s.cam, s.size, s.sdt, vol[1:-1, 1:-1, 1:-1], exact, cnt, *_workers())
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
def _fill_kernel(vol, exact, lo, mv, cam, size, sdt, cube, count, nw, ctr):
    """``cube[i + 1, j + 1, k + 1]``: the cube at ``(i, j, k)`` of ``vol`` has both signs;
    then the nodes of the inner grid that are corners of such a cube and not ``exact``
    get their ``f`` (clipped to +-1e3; its sign is already theirs), ``count[i]`` of them
    in plane ``i``."""
    n0, n1, n2 = vol.shape
    C = cam.shape[0]
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
    for _wk in numba.prange(nw):  # one work loop per thread
        while True:
            i = _next_item(ctr)
            if i >= n0 - 2:
                break
            m = 0
            for j in range(n1 - 2):
                for k in range(n2 - 2):
                    if exact[i, j, k]:
                        continue
                    if _touches_sign_change(cube, i, j, k):
                        x0 = lo[0] + i * mv
                        x1 = lo[1] + j * mv
                        x2 = lo[2] + k * mv
                        f = np.inf
                        for c in range(C):
                            fc = f_cam(c, x0, x1, x2, cam, size, sdt)
                            if fc < f:
                                f = fc
                        vol[i + 1, j + 1, k + 1] = min(max(f, -1e3), 1e3)
                        m += 1
            count[i] = m


def mesh_fill(stack: ViewStack, vol: np.ndarray, exact: np.ndarray, lo: np.ndarray, mv: float) -> tuple[np.ndarray, int]:
    """After :func:`mesh_signs`: the marching-cubes mask (vol's shape; True at the last
    corner of each cube with both signs, as skimage reads it), and the exact ``f``
    (:func:`f_all`, clipped to +-1e3) written into ``vol`` at the corners of those cubes
    whose value is not yet exact; returns the mask and the number of such corners."""
    cube = np.empty(vol.shape, dtype=np.bool_)
    count = np.zeros(exact.shape[0], dtype=np.int64)
    s = stack
    _fill_kernel(vol, exact, np.ascontiguousarray(lo, dtype=np.float64), float(mv), s.cam, s.size, s.sdt, cube, count,
                 *_workers())
    return cube, int(count.sum())
