"""Least-squares fits of geometric primitives with their uncertainty, and minimum-zone form.

Every fit minimises ``sum_i w_i r_i^2`` of the points' orthogonal residuals ``r_i`` (mm) by
Gauss-Newton (Levenberg-Marquardt damped) in a *local* minimal parametrisation about the
current estimate (offsets and tilts of the primitive, its size), so each parameter is well
scaled and free of the gauge freedoms (a plane's point sliding in the plane, an axis point
sliding along the axis). At the solution, with ``J`` the (N, p) Jacobian of the residuals in
that parametrisation and ``W = diag(w)``::

    s^2 = sum_i w_i r_i^2 / (N - p)          cov = s^2 (J^T W J)^-1

``cov`` is the covariance of the local parameters (:attr:`Fit.names`), and the standard
uncertainty of any derived quantity (a radius, the distance between two planes, the angle
between two axes) follows by first-order propagation ``u^2 = g^T cov g`` with ``g`` its
gradient in those parameters (:func:`propagate`, central differences). The weights are
relative (e.g. the bcps stage's per-point confidence): ``s^2`` absorbs their scale.

A fit says when it cannot be trusted (:attr:`Fit.problem`, None when it can): too few points
for its parameters, a singular normal matrix (points on a line for a plane, one generator of
a cylinder), or a key parameter amplified far beyond the points' own scatter -- the radius
of a short arc, the tilt of a plane seen along a narrow strip (:attr:`Fit.amplification`:
the parameter's standard uncertainty over ``s / sqrt(N)``; about 1 for a full circle, a few
for a square face, hundreds for a 10-degree arc).

Minimum-zone (Chebyshev) form -- :func:`flatness`, :func:`roundness`,
:func:`cylindricity` -- minimises the width of the zone that holds every point, as the ISO
definitions require; the zone's parameters are linearised about the least-squares fit (the
tilts involved are micro-radians to milli-radians, the linearisation error is below 1e-9 mm)
and the linear programme is solved by HiGHS (:mod:`inspector.kernels.lp`), re-linearised until it
settles. :func:`circle_mcc` and :func:`circle_mic` give the minimum circumscribed and
maximum inscribed circles the same way.

Units: mm and radians inside; angles in the results' ``*_deg`` names are degrees.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "Fit",
    "FitError",
    "MAX_AMPLIFICATION",
    "angle_between",
    "circle_mcc",
    "circle_mic",
    "cylinder_lm_numpy",
    "cylinder_residual_numpy",
    "cylindricity",
    "direction_of",
    "distance_between",
    "geometric_distance",
    "group_moments",
    "fit_circle",
    "fit_cone",
    "fit_cylinder",
    "fit_line",
    "fit_plane",
    "fit_sphere",
    "fit_torus",
    "between_groups_f",
    "design_effect",
    "grouped",
    "geometric_angle",
    "plane_jackknife",
    "planes_without",
    "flatness",
    "orthonormal_basis",
    "propagate",
    "roundness",
    "roundness_sections",
]

#: A key parameter whose standard uncertainty exceeds this many times ``s / sqrt(N)`` is not
#: constrained by the points (a full circle: ~1; a half circle: ~3; a 60-degree arc: ~25;
#: a 10-degree arc: ~1000).
MAX_AMPLIFICATION = 30.0
#: A normal matrix whose scaled condition number exceeds this is singular.
MAX_CONDITION = 1e12
#: Gauss-Newton stops when no step moves the residuals' weighted sum of squares by more than this (relative).
#: A step that lowers the cost by a fraction ``e`` moved the parameters by about ``sqrt(e) s``:
#: 1e-10 leaves them within 1e-5 of the points' scatter (and Gauss-Newton converges
#: quadratically, so the last step taken is already far below that); 1e-13 cost two more
#: evaluations per fit for nothing.
_RTOL = 1e-10
_MAX_ITER = 100


class FitError(ValueError):
    """The input cannot be fitted at all (wrong shapes, non-finite values, negative weights)."""


@dataclass(frozen=True, eq=False)
class Fit:
    """One least-squares fit.

    Attributes
    ----------
    kind : str
        ``plane``, ``line``, ``circle``, ``cylinder``, ``sphere``, ``cone`` or ``torus``.
    params : dict
        The primitive, reference frame, mm (see each ``fit_*``); vectors as (3,) arrays.
    residuals : (N,) float
        Signed orthogonal residuals, mm (positive outside a circle, cylinder, sphere, cone
        or a torus's tube; along the normal for a plane; the distance for a line).
    names : tuple of str
        The local parameters ``cov`` is expressed in.
    cov : (p, p) float
        Their covariance, mm^2 / rad^2 (``inf`` everywhere when the fit is singular).
    s : float
        Weighted residual standard deviation ``sqrt(sum w r^2 / (N - p))``, mm.
    n : int
        Points used.
    u : dict of str to float
        Standard uncertainties of the primitive's derived quantities (``radius``,
        ``diameter``, ``offset``, ``tilt_rad``, ``half_angle_deg`` ...).
    amplification : float
        The key parameter's standard uncertainty over ``s / sqrt(N)``.
    problem : str or None
        Why the fit cannot be trusted; None when it can.
    design_effect : float
        The factor :func:`grouped` multiplied ``cov`` by (1: the points taken as independent).
    """

    kind: str
    params: dict[str, Any]
    residuals: np.ndarray
    names: tuple[str, ...]
    cov: np.ndarray
    s: float
    n: int
    u: dict[str, float]
    amplification: float
    problem: str | None
    _geometry: Callable[[np.ndarray], dict[str, Any]] = field(repr=False)
    design_effect: float = 1.0

    @property
    def ok(self) -> bool:
        """Whether the fit can be trusted (no :attr:`problem`)."""
        return self.problem is None

    def perturbed(self, delta: np.ndarray) -> dict[str, Any]:
        """The primitive moved by ``delta`` (p,) in the local parameters :attr:`names`."""
        return self._geometry(np.asarray(delta, float))

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "params": {k: _plain(v) for k, v in self.params.items()}, "s": self.s,
                "n": self.n, "u": dict(self.u), "amplification": self.amplification, "problem": self.problem,
                "design_effect": self.design_effect}


def _mean_squares(residuals: np.ndarray, groups: np.ndarray, weights: np.ndarray | None) -> tuple[float, float, float]:
    """(between, within, total) weighted mean squares of ``residuals`` grouped by ``groups``;
    NaN when fewer than two groups or no degree of freedom within them."""
    r = np.asarray(residuals, float).ravel()
    g = np.asarray(groups).ravel()
    w = np.ones(len(r)) if weights is None else np.asarray(weights, float).ravel()
    if g.shape != r.shape or w.shape != r.shape:
        raise FitError(f"residuals, groups and weights must have one shape, got {r.shape}, {g.shape}, {w.shape}")
    labels, idx = np.unique(g, return_inverse=True)
    G, n = len(labels), len(r)
    if G < 2 or n - G <= 0:
        return float("nan"), float("nan"), float("nan")
    w = w / max(float(w.mean()), 1e-300)
    W = np.bincount(idx, weights=w, minlength=G)
    mean_g = np.bincount(idx, weights=w * r, minlength=G) / np.maximum(W, 1e-300)
    grand = float((w * r).sum() / w.sum())
    between = float((W * (mean_g - grand) ** 2).sum()) / (G - 1)
    within = float((w * (r - mean_g[idx]) ** 2).sum()) / (n - G)
    total = float((w * (r - grand) ** 2).sum()) / (n - 1)
    return between, within, total


def between_groups_f(residuals: np.ndarray, groups: np.ndarray, weights: np.ndarray | None = None) -> float:
    """The one-way analysis-of-variance ratio of ``residuals`` (N,) grouped by ``groups`` (N,):
    the mean square between the groups' (weighted) means over the mean square within them.

    About 1 when the groups share nothing but the points' scatter; large when each group's
    points are off together (a camera's contour placed a little off: all its points move).
    NaN with fewer than two groups or no degree of freedom within them."""
    between, within, _ = _mean_squares(residuals, groups, weights)
    return between / within if within > 0 else (float("nan") if np.isnan(within) else float("inf"))


def design_effect(residuals: np.ndarray, groups: np.ndarray, weights: np.ndarray | None = None) -> float:
    """How many times the variance of a mean of ``residuals`` exceeds what independent points
    would give, their shared error being in ``groups``: the mean square between the groups
    over the residuals' whole mean square (Kish's design effect for cluster samples,
    ``1 + (m - 1) rho`` for groups of ``m`` points with intra-group correlation ``rho``).
    About 1 for independent points; NaN when the groups cannot tell."""
    between, _, total = _mean_squares(residuals, groups, weights)
    return between / total if total > 0 else float("nan")


def grouped(fit: Fit, groups: np.ndarray, weights: np.ndarray | None = None) -> Fit:
    """``fit`` with its covariance multiplied by the design effect of ``groups`` (N,), one
    label per point in the order the fit used them (e.g. the camera whose contour gave it).

    Least squares takes the points as independent, so its covariance shrinks as 1/N. Points
    that share an error source are not: every point of one camera's contour moves with that
    camera's edge placement and calibration, and a plane seen only along edges that few
    cameras show is held by a handful of independent observations, not thousands. The
    design effect of the residuals (:func:`design_effect`) is the factor by which the groups'
    mean scatter exceeds what independent points would give (for an offset, the ratio of
    the cluster-robust variance to the independent one); when above 1 it scales ``cov`` and
    ``u`` (by its square root). A fit with too few groups to tell, or already singular, is
    returned unchanged.
    """
    if not np.isfinite(fit.cov).all() or len(fit.residuals) == 0:
        return fit
    F = design_effect(fit.residuals, groups, weights)
    if not np.isfinite(F) or F <= 1.0:
        return fit
    k = float(np.sqrt(F))
    return dataclasses.replace(fit, cov=fit.cov * F, u={key: v * k for key, v in fit.u.items()}, design_effect=F)


def _plain(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        return [float(x) for x in v.ravel()]
    if isinstance(v, np.generic):
        return v.item()
    return v


# --------------------------------------------------------------------------- helpers


def orthonormal_basis(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (3,), (3,) that make a right-handed orthonormal frame with unit ``a`` (3,)."""
    # Written out rather than np.cross: this is called in every Gauss-Newton step of every
    # fit, and np.cross's generality costs ~20x the arithmetic for one pair of 3-vectors.
    a0, a1, a2 = (float(x) for x in np.asarray(a, float).ravel()[:3])
    i = int(np.argmin((abs(a0), abs(a1), abs(a2))))
    if i == 0:  # a x e_x
        u = (0.0, a2, -a1)
    elif i == 1:  # a x e_y
        u = (-a2, 0.0, a0)
    else:  # a x e_z
        u = (a1, -a0, 0.0)
    nu = math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
    u0, u1, u2 = u[0] / nu, u[1] / nu, u[2] / nu
    return np.array([u0, u1, u2]), np.array([a1 * u2 - a2 * u1, a2 * u0 - a0 * u2, a0 * u1 - a1 * u0])


