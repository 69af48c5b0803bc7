"""Rigid transforms and the robust fit of points onto a reference mesh, pure kernels.

The helpers the pose kernels share: :mod:`~inspector.kernels.registration` (the global
alignment and the re-fit on points), :mod:`~inspector.kernels.axis` (turns about an axis of
near-symmetry) and :mod:`~inspector.kernels.pose` (the pose search) import them from here,
and this module imports none of those (no import circle).

Conventions (CONTRACT): millimetres; ``pose`` is the 4x4 homogeneous transform mapping
reference coordinates to world coordinates, ``x_world = R @ x_ref + t``. Inside the fits
the reference is re-centred on its bounding-box centre (:class:`RefMesh`) and a pose is
held as ``W``, world -> that internal frame.

The fit (:func:`robust_fit`, one step: :class:`GaussNewtonStep`) is an iteratively
reweighted Gauss-Newton on se(3), vectorised over several candidate poses at once: each
point's residual is its distance to the closest point of the posed reference, its gradient
the direction to that point (the triangle normal on the surface), and the weights are
Tukey's biweight.
"""

from __future__ import annotations

from functools import cached_property
from typing import Any

import numpy as np
import open3d as o3d
from scipy.spatial.transform import Rotation

__all__ = [
    "POKE_TOLERANCE", "REF_SAMPLES", "GaussNewtonStep", "RefMesh", "as_mesh", "as_points", "as_pose",
    "axis_turn_deg", "inverse", "orthonormalize", "poking", "positive", "rigid_transform", "robust_fit", "rodrigues",
    "rotation_deg", "transform", "turns_about_axis",
]

#: Reference surface samples for the principal axes, the FPFH features and the axis.
REF_SAMPLES = 1500
#: Tukey efficiency constant and MAD -> sigma factor.
_TUKEY_C = 4.685
_MAD_SIGMA = 1.4826
#: A Gauss-Newton fit stops when a step predicts less than this relative cost decrease.
_REL_DECREASE = 1e-4
#: Correspondences whose normals disagree more than this (cosine) are ignored.
_NORMAL_COS = -0.5
#: The Tukey cutoff of a fit shrinks by at most this factor per iteration.
_SHRINK = 0.5
#: Fraction of hull points a pose may put inside the reference beyond the best pose's, and
#: the hull points used (a regular subset).
POKE_TOLERANCE = 0.002
_HULL_POINTS = 1500


# --------------------------------------------------------------------------- validation


