"""Compiled kernels for :mod:`inspector.kernels.carving` (cell tests, Newton points, hull function).

Profiling ``carve`` at 0.1 mm showed its time in the numpy projection / bilinear
sampling of the cell tests and of the Newton steps (one temporary array per operation,
camera by camera). These Numba kernels fuse projection (OpenCV distortion continued by
the identity beyond the validity box), bilinear sampling of the signed distance and the
per-cell / per-point early exit, in parallel over cells / points. They repeat the numpy
reference (``backend="numpy"`` of :func:`carving.carve`) operation by operation, so the
same cells are kept and the points agree to rounding.
"""

from __future__ import annotations

from collections.abc import Sequence

import numba
import numpy as np

# OpenMP (libgomp): the TBB found in some environments is too old (see hull_jit). Set
# before the first parallel kernel runs; this module is imported only by the numba backend
# of :func:`carving.carve` (lazily).
numba.config.THREADING_LAYER = "omp"

__all__ = ["ViewStack", "stack_views", "classify_cells", "f_all", "refine_points"]


class ViewStack:
    """:class:`carving._View` objects packed into arrays (C cameras)."""

    def __init__(self, views: Sequence) -> None:
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
        self.sdt = np.zeros((C, n), dtype=np.float32)
        for i, v in enumerate(views):
            self.sdt[i, : v.sdt.size] = v.sdt

    def args(self) -> tuple:
        return (self.R, self.t, self.K2, self.c, self.dist, self.has_dist, self.box, self.s_in, self.s_out,
                self.fgeo, self.size, self.open, self.sdt)


def stack_views(views: Sequence) -> ViewStack:
    return ViewStack(views)


#: Depth below which a point is "at or behind" the camera, mm (``carving._Z_MIN``).
Z_MIN = 1e-6
#: Hull-function value of points behind a camera, mm (``carving._BEHIND_MM``).
BEHIND = -1e9


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
    e = np.hypot(u - qu, w - qv)
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
            u, w, z, xn, yn = project(c, x0, x1, x2, R, t, K2, cc, dist, has_dist, box)
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
                cv = True
                break
            if ok and low > 0.0:
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

