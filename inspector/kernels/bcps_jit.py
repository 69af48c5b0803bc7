"""Compiled ray selection: :func:`inspector.kernels.bcps.select_on_rays` fused per ray.

Profiling the ``ray`` method (after the exact distance index of
:mod:`inspector.kernels.meshdist`) left its time in the hull kernel (2.3 million samples,
15 projections each) and in the numpy glue between levels. This kernel runs the same
search -- coarse samples, then ``refine_levels`` grids around the best one, the same
costs, tolerances, pruning and tie-breaking -- one ray per iteration, in parallel over
rays, and adds two exact shortcuts:

* the cameras are tried starting from the one that last rejected a sample of the ray
  (consecutive samples are usually rejected by the same camera), so a rejected sample
  costs about one projection instead of half the rig;
* a refinement sample whose Lipschitz bound ``s_c - |t - t_c|`` (the signed distance is
  1-Lipschitz) cannot beat the current best is not even tested against the hull.

Rays for which some signed distance fell outside the distance index's band are flagged;
the caller answers them with the numpy path and the exact fallback.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from inspector.kernels.hull_jit import CameraStack, map_value  # map_value: inlined into the kernels below
from inspector.kernels.meshdist import signed_at

numba.config.THREADING_LAYER = "omp"  # type: ignore[attr-defined]  # set at run time

# Numba's on-disk cache of this module's kernels is keyed on this file alone, not on
# hull_jit's: a change to map_value (issue 26: the maps stored cropped, CameraStack.sizes
# of 7 columns) must come with a change to this file, or a stale cache would inline the old one.
MAP_LAYOUT = 2  # CameraStack.sizes layout this module was compiled against

__all__ = ["select_rays", "coarse_violations", "MAP_LIPSCHITZ"]

#: Bound of the inside-maps' rate of change, px per px of image motion (bilinear
#: interpolation of distance transforms and of the coverage ramp: sqrt(2) to about 2.7
#: where the ramp meets the restored depth), with room to spare.
MAP_LIPSCHITZ = 3.0
#: Extra margin of the skip tests, px.
_MARGIN = 1.0
#: No table of coarse violations (:func:`coarse_violations`).
_NONE_I = np.zeros(0, np.int64)
_NONE_F = np.zeros(0)


@numba.njit(cache=True, inline="always")
def _violation(x0, x1, x2, tk, K, R, t, dist, maps, sizes, open_border, limit, skip, first, lc, grec, trec):
    """Hull violation (px) of the ray's point at ``tk`` and the camera to try first next time.

    ``grec[c]``, ``trec[c]``: the last map value sampled for camera ``c`` on this ray and
    where (NaN: none); ``lc[c]`` bounds how fast that value can change along the ray (px
    per mm), so a camera whose silhouette the point cannot have left (or entered) since is
    not projected again.
    """
    C = K.shape[0]
    worst = 0.0
    arg = first
    for jj in range(C):
        c = first + jj
        if c >= C:
            c -= C
        if c == skip:
            continue
        tr = trec[c]
        if tr == tr:
            slack = lc[c] * abs(tk - tr)
            gr = grec[c]
            if gr - slack > _MARGIN:
                continue  # still inside this silhouette: contributes nothing
            if gr + slack < -(limit + _MARGIN):
                return -(gr + slack), c  # still farther out than the limit
        code, g = map_value(c, x0, x1, x2, K, R, t, dist, maps, sizes, open_border)
        if code == 1:
            continue
        if code == 2:
            return 1e6, c
        grec[c] = g
        trec[c] = tk
        if -g > worst:
            worst = -g
            arg = c
            if worst > limit:
                return worst, c
    return worst, arg


@numba.njit(cache=True, inline="always")
def _sd(x0, x1, x2, Ai, sc, tri, pn, lo, h, dims, start, items, dc):
    """Signed distance of a world point to the (scaled) reference: ``sc * sd_ref(Ai x)``
    with ``Ai`` (3, 4) the world -> reference map."""
    px = Ai[0, 0] * x0 + Ai[0, 1] * x1 + Ai[0, 2] * x2 + Ai[0, 3]
    py = Ai[1, 0] * x0 + Ai[1, 1] * x1 + Ai[1, 2] * x2 + Ai[1, 3]
    pz = Ai[2, 0] * x0 + Ai[2, 1] * x1 + Ai[2, 2] * x2 + Ai[2, 3]
    return sc * signed_at(px, py, pz, tri, pn, lo, h, dims, start, items, dc)


@numba.njit(cache=True, inline="always")
def _coarse_samples(a0, a1, step):
    """How many coarse samples ``a0 + k * step`` lie in ``[a0, a1]`` (to 1e-9 mm): the
    selection and its table of coarse violations (:func:`_coarse_kernel`) must agree."""
    n = int(math.ceil((a1 - a0) / step)) + 1
    while n > 0 and a0 + step * (n - 1) > a1 + 1e-9:
        n -= 1
    return n


@numba.njit(cache=True, inline="always")
def _ray_speeds(origin, d0, d1, d2, ta, tb, K, R, t, lc):
    """Per camera, a bound of how fast the map value changes along the ray over
    ``[ta, tb]``, px per mm: ``lc`` (the rig-wide bound) where this ray's own is not lower.

    With ``A + s B`` the ray in camera coordinates, its projection moves at
    ``|K2 (B_xy A_z - A_xy B_z)| / Z(s)^2`` px per mm (the numerator is constant along the
    ray), largest where the depth ``Z`` is least, at an end of the range. A ray nearly
    along a camera's line of sight barely moves in its image: that camera's last value
    then holds for many samples (issue 26: fewer projections, the same decisions).
    """
    C = K.shape[0]
    out = np.empty(C)
    o0 = origin[0]
    o1 = origin[1]
    o2 = origin[2]
    for c in range(C):
        out[c] = lc[c]
        if not (lc[c] < np.inf):
            continue  # lens distortion: never skipped
        ax = R[c, 0, 0] * o0 + R[c, 0, 1] * o1 + R[c, 0, 2] * o2 + t[c, 0]
        ay = R[c, 1, 0] * o0 + R[c, 1, 1] * o1 + R[c, 1, 2] * o2 + t[c, 1]
        az = R[c, 2, 0] * o0 + R[c, 2, 1] * o1 + R[c, 2, 2] * o2 + t[c, 2]
        bx = R[c, 0, 0] * d0 + R[c, 0, 1] * d1 + R[c, 0, 2] * d2
        by = R[c, 1, 0] * d0 + R[c, 1, 1] * d1 + R[c, 1, 2] * d2
        bz = R[c, 2, 0] * d0 + R[c, 2, 1] * d1 + R[c, 2, 2] * d2
        z = min(az + ta * bz, az + tb * bz)
        if not (z > 0.0):
            continue
        wx = bx * az - ax * bz
        wy = by * az - ay * bz
        ux = K[c, 0, 0] * wx + K[c, 0, 1] * wy
        uy = K[c, 1, 1] * wy
        out[c] = min(lc[c], MAP_LIPSCHITZ * math.sqrt(ux * ux + uy * uy) / (z * z))
    return out


@numba.njit(cache=True, nogil=True)
def _distances_along(origin, d0, d1, d2, a0, step, Ai, sc, tri, pn, lo, h, dims, start, items, dc, out):
    """The signed distances of a ray's samples ``a0 + k * step`` into ``out`` (n,); False
    at the first outside the index's band (NaN; the rest not computed). One call per ray,
    not inlined: a third inlined copy of the distance made the kernel below slower to
    compile."""
    for k in range(out.shape[0]):
        tk = a0 + step * k
        out[k] = _sd(origin[0] + tk * d0, origin[1] + tk * d1, origin[2] + tk * d2, Ai, sc, tri, pn, lo, h, dims,
                     start, items, dc)
        if np.isnan(out[k]):
            return False
    return True


@numba.njit(parallel=True, cache=True, nogil=True)
def _select_kernel(origins, entry, dirs, t0, t1, K, R, t, dist, maps, sizes, open_border, skips, lc,
                   tri, pn, lo, h, dims, start, items, dc, Ai, sc,
                   step, levels, offsets, tol, accept, weights, lips, segments, cstart, ccount, cvals,
                   t_out, v_out, s_out, seg_out, oob_out):
    # One call for the rays of every camera of a pass (issue 26: sixteen calls, one per
    # camera, each a parallel region of a few milliseconds, lost a seventh of two threads'
    # time to the regions' start and end, and the Python between them). Ray r goes through
    # the contour of camera skips[entry[r]], from origins[entry[r]]; lips and weights are
    # that camera's. With a table of the coarse samples' violations (cstart[r] >= 0, from
    # _coarse_kernel: they do not depend on the pose) only its admitted samples are placed.
    M = dirs.shape[0]
    C = K.shape[0]
    nref = offsets.shape[0]
    half = (nref - 1) // 2
    reach = (levels + 1) * step
    for r in numba.prange(M):
        t_out[r] = np.nan
        v_out[r] = np.inf
        s_out[r] = np.inf
        seg_out[r] = 0.0
        oob_out[r] = False
        a0 = t0[r]
        a1 = t1[r]
        if not (a1 > a0):
            continue
        e = entry[r]
        origin = origins[e]
        skip = skips[e]
        lip = lips[e]
        weight = weights[e]
        d0 = dirs[r, 0]
        d1 = dirs[r, 1]
        d2 = dirs[r, 2]
        first = 0
        grec = np.empty(C)
        trec = np.full(C, np.nan)
        # every sample of the ray lies within [a0, a1] widened by at most a step per level
        lcr = _ray_speeds(origin, d0, d1, d2, a0 - reach, a1 + reach, K, R, t, lc)
        gs = np.empty(nref)  # a refinement level's distances, in the order tested
        gj = np.empty(nref, np.int64)  # and their grid indices
        eps = max(0.5 * lip * step, accept)
        bc = np.inf
        bt = 0.0
        bv = np.inf
        bs = np.inf
        qt = 0.0  # the deepest accepted sample, whatever its penalty: the second seed
        qv = np.inf
        qs = np.inf
        nfeas = 0
        oob = False
        n = _coarse_samples(a0, a1, step)
        # Without the segment's length (a selection that only feeds a fit), the coarse
        # samples' distances come first and the hull tests go by increasing distance, from
        # the nearest, until no untested sample can cost less than the best (a cost is its
        # distance plus a penalty): the same best and deepest samples as the scan in index
        # order, whose hull tests are mostly of samples that cannot win. A ray with a
        # distance outside the index's band is scanned, which flags it where it must. With
        # the table, the samples it admits are scanned in index order: only their distances.
        tab = cstart.shape[0] > 0 and cstart[r] >= 0 and ccount[r] == n
        ordered = not segments and not tab
        sv = np.empty(n if ordered else 0)
        if ordered:
            ordered = _distances_along(origin, d0, d1, d2, a0, step, Ai, sc, tri, pn, lo, h, dims, start, items, dc, sv)
        bk = n
        qk = n
        base = cstart[r] if tab else 0
        for i in range(n):
            if tab and not cvals[base + i] <= eps:
                continue  # the table's hull test rejected it (the same test, once an inspection)
            if ordered:
                # the nearest untested sample, the first in index among equals (few are
                # tested: picking each in turn is cheaper than a sort)
                k = -1
                s = np.inf
                for j in range(n):
                    if sv[j] < s:
                        s = sv[j]
                        k = j
                if k < 0 or s > bc:
                    break
                sv[k] = np.inf
            else:
                k = i
            tk = a0 + step * k
            x0 = origin[0] + tk * d0
            x1 = origin[1] + tk * d1
            x2 = origin[2] + tk * d2
            if tab:
                v = cvals[base + k]
            else:
                v, first = _violation(x0, x1, x2, tk, K, R, t, dist, maps, sizes, open_border, eps, skip, first, lcr,
                                      grec, trec)
            if v > eps:
                continue
            if not ordered:
                s = _sd(x0, x1, x2, Ai, sc, tri, pn, lo, h, dims, start, items, dc)
                if np.isnan(s):
                    oob = True
                    continue
                nfeas += 1
            c = s + weight * max(v - tol, 0.0)
            if c < bc or (c == bc and k < bk):  # the least cost, the first in index among equals
                bc = c
                bt = tk
                bv = v
                bs = s
                bk = k
            if s < qs or (s == qs and k < qk):  # the deepest admitted, likewise
                qt = tk
                qv = v
                qs = s
                qk = k
        if not segments:  # (a table or the distance order: not every sample was counted)
            nfeas = -1
        # (the coarse and refinement loops repeat "sample -> hull -> distance" on purpose:
        # a shared helper is not inlinable by Numba with this many arguments, and an
        # out-of-line call per sample made the kernel 5x slower)
        seg_out[r] = nfeas * step if nfeas >= 0 else np.nan
        if oob:
            oob_out[r] = True
            continue
        if not (bc < np.inf):
            continue  # no candidate: the numpy path never finds one in refinement either
        # Refine around the best coarse sample and, if another, around the deepest one: a
        # ray grazing where the hull is thinner than a coarse step has its true point's
        # coarse neighbours well outside some silhouette, so a worse point elsewhere on
        # the ray wins the coarse round (binary shaft: a point 0.15 mm out, where the ray
        # passes 0.01 mm from the surface 9 mm farther on).
        two = qs < bs and abs(qt - bt) > step
        ft = bt
        fv = bv
        fs = bs
        fc = np.inf
        for seed in range(2 if two else 1):
            if seed == 1:
                bt = qt
                bv = qv
                bs = qs
            hh = step
            for _ in range(levels):
                eps = max(0.5 * lip * hh / half, accept)
                cb = bs + weight * max(bv - tol, 0.0)
                lcost = np.inf
                lt = 0.0
                lv = 0.0
                ls = 0.0
                lj = nref
                # The grid's distances first, then its samples in increasing distance: the
                # first one the hull admits without penalty ends the level (every other one
                # is no nearer, and its cost, distance plus penalty, cannot be lower). The
                # hull test, which reads most cameras' maps near the hull's edge, runs on
                # those samples only, instead of on every sample nearer than the seed. The
                # same winner as testing them in grid order: the least cost, the first in
                # grid order among equal ones. A sample no nearer than the level's seed is
                # never tested; one whose distance is outside the index's band (NaN) is
                # tested last, and flags the ray only where the hull lets it compete.
                m = 0
                for j in range(nref):
                    tt = bt + hh * offsets[j]
                    if bs - abs(tt - bt) >= cb:
                        continue  # (the distance is 1-Lipschitz: it cannot beat the seed)
                    s = _sd(origin[0] + tt * d0, origin[1] + tt * d1, origin[2] + tt * d2, Ai, sc, tri, pn, lo, h,
                            dims, start, items, dc)
                    if s >= cb:
                        continue
                    # insertion into the order: by distance, NaN last, then by grid index
                    k = m
                    while k > 0 and (np.isnan(gs[k - 1]) and not np.isnan(s) or gs[k - 1] > s):
                        gs[k] = gs[k - 1]
                        gj[k] = gj[k - 1]
                        k -= 1
                    gs[k] = s
                    gj[k] = j
                    m += 1
                for k in range(m):
                    s = gs[k]
                    j = gj[k]
                    nan = np.isnan(s)
                    if nan and oob:
                        break  # the ray is flagged already; a NaN never wins
                    if not nan and (s > lcost or (s == lcost and j > lj)):
                        continue  # cannot win (the rest, further in the order, may still be NaN)
                    tt = bt + hh * offsets[j]
                    x0 = origin[0] + tt * d0
                    x1 = origin[1] + tt * d1
                    x2 = origin[2] + tt * d2
                    v, first = _violation(x0, x1, x2, tt, K, R, t, dist, maps, sizes, open_border, eps, skip, first, lcr, grec, trec)
                    if v > eps:
                        continue
                    pen = weight * max(v - tol, 0.0)
                    if bs - abs(tt - bt) + pen >= cb:
                        continue
                    if nan:
                        oob = True
                        continue
                    c = s + pen
                    if c < lcost or (c == lcost and j < lj):
                        lcost = c
                        lt = tt
                        lv = v
                        ls = s
                        lj = j
                if lcost < cb:
                    bt = lt
                    bv = lv
                    bs = ls
                hh = hh / half
            c = bs + weight * max(bv - tol, 0.0)
            if c < fc:
                fc = c
                ft = bt
                fv = bv
                fs = bs
        bt = ft
        bv = fv
        bs = fs
        if oob:
            oob_out[r] = True
            continue
        t_out[r] = bt
        v_out[r] = bv
        s_out[r] = bs


@numba.njit(parallel=True, cache=True, nogil=True)
def _coarse_kernel(origins, entry, dirs, t0, t1, K, R, t, dist, maps, sizes, open_border, skips, lc, step, eps_e,
                   cstart, ccount, cvals):
    # The hull violation of each ray's coarse samples, in index order as the scan of
    # _select_kernel (the same function of the same point and limit); inf where rejected.
    M = dirs.shape[0]
    C = K.shape[0]
    for r in numba.prange(M):
        ccount[r] = 0
        a0 = t0[r]
        a1 = t1[r]
        if not (a1 > a0):
            continue
        e = entry[r]
        origin = origins[e]
        eps = eps_e[e]
        d0 = dirs[r, 0]
        d1 = dirs[r, 1]
        d2 = dirs[r, 2]
        n = _coarse_samples(a0, a1, step)
        first = 0
        grec = np.empty(C)
        trec = np.full(C, np.nan)
        lcr = _ray_speeds(origin, d0, d1, d2, a0, a1, K, R, t, lc)
        base = cstart[r]
        for k in range(n):
            tk = a0 + step * k
            v, first = _violation(origin[0] + tk * d0, origin[1] + tk * d1, origin[2] + tk * d2, tk, K, R, t, dist,
                                  maps, sizes, open_border, eps, skips[e], first, lcr, grec, trec)
            cvals[base + k] = v if v <= eps else np.inf
        ccount[r] = n


def coarse_violations(origins, entry, dirs, t0, t1, stack, skips, eps, *, step_mm, bounds):
    """The hull violation, px, of every coarse sample ``t0 + k * step_mm`` (``k = 0 .. n - 1``,
    up to ``t1``) of rays ``origins[entry] + t * dirs`` (M, 3): a table that
    :func:`select_rays` reads instead of testing them (they do not depend on the pose).

    ``eps`` (E,) is each camera's coarse acceptance, px (a violation above it is stored as
    inf); the other parameters are :func:`select_rays`'.

    Returns
    -------
    start, count : (M,) int
        Where each ray's samples begin in ``values``, and how many (0: an empty range).
    values : (S,) float
        The violations, px, ray after ray.
    """
    t0 = np.ascontiguousarray(t0, dtype=np.float64)
    t1 = np.ascontiguousarray(t1, dtype=np.float64)
    M = len(t0)
    with np.errstate(invalid="ignore"):
        room = np.where(t1 > t0, np.ceil((t1 - t0) / step_mm) + 1, 0).astype(np.int64)  # the kernel's n or more
    start = np.zeros(M, np.int64)
    np.cumsum(room[:-1], out=start[1:])
    count = np.zeros(M, np.int64)
    values = np.empty(int(room.sum()))
    if M:
        _coarse_kernel(
            np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3), np.ascontiguousarray(entry, dtype=np.int64),
            np.ascontiguousarray(dirs, dtype=np.float64), t0, t1, stack.K, stack.R, stack.t, stack.dist, stack.maps,
            stack.sizes, stack.open_border, np.ascontiguousarray(skips, dtype=np.int64),
            MAP_LIPSCHITZ * camera_speed(stack, np.asarray(bounds, float)), float(step_mm),
            np.ascontiguousarray(eps, dtype=np.float64), start, count, values,
        )
    return start, count, values


def camera_speed(stack: CameraStack, bounds: np.ndarray) -> np.ndarray:
    """Per camera, a bound of how fast a point's projection moves, px per mm, for points
    in the sphere around ``bounds`` (2, 3) mm; inf for cameras with lens distortion
    (never skipped).

    With ``z`` the depth and ``x`` the normalized coordinates, the Jacobian of ``x`` is
    ``[I | -x] / z``, whose largest singular value is ``sqrt(1 + |x|^2) / z``.
    """
    key = np.asarray(bounds, np.float64).tobytes()
    cached = stack.speed_cache
    if cached is not None and cached[0] == key:
        return cached[1]
    centre = 0.5 * (bounds[0] + bounds[1])
    radius = 0.5 * float(np.linalg.norm(bounds[1] - bounds[0]))
    out = np.full(len(stack.K), np.inf)
    for c in range(len(stack.K)):
        if np.any(stack.dist[c]):
            continue
        pc = stack.R[c] @ centre + stack.t[c]
        zmin = pc[2] - radius
        if zmin <= 0:
            continue
        xmax = (float(np.hypot(pc[0], pc[1])) + radius) / zmin
        k2 = float(np.linalg.norm(stack.K[c][:2, :2], 2))
        out[c] = k2 * np.sqrt(1.0 + xmax * xmax) / zmin
    stack.speed_cache = (key, out)  # the same bounds for every camera of a pass
    return out


def select_rays(origins, entry, dirs, t0, t1, stack, skips, mesh, pose, *, step_mm, refine_levels, refine_samples,
                tolerance_px, accept_px, weights, lips, bounds, sd_scale=1.0, segments=True, coarse=None):
    """Run the fused search on rays ``origins[entry] + t * dirs`` (M, 3) over ``[t0, t1]`` (M,),
    the rays of several cameras at once.

    Parameters are those of :func:`inspector.kernels.bcps.select_on_rays`, per camera:
    ``origins`` (E, 3) the cameras' centres, mm, ``skips`` (E,) int their indices in
    ``stack``, ``weights`` (E,) their cost of a pixel of violation, mm, and ``lips`` (E,)
    their bound of the projection's rate, px per mm; ``entry`` (M,) int the camera
    (0 .. E-1) each ray belongs to. ``bounds`` (2, 3) is the box of the rays' samples, mm;
    ``stack`` a :class:`~inspector.kernels.hull_jit.CameraStack`, ``mesh`` a
    :class:`~inspector.kernels.meshdist.MeshDistance` of the reference and ``pose`` (4, 4)
    reference -> world, or any invertible affine placement: the signed distance of a world
    point ``x`` is then ``sd_scale * mesh(pose^-1 x)`` (a scaled reference,
    :class:`~inspector.kernels.prior.SizePrior`; still 1-Lipschitz). ``segments=False``:
    the segments' lengths are not measured (NaN), which lets the coarse search test only
    the samples that can win (the same selected points). ``coarse``: the rays' table of
    :func:`coarse_violations` ``(start, count, values)``, made with the same step, ranges
    and each camera's ``max(0.5 * lip * step_mm, accept_px)``; its violations are read
    instead of tested (the same results; a ray whose count differs is tested).

    Returns
    -------
    t : (M,) float
        Ray parameter of the selected point (NaN: no candidate).
    violation, deviation, segment_mm : (M,) float
    out_of_band : (M,) bool
        Rays that met a signed distance outside the index's band (answer them elsewhere).
    """
    M = len(dirs)
    out = [np.empty(M) for _ in range(4)]
    oob = np.zeros(M, dtype=np.bool_)
    if M:
        Ai = np.ascontiguousarray(np.linalg.inv(np.asarray(pose, dtype=np.float64))[:3])
        _select_kernel(
            np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3), np.ascontiguousarray(entry, dtype=np.int64),
            np.ascontiguousarray(dirs, dtype=np.float64),
            np.ascontiguousarray(t0, dtype=np.float64), np.ascontiguousarray(t1, dtype=np.float64),
            stack.K, stack.R, stack.t, stack.dist, stack.maps, stack.sizes, stack.open_border,
            np.ascontiguousarray(skips, dtype=np.int64),
            MAP_LIPSCHITZ * camera_speed(stack, np.asarray(bounds, float)),
            *mesh.args(), Ai, float(sd_scale),
            float(step_mm), int(refine_levels), np.linspace(-1.0, 1.0, int(refine_samples)), float(tolerance_px),
            float(accept_px), np.ascontiguousarray(weights, dtype=np.float64), np.ascontiguousarray(lips, dtype=np.float64),
            bool(segments), *(coarse if coarse is not None else (_NONE_I, _NONE_I, _NONE_F)), *out, oob,
        )
    return out[0], out[1], out[2], out[3], oob


@numba.njit(cache=True, nogil=True)
def _ranges_kernel(puv, z, uv, cos, rho, radius, t0, t1):
    n = puv.shape[0]
    lo0 = np.inf
    lo1 = np.inf
    hi0 = -np.inf
    hi1 = -np.inf
    for i in range(n):
        a = math.floor(puv[i, 0] / rho)
        b = math.floor(puv[i, 1] / rho)
        lo0 = min(lo0, a)
        lo1 = min(lo1, b)
        hi0 = max(hi0, a)
        hi1 = max(hi1, b)
    # cells with a one-cell border, so the 3x3 neighbourhood of any cell is inside
    w = int(hi0 - lo0) + 3
    h = int(hi1 - lo1) + 3
    zmin = np.full((h, w), np.inf)
    zmax = np.full((h, w), -np.inf)
    for i in range(n):
        a = int(math.floor(puv[i, 0] / rho) - lo0) + 1
        b = int(math.floor(puv[i, 1] / rho) - lo1) + 1
        zi = z[i]
        for bb in range(b - 1, b + 2):
            for aa in range(a - 1, a + 2):
                if zi < zmin[bb, aa]:
                    zmin[bb, aa] = zi
                if zi > zmax[bb, aa]:
                    zmax[bb, aa] = zi
    for m in range(uv.shape[0]):
        a = int(math.floor(uv[m, 0] / rho) - lo0) + 1
        b = int(math.floor(uv[m, 1] / rho) - lo1) + 1
        if a < 0 or b < 0 or a >= w or b >= h or not (zmin[b, a] <= zmax[b, a]):
            continue
        t0[m] = zmin[b, a] / cos[m] - radius
        t1[m] = zmax[b, a] / cos[m] + radius


def ray_ranges(puv: np.ndarray, z: np.ndarray, uv: np.ndarray, cos: np.ndarray, rho: float,
               radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Compiled core of :func:`inspector.kernels.bcps.ray_ranges` (same cells, same result).

    ``puv`` (N, 2) and ``z`` (N,): projections and depths of the reconstruction points in
    front of the camera; ``uv`` (M, 2) the contour points, ``cos`` (M,) their rays' cosine
    to the optical axis; ``rho`` the cell, px; ``radius`` the margin, mm.
    """
    M = len(uv)
    t0 = np.full(M, np.inf)
    t1 = np.full(M, -np.inf)
    if len(z) and M:
        _ranges_kernel(np.ascontiguousarray(puv, dtype=np.float64), np.ascontiguousarray(z, dtype=np.float64),
                       np.ascontiguousarray(uv, dtype=np.float64), np.ascontiguousarray(cos, dtype=np.float64),
                       float(rho), float(radius), t0, t1)
    return t0, t1