def _unit(v: np.ndarray) -> np.ndarray:
    # math.sqrt of the dot product: np.linalg.norm's generality costs 3x for one 3-vector,
    # and this runs in every perturbed geometry of every uncertainty propagation.
    return v / math.sqrt(float(v @ v))


def _check(points: Any, weights: Any, dim: int = 3) -> tuple[np.ndarray, np.ndarray]:
    P = np.asarray(points, float)
    if P.ndim != 2 or P.shape[1] != dim:
        raise FitError(f"points must be (N, {dim}), got {P.shape}")
    if not np.isfinite(P).all():
        raise FitError("points hold non-finite values")
    if weights is None:
        w = np.ones(len(P))
    else:
        w = np.asarray(weights, float).ravel()
        if w.shape != (len(P),):
            raise FitError(f"weights must be ({len(P)},), got {w.shape}")
        if not np.isfinite(w).all() or (w < 0).any():
            raise FitError("weights must be finite and >= 0")
    keep = w > 0
    if keep.all():  # no copy: the robust refits pass the same points again and again
        return P, w
    return P[keep], w[keep]


def _covariance(J: np.ndarray, r: np.ndarray, w: np.ndarray, p: int) -> tuple[np.ndarray, float, float]:
    """``cov = s^2 (J^T W J)^-1``, ``s`` and the scaled condition number of ``J^T W J``."""
    n = len(r)
    A = J.T @ (J * w[:, None])
    dof = n - p
    s2 = float(np.sum(w * r * r) / dof) if dof > 0 else float("nan")
    d = np.sqrt(np.clip(np.diag(A), 1e-300, None))
    As = A / np.outer(d, d)  # scaled: the condition number does not depend on the units
    ev = np.linalg.eigvalsh(As)
    cond = float(ev[-1] / ev[0]) if ev[0] > 0 else float("inf")
    if not np.isfinite(cond) or cond > MAX_CONDITION or dof <= 0:
        return np.full((p, p), np.inf), float(np.sqrt(s2)) if dof > 0 else float("nan"), cond
    cov = s2 * (np.linalg.inv(As) / np.outer(d, d))
    return 0.5 * (cov + cov.T), float(np.sqrt(s2)), cond