def as_points(name: str, a: np.ndarray, *, min_rows: int = 1) -> np.ndarray:
    """``a`` as finite float points (N, 3), N >= ``min_rows``; ValueError naming ``name`` otherwise."""
    arr = np.asarray(a, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {arr.shape}")
    if arr.shape[0] < min_rows:
        raise ValueError(f"{name} needs at least {min_rows} rows, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def as_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A checked mesh: vertices (V, 3) float and faces (F, 3) int64 indexing them; ValueError otherwise."""
    v = as_points("ref_vertices", vertices, min_rows=3)
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] < 1:
        raise ValueError(f"ref_faces must have shape (F, 3) with F >= 1, got {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        if not (np.issubdtype(f.dtype, np.floating) and np.all(np.isfinite(f)) and np.all(f == np.round(f))):
            raise ValueError("ref_faces must hold integer vertex indices")
    f = f.astype(np.int64)
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"ref_faces indices must lie in [0, {len(v) - 1}], got [{f.min()}, {f.max()}]")
    return v, f


def as_pose(pose: np.ndarray) -> np.ndarray:
    """``pose`` as a finite proper rigid transform (4, 4) float; ValueError otherwise."""
    p = np.asarray(pose, dtype=float)
    if p.shape != (4, 4):
        raise ValueError(f"pose must have shape (4, 4), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("pose contains NaN or infinite values")
    R = p[:3, :3]
    if not np.allclose(p[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise ValueError(f"pose last row must be [0, 0, 0, 1], got {p[3].tolist()}")
    if not (np.allclose(R @ R.T, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0):
        raise ValueError("pose[:3, :3] must be a proper rotation matrix")
    return p


def positive(name: str, x: float) -> float:
    """``x`` as a finite positive float; ValueError naming ``name`` otherwise."""
    x = float(x)
    if not np.isfinite(x) or x <= 0:
        raise ValueError(f"{name} must be a finite positive number, got {x}")
    return x


# --------------------------------------------------------------------------- geometry helpers


def rigid_transform(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(4, 4) transform ``x -> R x + t`` from a rotation (3, 3) and a translation (3,)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def inverse(T: np.ndarray) -> np.ndarray:
    """Inverse (4, 4) of a rigid transform (4, 4)."""
    R = T[:3, :3]
    return rigid_transform(R.T, -R.T @ T[:3, 3])


def rodrigues(w: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) -> rotation matrices (..., 3, 3)."""
    theta = np.linalg.norm(w, axis=-1)
    k = w / np.where(theta > 0, theta, 1.0)[..., None]
    K = np.zeros(w.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -k[..., 2], k[..., 1]
    K[..., 1, 0], K[..., 1, 2] = k[..., 2], -k[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -k[..., 1], k[..., 0]
    s, c = np.sin(theta)[..., None, None], np.cos(theta)[..., None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """Nearest proper rotations to (..., 3, 3) matrices."""
    u, _, vt = np.linalg.svd(R)
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= d[..., None]
    return u @ vt


def turns_about_axis(axis: np.ndarray, centre: np.ndarray, angles_deg: np.ndarray) -> np.ndarray:
    """Rotations (K, 4, 4) by ``angles_deg`` about the line (axis (3,) unit, centre (3,) mm),
    in the frame those are given in."""
    a = np.asarray(angles_deg, float).reshape(-1)
    T = np.tile(np.eye(4), (len(a), 1, 1))
    T[:, :3, :3] = rodrigues(np.radians(a)[:, None] * axis[None])
    T[:, :3, 3] = centre - np.matmul(T[:, :3, :3], centre)
    return T


def rotation_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle of the rotation between two poses (4, 4), degrees."""
    R = a[:3, :3].T @ b[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def axis_turn_deg(a: np.ndarray, b: np.ndarray, axis: np.ndarray) -> float:
    """The turn (degrees) about ``axis`` (3,) (reference frame) of placement ``b`` (4, 4,
    maybe scaled) relative to placement ``a`` (4, 4)."""
    M = np.linalg.inv(a)[:3, :3] @ b[:3, :3]
    M = M / np.cbrt(np.linalg.det(M))
    return float(np.degrees(Rotation.from_matrix(M).as_rotvec() @ np.asarray(axis, float)))


# --------------------------------------------------------------------------- the reference mesh


class RefMesh:
    """The reference mesh re-centred on its bounding-box centre, with a raycasting scene.

    ``x_ref = x_internal + centre``. Poses handled internally are ``W``: world ->
    internal frame, (4, 4), the inverse of the internal pose.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, index: Any = None) -> None:
        self.index = index  # MeshDistance of the reference (its own frame), or None
        self.centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
        self.vertices = vertices - self.centre
        self.faces = faces
        tri = self.vertices[faces]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        dbl = np.linalg.norm(cross, axis=1)
        self.face_areas = 0.5 * dbl
        self.area = float(self.face_areas.sum())
        if not self.area > 0:
            raise ValueError("reference mesh has zero surface area")
        self.face_normals = cross / np.where(dbl > 0, dbl, 1.0)[:, None]
        self.diag = float(np.linalg.norm(np.ptp(self.vertices, axis=0)))

    @cached_property
    def scene(self) -> o3d.t.geometry.RaycastingScene:
        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d.core.Tensor(self.vertices.astype(np.float32))
        mesh.triangle.indices = o3d.core.Tensor(self.faces.astype(np.int32))
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(mesh)
        return scene

    def pose_from_w(self, W: np.ndarray) -> np.ndarray:
        """World -> internal transform -> reference -> world pose."""
        return inverse(W) @ rigid_transform(np.eye(3), -self.centre)

    def w_from_pose(self, pose: np.ndarray) -> np.ndarray:
        """Reference -> world pose -> world -> internal transform."""
        return inverse(pose @ rigid_transform(np.eye(3), self.centre))

    def sample(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``n`` area-uniform surface samples (internal frame) and their face normals."""
        idx = rng.choice(len(self.faces), size=n, p=self.face_areas / self.area)
        r1 = np.sqrt(rng.random(n))
        r2 = rng.random(n)
        tri = self.vertices[self.faces[idx]]
        pts = (1 - r1)[:, None] * tri[:, 0] + (r1 * (1 - r2))[:, None] * tri[:, 1] + (r1 * r2)[:, None] * tri[:, 2]
        return pts, self.face_normals[idx]

    def distance(self, q: np.ndarray) -> np.ndarray:
        """Unsigned distance of internal-frame points ``q`` (..., 3) to the surface, (...)."""
        if self.index is not None:
            return np.abs(self.index(q.reshape(-1, 3) + self.centre)).reshape(q.shape[:-1])
        flat = np.ascontiguousarray(q.reshape(-1, 3), dtype=np.float32)
        d = self.scene.compute_distance(o3d.core.Tensor(flat)).numpy()
        return d.astype(float).reshape(q.shape[:-1])

    def residuals(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`closest` of internal-frame points ``q`` (..., 3) and their distances (...) to
        them: with the distance index, in one compiled pass (the same numbers)."""
        if self.index is not None:
            c, n, r = self.index.residuals(q.reshape(-1, 3), self.centre, self.face_normals)
            return c.reshape(q.shape), n.reshape(q.shape), r.reshape(q.shape[:-1])
        c, n = self.closest(q)
        d = q - c
        return c, n, np.sqrt(np.sum(d * d, axis=-1))

    def closest(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest surface points (..., 3) and the normals (..., 3) of their triangles."""
        if self.index is not None:
            c, ids = self.index.closest(q.reshape(-1, 3) + self.centre)
            return (c - self.centre).reshape(q.shape), self.face_normals[ids].reshape(q.shape)
        flat = np.ascontiguousarray(q.reshape(-1, 3), dtype=np.float32)
        ans = self.scene.compute_closest_points(o3d.core.Tensor(flat))
        c = ans["points"].numpy().astype(float).reshape(q.shape)
        ids = ans["primitive_ids"].numpy().astype(np.int64)
        return c, self.face_normals[ids].reshape(q.shape)


# --------------------------------------------------------------------------- robust Gauss-Newton


def transform(W: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Apply K transforms (K, 4, 4) to points (N, 3) -> (K, N, 3)."""
    return np.matmul(x[None], W[:, :3, :3].transpose(0, 2, 1)) + W[:, None, :3, 3]


class GaussNewtonStep:
    """One Gauss-Newton step of K candidate poses on the same points.

    The Tukey cutoff of each candidate is ``4.685 * 1.4826 * median(r)`` clipped
    to ``[floor, cutoff]``, but shrinks by at most a factor ``shrink`` per step
    (so that weakly constrained motions converge before their evidence is cut
    off). With ``n_keep``, the candidates are first ranked by their mean capped
    distance ``mean(min(r, cap))`` and only the best ``n_keep`` (in their
    original order) are kept and stepped.

    Attributes
    ----------
    keep : (K',) int
        Indices of the stepped candidates among the K given.
    score : (K,) float
        Mean capped distance of each given candidate, mm (only with ``n_keep``).
    W : (K', 4, 4) float
        Poses after the step (world -> internal).
    cutoff : (K',) float
        Tukey cutoff used, mm.
    settled : (K',) bool
        Whether the cutoff has reached its data-driven value (is not shrinking).
    move : (K',) float
        Weighted RMS motion of the points along their residual directions, mm.
    cost : (K',) float
        Weighted mean squared residual before the step, mm^2.
    """

    def __init__(
        self,
        ref: RefMesh,
        x: np.ndarray,
        W: np.ndarray,
        cutoff: np.ndarray,
        floor: np.ndarray,
        normals: np.ndarray | None,
        *,
        n_keep: int | None = None,
        cap: float = np.inf,
        shrink: float = _SHRINK,
    ) -> None:
        q = transform(W, x)
        c, n, r = ref.residuals(q)
        self.keep = np.arange(len(W))
        if n_keep is not None:
            self.score = np.minimum(r, cap).mean(axis=1)
            if n_keep < len(W):
                self.keep = np.sort(np.argsort(self.score, kind="stable")[:n_keep])
                k = self.keep
                W, q, c, n, r, cutoff, floor = W[k], q[k], c[k], n[k], r[k], cutoff[k], floor[k]
        target = np.maximum(floor, np.minimum(cutoff, _TUKEY_C * _MAD_SIGMA * np.median(r, axis=1)))
        self.cutoff = np.maximum(target, shrink * cutoff)  # shrink gradually (inf stays inf)
        self.cutoff[~np.isfinite(cutoff)] = target[~np.isfinite(cutoff)]
        self.settled = self.cutoff <= target
        from inspector.kernels.gn_jit import normal_equations  # lazy: Numba only where a fit runs

        H, b, q0, scale, self.cost, sw, count = normal_equations(q, c, n, r, self.cutoff, W[:, :3, :3], normals,
                                                                 _NORMAL_COS)
        cutoff = self.cutoff
        ok = count >= 6  # fewer cannot fix 6 degrees of freedom
        tr = np.trace(H, axis1=1, axis2=2)
        H = H + np.eye(6) * (1e-9 * tr / 6.0 + 1e-12)[:, None, None]
        xi = -np.linalg.solve(H, b[..., None])[..., 0]
        xi[~ok] = 0.0
        # Trust region: no point should move farther than the cutoff in one step
        # (beyond it the weights, hence the linearisation, say nothing).
        size = np.linalg.norm(xi, axis=1)
        xi *= np.minimum(1.0, cutoff / np.maximum(size, 1e-300))[:, None]
        self.move = np.sqrt(np.maximum(np.sum(xi * np.matmul(H, xi[..., None])[..., 0], axis=1), 0.0) / sw)
        dR = rodrigues(xi[:, :3] / scale[:, None])
        D = np.zeros_like(W)
        D[:, :3, :3] = dR
        D[:, :3, 3] = q0 - np.matmul(dR, q0[..., None])[..., 0] + xi[:, 3:]
        D[:, 3, 3] = 1.0
        Wn = D @ W  # the step moves the points, in the reference frame, by D
        Wn[:, :3, :3] = orthonormalize(Wn[:, :3, :3])
        self.W = Wn


def robust_fit(
    ref: RefMesh,
    points: np.ndarray,
    W: np.ndarray,
    *,
    floor_mm: float,
    start_mm: float,
    iterations: int,
    tol: float,
    normals: np.ndarray | None = None,
    shrink: float = _SHRINK,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Iteratively reweighted Gauss-Newton of points onto the reference surface.

    Parameters
    ----------
    ref : RefMesh
    points : (N, 3) float
        World points, mm.
    W : (4, 4) float
        Initial world -> internal-reference transform.
    floor_mm, start_mm : float
        Lowest and initial Tukey cutoff, mm. The cutoff follows
        ``4.685 * 1.4826 * median |r|`` between these bounds, never increasing
        and shrinking by at most a factor ``shrink`` per iteration.
    iterations : int
        Maximum number of Gauss-Newton steps.
    tol : float
        Stop when a step moves the points by less than ``tol`` mm (weighted RMS
        along their residual directions), or predicts a relative cost decrease
        below ``_REL_DECREASE`` (sliding along a near-symmetry).
    normals : (N, 3) float, optional
        World unit normals of ``points``, used to reject wrong-side matches.
    shrink : float
        Slowest allowed decrease of the cutoff per iteration, in (0, 1].

    Returns
    -------
    W : (4, 4) float
        Refined world -> internal transform.
    dist : (N,) float
        Final distance of each point to the posed reference, mm.
    cutoff : float
        Final Tukey cutoff, mm.
    """
    cutoff = max(start_mm, floor_mm)
    Wk = W[None]
    for _ in range(iterations):
        step = GaussNewtonStep(ref, points, Wk, np.array([cutoff]), np.array([floor_mm]), normals, shrink=shrink)
        Wk, cutoff = step.W, float(step.cutoff[0])
        move, cost = float(step.move[0]), float(step.cost[0])
        if step.settled[0] and (move < tol or move * move < _REL_DECREASE * cost):
            break
    dist = ref.distance(transform(Wk, points)[0])
    return Wk[0], dist, cutoff


def poking(ref: RefMesh, hull: np.ndarray, W: np.ndarray, depth_mm: float) -> np.ndarray:
    """Fraction (K,) of the hull points (H, 3), world, that lie deeper than ``depth_mm``
    inside the reference under each world -> internal transform ``W`` (K, 4, 4)."""
    x = hull[:: max(1, len(hull) // _HULL_POINTS)]
    q = transform(W, x)
    if ref.index is not None:
        sd = ref.index(q.reshape(-1, 3) + ref.centre).reshape(q.shape[:-1])
    else:
        sd = ref.distance(q)  # unsigned: no depth test without the signed index
        return np.zeros(len(W))
    return np.mean(sd < -depth_mm, axis=1)