@numba.njit(cache=True)
def grad_cam(c, x0, x1, x2, h, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt):
    fp0 = f_cam(c, x0 + h, x1, x2, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
    fp1 = f_cam(c, x0, x1 + h, x2, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
    fp2 = f_cam(c, x0, x1, x2 + h, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
    fm0 = f_cam(c, x0 - h, x1, x2, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
    fm1 = f_cam(c, x0, x1 - h, x2, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
    fm2 = f_cam(c, x0, x1, x2 - h, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
    h2 = 2.0 * h
    return (fp0 - fm0) / h2, (fp1 - fm1) / h2, (fp2 - fm2) / h2

@numba.njit(parallel=True, cache=True, nogil=True)
def _refine_kernel(Cn, act, size_mm, h, max_iter, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt,
           Xo, No, fo, good):
    N = Cn.shape[0]
    C = R.shape[0]
    for n in numba.prange(N):
        c0 = Cn[n, 0]
        c1 = Cn[n, 1]
        c2 = Cn[n, 2]
        x0 = c0
        x1 = c1
        x2 = c2
        fres = np.inf
        ares = 0
        ox0 = c0
        ox1 = c1
        ox2 = c2
        aprev = -1
        g0 = 0.0
        g1 = 0.0
        g2 = 0.0
        for it in range(max_iter + 1):
            f = np.inf
            a = 0
            for c in range(C):
                if not act[n, c]:
                    continue
                fc = f_cam(c, x0, x1, x2, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
                if fc < f:
                    f = fc
                    a = c
            if a != aprev:
                g0, g1, g2 = grad_cam(a, x0, x1, x2, h, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
                aprev = a
            if abs(f) <= 1e-3 * size_mm or it == max_iter:
                ox0 = x0
                ox1 = x1
                ox2 = x2
                fres = f
                ares = a
                break
            gn2 = g0 * g0 + g1 * g1 + g2 * g2
            k = f / max(gn2, 1e-12) if gn2 > 1e-12 else 0.0
            x0 = x0 - k * g0
            x1 = x1 - k * g1
            x2 = x2 - k * g2
            if max(abs(x0 - c0), max(abs(x1 - c1), abs(x2 - c2))) > 0.75 * size_mm:
                break
        ok = (max(abs(ox0 - c0), max(abs(ox1 - c1), abs(ox2 - c2))) <= 0.5 * size_mm * (1.0 + 1e-9)) and (
            abs(fres) <= 0.02 * size_mm)
        good[n] = False
        if ok:
            d0, d1, d2 = grad_cam(ares, ox0, ox1, ox2, h, R, t, K2, cc, dist, has_dist, box, fgeo, size, opn, sdt)
            gn = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            if gn > 1e-9:
                good[n] = True
                Xo[n, 0] = ox0
                Xo[n, 1] = ox1
                Xo[n, 2] = ox2
                No[n, 0] = -d0 / gn
                No[n, 1] = -d1 / gn
                No[n, 2] = -d2 / gn
                fo[n] = fres

@numba.njit(cache=True, nogil=True)
def _gather_kernel(cells, act, status, finest, origin, size_mm, lohi, centres, bact, child_cells, child_act):
    N = cells.shape[0]
    C = act.shape[1]
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


_K = dict(classify=_classify_kernel, f_all=_f_all_kernel, refine=_refine_kernel, gather=_gather_kernel)


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


def refine_points(stack: ViewStack, C: np.ndarray, active: np.ndarray, size_mm: float, h: float,
                  max_iter: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Compiled :func:`carving._refine_points`; ``C`` (N, 3) cell centres."""
    k = _compile()["refine"]
    C = np.ascontiguousarray(C, dtype=np.float64)
    n = len(C)
    Xo = np.empty((n, 3))
    No = np.empty((n, 3))
    fo = np.empty(n)
    good = np.zeros(n, dtype=np.bool_)
    if n:
        s = stack
        k(C, np.ascontiguousarray(active, dtype=np.bool_), float(size_mm), float(h), int(max_iter), s.R, s.t, s.K2,
          s.c, s.dist, s.has_dist, s.box, s.fgeo, s.size, s.open, s.sdt, Xo, No, fo, good)
    return Xo[good], No[good], fo[good]


def gather(cells: np.ndarray, act: np.ndarray, status: np.ndarray, n_boundary: int, finest: bool,
           origin: np.ndarray, size_mm: float) -> tuple:
    """After :func:`classify_cells`: integer bounds ``[lo, hi)`` (2, 3) of the kept cells
    (inside, plus boundary at the finest level; lo > hi when none), and either the
    boundary cells' centres (nb, 3) mm and flags (nb, C) (finest level) or their 8
    children's integer coordinates (8 nb, 3) and flags (8 nb, C), in the numpy order."""
    k = _compile()["gather"]
    C = act.shape[1]
    lohi = np.array([[np.iinfo(np.int64).max] * 3, [np.iinfo(np.int64).min] * 3], dtype=np.int64)
    if finest:
        centres = np.empty((n_boundary, 3))
        bact = np.empty((n_boundary, C), dtype=np.bool_)
        cc = np.empty((0, 3), dtype=cells.dtype)
        ca = np.empty((0, C), dtype=np.bool_)
    else:
        centres = np.empty((0, 3))
        bact = np.empty((0, C), dtype=np.bool_)
        cc = np.empty((8 * n_boundary, 3), dtype=cells.dtype)
        ca = np.empty((8 * n_boundary, C), dtype=np.bool_)
    k(np.ascontiguousarray(cells), act, status, bool(finest), np.ascontiguousarray(origin, dtype=np.float64),
      float(size_mm), lohi, centres, bact, cc, ca)
    if finest:
        return lohi, centres, bact
    return lohi, cc, ca