def _gauss_newton(residual: Callable[..., tuple[np.ndarray, np.ndarray | None]],
                  recentre: Callable[[np.ndarray], None], w: np.ndarray, p: int) -> None:
    """Levenberg-Marquardt on local parameters: ``residual(delta, jac) -> (r, J)`` at the state
    moved by ``delta`` (``J`` None when ``jac`` is false: a trial step needs only its cost);
    ``recentre(delta)`` makes that the new state (delta 0)."""
    lam = 1e-6
    r, J = residual(np.zeros(p), True)
    assert J is not None
    cost = float(np.sum(w * r * r))
    for _ in range(_MAX_ITER):
        A = J.T @ (J * w[:, None])
        g = J.T @ (w * r)
        D = np.diag(np.diag(A)) + 1e-12 * np.eye(p) * max(1.0, float(np.trace(A)) / p)
        improved = False
        for _ in range(30):
            try:
                step = -np.linalg.solve(A + lam * D, g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            r2 = residual(step, False)[0]
            cost2 = float(np.sum(w * r2 * r2))
            if np.isfinite(cost2) and cost2 <= cost:
                recentre(step)
                r, J = residual(np.zeros(p), True)
                assert J is not None
                done = cost - cost2 <= _RTOL * max(cost, 1e-300) or cost2 == 0.0
                cost = float(np.sum(w * r * r))
                lam = max(lam / 10.0, 1e-12)
                improved = True
                break
            lam *= 10.0
        if not improved or done:
            return


def _finish(kind: str, params: dict[str, Any], r: np.ndarray, J: np.ndarray | None, w: np.ndarray,
            names: tuple[str, ...], geometry: Callable[[np.ndarray], dict[str, Any]],
            key: int | None, key_name: str, min_points: int, max_amplification: float,
            extra_u: Callable[[np.ndarray], dict[str, float]]) -> Fit:
    assert J is not None  # the residual at the solution, with its Jacobian
    p = len(names)
    n = len(r)
    cov, s, cond = _covariance(J, r, w, p)
    problem = None
    if n < min_points:
        problem = f"too few points ({n} < {min_points})"
    elif not np.isfinite(cov).all():
        problem = f"the points do not constrain the {kind} (singular, condition {cond:.3g})"
    u = extra_u(cov) if np.isfinite(cov).all() else {}
    amp = float("nan")
    if key is not None and np.isfinite(cov).all():
        floor = max(s, 1e-9) / np.sqrt(max(n, 1))
        amp = float(np.sqrt(max(cov[key, key], 0.0)) / floor)
        if problem is None and amp > max_amplification:
            problem = (f"the points do not constrain the {kind}'s {key_name} (its uncertainty is {amp:.0f}x the "
                       f"points' scatter over sqrt(N); at most {max_amplification:g})")
    return Fit(kind, params, r, names, cov, s, n, u, amp, problem, geometry)


# --------------------------------------------------------------------------- plane


def fit_plane(points: np.ndarray, weights: np.ndarray | None = None, *, min_points: int = 6,
              max_amplification: float = 100.0) -> Fit:
    """Least-squares plane.

    Parameters
    ----------
    points : (N, 3) float
        mm.
    weights : (N,) float, optional
        Relative weights >= 0 (zero: point ignored).
    min_points : int
        Fewer points: :attr:`Fit.problem` says so.
    max_amplification : float
        Bound on the tilt's amplification: its uncertainty times the points' largest
        in-plane extent, over ``s / sqrt(N)`` (a square face ~5, a 10:1 strip ~40, points
        on one line: singular or thousands).

    Returns
    -------
    Fit
        ``params``: ``point`` (3,) the weighted centroid, ``normal`` (3,) unit (sign: the
        largest component positive unless the caller flips it). Local parameters
        ``offset`` (mm, along the normal) and ``tilt_u``, ``tilt_v`` (rad, towards the
        in-plane axes ``params['u']``, ``params['v']``: the points' principal directions).
        ``u``: ``offset``, ``tilt_rad`` (the larger tilt uncertainty).
    """
    P, w = _check(points, weights)
    if len(P) < 3:
        return _degenerate("plane", len(P), min_points)
    W = float(w.sum())
    c = (w @ P) / W
    d = P - c
    M = (d * w[:, None]).T @ d
    lam, vec = np.linalg.eigh(M)
    nrm = vec[:, 0]
    nrm = nrm * (1.0 if nrm[np.argmax(np.abs(nrm))] > 0 else -1.0)
    eu = vec[:, 2]
    ev_ = np.array([nrm[1] * eu[2] - nrm[2] * eu[1], nrm[2] * eu[0] - nrm[0] * eu[2], nrm[0] * eu[1] - nrm[1] * eu[0]])
    r = d @ nrm
    n = len(P)
    dof = n - 3
    s2 = float(w @ (r * r)) / dof if dof > 0 else float("nan")
    s = float(np.sqrt(s2)) if dof > 0 else float("nan")
    # The Jacobian of (offset, tilt_u, tilt_v) is (-1, d.eu, d.ev): about the weighted
    # centroid and in the scatter matrix's eigenbasis its normal matrix is diagonal,
    # diag(W, lambda_max, lambda_mid), so the covariance is written out instead of formed
    # from J (the same numbers: the scaled condition number is 1 unless a lambda is 0).
    singular = not (lam[1] > 0 and lam[2] > 0) or dof <= 0
    cov = np.full((3, 3), np.inf) if singular else np.diag([s2 / W, s2 / float(lam[2]), s2 / float(lam[1])])

    def geometry(delta: np.ndarray, c=c, nrm=nrm, eu=eu, ev_=ev_) -> dict[str, Any]:
        n2 = _unit(nrm + delta[1] * eu + delta[2] * ev_)
        return {"kind": "plane", "point": c + delta[0] * nrm, "normal": n2}

    params = {"point": c, "normal": nrm, "u": eu, "v": ev_}
    names = ("offset", "tilt_u", "tilt_v")
    if n < min_points:
        return Fit("plane", params, r, names, cov, s, n, {} if singular else _plane_u(cov), float("nan"),
                   f"too few points ({n} < {min_points})", geometry)
    if singular:
        return Fit("plane", params, r, names, cov, s, n, {}, float("nan"),
                   "the points do not constrain the plane (singular, condition inf)", geometry)
    u = _plane_u(cov)
    extent = float(np.ptp(d @ eu))
    amp = u["tilt_rad"] * extent / (max(s, 1e-9) / np.sqrt(n))
    problem = None
    if amp > max_amplification:
        problem = (f"the points do not constrain the plane's tilt (a strip or a line: its uncertainty is {amp:.0f}x "
                   f"the points' scatter over sqrt(N) and their extent; at most {max_amplification:g})")
    return Fit("plane", params, r, names, cov, s, n, u, amp, problem, geometry)


def _plane_u(cov: np.ndarray) -> dict[str, float]:
    return {"offset": float(np.sqrt(cov[0, 0])), "tilt_rad": float(np.sqrt(max(cov[1, 1], cov[2, 2])))}


def _degenerate(kind: str, n: int, min_points: int) -> Fit:
    return Fit(kind, {}, np.zeros(n), (), np.zeros((0, 0)), float("nan"), n, {}, float("nan"),
               f"too few points ({n} < {min_points})", lambda d: {})


# --------------------------------------------------------------------------- line


def fit_line(points: np.ndarray, weights: np.ndarray | None = None, *, min_points: int = 4) -> Fit:
    """Least-squares 3D line (orthogonal distance regression).

    Returns
    -------
    Fit
        ``params``: ``point`` (3,) the weighted centroid, ``direction`` (3,) unit. Local
        parameters ``shift_u``, ``shift_v`` (mm), ``tilt_u``, ``tilt_v`` (rad); the residual
        of each point is its two perpendicular components (``residuals`` holds their norm).
        ``u``: ``position`` (the larger shift), ``tilt_rad``.
    """
    P, w = _check(points, weights)
    if len(P) < 2:
        return _degenerate("line", len(P), min_points)
    c = (w[:, None] * P).sum(0) / w.sum()
    d = P - c
    _, vec = np.linalg.eigh((d * w[:, None]).T @ d)
    a = vec[:, 2] * (1.0 if vec[np.argmax(np.abs(vec[:, 2])), 2] > 0 else -1.0)
    eu, ev_ = orthonormal_basis(a)
    h = d @ a
    ru, rv = d @ eu, d @ ev_
    n = len(P)
    J = np.zeros((2 * n, 4))
    J[:n, 0] = -1.0
    J[:n, 2] = -h
    J[n:, 1] = -1.0
    J[n:, 3] = -h
    r2 = np.concatenate([ru, rv])
    w2 = np.concatenate([w, w])

    def geometry(delta: np.ndarray, c=c, a=a, eu=eu, ev_=ev_) -> dict[str, Any]:
        return {"kind": "line", "point": c + delta[0] * eu + delta[1] * ev_, "direction": _unit(a + delta[2] * eu + delta[3] * ev_)}

    def extra(cov: np.ndarray) -> dict[str, float]:
        return {"position": float(np.sqrt(max(cov[0, 0], cov[1, 1]))), "tilt_rad": float(np.sqrt(max(cov[2, 2], cov[3, 3])))}

    fit = _finish("line", {"point": c, "direction": a}, r2, J, w2, ("shift_u", "shift_v", "tilt_u", "tilt_v"), geometry,
                  None, "direction", 2 * min_points, np.inf, extra)
    problem = f"too few points ({n} < {min_points})" if n < min_points else fit.problem
    return Fit("line", fit.params, np.hypot(ru, rv), fit.names, fit.cov, fit.s, n, fit.u, fit.amplification, problem, geometry)


# --------------------------------------------------------------------------- circle


def _kasa(q: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float]:
    """Algebraic circle fit (Kasa) of (N, 2) points: centre (2,), radius."""
    A = np.column_stack([2.0 * q, np.ones(len(q))])
    b = (q * q).sum(1)
    sw = np.sqrt(w)
    sol, *_ = np.linalg.lstsq(A * sw[:, None], b * sw, rcond=None)
    ctr = sol[:2]
    return ctr, float(np.sqrt(max(sol[2] + ctr @ ctr, 1e-300)))


def fit_circle(points: np.ndarray, weights: np.ndarray | None = None, *, normal: np.ndarray | None = None,
               min_points: int = 6, max_amplification: float = MAX_AMPLIFICATION) -> Fit:
    """Least-squares circle in a plane.

    Parameters
    ----------
    points : (N, 3) float
        mm; projected onto the plane first.
    normal : (3,) float, optional
        The plane's normal (e.g. the cylinder's axis); default: the points' best-fit plane.

    Returns
    -------
    Fit
        ``params``: ``centre`` (3,), ``normal`` (3,), ``radius``. Local parameters
        ``centre_u``, ``centre_v`` (mm, in-plane), ``radius``. ``u``: ``radius``,
        ``diameter``, ``centre`` (the larger in-plane one).
    """
    P, w = _check(points, weights)
    if len(P) < 3:
        return _degenerate("circle", len(P), min_points)
    c0 = (w[:, None] * P).sum(0) / w.sum()
    if normal is None:
        _, vec = np.linalg.eigh(((P - c0) * w[:, None]).T @ (P - c0))
        nrm = vec[:, 0]
    else:
        nrm = _unit(np.asarray(normal, float))
    eu, ev_ = orthonormal_basis(nrm)
    q = np.column_stack([(P - c0) @ eu, (P - c0) @ ev_])
    ctr, R = _kasa(q, w)
    state: dict[str, Any] = {"c": ctr.copy(), "R": R}

    def residual(delta: np.ndarray, jac: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        dq = q - (state["c"] + delta[:2])
        rho = np.hypot(dq[:, 0], dq[:, 1])
        if not jac:
            return rho - (state["R"] + delta[2]), None
        e = dq / np.maximum(rho, 1e-300)[:, None]
        return rho - (state["R"] + delta[2]), np.column_stack([-e, -np.ones(len(q))])

    def recentre(delta: np.ndarray) -> None:
        state["c"] = state["c"] + delta[:2]
        state["R"] = state["R"] + delta[2]

    _gauss_newton(residual, recentre, w, 3)
    r, J = residual(np.zeros(3))
    centre = c0 + state["c"][0] * eu + state["c"][1] * ev_
    R = float(state["R"])

    def geometry(delta: np.ndarray, centre=centre, R=R) -> dict[str, Any]:
        return {"kind": "circle", "centre": centre + delta[0] * eu + delta[1] * ev_, "normal": nrm, "radius": R + delta[2]}

    def extra(cov: np.ndarray) -> dict[str, float]:
        return {"radius": float(np.sqrt(cov[2, 2])), "diameter": float(2.0 * np.sqrt(cov[2, 2])),
                "centre": float(np.sqrt(max(cov[0, 0], cov[1, 1])))}

    fit = _finish("circle", {"centre": centre, "normal": nrm, "radius": R}, r, J, w, ("centre_u", "centre_v", "radius"),
                  geometry, 2, "radius", min_points, max_amplification, extra)
    return fit


# --------------------------------------------------------------------------- sphere


def fit_sphere(points: np.ndarray, weights: np.ndarray | None = None, *, min_points: int = 8,
               max_amplification: float = MAX_AMPLIFICATION) -> Fit:
    """Least-squares sphere.

    Returns
    -------
    Fit
        ``params``: ``centre`` (3,), ``radius``. Local parameters ``cx``, ``cy``, ``cz``,
        ``radius`` (mm). ``u``: ``radius``, ``diameter``, ``centre`` (the largest axis).
    """
    P, w = _check(points, weights)
    if len(P) < 4:
        return _degenerate("sphere", len(P), min_points)
    A = np.column_stack([2.0 * P, np.ones(len(P))])
    sw = np.sqrt(w)
    sol, *_ = np.linalg.lstsq(A * sw[:, None], (P * P).sum(1) * sw, rcond=None)
    state: dict[str, Any] = {"c": sol[:3].copy(), "R": float(np.sqrt(max(sol[3] + sol[:3] @ sol[:3], 1e-300)))}

    def residual(delta: np.ndarray, jac: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        d = P - (state["c"] + delta[:3])
        rho = np.linalg.norm(d, axis=1)
        if not jac:
            return rho - (state["R"] + delta[3]), None
        e = d / np.maximum(rho, 1e-300)[:, None]
        return rho - (state["R"] + delta[3]), np.column_stack([-e, -np.ones(len(P))])

    def recentre(delta: np.ndarray) -> None:
        state["c"] = state["c"] + delta[:3]
        state["R"] = state["R"] + delta[3]

    _gauss_newton(residual, recentre, w, 4)
    r, J = residual(np.zeros(4))
    centre, R = state["c"].copy(), float(state["R"])

    def geometry(delta: np.ndarray, centre=centre, R=R) -> dict[str, Any]:
        return {"kind": "sphere", "centre": centre + delta[:3], "radius": R + delta[3]}

    def extra(cov: np.ndarray) -> dict[str, float]:
        return {"radius": float(np.sqrt(cov[3, 3])), "diameter": float(2.0 * np.sqrt(cov[3, 3])),
                "centre": float(np.sqrt(np.linalg.eigvalsh(cov[:3, :3])[-1]))}

    return _finish("sphere", {"centre": centre, "radius": R}, r, J, w, ("cx", "cy", "cz", "radius"), geometry, 3,
                   "radius", min_points, max_amplification, extra)


# --------------------------------------------------------------------------- cylinder


def _axis_candidates(P: np.ndarray, w: np.ndarray) -> list[np.ndarray]:
    c = (w[:, None] * P).sum(0) / w.sum()
    _, vec = np.linalg.eigh(((P - c) * w[:, None]).T @ (P - c))
    return [vec[:, k] for k in (2, 0, 1)]


def fit_cylinder(points: np.ndarray, weights: np.ndarray | None = None, *, axis: np.ndarray | None = None,
                 point: np.ndarray | None = None, radius: float | None = None, min_points: int = 10,
                 max_amplification: float = MAX_AMPLIFICATION) -> Fit:
    """Least-squares cylinder.

    Parameters
    ----------
    points : (N, 3) float
        mm.
    axis, point, radius : optional
        A starting estimate (e.g. the CAD nominal): unit direction (3,), a point on the axis
        (3,), mm. Without ``axis``, the points' three principal directions are tried and the
        best fit kept.

    Returns
    -------
    Fit
        ``params``: ``point`` (3,) on the axis at the points' weighted mean position along
        it, ``direction`` (3,) unit, ``radius``. Local parameters ``shift_u``, ``shift_v``
        (mm), ``tilt_u``, ``tilt_v`` (rad), ``radius`` (mm). ``u``: ``radius``, ``diameter``,
        ``position`` (the axis point, larger in-plane), ``tilt_rad``.
    """
    P, w = _check(points, weights)
    if len(P) < 5:
        return _degenerate("cylinder", len(P), min_points)
    starts = [_unit(np.asarray(axis, float))] if axis is not None else _axis_candidates(P, w)
    best = _least_cost([_fit_cylinder_from(P, w, a0, point, radius, min_points, max_amplification) for a0 in starts], w)
    assert best is not None
    return best


def _least_cost(candidates: Sequence[Fit], w: np.ndarray) -> Fit | None:
    """The candidate fit (one per start) with the smallest weighted sum of squared residuals;
    a later one wins only by more than 1e-12 (ties keep the first start). None when empty."""
    best: Fit | None = None
    for fit in candidates:
        if best is None or float(np.sum(w * fit.residuals ** 2)) < float(np.sum(w * best.residuals ** 2)) - 1e-12:
            best = fit
    return best


def cylinder_residual_numpy(P: np.ndarray, p: np.ndarray, a: np.ndarray, bu: np.ndarray, bv: np.ndarray,
                            R: float) -> tuple[np.ndarray, np.ndarray]:
    """Orthogonal residuals (N,) of points ``P`` (N, 3) to the cylinder of axis point ``p``,
    unit direction ``a`` and radius ``R`` (mm), and their Jacobian (N, 5) in the local
    parameters about the frame ``bu``, ``bv`` (shift_u, shift_v, tilt_u, tilt_v, radius).

    The reference the compiled :func:`inspector.kernels.fits_jit.cylinder_residual` (what
    the fit calls) is held to by the tests.
    """
    d = P - p
    h = d @ a
    rad = d - h[:, None] * a
    rho = np.sqrt(np.einsum("ij,ij->i", rad, rad))
    e = rad / np.maximum(rho, 1e-300)[:, None]
    eu, ev = e @ bu, e @ bv
    return rho - R, np.column_stack([-eu, -ev, -h * eu, -h * ev, -np.ones(len(P))])


def cylinder_lm_numpy(P: np.ndarray, w: np.ndarray, cw: np.ndarray, state: np.ndarray) -> None:
    """The cylinder's damped Gauss-Newton loop in numpy, in place on ``state`` (7,) (axis
    point, unit direction, radius; the point kept at the points' weighted centroid ``cw``
    along the axis): the reference the compiled :func:`inspector.kernels.fits_jit.cylinder_lm`
    (what the fit calls) is held to by the tests."""
    st: dict[str, Any] = {"p": state[0:3].copy(), "a": state[3:6].copy(), "R": float(state[6])}

    def centre() -> None:
        st["p"] = st["p"] + ((cw - st["p"]) @ st["a"]) * st["a"]
        st["basis"] = orthonormal_basis(st["a"])

    def residual(delta: np.ndarray, jac: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        bu, bv = st["basis"]  # (the reference computes J on trial steps too: same result)
        return cylinder_residual_numpy(P, st["p"] + delta[0] * bu + delta[1] * bv,
                                       _unit(st["a"] + delta[2] * bu + delta[3] * bv), bu, bv, st["R"] + delta[4])

    def recentre(delta: np.ndarray) -> None:
        bu, bv = st["basis"]
        st["p"] = st["p"] + delta[0] * bu + delta[1] * bv
        st["a"] = _unit(st["a"] + delta[2] * bu + delta[3] * bv)
        st["R"] = st["R"] + delta[4]
        centre()

    centre()
    _gauss_newton(residual, recentre, w, 5)
    state[:] = np.r_[st["p"], st["a"], st["R"]]


def _fit_cylinder_from(P: np.ndarray, w: np.ndarray, a0: np.ndarray, p0: np.ndarray | None, R0: float | None,
                       min_points: int, max_amplification: float) -> Fit:
    cw = (w[:, None] * P).sum(0) / w.sum()
    eu, ev_ = orthonormal_basis(a0)
    if p0 is None or R0 is None:
        q = np.column_stack([(P - cw) @ eu, (P - cw) @ ev_])
        ctr, Rk = _kasa(q, w)
        p_init = cw + ctr[0] * eu + ctr[1] * ev_
        R_init = Rk if R0 is None else float(R0)
        if p0 is not None:
            p_init = np.asarray(p0, float)
    else:
        p_init, R_init = np.asarray(p0, float), float(R0)
    from inspector.kernels import fits_jit  # lazy: Numba, only once a cylinder is fitted

    # The whole damped Gauss-Newton loop is compiled: on the few hundred points of a bore,
    # the numpy loop's call overhead was ~1 ms a fit (cylinder_lm_numpy is its reference).
    state = np.r_[p_init, a0, float(R_init)]
    fits_jit.cylinder_lm(P, w, cw, state, _RTOL, _MAX_ITER)
    a = state[3:6] * (1.0 if state[3 + int(np.argmax(np.abs(state[3:6])))] > 0 else -1.0)
    p, R = state[0:3].copy(), float(state[6])
    bu, bv = orthonormal_basis(a)
    r, Jr = np.empty(len(P)), np.empty((len(P), 5))
    fits_jit.cylinder_residual(P, p, a, bu, bv, R, r, Jr, True)

    def geometry(delta: np.ndarray, p=p, a=a, R=R, bu=bu, bv=bv) -> dict[str, Any]:
        return {"kind": "cylinder", "point": p + delta[0] * bu + delta[1] * bv,
                "direction": _unit(a + delta[2] * bu + delta[3] * bv), "radius": R + delta[4]}

    def extra(cov: np.ndarray) -> dict[str, float]:
        return {"radius": float(np.sqrt(cov[4, 4])), "diameter": float(2.0 * np.sqrt(cov[4, 4])),
                "position": float(np.sqrt(max(cov[0, 0], cov[1, 1]))), "tilt_rad": float(np.sqrt(max(cov[2, 2], cov[3, 3])))}

    h = (P - p) @ a
    return _finish("cylinder", {"point": p, "direction": a, "radius": R, "length": float(np.ptp(h))}, r, Jr, w,
                   ("shift_u", "shift_v", "tilt_u", "tilt_v", "radius"), geometry, 4, "radius", min_points,
                   max_amplification, extra)


# --------------------------------------------------------------------------- cone


def fit_cone(points: np.ndarray, weights: np.ndarray | None = None, *, axis: np.ndarray | None = None,
             apex: np.ndarray | None = None, half_angle_deg: float | None = None, min_points: int = 12,
             max_amplification: float = MAX_AMPLIFICATION) -> Fit:
    """Least-squares cone (a right circular cone: axis, apex, half-angle).

    Parameters
    ----------
    axis : (3,) float, optional
        Starting direction, unit, pointing from the apex into the cone (radius growing).
        Without it, the points' principal directions are tried.
    apex, half_angle_deg : optional
        Starting apex (3,) mm and half-angle (degrees).

    Returns
    -------
    Fit
        ``params``: ``apex`` (3,), ``axis`` (3,) unit (radius grows along it),
        ``half_angle_deg``, and ``point`` (3,) on the axis at the points' mean position along
        it with ``radius`` there (mm). Residuals are the orthogonal distances to the cone's
        surface. Local parameters ``shift_u``, ``shift_v`` (mm, of ``point``), ``tilt_u``,
        ``tilt_v`` (rad), ``radius`` (mm, at ``point``), ``half_angle`` (rad). ``u``:
        ``half_angle_deg``, ``radius``, ``tilt_rad``, ``apex`` (along the axis, mm).
    """
    P, w = _check(points, weights)
    if len(P) < 6:
        return _degenerate("cone", len(P), min_points)
    cw = (w[:, None] * P).sum(0) / w.sum()
    starts: list[tuple[np.ndarray, np.ndarray, float, float]] = []
    if axis is not None:
        a0 = _unit(np.asarray(axis, float))
        if apex is not None and half_angle_deg is not None:
            alpha = np.radians(half_angle_deg)
            ap = np.asarray(apex, float)
            p0 = ap + ((cw - ap) @ a0) * a0
            starts.append((p0, a0, float(np.linalg.norm(p0 - ap) * np.tan(alpha)), float(alpha)))
        else:
            starts += _cone_starts(P, w, cw, [a0])
    else:
        starts += _cone_starts(P, w, cw, _axis_candidates(P, w))
    best: Fit | None = None
    for p0, a0, r0, al0 in starts:
        fit = _fit_cone_from(P, w, cw, p0, a0, r0, al0, min_points, max_amplification)
        if fit.params and (best is None or np.sum(w * fit.residuals ** 2) < np.sum(w * best.residuals ** 2) - 1e-12):
            best = fit
    if best is None:
        return _degenerate("cone", len(P), min_points)
    return best


def _cone_starts(P: np.ndarray, w: np.ndarray, cw: np.ndarray, axes: Sequence[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray, float, float]]:
    """Algebraic starts: in the plane across ``a``, ``|q - c|^2 = (r0 + k h)^2`` is linear in
    (2c, r0^2 - c.c, 2 r0 k, k^2) with regressors (q, 1, h, h^2)."""
    out = []
    for a in axes:
        eu, ev_ = orthonormal_basis(a)
        d = P - cw
        q = np.column_stack([d @ eu, d @ ev_])
        h = d @ a
        A = np.column_stack([2.0 * q, np.ones(len(P)), h, h * h])
        sw = np.sqrt(w)
        sol, *_ = np.linalg.lstsq(A * sw[:, None], (q * q).sum(1) * sw, rcond=None)
        c = sol[:2]
        r0 = float(np.sqrt(max(sol[2] + c @ c, 1e-12)))
        k = sol[3] / (2.0 * r0)
        sgn = 1.0 if k >= 0 else -1.0
        out.append((cw + c[0] * eu + c[1] * ev_, sgn * a, r0, float(np.arctan(abs(k)))))
    return out


def _fit_cone_from(P: np.ndarray, w: np.ndarray, cw: np.ndarray, p0: np.ndarray, a0: np.ndarray, r0: float, al0: float,
                   min_points: int, max_amplification: float) -> Fit:
    state: dict[str, Any] = {"p": np.asarray(p0, float).copy(), "a": _unit(np.asarray(a0, float)), "r": float(r0), "al": float(al0)}

    def centre_state() -> None:
        a = state["a"]
        t = (cw - state["p"]) @ a
        state["p"] = state["p"] + t * a
        state["r"] = state["r"] + t * np.tan(state["al"])

    centre_state()

    def residual(delta: np.ndarray, jac: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        a = state["a"]
        bu, bv = orthonormal_basis(a)
        p = state["p"] + delta[0] * bu + delta[1] * bv
        a2 = _unit(a + delta[2] * bu + delta[3] * bv)
        r0_ = state["r"] + delta[4]
        al = state["al"] + delta[5]
        d = P - p
        h = d @ a2
        rad = d - h[:, None] * a2
        rho = np.linalg.norm(rad, axis=1)
        e = rad / np.maximum(rho, 1e-300)[:, None]
        ca, ta = np.cos(al), np.tan(al)
        g = rho - r0_ - h * ta
        if not jac:
            return g * ca, None
        eu_, ev2 = e @ bu, e @ bv
        du, dv = d @ bu, d @ bv
        J = np.column_stack([-eu_ * ca, -ev2 * ca, (-h * eu_ - ta * du) * ca, (-h * ev2 - ta * dv) * ca,
                             -np.full(len(P), ca), -h / ca - g * np.sin(al)])
        return g * ca, J

    def recentre(delta: np.ndarray) -> None:
        a = state["a"]
        bu, bv = orthonormal_basis(a)
        state["p"] = state["p"] + delta[0] * bu + delta[1] * bv
        state["a"] = _unit(a + delta[2] * bu + delta[3] * bv)
        state["r"] = state["r"] + delta[4]
        state["al"] = state["al"] + delta[5]
        centre_state()

    _gauss_newton(residual, recentre, w, 6)
    if state["al"] < 0:  # the same cone with the axis reversed
        state["a"], state["al"] = -state["a"], -state["al"]
    r, J = residual(np.zeros(6))
    p, a, rr, al = state["p"].copy(), state["a"].copy(), float(state["r"]), float(state["al"])
    if not (0.0 < al < np.pi / 2) or rr <= 0:
        return _degenerate("cone", len(P), min_points)
    bu, bv = orthonormal_basis(a)

    def geometry(delta: np.ndarray, p=p, a=a, rr=rr, al=al, bu=bu, bv=bv) -> dict[str, Any]:
        p2 = p + delta[0] * bu + delta[1] * bv
        a2 = _unit(a + delta[2] * bu + delta[3] * bv)
        r2, al2 = rr + delta[4], al + delta[5]
        return {"kind": "cone", "point": p2, "axis": a2, "radius": r2, "half_angle_deg": float(np.degrees(al2)),
                "apex": p2 - (r2 / np.tan(al2)) * a2}

    def extra(cov: np.ndarray) -> dict[str, float]:
        g = np.zeros(6)
        g[4], g[5] = -1.0 / np.tan(al), rr / np.sin(al) ** 2  # apex position along the axis
        return {"half_angle_deg": float(np.degrees(np.sqrt(cov[5, 5]))), "radius": float(np.sqrt(cov[4, 4])),
                "tilt_rad": float(np.sqrt(max(cov[2, 2], cov[3, 3]))), "apex": float(np.sqrt(max(g @ cov @ g, 0.0)))}

    params = {"apex": p - (rr / np.tan(al)) * a, "axis": a, "half_angle_deg": float(np.degrees(al)), "point": p, "radius": rr}
    return _finish("cone", params, r, J, w, ("shift_u", "shift_v", "tilt_u", "tilt_v", "radius", "half_angle"), geometry,
                   5, "half-angle", min_points, max_amplification, extra)


# --------------------------------------------------------------------------- torus


def fit_torus(points: np.ndarray, weights: np.ndarray | None = None, *, axis: np.ndarray | None = None,
              centre: np.ndarray | None = None, major_radius: float | None = None, minor_radius: float | None = None,
              min_points: int = 14, max_amplification: float = MAX_AMPLIFICATION) -> Fit:
    """Least-squares torus (a circle of radius ``r``, the tube, swept about an axis at a
    distance ``R`` from it: a fillet round an edge, a groove, an O-ring seat).

    The residual of a point ``p`` is its orthogonal distance to the surface: with
    ``h = (p - c).a`` and ``rho = |(p - c) - h a|``, ``sqrt((rho - R)^2 + h^2) - r``
    (positive outside the tube).

    Parameters
    ----------
    points : (N, 3) float
        mm.
    axis, centre, major_radius, minor_radius : optional
        A starting estimate (e.g. the CAD nominal): unit direction (3,), the centre (3,) (on
        the axis, in the plane of the tube's centre circle), ``R`` and ``r`` mm. What is not
        given is estimated: the axis from the points' three principal directions (each tried,
        the best fit kept); ``R``, ``r`` and the centre's place along the axis from a circle
        fitted to the points' profile (distance from the axis, height along it) about the
        axis through ``centre`` -- or, without it, through the points' weighted centroid: then
        the points should go most of the way round the axis (a partial ring's centroid is off
        its axis). A ``centre`` given with both radii is taken as it is.

    Returns
    -------
    Fit
        ``params``: ``centre`` (3,), ``axis`` (3,) unit (largest component positive),
        ``major_radius`` ``R`` and ``minor_radius`` ``r`` (mm). Local parameters
        ``shift_u``, ``shift_v``, ``shift_axial`` (mm, of the centre), ``tilt_u``, ``tilt_v``
        (rad, of the axis about the centre), ``major_radius``, ``minor_radius`` (mm). ``u``:
        ``minor_radius``, ``major_radius``, ``centre`` (the largest axis), ``tilt_rad``. The key
        parameter (:attr:`Fit.amplification`) is the minor radius: a short arc of the tube
        (a fillet's profile seen over a few degrees) does not fix it.
    """
    P, w = _check(points, weights)
    if len(P) < 7:
        return _degenerate("torus", len(P), min_points)
    axes = [_unit(np.asarray(axis, float))] if axis is not None else _axis_candidates(P, w)
    tried = [_fit_torus_from(P, w, a0, *_torus_start(P, w, a0, centre, major_radius, minor_radius), min_points,
                             max_amplification) for a0 in axes]
    best = _least_cost([f for f in tried if f.params], w)
    if best is None:
        return _degenerate("torus", len(P), min_points)
    return best


def _torus_start(P: np.ndarray, w: np.ndarray, a: np.ndarray, c0: np.ndarray | None, R0: float | None,
                 r0: float | None) -> tuple[np.ndarray, float, float]:
    """The centre, ``R`` and ``r`` to start from about axis ``a``: all three when given, else
    an algebraic circle fit (:func:`_kasa`) to the profile (``rho``, ``h``) about the axis
    through ``c0`` (or the weighted centroid) places the centre along that axis and gives the
    radii not given."""
    if c0 is not None and R0 is not None and r0 is not None:
        return np.asarray(c0, float), float(R0), float(r0)
    base = np.asarray(c0, float) if c0 is not None else (w[:, None] * P).sum(0) / w.sum()
    d = P - base
    h = d @ a
    rho = np.linalg.norm(d - h[:, None] * a, axis=1)
    ctr, rk = _kasa(np.column_stack([rho, h]), w)
    return base + ctr[1] * a, float(ctr[0]) if R0 is None else float(R0), rk if r0 is None else float(r0)


def _fit_torus_from(P: np.ndarray, w: np.ndarray, a0: np.ndarray, c0: np.ndarray, R0: float, r0: float,
                    min_points: int, max_amplification: float) -> Fit:
    state: dict[str, Any] = {"c": np.asarray(c0, float).copy(), "a": _unit(np.asarray(a0, float)), "R": float(R0),
                             "r": float(r0)}
    J = np.empty((len(P), 7))
    J[:, 6] = -1.0

    def residual(delta: np.ndarray, jac: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        a = state["a"]
        bu, bv = orthonormal_basis(a)
        c = state["c"] + delta[0] * bu + delta[1] * bv + delta[2] * a
        a2 = _unit(a + delta[3] * bu + delta[4] * bv)
        R = state["R"] + delta[5]
        d = P - c
        h = d @ a2
        rad = d - h[:, None] * a2
        rho = np.sqrt(np.einsum("ij,ij->i", rad, rad))
        e = rad / np.maximum(rho, 1e-300)[:, None]
        s = np.maximum(np.hypot(rho - R, h), 1e-300)
        if not jac:
            return s - (state["r"] + delta[6]), None
        # the surface's outward normal at the point's foot: d s / d p
        nr, nh = (rho - R) / s, h / s
        eu_, ev2 = e @ bu, e @ bv
        J[:, 0] = -nr * eu_  # a shift of the centre moves the point by minus it
        J[:, 1] = -nr * ev2
        J[:, 2] = -nh
        J[:, 3] = R * nh * eu_  # a tilt about the centre: d s = h R (e . b) / s
        J[:, 4] = R * nh * ev2
        J[:, 5] = -nr
        return s - (state["r"] + delta[6]), J.copy()

    def recentre(delta: np.ndarray) -> None:
        a = state["a"]
        bu, bv = orthonormal_basis(a)
        state["c"] = state["c"] + delta[0] * bu + delta[1] * bv + delta[2] * a
        state["a"] = _unit(a + delta[3] * bu + delta[4] * bv)
        state["R"] = state["R"] + delta[5]
        state["r"] = state["r"] + delta[6]

    _gauss_newton(residual, recentre, w, 7)
    state["a"] = state["a"] * (1.0 if state["a"][np.argmax(np.abs(state["a"]))] > 0 else -1.0)
    r, Jr = residual(np.zeros(7))
    c, a, R, rr = state["c"].copy(), state["a"].copy(), float(state["R"]), float(state["r"])
    if not (R > 0 and rr > 0) or not np.isfinite(r).all():
        return _degenerate("torus", len(P), min_points)
    bu, bv = orthonormal_basis(a)

    def geometry(delta: np.ndarray, c=c, a=a, R=R, rr=rr, bu=bu, bv=bv) -> dict[str, Any]:
        return {"kind": "torus", "centre": c + delta[0] * bu + delta[1] * bv + delta[2] * a,
                "axis": _unit(a + delta[3] * bu + delta[4] * bv), "major_radius": R + delta[5],
                "minor_radius": rr + delta[6]}

    def extra(cov: np.ndarray) -> dict[str, float]:
        return {"minor_radius": float(np.sqrt(cov[6, 6])), "major_radius": float(np.sqrt(cov[5, 5])),
                "centre": float(np.sqrt(np.linalg.eigvalsh(cov[:3, :3])[-1])),
                "tilt_rad": float(np.sqrt(max(cov[3, 3], cov[4, 4])))}

    return _finish("torus", {"centre": c, "axis": a, "major_radius": R, "minor_radius": rr}, r, Jr, w,
                   ("shift_u", "shift_v", "shift_axial", "tilt_u", "tilt_v", "major_radius", "minor_radius"), geometry,
                   6, "minor radius", min_points, max_amplification, extra)


# --------------------------------------------------------------------------- derived quantities


def propagate(f: Callable[..., float], fits: Sequence[Fit], *, rel_step: float = 1e-3) -> tuple[float, float]:
    """A derived quantity of one or more independent fits and its standard uncertainty.

    Parameters
    ----------
    f : callable
        ``f(*geometries) -> float`` of the fits' primitives (the ``perturbed`` dicts).
    fits : sequence of Fit
        With finite covariances (independent of each other: different points).

    Returns
    -------
    value, u : float
        ``f`` at the fits and ``sqrt(sum_k g_k^T cov_k g_k)`` with ``g_k`` its gradient in fit
        ``k``'s local parameters (central differences, steps ``rel_step`` standard deviations).
    """
    zeros = [np.zeros(len(ft.names)) for ft in fits]
    base = [ft.perturbed(z) for ft, z in zip(fits, zeros)]
    value = float(f(*base))
    var = 0.0
    for k, ft in enumerate(fits):
        if not np.isfinite(ft.cov).all():
            return value, float("inf")
        p = len(ft.names)
        g = np.zeros(p)
        sd = np.sqrt(np.clip(np.diag(ft.cov), 0.0, None))
        for j in range(p):
            hstep = rel_step * sd[j] if sd[j] > 0 else 1e-9
            vals = []
            for sgn in (1.0, -1.0):
                d = np.zeros(p)
                d[j] = sgn * hstep
                geo = list(base)
                geo[k] = ft.perturbed(d)
                vals.append(float(f(*geo)))
            g[j] = (vals[0] - vals[1]) / (2.0 * hstep)
        var += float(g @ ft.cov @ g)
    return value, float(np.sqrt(max(var, 0.0)))


def direction_of(geo: dict[str, Any]) -> np.ndarray:
    """The plane's normal or the axis direction (3,) of a primitive (a ``perturbed`` dict; a
    torus's: its axis)."""
    for key in ("normal", "direction", "axis"):
        if key in geo:
            return np.asarray(geo[key], float)
    raise FitError(f"a {geo.get('kind')} has no direction")


def _is_plane(geo: dict[str, Any]) -> bool:
    return geo.get("kind") == "plane"


def angle_between(a: Fit, b: Fit) -> tuple[float, float]:
    """Angle between two planes, axes or a plane and an axis, degrees, and its standard uncertainty.

    Plane/plane and axis/axis: the angle between their normals or directions folded to
    [0, 90] (a plane's normal sign is arbitrary); plane/axis: the angle between the axis and
    the plane (90 when the axis is along the normal).
    """
    return propagate(geometric_angle, [a, b])


def geometric_angle(ga: dict[str, Any], gb: dict[str, Any]) -> float:
    """The angle between two primitives (``perturbed`` dicts), degrees: see :func:`angle_between`."""
    c = abs(float(direction_of(ga) @ direction_of(gb)))
    ang = float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
    return 90.0 - ang if _is_plane(ga) != _is_plane(gb) else ang


def plane_jackknife(points: np.ndarray, weights: np.ndarray | None, groups: np.ndarray, normal: np.ndarray, *,
                    min_points: int = 10) -> dict[Any, dict[str, Any] | None]:
    """The least-squares plane of ``points`` without each group in turn (a delete-one-group
    jackknife), in one pass over the points.

    Parameters
    ----------
    points : (N, 3) float
        mm.
    weights : (N,) float or None
        Relative weights > 0 (None: all 1).
    groups : (N,)
        Each point's group (e.g. the camera whose contour gave it).
    normal : (3,) float
        The side each plane's normal is turned to (the full fit's normal).
    min_points : int
        A group whose removal leaves fewer points gets None.

    Returns
    -------
    dict
        Group label -> the plane without that group's points, as :func:`fit_plane`'s
        geometry (``{"kind": "plane", "point", "normal"}``), or None.

    Notes
    -----
    The weighted sums of each group (weight, first and second moments about the whole
    centroid) are taken once; each leave-one-out plane is the smallest eigenvector of the
    remaining scatter (the same plane :func:`fit_plane` fits to those points), so G refits
    cost G 3 x 3 eigenproblems instead of G passes over the points.
    """
    P = np.asarray(points, float).reshape(-1, 3)
    w = np.ones(len(P)) if weights is None else np.asarray(weights, float).ravel()
    g = np.asarray(groups).ravel()
    if w.shape != (len(P),) or g.shape != (len(P),):
        raise FitError(f"weights and groups must be ({len(P)},), got {w.shape}, {g.shape}")
    labels, idx = np.unique(g, return_inverse=True)
    c0 = (w[:, None] * P).sum(0) / max(float(w.sum()), 1e-300)
    W, S, M, count = group_moments(P - c0, w, idx.ravel(), len(labels))
    return planes_without(W.sum() - W, S.sum(0) - S, M.sum(0) - M, len(P) - count, labels, c0, normal,
                          min_points=min_points)


def group_moments(d: np.ndarray, w: np.ndarray, group: np.ndarray,
                  count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each group's weighted moments of points (one pass over them).

    Parameters
    ----------
    d : (N, 3) float
        The points about a common origin (a centroid: no cancellation far from the origin), mm.
    w : (N,) float
        Weights.
    group : (N,) int
        Each point's group, in ``[0, count)``.
    count : int

    Returns
    -------
    W : (count,) float
        Sum of weights.
    S : (count, 3) float
        Weighted sum of ``d``.
    M : (count, 3, 3) float
        Weighted sum of ``d d^T``.
    n : (count,) int
        Points.
    """
    # (bincount of nothing is an integer array: the sums are made float)
    W = np.bincount(group, weights=w, minlength=count).astype(float)
    S = np.stack([np.bincount(group, weights=w * d[:, i], minlength=count) for i in range(3)], axis=1).astype(float)
    M = np.empty((count, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            M[:, i, j] = M[:, j, i] = np.bincount(group, weights=w * d[:, i] * d[:, j], minlength=count)
    return W, S, M, np.bincount(group, minlength=count)


def planes_without(W: np.ndarray, S: np.ndarray, M: np.ndarray, n: np.ndarray, labels: np.ndarray,
                   c0: np.ndarray, normal: np.ndarray, *, min_points: int = 10) -> dict[Any, dict[str, Any] | None]:
    """The least-squares planes of point sets given by their moments (each set: the points
    without one group), in one batched eigen-decomposition.

    Parameters
    ----------
    W, S, M, n : (G,), (G, 3), (G, 3, 3), (G,)
        Each set's weight, first and second moments about ``c0``, and point count
        (:func:`group_moments`, totals less one group's).
    labels : (G,)
        Each set's label (the group left out).
    c0 : (3,) float
        The origin of the moments, mm.
    normal : (3,) float
        The side each plane's normal is turned to.
    min_points : int
        A set with fewer points gets None.

    Returns
    -------
    dict
        Label -> ``{"kind": "plane", "point", "normal"}`` (:func:`fit_plane`'s geometry), or None.
    """
    ok = (n >= min_points) & (W > 0)
    Wd = np.where(ok, W, 1.0)
    mean = S / Wd[:, None]
    C = M / Wd[:, None, None] - mean[:, :, None] * mean[:, None, :]
    C[~ok] = np.eye(3)
    nrm = np.linalg.eigh(C)[1][:, :, 0]
    nrm *= np.where(nrm @ np.asarray(normal, float) >= 0, 1.0, -1.0)[:, None]
    return {label: ({"kind": "plane", "point": c0 + mean[k], "normal": nrm[k]} if ok[k] else None)
            for k, label in enumerate(np.asarray(labels).tolist())}


def _point_of(geo: dict[str, Any]) -> np.ndarray:
    for key in ("centre", "point", "apex"):
        if key in geo:
            return np.asarray(geo[key], float)
    raise FitError(f"a {geo.get('kind')} has no position")


def geometric_distance(ga: dict[str, Any], gb: dict[str, Any]) -> float:
    """The distance between two primitives (``perturbed`` dicts), mm: see :func:`distance_between`."""
    ka, kb = ga["kind"], gb["kind"]
    if ka == "plane" and kb == "plane":
        # Parallel planes: along the mean normal, between the planes' heights at the midpoint
        # of their points' centroids (thickness or step height).
        # (Written for few array operations: the uncertainty and the camera jackknife call
        # this about thirty times per thickness.)
        na, nb = ga["normal"], gb["normal"]
        if float(na @ nb) < 0:
            nb = -nb
        nbar = _unit(na + nb)
        half = 0.5 * (gb["point"] - ga["point"])  # from either point to their midpoint, +-
        return abs(float(half @ nb) / float(nbar @ nb) + float(half @ na) / float(nbar @ na))
    if kb == "plane" and ka != "plane":
        ga, gb, ka, kb = gb, ga, kb, ka
    if ka == "plane":
        # an axis (parallel to the plane) or a centre, to the plane
        return abs(float((_point_of(gb) - ga["point"]) @ direction_of(ga)))
    axial = ("line", "cylinder", "cone")
    if ka in axial and kb in axial:
        # Two (near-)parallel axes: distance between them at the midpoint of their points.
        pa, pb = _point_of(ga), _point_of(gb)
        da, db = direction_of(ga), direction_of(gb)
        if da @ db < 0:
            db = -db
        dbar = _unit(da + db)
        m = 0.5 * (pa + pb)
        qa = pa + ((m - pa) @ dbar) / (da @ dbar) * da
        qb = pb + ((m - pb) @ dbar) / (db @ dbar) * db
        d = qb - qa
        return float(np.linalg.norm(d - (d @ dbar) * dbar))
    if ka in axial or kb in axial:
        ax, pt = (ga, gb) if ka in axial else (gb, ga)
        d = _point_of(pt) - _point_of(ax)
        a = direction_of(ax)
        return float(np.linalg.norm(d - (d @ a) * a))
    return float(np.linalg.norm(_point_of(ga) - _point_of(gb)))


def distance_between(a: Fit, b: Fit) -> tuple[float, float]:
    """Distance between two fitted features, mm, and its standard uncertainty.

    Plane/plane (parallel: a thickness or a step): along their mean normal, at the midpoint
    of the two planes' points; plane/axis or plane/centre: from the axis point or centre to
    the plane; axis/axis (parallel): between the axes at the midpoint of their points;
    axis/centre: from the centre to the axis; centre/centre: between the centres. A torus
    counts by its centre (as a sphere: two grooves along a shaft are their centres apart).
    """
    return propagate(geometric_distance, [a, b])


# --------------------------------------------------------------------------- minimum zone


def _lp_zone(base: np.ndarray, G: np.ndarray, mode: str = "zone") -> tuple[float, np.ndarray]:
    """Minimise over x the zone of ``base + G x``: ``zone`` max - min, ``mcc`` the max,
    ``mic`` minus the min. Returns (value, x).

    Only the points at the zone's edges constrain it: the programme is solved on the most
    extreme points first and grown by the ones that end up outside (an active set), so a
    plane of thousands of points costs a few small programmes.
    """
    n = len(base)
    k0 = 64
    if n <= 4 * k0:
        active = np.arange(n)
    else:
        order = np.argsort(base)
        active = np.unique(np.r_[order[:k0], order[-k0:]])
    x = np.zeros(G.shape[1])
    for _ in range(50):
        val, x = _lp_solve(base[active], G[active], mode)
        y = base + G @ x
        ya = y[active]
        hi, lo = ya.max(), ya.min()
        tol = 1e-12 * max(1.0, float(np.abs(base).max()))
        out = np.flatnonzero(((y > hi + tol) & (mode != "mic")) | ((y < lo - tol) & (mode != "mcc")))
        if out.size == 0:
            break
        worst = out[np.argsort(-np.maximum(y[out] - hi, lo - y[out]))[:k0]]
        active = np.union1d(active, worst)
    y = base + G @ x
    return {"zone": float(np.ptp(y)), "mcc": float(y.max()), "mic": float(y.min())}[mode], x


def _minimize(cost: np.ndarray, A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`inspector.kernels.lp.minimize_free`, its failure as a :class:`FitError`."""
    from inspector.kernels import lp  # lazy: HiGHS, only for a form characteristic (not at recipe load)

    try:
        return lp.minimize_free(cost, A, b)
    except lp.LPError as e:
        raise FitError(f"minimum-zone programme failed: {e}") from None


def _lp_solve(base: np.ndarray, G: np.ndarray, mode: str) -> tuple[float, np.ndarray]:
    n, k = G.shape
    # variables: x (k), U, L
    if mode == "zone":
        cost = np.r_[np.zeros(k), 1.0, -1.0]
    elif mode == "mcc":
        cost = np.r_[np.zeros(k), 1.0, 0.0]
    else:
        cost = np.r_[np.zeros(k), 0.0, -1.0]
    # base + G x <= U  ->  G x - U <= -base ;  base + G x >= L  ->  -G x + L <= base
    A = np.block([[G, -np.ones((n, 1)), np.zeros((n, 1))], [-G, np.zeros((n, 1)), np.ones((n, 1))]])
    b = np.r_[-base, base]
    if mode == "mcc":
        A, b = A[:n], b[:n]
    elif mode == "mic":
        A, b = A[n:], b[n:]
    x = _minimize(cost, A, b)[:k]
    y = base + G @ x
    return {"zone": float(np.ptp(y)), "mcc": float(y.max()), "mic": float(y.min())}[mode], x


#: Re-linearising a zone stops when the next correction would change it by less than this, mm
#: (the correction is second order in the step just taken: tilt^2 x extent, shift^2 / radius).
#: One nanometre: form is reported to a tenth of a micrometre at best, and from the
#: least-squares start the first step is already below it on measured parts (tilts of
#: 1e-4 rad over 60 mm: 0.6 nm), so one programme is solved instead of two.
_ZONE_SETTLED_MM = 1e-6


def _zone_blocks(bases: Sequence[np.ndarray], Gs: Sequence[np.ndarray], k0: int = 16) -> list[np.ndarray]:
    """Minimum zones of several independent linearised problems in one linear programme.

    Block ``s`` asks for ``x_s`` minimising ``ptp(bases[s] + Gs[s] @ x_s)``; the programme
    minimises the largest block's zone (plus a thousandth of their sum, so that every block
    sits at its own minimum too). Solving the blocks together costs one call of the LP
    solver instead of one each (its fixed cost, a few ms, dominates these small programmes).
    Only the points at the zones' edges constrain them: each block starts from its ``k0``
    most extreme points at each side and grows by the points left outside (an active set).

    Parameters
    ----------
    bases : sequence of (N_s,) float
    Gs : sequence of (N_s, k) float
        The same ``k`` for every block.

    Returns
    -------
    list of (k,) float
        Each block's ``x_s``.
    """
    S = len(bases)
    k = Gs[0].shape[1]
    actives = []
    for b in bases:
        n = len(b)
        if n <= 4 * k0:
            actives.append(np.arange(n))
        else:
            order = np.argsort(b)
            actives.append(np.unique(np.r_[order[:k0], order[-k0:]]))
    nv = S * k + 2 * S + 1  # x_s ..., U_s ..., L_s ..., z
    cost = np.zeros(nv)
    cost[-1] = 1.0
    cost[S * k:S * k + S] = 1e-3 / S
    cost[S * k + S:S * k + 2 * S] = -1e-3 / S
    xs = [np.zeros(k) for _ in range(S)]
    for _ in range(50):
        rows, rhs = [], []
        for s in range(S):
            a = actives[s]
            G, b = Gs[s][a], bases[s][a]
            m = len(a)
            up = np.zeros((m, nv))
            up[:, s * k:(s + 1) * k] = G
            up[:, S * k + s] = -1.0
            lo = np.zeros((m, nv))
            lo[:, s * k:(s + 1) * k] = -G
            lo[:, S * k + S + s] = 1.0
            zr = np.zeros((1, nv))
            zr[0, S * k + s], zr[0, S * k + S + s], zr[0, -1] = 1.0, -1.0, -1.0
            rows += [up, lo, zr]
            rhs += [-b, b, np.zeros(1)]
        sol = _minimize(cost, np.vstack(rows), np.concatenate(rhs))
        grown = False
        for s in range(S):
            xs[s] = sol[s * k:(s + 1) * k]
            y = bases[s] + Gs[s] @ xs[s]
            ya = y[actives[s]]
            hi, lo_ = ya.max(), ya.min()
            tol = 1e-12 * max(1.0, float(np.abs(bases[s]).max()))
            out = np.flatnonzero((y > hi + tol) | (y < lo_ - tol))
            if out.size:
                worst = out[np.argsort(-np.maximum(y[out] - hi, lo_ - y[out]))[:k0]]
                actives[s] = np.union1d(actives[s], worst)
                grown = True
        if not grown:
            break
    return xs


def flatness(points: np.ndarray, fit: Fit | None = None) -> float:
    """Minimum-zone flatness, mm: the smallest distance between two parallel planes holding
    every point (N, 3) mm. ``fit``: their least-squares plane (computed when absent).

    Only the points at the zone's two sides constrain it: the programme starts from the
    highest and lowest few and grows by those left outside (:func:`_zone_blocks`), which
    costs less than reducing the points to their convex hull first (1.0 ms against 3.0 ms
    for 3200 points of a face, the same zone)."""
    P, _ = _check(points, None)
    if len(P) < 3:
        raise FitError("flatness needs at least 3 points")
    fit = fit or fit_plane(P)
    c, nrm, eu, ev_ = fit.params["point"], fit.params["normal"], fit.params["u"], fit.params["v"]
    extent = float(np.ptp((P - c) @ eu)) + float(np.ptp((P - c) @ ev_))
    for _ in range(6):
        d = P - c
        base = d @ nrm
        G = np.column_stack([d @ eu, d @ ev_])
        (x,) = _zone_blocks([base], [G])
        nrm = _unit(nrm + x[0] * eu + x[1] * ev_)
        eu, ev_ = orthonormal_basis(nrm)
        if float(x @ x) * extent < _ZONE_SETTLED_MM:
            break
    return float(np.ptp((P - c) @ nrm))


def _circle_zone(P: np.ndarray, fit: Fit, mode: str) -> tuple[float, np.ndarray]:
    centre, nrm = fit.params["centre"], fit.params["normal"]
    eu, ev_ = orthonormal_basis(nrm)
    q = np.column_stack([(P - centre) @ eu, (P - centre) @ ev_])
    c = np.zeros(2)
    val = float("nan")
    for _ in range(8):
        dq = q - c
        rho = np.hypot(dq[:, 0], dq[:, 1])
        e = dq / np.maximum(rho, 1e-300)[:, None]
        val, x = _lp_zone(rho, -e, mode)
        c = c + x
        if np.linalg.norm(x) < 1e-10:
            break
    rho = np.hypot(*(q - c).T)
    val = {"zone": float(np.ptp(rho)), "mcc": float(rho.max()), "mic": float(rho.min())}[mode]
    return val, centre + c[0] * eu + c[1] * ev_


def roundness(points: np.ndarray, fit: Fit | None = None, *, normal: np.ndarray | None = None) -> float:
    """Minimum-zone roundness, mm: the smallest radial distance between two concentric circles
    holding every point of one cross-section (N, 3) mm, projected along ``normal`` (or
    ``fit``'s normal; ``fit``: their least-squares circle, computed when absent)."""
    P, _ = _check(points, None)
    if len(P) < 4:
        raise FitError("roundness needs at least 4 points")
    fit = fit or fit_circle(P, normal=normal)
    return _circle_zone(P, fit, "zone")[0]


def circle_mcc(points: np.ndarray, fit: Fit | None = None, *, normal: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """Minimum circumscribed circle of a cross-section: radius (mm) and centre (3,)."""
    P, _ = _check(points, None)
    fit = fit or fit_circle(P, normal=normal)
    return _circle_zone(P, fit, "mcc")


def circle_mic(points: np.ndarray, fit: Fit | None = None, *, normal: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """Maximum inscribed circle of a cross-section: radius (mm) and centre (3,)."""
    P, _ = _check(points, None)
    fit = fit or fit_circle(P, normal=normal)
    return _circle_zone(P, fit, "mic")


def cylindricity(points: np.ndarray, fit: Fit | None = None) -> float:
    """Minimum-zone cylindricity, mm: the smallest radial distance between two coaxial
    cylinders holding every point (N, 3) mm. ``fit``: their least-squares cylinder."""
    P, _ = _check(points, None)
    if len(P) < 6:
        raise FitError("cylindricity needs at least 6 points")
    fit = fit or fit_cylinder(P)
    p, a = fit.params["point"].copy(), fit.params["direction"].copy()
    R = max(float(fit.params["radius"]), 1e-6)
    for _ in range(8):
        bu, bv = orthonormal_basis(a)
        d = P - p
        h = d @ a
        rad = d - h[:, None] * a
        rho = np.linalg.norm(rad, axis=1)
        e = rad / np.maximum(rho, 1e-300)[:, None]
        eu_, ev2 = e @ bu, e @ bv
        G = np.column_stack([-eu_, -ev2, -h * eu_, -h * ev2])
        (x,) = _zone_blocks([rho], [G])
        p = p + x[0] * bu + x[1] * bv
        a = _unit(a + x[2] * bu + x[3] * bv)
        length = float(np.ptp(h))
        if float(x[:2] @ x[:2]) / R + float(x[2:] @ x[2:]) * (length + R) < _ZONE_SETTLED_MM:
            break
    d = P - p
    h = d @ a
    return float(np.ptp(np.linalg.norm(d - h[:, None] * a, axis=1)))


def roundness_sections(sections: Sequence[np.ndarray], normal: np.ndarray) -> np.ndarray:
    """Minimum-zone roundness of several cross-sections at once, mm.

    Parameters
    ----------
    sections : sequence of (N_s, 3) float
        The points of each cross-section, mm (at least 4 each).
    normal : (3,) float
        The sections' common normal (a cylinder's axis); the points are projected along it.

    Returns
    -------
    (S,) float
        Each section's roundness (radial width of the thinnest concentric ring holding it).
        The centres start from an algebraic circle fit of each section; all sections are
        solved in one linear programme and re-linearised together.
    """
    nrm = _unit(np.asarray(normal, float))
    eu, ev_ = orthonormal_basis(nrm)
    qs, cs, Rs = [], [], []
    for P in sections:
        P, _ = _check(P, None)
        if len(P) < 4:
            raise FitError("roundness needs at least 4 points")
        q = np.column_stack([P @ eu, P @ ev_])
        ctr, R = _kasa(q, np.ones(len(q)))
        qs.append(q)
        cs.append(ctr)
        Rs.append(max(R, 1e-6))
    for _ in range(8):
        bases, Gs = [], []
        for q, c in zip(qs, cs):
            dq = q - c
            rho = np.hypot(dq[:, 0], dq[:, 1])
            bases.append(rho)
            Gs.append(-dq / np.maximum(rho, 1e-300)[:, None])
        xs = _zone_blocks(bases, Gs)
        cs = [c + x for c, x in zip(cs, xs)]
        if max(float(x @ x) / R for x, R in zip(xs, Rs)) < _ZONE_SETTLED_MM:
            break
    return np.array([float(np.ptp(np.hypot(*(q - c).T))) for q, c in zip(qs, cs)])
