"""An exact D-shaft (a Ø20 x 30 mm cylinder with a 1.5 mm deep flat on +x, axis z) and its
exact contour rays: the turn judge's and the pose search's unit tests run on this analytic
geometry, not on captures.

A camera at ``P`` in the plane z = 0 sees the shaft's side as two contour lines: the lines
from ``P`` that graze the D-shaped section (on the arc, or at a corner of the flat), at
every height. Its contour rays go from ``P`` through those lines; each grazes the shaft
exactly, so its smallest signed distance to the shaft in the true pose is 0.
"""

from __future__ import annotations

import numpy as np

#: Radius, the flat's distance from the axis, the length (mm); the flat's half-width.
R, H, L = 10.0, 8.5, 30.0
W = float(np.sqrt(R * R - H * H))
AXIS, CENTRE = np.array([0.0, 0.0, 1.0]), np.zeros(3)
#: The shaft's extent (2, 3): what :func:`~inspector.kernels.axis.turn_zone` reads of its vertices.
EXTENT = np.array([[-R, -R, -L / 2], [R, R, L / 2]])


def _section(x: np.ndarray, y: np.ndarray, flat: bool) -> np.ndarray:
    """Exact signed distance (N,) to the D section (the disc of radius R, cut by x <= H)."""
    rho = np.hypot(x, y)
    if not flat:
        return rho - R
    inside = (rho <= R) & (x <= H)
    # Outside, the nearest point is the arc's radial projection where that lies on the D,
    # or the flat's projection clipped to the flat (which always does).
    arc = np.where(R * x <= H * rho, rho - R, np.inf)
    chord = np.hypot(x - H, y - np.clip(y, -W, W))
    return np.where(inside, np.maximum(rho - R, x - H), np.minimum(arc, chord))


def sdf(X: np.ndarray, flat: bool = True) -> np.ndarray:
    """Exact signed distance (N,) of points (N, 3), shaft frame, to the D-shaft (the section
    extruded over |z| <= L/2; ``flat=False``: the plain cylinder), mm, negative inside."""
    X = np.asarray(X, float).reshape(-1, 3)
    d, e = _section(X[:, 0], X[:, 1], flat), np.abs(X[:, 2]) - L / 2
    return np.minimum(np.maximum(d, e), 0.0) + np.hypot(np.maximum(d, 0.0), np.maximum(e, 0.0))


def _grazed(P: np.ndarray) -> np.ndarray:
    """The two points (2, 2) of the D section that the lines from ``P`` (2,) graze."""
    base = np.arctan2(P[1], P[0])
    cand = [np.array([H, W]), np.array([H, -W])]  # the flat's corners
    for s in (1.0, -1.0):  # the circle's tangent points, where they lie on the D
        th = base + s * np.arccos(R / np.hypot(*P))
        q = R * np.array([np.cos(th), np.sin(th)])
        if q[0] <= H:
            cand.append(q)
    C = np.array(cand)
    # The extreme directions seen from P.
    ang = np.arctan2(C[:, 1] - P[1], C[:, 0] - P[0]) - np.arctan2(-P[1], -P[0])
    ang = (ang + np.pi) % (2 * np.pi) - np.pi
    return C[[np.argmin(ang), np.argmax(ang)]]


def rays(pose: np.ndarray, cameras: int = 6, heights: int = 5, distance_mm: float = 400.0) -> list:
    """Every camera's contour rays (:class:`~inspector.kernels.bcps.Rays`) of the D-shaft
    placed by ``pose`` (4, 4, shaft -> world): ``cameras`` cameras around the axis, rays
    through both contour lines at ``heights`` heights; each ray's range is +-15 mm about
    its grazing point."""
    from inspector.kernels.bcps import Rays

    out = []
    for k in range(cameras):
        a = 2.0 * np.pi * (k + 0.3) / cameras
        P = distance_mm * np.array([np.cos(a), np.sin(a)])
        z = np.linspace(-0.4 * L, 0.4 * L, heights)
        target = np.concatenate([np.column_stack([np.full(heights, g[0]), np.full(heights, g[1]), z]) for g in _grazed(P)])
        origin = np.array([P[0], P[1], 0.0])
        d = target - origin
        depth = np.linalg.norm(d, axis=1)
        d /= depth[:, None]
        out.append(Rays(pose[:3, :3] @ origin + pose[:3, 3], d @ pose[:3, :3].T, depth - 15.0, depth + 15.0))
    return out


def mesh(sections: int = 64):
    """The D-shaft as a watertight trimesh, shaft frame."""
    import trimesh

    cyl = trimesh.creation.cylinder(radius=R, height=L, sections=sections)
    box = trimesh.creation.box((2 * R, 2 * R + 2, L + 2))
    box.apply_translation((H - R, 0, 0))
    return trimesh.boolean.intersection([cyl, box], engine="manifold")
