"""Straight edges of a part from the contour rays that graze them.

A silhouette shows a polyhedral part only along its edges: every contour ray of a sharp,
straight edge touches the part on that edge and nowhere else. The point the bcps stage
places on such a ray lies somewhere on the ray's stretch inside the visual hull, which
around an edge is a wedge wider than the part: the farther that stretch reaches, the
farther outside the faces the point lies (tens of microns on a cube; issue 28,
``docs/characteristics.md``). The *line* of each ray is exact to the contour's precision,
though, and the edge is the one line that meets them all: rays from two cameras already fix
it (each camera's rays of one edge lie in one plane through the camera's centre and the
edge), more cameras over-determine it. This module fits that line (least squares on the
line-to-line distances) and puts each ray's point where the ray meets it.

No library fits a line to lines (Plücker-coordinate solvers in vision toolkits solve the
exact four-line case, not a weighted least-squares fit over thousands of rays), hence this
module: Gauss-Newton on each line's four parameters. All the lines of a part are fitted
together (:func:`fit_lines_to_rays`: every ray carries the index of its line, and each step
solves every line's 4 x 4 system at once): a part's twenty edges one by one cost twenty
times numpy's per-call overhead, which was most of the time.

All lengths are mm; directions are unit vectors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["RayLine", "RayLines", "closest_on_rays", "fit_line_to_rays", "fit_lines_to_rays", "line_ray_distances",
           "lines_jackknife"]

#: The normal matrix's smallest to largest eigenvalue below this: the rays do not fix the
#: line (one camera's rays all lie in one plane, and every line of that plane meets them).
MIN_CONDITION = 1e-8


@dataclass(frozen=True)
class RayLines:
    """Lines fitted to rays, one per line index.

    Attributes
    ----------
    point : (L, 3) float
        A point of each line (the one nearest its start's point), mm.
    direction : (L, 3) float
        Unit directions.
    s : (L,) float
        Weighted residual standard deviation of each line's rays, mm (NaN: fewer than five).
    determined : (L,) bool
        Whether the rays fix the line (rays in one plane, or fewer than five, do not).
    normal : (L, 4, 4) float
        Each line's normal matrix ``J^T W J`` in its four local parameters (two offsets
        across the line, mm; two turns, rad).
    """

    point: np.ndarray
    direction: np.ndarray
    s: np.ndarray
    determined: np.ndarray
    normal: np.ndarray


@dataclass(frozen=True)
class RayLine:
    """A line fitted to rays.

    Attributes
    ----------
    point : (3,) float
        A point of the line, mm.
    direction : (3,) float
        Unit direction.
    residuals : (N,) float
        Signed distance from each ray to the line, mm.
    cov : (4, 4) float
        Covariance of the line's four parameters (two offsets across the line, mm; two
        turns, rad) from the residuals' scatter.
    s : float
        Weighted residual standard deviation, mm.
    determined : bool
        Whether the rays fix the line (rays in one plane, or fewer than five, do not).
    """

    point: np.ndarray
    direction: np.ndarray
    residuals: np.ndarray
    cov: np.ndarray
    s: float
    determined: bool


def _bases(U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing each row of ``U`` (L, 3) to a right-handed frame."""
    a = np.where((np.abs(U[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = np.cross(U, a)
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    return e1, np.cross(U, e1)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", a, b)


def _linearised(c: np.ndarray, u: np.ndarray, e1: np.ndarray, e2: np.ndarray, O: np.ndarray,
                D: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each ray's residual to its line (c, u), and the Jacobian in the line's four local
    parameters (offsets along ``e1``, ``e2``; turns of ``u`` towards them); every argument
    (N, 3), one row per ray. Returns J (N, 4), r (N,) and which rays are not parallel to
    their line (N,)."""
    m = np.cross(u, D)
    mn = np.sqrt(_dot(m, m))
    ok = mn > 1e-9
    mn = np.where(ok, mn, 1.0)
    n = m / mn[:, None]
    W = c - O
    r = _dot(W, n)
    # d r / d(offset along e) = e . n; d r / d(turn towards e) = (W . dm - r n . dm) / |m|,
    # dm = e x D (the direction's first-order change is e, perpendicular to it).
    J = np.empty((len(O), 4))
    J[:, 0] = _dot(n, e1)
    J[:, 1] = _dot(n, e2)
    for k, e in enumerate((e1, e2)):
        dm = np.cross(e, D)
        J[:, 2 + k] = (_dot(W, dm) - r * _dot(n, dm)) / mn
    return J, r, ok


def _normal_equations(J: np.ndarray, r: np.ndarray, w: np.ndarray, key: np.ndarray,
                      count: int) -> tuple[np.ndarray, np.ndarray]:
    """``J^T W J`` (count, 4, 4) and ``J^T W r`` (count, 4) summed over the rays of each key."""
    H = np.empty((count, 4, 4))
    for i in range(4):
        for j in range(i, 4):
            H[:, i, j] = H[:, j, i] = np.bincount(key, weights=w * J[:, i] * J[:, j], minlength=count)
    g = np.stack([np.bincount(key, weights=w * J[:, i] * r, minlength=count) for i in range(4)], axis=1)
    return H, g


def fit_lines_to_rays(origins: np.ndarray, directions: np.ndarray, line: np.ndarray, points: np.ndarray,
                      starts: np.ndarray, weights: np.ndarray | None = None, *, iterations: int = 20,
                      tol_mm: float = 1e-7) -> RayLines:
    """The lines nearest to sets of rays (weighted least squares on the line-to-ray distances),
    all at once.

    Parameters
    ----------
    origins, directions : (N, 3) float
        The rays: a point of each (a camera's centre) and its unit direction, mm.
    line : (N,) int
        The line each ray belongs to, in ``[0, L)``.
    points, starts : (L, 3) float
        Each line's start (a CAD edge: within a few degrees and a millimetre of the answer):
        a point and a direction.
    weights : (N,) float, optional
        Relative weights (default 1).
    iterations : int
        Gauss-Newton steps at most.
    tol_mm : float
        Stop when no step moves a line by more than this.

    Returns
    -------
    RayLines
    """
    O = np.asarray(origins, float).reshape(-1, 3)
    D = np.asarray(directions, float).reshape(-1, 3)
    li = np.asarray(line, np.int64).ravel()
    C0 = np.asarray(points, float).reshape(-1, 3)
    L = len(C0)
    w = np.ones(len(O)) if weights is None else np.asarray(weights, float).ravel()
    C = C0.copy()
    U = np.asarray(starts, float).reshape(-1, 3)
    U = U / np.linalg.norm(U, axis=1)[:, None]
    H = np.zeros((L, 4, 4))
    for _ in range(max(1, iterations)):
        E1, E2 = _bases(U)
        J, r, ok = _linearised(C[li], U[li], E1[li], E2[li], O, D)
        H, g = _normal_equations(J, r, np.where(ok, w, 0.0), li, L)
        tr = np.trace(H, axis1=1, axis2=2)
        reg = np.where(tr > 0, 1e-12 * tr, 1.0)[:, None, None] * np.eye(4)
        step = -np.linalg.solve(H + reg, g[:, :, None])[:, :, 0]
        C = C + step[:, :1] * E1 + step[:, 1:2] * E2
        U = U + step[:, 2:3] * E1 + step[:, 3:4] * E2
        U /= np.linalg.norm(U, axis=1)[:, None]
        if float(np.max(np.abs(step[:, :2]).sum(1) + 50.0 * np.abs(step[:, 2:]).sum(1), initial=0.0)) < tol_mm:
            break
    C = C + _dot(C0 - C, U)[:, None] * U  # the gauge: each line's point nearest its start's
    r = line_ray_distances(C[li], U[li], O, D)
    good = np.isfinite(r)
    n = np.bincount(li[good], minlength=L)
    wsum = np.bincount(li[good], weights=w[good], minlength=L)
    ss = np.bincount(li[good], weights=w[good] * r[good] ** 2, minlength=L)
    dof = n - 4
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where((dof > 0) & (wsum > 0), np.sqrt(ss / wsum * n / dof), np.nan)
    ev = np.linalg.eigvalsh(H)
    determined = (dof > 0) & (ev[:, -1] > 0) & (ev[:, 0] > MIN_CONDITION * ev[:, -1])
    return RayLines(C, U, s, determined, H)


def fit_line_to_rays(origins: np.ndarray, directions: np.ndarray, weights: np.ndarray | None = None, *,
                     point: np.ndarray, direction: np.ndarray, iterations: int = 20,
                     tol_mm: float = 1e-7) -> RayLine:
    """The line nearest to one set of rays (:func:`fit_lines_to_rays` for a single line),
    with its residuals and covariance.

    Parameters
    ----------
    origins, directions : (N, 3) float
        The rays (directions unit), mm.
    weights : (N,) float, optional
        Relative weights (default 1).
    point, direction : (3,) float
        The start.
    iterations, tol_mm
        As :func:`fit_lines_to_rays`.

    Returns
    -------
    RayLine
        ``point`` is the line's point nearest the start's ``point``.
    """
    O = np.asarray(origins, float).reshape(-1, 3)
    D = np.asarray(directions, float).reshape(-1, 3)
    got = fit_lines_to_rays(O, D, np.zeros(len(O), np.int64), np.asarray(point, float)[None],
                            np.asarray(direction, float)[None], weights, iterations=iterations, tol_mm=tol_mm)
    c, u, s, det = got.point[0], got.direction[0], float(got.s[0]), bool(got.determined[0])
    cov = np.linalg.pinv(got.normal[0]) * (s * s if np.isfinite(s) else np.nan) if det else np.full((4, 4), np.inf)
    return RayLine(c, u, line_ray_distances(c, u, O, D), cov, s, det)


def lines_jackknife(origins: np.ndarray, directions: np.ndarray, line: np.ndarray, groups: np.ndarray,
                    fitted: RayLines, weights: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each line fitted without each group of its rays in turn (delete-one-group jackknife),
    all at once.

    Parameters
    ----------
    origins, directions : (N, 3) float
        The rays (directions unit), mm.
    line : (N,) int
        Each ray's line.
    groups : (N,)
        Each ray's group (the camera that gave it).
    fitted : RayLines
        The lines fitted to all the rays (:func:`fit_lines_to_rays`).
    weights : (N,) float, optional

    Returns
    -------
    labels : (G,)
        The groups.
    point, direction : (L, G, 3) float
        Line ``l`` without group ``labels[g]``'s rays.
    fixed : (L, G) bool
        Whether the other rays still fix the line.
    present : (L, G) bool
        Whether the group gave the line any ray (where not, the line is as fitted).

    Notes
    -----
    Each replica is one Gauss-Newton step from the full fit with that group's terms taken
    out of the normal equations: exact to first order in the change, which is microns
    against the rays' metres of lever.
    """
    O = np.asarray(origins, float).reshape(-1, 3)
    D = np.asarray(directions, float).reshape(-1, 3)
    li = np.asarray(line, np.int64).ravel()
    w = np.ones(len(O)) if weights is None else np.asarray(weights, float).ravel()
    labels, gi = np.unique(np.asarray(groups).ravel(), return_inverse=True)
    L, G = len(fitted.point), len(labels)
    C, U = fitted.point, fitted.direction
    E1, E2 = _bases(U)
    J, r, ok = _linearised(C[li], U[li], E1[li], E2[li], O, D)
    key = li * G + gi.ravel()
    Hg, gg = _normal_equations(J, r, np.where(ok, w, 0.0), key, L * G)
    Hg, gg = Hg.reshape(L, G, 4, 4), gg.reshape(L, G, 4)
    count = np.bincount(key, minlength=L * G).reshape(L, G)
    H, g = Hg.sum(1), gg.sum(1)
    Hk = H[:, None] - Hg
    top = np.linalg.eigvalsh(H)[:, -1]
    fixed = (np.linalg.eigvalsh(Hk)[..., 0] > MIN_CONDITION * top[:, None]) & (top[:, None] > 0) \
        & (count.sum(1)[:, None] - count >= 5)
    Hk[~fixed] = np.eye(4)
    step = -np.linalg.solve(Hk, (g[:, None] - gg)[..., None])[..., 0]
    Ck = C[:, None] + step[..., :1] * E1[:, None] + step[..., 1:2] * E2[:, None]
    Uk = U[:, None] + step[..., 2:3] * E1[:, None] + step[..., 3:4] * E2[:, None]
    Uk /= np.linalg.norm(Uk, axis=2)[..., None]
    return labels, Ck, Uk, fixed, count > 0


def line_ray_distances(point: np.ndarray, direction: np.ndarray, origins: np.ndarray,
                       directions: np.ndarray) -> np.ndarray:
    """Signed distance between a line and each ray's line, mm.

    Parameters
    ----------
    point, direction : (3,) or (N, 3) float
        The line (direction unit), or one line per ray.
    origins, directions : (N, 3) float
        The rays (directions unit), mm.

    Returns
    -------
    (N,) float
        ``(point - origin) . n`` with ``n`` the unit common normal ``direction x d``; NaN for a
        ray parallel to the line.
    """
    D = np.asarray(directions, float).reshape(-1, 3)
    m = np.cross(np.broadcast_to(np.asarray(direction, float), D.shape), D)
    norm = np.sqrt(_dot(m, m))
    W = np.broadcast_to(np.asarray(point, float), D.shape) - np.asarray(origins, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return _dot(W, m) / np.where(norm > 1e-12, norm, np.nan)


def closest_on_rays(origins: np.ndarray, directions: np.ndarray, point: np.ndarray,
                    direction: np.ndarray) -> np.ndarray:
    """Each ray's point nearest to a line (where the ray grazes the edge), mm.

    Parameters
    ----------
    origins, directions : (N, 3) float
        The rays (directions unit).
    point, direction : (3,) or (N, 3) float
        The line (direction unit), or one line per ray.

    Returns
    -------
    (N, 3) float
        NaN for a ray parallel to the line.
    """
    O = np.asarray(origins, float).reshape(-1, 3)
    D = np.asarray(directions, float).reshape(-1, 3)
    u = np.broadcast_to(np.asarray(direction, float), D.shape)
    w0 = O - np.asarray(point, float)
    b = _dot(D, u)
    d = _dot(D, w0)
    e = _dot(w0, u)
    den = 1.0 - b * b
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(den > 1e-12, (b * e - d) / den, np.nan)
    return O + t[:, None] * D
