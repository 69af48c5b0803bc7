"""Rigid registration of the CAD reference onto measured points, pure kernels.

Two entry points, arrays in and an :class:`~inspector.model.Alignment` out:

* :func:`align_reference` — global registration of the reference mesh onto the
  visual-hull reconstruction, from any orientation, then a robust fine fit;
* :func:`refine_on_points` — robust re-fit of an existing pose on points that
  should lie on the reference surface (the BCPS points).

Conventions (CONTRACT): millimetres; ``pose`` is the 4x4 homogeneous transform
mapping reference coordinates to world coordinates, ``x_world = R @ x_ref + t``.

Method
------
Distances are always measured to the exact reference triangles, with an Open3D
:class:`open3d.t.geometry.RaycastingScene` built once in the reference frame
re-centred on its bounding-box centre (this keeps the float32 queries precise).

All fits are the same iteratively reweighted Gauss-Newton on se(3), vectorised
over several candidate poses at once: each point's residual is its distance to
the closest point of the posed reference, its gradient the direction to that
point (the triangle normal on the surface), and the weights are Tukey's
biweight.

:func:`align_reference` first generates rotation hypotheses: the principal
frames of the reconstruction and of the reference matched through the 24
rotations of the cube group (all axis permutations and proper sign flips), the
permutations restricted to axes of similar variance, and, where variances are
nearly equal (the axes are then ill-defined), also turned by intermediate
angles; plus the identity and one FPFH + RANSAC estimate
(:func:`open3d.pipelines.registration.registration_ransac_based_on_feature_matching`).
All start with the centroids matched and are fitted together on a coarse voxel
subsample (one genuine point per voxel) with successive halving: every few
iterations the worse half, by the mean capped distance of the points to the
posed reference, is dropped. The survivor is then fitted on a finer subsample
and polished at full resolution with a Tukey cutoff that adapts to the data
(``4.685 * 1.4826 * median |r|``, shrinking gradually) but never drops
below a floor, so that gross outliers (visual-hull bulges, defects) have no
influence once the fit has converged. :func:`refine_on_points` is that last
stage alone.

Open3D's own ICP is not used: the fits need exact point-to-mesh distances and
batching over candidates, which the raycasting scene provides directly.
"""

from __future__ import annotations

import itertools
import weakref
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np
import open3d as o3d

from inspector.kernels.robust import tukey, tukey_loss
from inspector.model import Alignment, PoseConfidence

__all__ = ["AxisScan", "TurnZone", "align_reference", "pose_confidence", "refine_on_points", "scan_about_axis", "turn_zone",
           "turns_about_axis"]

_REG = o3d.pipelines.registration

#: Number of points aimed at in the coarse subsample (sets its voxel size), and
#: the fewest it may have whatever ``voxel_mm``.
_COARSE_POINTS = 400
_COARSE_MIN_POINTS = 100
#: Reference surface samples for the principal axes and the FPFH features.
_REF_SAMPLES = 1500
#: Variance ratio above which two principal axes are treated as interchangeable,
#: and above which they are also sampled at intermediate angles.
_SIMILAR = 0.7
_DEGENERATE = 0.8
#: Coarse search: Tukey cutoff and score cap in coarse voxels, iterations, point
#: queries per iteration (all candidates together), and successive halving (every
#: ``_PRUNE_EVERY`` iterations, down to ``_KEEP_MIN`` candidates).
_COARSE_CUTOFF = 3.0
_SCORE_CAP = 1.0
_COARSE_ITERATIONS = 20
_COARSE_BUDGET = 8000
_FIRST_PRUNE = 6
_PRUNE_EVERY = 2
_KEEP_MIN = 3
#: FPFH + RANSAC hypothesis: iteration cap and neighbours per feature.
_RANSAC_ITERATIONS = 4000
_FPFH_MAX_NN = 40
#: Tukey efficiency constant and MAD -> sigma factor.
_TUKEY_C = 4.685
_MAD_SIGMA = 1.4826
#: A Gauss-Newton fit stops when a step predicts less than this relative cost decrease.
_REL_DECREASE = 1e-4
#: Correspondences whose normals disagree more than this (cosine) are ignored.
_NORMAL_COS = -0.5
#: The Tukey cutoff of a fit shrinks by at most this factor per iteration (faster
#: in the fine stage of the global alignment, which starts from a converged pose).
_SHRINK = 0.5
_FINE_SHRINK = 0.25


def _cube_group() -> np.ndarray:
    """The 24 proper rotations mapping the coordinate axes onto themselves, (24, 3, 3)."""
    mats = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[perm, np.arange(3)] = signs  # column i -> +-axis perm[i]
            if np.linalg.det(m) > 0:
                mats.append(m)
    return np.array(mats)


_CUBE_GROUP = _cube_group()


# --------------------------------------------------------------------------- validation


def _as_points(name: str, a: np.ndarray, *, min_rows: int = 1) -> np.ndarray:
    arr = np.asarray(a, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {arr.shape}")
    if arr.shape[0] < min_rows:
        raise ValueError(f"{name} needs at least {min_rows} rows, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def _as_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v = _as_points("ref_vertices", vertices, min_rows=3)
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


def _as_pose(pose: np.ndarray) -> np.ndarray:
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


def _positive(name: str, x: float) -> float:
    x = float(x)
    if not np.isfinite(x) or x <= 0:
        raise ValueError(f"{name} must be a finite positive number, got {x}")
    return x


# --------------------------------------------------------------------------- geometry helpers


def _rigid(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _inverse(T: np.ndarray) -> np.ndarray:
    R = T[:3, :3]
    return _rigid(R.T, -R.T @ T[:3, 3])


def _rodrigues(w: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) -> rotation matrices (..., 3, 3)."""
    theta = np.linalg.norm(w, axis=-1)
    k = w / np.where(theta > 0, theta, 1.0)[..., None]
    K = np.zeros(w.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -k[..., 2], k[..., 1]
    K[..., 1, 0], K[..., 1, 2] = k[..., 2], -k[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -k[..., 1], k[..., 0]
    s, c = np.sin(theta)[..., None, None], np.cos(theta)[..., None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def _orthonormalize(R: np.ndarray) -> np.ndarray:
    """Nearest proper rotations to (..., 3, 3) matrices."""
    u, _, vt = np.linalg.svd(R)
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= d[..., None]
    return u @ vt


def _principal_frame(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal axes of ``x`` (N, 3): eigenvectors as columns (det +1) and variances, decreasing."""
    vals, vecs = np.linalg.eigh(np.cov(x, rowvar=False))
    E = vecs[:, ::-1].copy()
    if np.linalg.det(E) < 0:
        E[:, 2] = -E[:, 2]
    return E, np.maximum(vals[::-1], 0.0)


def _cloud(points: np.ndarray, normals: np.ndarray | None = None) -> o3d.geometry.PointCloud:
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, dtype=float)))
    if normals is not None:
        pc.normals = o3d.utility.Vector3dVector(np.ascontiguousarray(normals, dtype=float))
    return pc


def _voxel_pick(points: np.ndarray, voxel: float) -> np.ndarray:
    """Indices (M,) of one point per occupied voxel of size ``voxel``, in input order.

    Unlike a voxel-grid average, the kept points are genuine surface samples
    (averaging pulls points off curved surfaces and edges).
    """
    cell = np.floor((points - points.min(axis=0)) / voxel).astype(np.int64)
    dims = cell.max(axis=0) + 1
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    _, first = np.unique(key, return_index=True)
    return np.sort(first)


class _Reference:
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
        return _inverse(W) @ _rigid(np.eye(3), -self.centre)

    def w_from_pose(self, pose: np.ndarray) -> np.ndarray:
        """Reference -> world pose -> world -> internal transform."""
        return _inverse(pose @ _rigid(np.eye(3), self.centre))

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


def _transform(W: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Apply K transforms (K, 4, 4) to points (N, 3) -> (K, N, 3)."""
    return np.matmul(x[None], W[:, :3, :3].transpose(0, 2, 1)) + W[:, None, :3, 3]


class _Step:
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
        ref: _Reference,
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
        q = _transform(W, x)
        c, n = ref.closest(q)
        d = q - c
        r = np.sqrt(np.sum(d * d, axis=2))
        self.keep = np.arange(len(W))
        if n_keep is not None:
            self.score = np.minimum(r, cap).mean(axis=1)
            if n_keep < len(W):
                self.keep = np.sort(np.argsort(self.score, kind="stable")[:n_keep])
                k = self.keep
                W, q, n, d, r, cutoff, floor = W[k], q[k], n[k], d[k], r[k], cutoff[k], floor[k]
        target = np.maximum(floor, np.minimum(cutoff, _TUKEY_C * _MAD_SIGMA * np.median(r, axis=1)))
        self.cutoff = np.maximum(target, shrink * cutoff)  # shrink gradually (inf stays inf)
        self.cutoff[~np.isfinite(cutoff)] = target[~np.isfinite(cutoff)]
        self.settled = self.cutoff <= target
        cutoff = self.cutoff
        # Gradient of the distance field: direction from the closest point, or the
        # triangle normal for points (numerically) on the surface.
        on_surface = r <= 1e-6
        g = np.where(on_surface[..., None], n, d / np.where(on_surface, 1.0, r)[..., None])
        w = tukey(r, cutoff[:, None])
        if normals is not None:
            nq = np.matmul(normals[None], W[:, :3, :3].transpose(0, 2, 1))
            w = w * (np.sum(nq * n, axis=2) > _NORMAL_COS)
        sw = w.sum(axis=1)
        ok = np.count_nonzero(w, axis=1) >= 6  # fewer cannot fix 6 degrees of freedom
        sw = np.where(sw > 0, sw, 1.0)
        q0 = np.matmul(w[:, None, :], q)[:, 0] / sw[:, None]
        lever = q - q0[:, None, :]
        scale = np.sqrt(np.sum(w * np.sum(lever * lever, axis=2), axis=1) / sw)
        scale = np.maximum(scale, 1e-9)
        J = np.concatenate([np.cross(lever, g) / scale[:, None, None], g], axis=2)  # (K, N, 6)
        Jw = J * w[..., None]
        H = np.matmul(Jw.transpose(0, 2, 1), J)
        b = np.matmul(Jw.transpose(0, 2, 1), r[..., None])[..., 0]
        tr = np.trace(H, axis1=1, axis2=2)
        H = H + np.eye(6) * (1e-9 * tr / 6.0 + 1e-12)[:, None, None]
        xi = -np.linalg.solve(H, b[..., None])[..., 0]
        xi[~ok] = 0.0
        # Trust region: no point should move farther than the cutoff in one step
        # (beyond it the weights, hence the linearisation, say nothing).
        size = np.linalg.norm(xi, axis=1)
        xi *= np.minimum(1.0, cutoff / np.maximum(size, 1e-300))[:, None]
        self.move = np.sqrt(np.maximum(np.sum(xi * np.matmul(H, xi[..., None])[..., 0], axis=1), 0.0) / sw)
        self.cost = np.sum(w * r * r, axis=1) / sw
        dR = _rodrigues(xi[:, :3] / scale[:, None])
        D = np.zeros_like(W)
        D[:, :3, :3] = dR
        D[:, :3, 3] = q0 - np.matmul(dR, q0[..., None])[..., 0] + xi[:, 3:]
        D[:, 3, 3] = 1.0
        Wn = D @ W  # the step moves the points, in the reference frame, by D
        Wn[:, :3, :3] = _orthonormalize(Wn[:, :3, :3])
        self.W = Wn


def _robust_fit(
    ref: _Reference,
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
    ref : _Reference
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
        step = _Step(ref, points, Wk, np.array([cutoff]), np.array([floor_mm]), normals, shrink=shrink)
        Wk, cutoff = step.W, float(step.cutoff[0])
        move, cost = float(step.move[0]), float(step.cost[0])
        if step.settled[0] and (move < tol or move * move < _REL_DECREASE * cost):
            break
    dist = ref.distance(_transform(Wk, points)[0])
    return Wk[0], dist, cutoff


def _near_axis(ref: _Reference) -> tuple[np.ndarray, np.ndarray] | None:
    """The reference's axis of near-symmetry: unit direction (3,) and a point on it (3,),
    internal frame; None when it has no single such axis.

    The principal axis of the surface's exact second moments whose two partners have
    nearly equal variance (ratio above ``_DEGENERATE``: a shaft, a nut, a flange, a hub, a
    gear), through the surface's centroid; a box, a cube or a sphere has none. Exact
    moments, not samples: a flange's axis from 1500 samples is half a degree off, which
    hides its own symmetries (a turn by 90 degrees about a tilted axis moves its rim).
    """
    cache = _SELF_CACHE.setdefault(ref.index, {}) if ref.index is not None else ref.__dict__
    if "near_axis" in cache:
        return cache["near_axis"]
    tri = ref.vertices[ref.faces]
    A = ref.face_areas
    centre = (A[:, None] * tri.sum(axis=1)).sum(axis=0) / (3.0 * ref.area)
    t = tri - centre
    s = t.sum(axis=1)
    # Integral of x x^T over a triangle: A / 12 (s s^T + sum_i v_i v_i^T).
    M = (np.einsum("f,fi,fj->ij", A, s, s) + np.einsum("f,fki,fkj->ij", A, t, t)) / (12.0 * ref.area)
    vals, vecs = np.linalg.eigh(M)
    E, lam = vecs[:, ::-1], np.maximum(vals[::-1], 0.0)
    close01, close12 = lam[1] >= _DEGENERATE * lam[0], lam[2] >= _DEGENERATE * lam[1]
    near = None if close01 == close12 else _true_axis(ref, (E[:, 2] if close01 else E[:, 0]), centre)
    cache["near_axis"] = near
    return near


def _true_axis(ref: _Reference, axis: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The geometric axis near the principal one: the reference turned by 90 degrees about
    (``axis``, ``centre``) is fitted back onto itself (robustly: the keying features are
    outliers), and the axis of the composed rotation is returned with its point nearest
    ``centre``. A keyway tilts a shaft's principal axis by 0.7 degree, which a turn by
    180 degrees turns into half a millimetre at its ends."""
    s, _ = ref.sample(_REF_SAMPLES, np.random.default_rng(2))
    T = turns_about_axis(axis, centre, np.array([90.0]))[0]
    W, dist, _ = _robust_fit(ref, _transform(T[None], s)[0], np.eye(4), floor_mm=1e-3 * ref.diag,
                             start_mm=0.05 * ref.diag, iterations=40, tol=1e-7 * ref.diag)
    if np.mean(dist <= 0.01 * ref.diag) < 0.5:
        return axis, centre
    M = W @ T
    R = M[:3, :3]
    a = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if np.linalg.norm(a) < 1e-9:
        return axis, centre
    a = a / np.linalg.norm(a)
    a = a if a @ axis >= 0 else -a
    # Points c with R c + t = c: least squares (I - R) c = t, then the one nearest centre.
    c = np.linalg.lstsq(np.eye(3) - R, M[:3, 3], rcond=None)[0]
    c = c + ((centre - c) @ a) * a
    return a, c


def turns_about_axis(axis: np.ndarray, centre: np.ndarray, angles_deg: np.ndarray) -> np.ndarray:
    """Rotations (K, 4, 4) by ``angles_deg`` about the line (axis (3,) unit, centre (3,) mm),
    in the frame those are given in."""
    a = np.asarray(angles_deg, float).reshape(-1)
    T = np.tile(np.eye(4), (len(a), 1, 1))
    T[:, :3, :3] = _rodrigues(np.radians(a)[:, None] * axis[None])
    T[:, :3, 3] = centre - np.matmul(T[:, :3, :3], centre)
    return T


def _axis_turns(ref: _Reference, angles_deg: tuple[float, ...]) -> np.ndarray:
    """Internal-frame rotations (K, 4, 4) about the reference's axis of near-symmetry:
    the identity first, then one turn per angle; the identity alone for a reference with
    no single such axis (a box, a cube, a sphere)."""
    near = _near_axis(ref)
    if near is None or not len(angles_deg):
        return np.eye(4)[None]
    return turns_about_axis(near[0], near[1], np.concatenate([[0.0], np.asarray(angles_deg, float)]))


# --------------------------------------------------------------------------- turns about the axis

#: The axis scan: turns spaced so that the reference's outermost point moves by at most
#: one Tukey cutoff between two of them (a feature is never skipped), at most this many
#: turns; points used (a regular subset); local minima kept as fit starts.
_SCAN_MAX_TURNS = 360
_SCAN_POINTS = 2000
_SCAN_STARTS = 6
#: A turn is a symmetry of the reference when it moves fewer than this fraction of its
#: surface (area-uniform samples) farther than ``_SELF_TOL_MM`` off itself (tessellation
#: of a 30 mm circle in 128 sections: 9 um).
_SELF_SAMPLES = 4000
_SELF_TOL_MM = 0.05
_SYMMETRY_FRACTION = 0.002


@dataclass(frozen=True, eq=False)
class AxisScan:
    """Points against the reference turned about its axis of near-symmetry.

    Attributes
    ----------
    axis : (3,) float
        Unit direction of the axis, reference frame.
    centre : (3,) float
        A point of the axis, reference frame, mm.
    angles_deg : (K,) float
        The turns scanned, degrees in [0, 360), 0 first (the pose given).
    cost : (K,) float
        Mean Tukey loss of the points against the reference at ``pose`` turned by each
        angle: 0 when every point is on the surface, 1 when every point is beyond
        ``cutoff_mm``.
    moved : (K,) float
        Fraction of the reference's surface each turn moves off itself (0: a symmetry).
    cutoff_mm : float
        Tukey cutoff, mm.
    radius_mm : float
        Largest distance of the reference's surface from the axis, mm.
    n_points : int
        Points scanned (the loss is averaged over a regular subset of them).
    poke : (K,) float or None
        With hull points: the fraction of them each turn puts deeper than the hull depth
        inside the reference (0 where the turned reference is inside the visual hull).
    """

    axis: np.ndarray
    centre: np.ndarray
    angles_deg: np.ndarray
    cost: np.ndarray
    moved: np.ndarray
    cutoff_mm: float
    radius_mm: float
    n_points: int = 0
    poke: np.ndarray | None = None

    @property
    def inside_hull(self) -> np.ndarray:
        """(K,) bool: turns that keep the reference inside the hull as well as the best turn
        does (all True without hull points)."""
        if self.poke is None:
            return np.ones(len(self.angles_deg), bool)
        return self.poke <= self.poke.min() + _POKE_TOLERANCE

    @property
    def symmetric(self) -> np.ndarray:
        """(K,) bool: the turns that map the reference onto itself."""
        return self.moved < _SYMMETRY_FRACTION

    def distinct(self, width_deg: float | None = None) -> np.ndarray:
        """(K,) bool: turns that are neither near 0 nor near a symmetry of the reference
        (within ``width_deg``, default: the angle over which the outermost point moves two
        cutoffs)."""
        w = width_deg if width_deg is not None else np.degrees(2.0 * self.cutoff_mm / self.radius_mm)
        sym = self.angles_deg[self.symmetric]
        gap = np.abs((self.angles_deg[:, None] - sym[None, :] + 180.0) % 360.0 - 180.0)
        return ~(gap <= w).any(axis=1)

    def minima(self, n: int) -> np.ndarray:
        """Indices of the ``n`` lowest local minima of ``cost`` (circular), lowest first."""
        c = self.cost
        is_min = (c <= np.roll(c, 1)) & (c <= np.roll(c, -1))
        idx = np.flatnonzero(is_min)
        return idx[np.argsort(c[idx], kind="stable")][:n]


_SELF_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


@dataclass(frozen=True, eq=False)
class TurnZone:
    """Where a turn of the reference about its axis can change the distance to it.

    Turning about the axis keeps a point's distance ``rho`` from the axis and its height
    ``z`` along it; a point whose signed distance to the reference is the same at every turn
    of the reference (a surface of revolution nearby, or far from any surface) is
    *invariant*. A ray all of whose points are invariant has the same silhouette residual at
    every turn, so a search over turns need not look at it (a keyed shaft: 60 % of the
    contour rays; the others carry all the evidence).

    Attributes
    ----------
    axis, centre : (3,) float
        The axis (unit) and a point on it, reference frame.
    z0 : float
        Height of the grid's first row, mm.
    cell_mm : float
    variable : (R, Z) bool
        Cells (``rho`` from 0, ``z`` from ``z0``) where the signed distance varies with the
        turn and comes within the band of the surface, dilated by one cell.
    """

    axis: np.ndarray
    centre: np.ndarray
    z0: float
    cell_mm: float
    variable: np.ndarray

    def hits(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: which reference-frame points (N, 3), mm, lie in a variable cell."""
        rel = np.asarray(points, float).reshape(-1, 3) - self.centre
        z = rel @ self.axis
        rho = np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - z * z, 0.0))
        i = np.floor(rho / self.cell_mm).astype(np.int64)
        j = np.floor((z - self.z0) / self.cell_mm).astype(np.int64)
        R, Z = self.variable.shape
        ok = (i < R) & (j >= 0) & (j < Z)
        out = np.zeros(len(rel), bool)
        out[ok] = self.variable[i[ok], j[ok]]
        return out


def turn_zone(index: Any, vertices: np.ndarray, axis: np.ndarray, centre: np.ndarray, *, cell_mm: float = 0.5,
              band_mm: float = 1.0, tol_mm: float = 0.005, turns: int = 120) -> TurnZone:
    """The :class:`TurnZone` of a reference about (``axis``, ``centre``).

    Parameters
    ----------
    index : callable
        ``(N, 3) -> (N,)`` signed distance to the reference, reference frame, mm (NaN far
        from it is fine: e.g. ``MeshDistance.near``).
    vertices : (V, 3) float
        The reference's vertices (its extent), mm.
    axis, centre : (3,) float
        Unit axis and a point on it, reference frame.
    cell_mm : float
        Grid cell in ``rho`` and ``z``, mm.
    band_mm : float
        Only distances within this of the surface count, mm.
    tol_mm : float
        A cell varies when its distance ranges over more than this, mm.
    turns : int
        Turns sampled at each cell centre (every 3 degrees: a Ø5 bolt hole on a Ø38 circle
        spans 15).
    """
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    c = np.asarray(centre, float)
    rel = np.asarray(vertices, float) - c
    z = rel @ a
    rho = np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - z * z, 0.0))
    e1 = np.cross(a, (1.0, 0.0, 0.0) if abs(a[0]) < 0.9 else (0.0, 1.0, 0.0))
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    z0 = float(z.min()) - band_mm - cell_mm
    nr = int(np.ceil((float(rho.max()) + band_mm) / cell_mm)) + 1
    nz = int(np.ceil((float(z.max()) + band_mm + cell_mm - z0) / cell_mm)) + 1
    r_c = (np.arange(nr) + 0.5) * cell_mm
    z_c = z0 + (np.arange(nz) + 0.5) * cell_mm
    phi = np.linspace(0.0, 2.0 * np.pi, int(turns), endpoint=False)
    R, Z, F = np.meshgrid(r_c, z_c, phi, indexing="ij")
    X = c + Z.reshape(-1, 1) * a + (R * np.cos(F)).reshape(-1, 1) * e1 + (R * np.sin(F)).reshape(-1, 1) * e2
    sd = np.asarray(index(X), float).reshape(R.shape)
    sd = np.where(np.isnan(sd), np.inf, sd)
    near = np.abs(sd).min(axis=2) < band_mm
    spread = np.where(np.isfinite(sd), sd, 1e9).max(axis=2) - sd.min(axis=2)
    variable = near & (spread > tol_mm)
    from scipy.ndimage import binary_dilation

    variable = binary_dilation(variable, np.ones((3, 3), bool))
    return TurnZone(axis=a, centre=c, z0=z0, cell_mm=float(cell_mm), variable=variable)


def _self_moved(ref: _Reference, axis: np.ndarray, centre: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Fraction (K,) of the reference's surface samples that the turns ``T`` (K, 4, 4)
    move farther than ``_SELF_TOL_MM`` off the reference."""
    s, _ = ref.sample(_SELF_SAMPLES, np.random.default_rng(1))
    return np.mean(ref.distance(_transform(T, s)) > _SELF_TOL_MM, axis=1)


def _scan(ref: _Reference, points: np.ndarray, W: np.ndarray, cutoff_mm: float,
          hull: tuple[np.ndarray, float] | None = None) -> AxisScan | None:
    """Scan the turns of the reference about its near-symmetry axis for world ``points``
    (N, 3) and the world -> internal transform ``W`` (4, 4); None without such an axis.
    ``hull``: visual-hull points (H, 3), world, and the depth that counts, mm."""
    near = _near_axis(ref)
    if near is None:
        return None
    axis, centre = near
    s, _ = ref.sample(_REF_SAMPLES, np.random.default_rng(0))
    rel = s - centre
    radius = float(np.sqrt(np.max(np.sum(rel * rel, axis=1) - (rel @ axis) ** 2)))
    step = np.degrees(cutoff_mm / max(radius, 1e-9))
    # A multiple of 120 turns, so that the symmetries of 2-6, 8, 10 and 12 holes or teeth
    # are among them.
    k = int(min(_SCAN_MAX_TURNS, 120 * np.ceil(360.0 / step / 120)))
    angles = np.arange(k) * (360.0 / k)
    T = turns_about_axis(axis, centre, angles)
    # The reference's own symmetries depend on it alone: computed once per distance index.
    cache = _SELF_CACHE.setdefault(ref.index, {}) if ref.index is not None else {}
    if k not in cache:
        cache[k] = _self_moved(ref, axis, centre, T)
    x = points[:: max(1, len(points) // _SCAN_POINTS)]
    # The reference turned by an angle is the points turned back by it (in its frame).
    back = turns_about_axis(axis, centre, -angles) @ W
    cost = np.mean(tukey_loss(ref.distance(_transform(back, x)), cutoff_mm), axis=1)
    poke = None if hull is None else _poking(ref, hull[0], back, hull[1])
    return AxisScan(axis=axis, centre=centre + ref.centre, angles_deg=angles, cost=cost, moved=cache[k],
                    cutoff_mm=float(cutoff_mm), radius_mm=radius, n_points=len(points), poke=poke)


def _best_start(ref: _Reference, points: np.ndarray, W: np.ndarray, *, floor_mm: float, start_mm: float,
                iterations: int, judge_mm: float | None = None,
                hull: tuple[np.ndarray, float] | None = None) -> np.ndarray:
    """Fit all candidate transforms (K, 4, 4) together and return the one (4, 4) with the
    lowest Tukey cost at ``judge_mm`` (default ``floor_mm``; every candidate judged on the
    same points). With ``hull`` (points (H, 3) of the part's visual hull, world, and a
    depth, mm), candidates that put more hull points deeper than that inside the reference
    than the best of them does (plus a small tolerance) are never chosen: the part lies
    inside its visual hull, so a reference pose that pokes out of it contradicts the
    silhouettes."""
    cutoff = np.full(len(W), max(start_mm, floor_mm))
    floor = np.full(len(W), floor_mm)
    for _ in range(iterations):
        step = _Step(ref, points, W, cutoff, floor, None)
        W, cutoff = step.W, step.cutoff
        if step.settled.all() and float(step.move.max()) < 1e-3 * floor_mm:
            break
    r = ref.distance(_transform(W, points))
    cost = np.sum(tukey_loss(r, judge_mm if judge_mm is not None else floor_mm), axis=1)
    if hull is not None:
        poke = _poking(ref, hull[0], W, hull[1])
        cost = np.where(poke <= poke.min() + _POKE_TOLERANCE, cost, np.inf)
    return W[int(np.argmin(cost))]


#: Fraction of hull points a pose may put inside the reference beyond the best pose's.
_POKE_TOLERANCE = 0.002
_HULL_POINTS = 1500


def _poking(ref: _Reference, hull: np.ndarray, W: np.ndarray, depth_mm: float) -> np.ndarray:
    """Fraction (K,) of the hull points (H, 3), world, that lie deeper than ``depth_mm``
    inside the reference under each world -> internal transform ``W`` (K, 4, 4)."""
    x = hull[:: max(1, len(hull) // _HULL_POINTS)]
    q = _transform(W, x)
    if ref.index is not None:
        sd = ref.index(q.reshape(-1, 3) + ref.centre).reshape(q.shape[:-1])
    else:
        sd = ref.distance(q)  # unsigned: no depth test without the signed index
        return np.zeros(len(W))
    return np.mean(sd < -depth_mm, axis=1)


def _summary(dist: np.ndarray, inlier_mm: float) -> tuple[float, float]:
    inl = dist <= inlier_mm
    fitness = float(np.mean(inl)) if len(dist) else 0.0
    rmse = float(np.sqrt(np.mean(dist[inl] ** 2))) if np.any(inl) else 0.0
    return fitness, rmse


# --------------------------------------------------------------------------- global alignment


def _rotation_hypotheses(xs: np.ndarray, xt: np.ndarray) -> np.ndarray:
    """Candidate rotations world -> reference from matched principal frames, (K, 3, 3).

    ``xs`` (N, 3) are world points, ``xt`` (M, 3) reference points, both roughly
    uniform on the surface. The principal frames are matched through the rotations
    of the cube group that only exchange axes of similar variance (ratio above
    ``_SIMILAR``; the 4 sign flips always). Where variances are nearly equal
    (ratio above ``_DEGENERATE``) the axes are ill-defined, so the candidates are
    also turned by intermediate angles: about the distinct axis in 7.5 degree
    steps when two variances are close, about each axis by 45 degrees when all
    three are. The identity comes first.
    """
    Es, ls = _principal_frame(xs)
    Et, lt = _principal_frame(xt)
    lam = 0.5 * (ls + lt)  # decreasing

    def close(i: int, j: int, ratio: float) -> bool:
        return bool(lam[max(i, j)] >= ratio * lam[min(i, j)])

    pairs = ((0, 1), (1, 2), (0, 2))
    similar = np.eye(3, dtype=bool)
    for i, j in pairs:
        similar[i, j] = similar[j, i] = close(i, j, _SIMILAR)
    target_axis = np.argmax(np.abs(_CUBE_GROUP), axis=1)  # (24, 3): axis each axis goes to
    allowed = [G for G, ax in zip(_CUBE_GROUP, target_axis) if all(similar[i, ax[i]] for i in range(3))]
    degenerate = [(i, j) for i, j in pairs if close(i, j, _DEGENERATE)]
    offsets = [np.eye(3)]
    if len(degenerate) >= 2:
        offsets += [_rodrigues(np.eye(3)[a] * (np.pi / 4)) for a in range(3)]
    elif len(degenerate) == 1:
        axis = 3 - sum(degenerate[0])
        # 7.5 degree steps: from 22.5, the hull fit could stay 11 degrees off about a
        # shaft's axis (1.7 mm at its flat), too far for the BCPS re-fit.
        offsets += [_rodrigues(np.eye(3)[axis] * (k * np.pi / 24)) for k in range(1, 12)]
    rots = [np.eye(3)] + [Et @ G @ O @ Es.T for O in offsets for G in allowed]
    return np.array(rots)


def _ransac_hypothesis(
    src: o3d.geometry.PointCloud, tgt: o3d.geometry.PointCloud, voxel: float, seed: int
) -> np.ndarray | None:
    """FPFH feature matching + RANSAC, world -> reference (4, 4), or None on failure."""
    param = o3d.geometry.KDTreeSearchParamHybrid(radius=5.0 * voxel, max_nn=_FPFH_MAX_NN)
    fs = _REG.compute_fpfh_feature(src, param)
    ft = _REG.compute_fpfh_feature(tgt, param)
    o3d.utility.random.seed(int(seed))  # Open3D's RNG is global; RANSAC is its only user here
    res = _REG.registration_ransac_based_on_feature_matching(
        src,
        tgt,
        fs,
        ft,
        False,
        1.5 * voxel,
        _REG.TransformationEstimationPointToPoint(False),
        3,
        [
            _REG.CorrespondenceCheckerBasedOnEdgeLength(0.9),
            _REG.CorrespondenceCheckerBasedOnDistance(1.5 * voxel),
        ],
        _REG.RANSACConvergenceCriteria(_RANSAC_ITERATIONS, 0.999),
    )
    T = np.asarray(res.transformation, dtype=float)
    if res.fitness > 0 and np.all(np.isfinite(T)) and np.allclose(T[3], [0, 0, 0, 1]):
        return T
    return None


def _coarse_search(
    ref: _Reference, x: np.ndarray, nx: np.ndarray, W: np.ndarray, voxel: float
) -> np.ndarray:
    """Fit all candidates (K, 4, 4) on the coarse points ``x``, halving them as they go.

    Each iteration uses a regular subset of ``x`` of about
    ``_COARSE_BUDGET / K`` points (all of them once few candidates are left);
    every ``_PRUNE_EVERY`` iterations the worse half is dropped by the mean
    distance of the points to the posed reference, each capped at
    ``_SCORE_CAP * voxel``. Returns the best world -> internal transform (4, 4).
    """
    cap = _SCORE_CAP * voxel
    cutoff = np.full(len(W), _COARSE_CUTOFF * voxel)
    for it in range(_COARSE_ITERATIONS):
        stride = max(1, int(np.ceil(len(x) * len(W) / _COARSE_BUDGET)))
        prune = it >= _FIRST_PRUNE and (it - _FIRST_PRUNE) % _PRUNE_EVERY == 0 and len(W) > _KEEP_MIN
        n_keep = max(_KEEP_MIN, (len(W) + 1) // 2) if prune else None
        step = _Step(ref, x[::stride], W, cutoff, cutoff, nx[::stride], n_keep=n_keep, cap=cap)
        W, cutoff = step.W, cutoff[step.keep]
        if len(W) <= _KEEP_MIN and float(step.move.max()) < 1e-3 * voxel:
            break
    step = _Step(ref, x, W, cutoff, cutoff, nx, n_keep=len(W), cap=cap)
    return W[int(np.argmin(step.score))]


def align_reference(
    points: np.ndarray,
    normals: np.ndarray,
    ref_vertices: np.ndarray,
    ref_faces: np.ndarray,
    *,
    voxel_mm: float = 1.0,
    inlier_mm: float = 1.0,
    seed: int = 0,
    index: Any = None,
) -> Alignment:
    """Globally align the reference mesh onto a reconstruction.

    Works from any initial orientation and translation (the centroids are matched
    first); robust to the outward bulges of a visual hull, to local defects and
    to a few percent of scale error. For symmetric parts one of the equivalent
    poses is returned. Deterministic for a given ``seed``.

    Parameters
    ----------
    points : (N, 3) float
        Reconstruction surface points, world mm (N >= 10).
    normals : (N, 3) float
        Outward normals of ``points`` (any non-zero length).
    ref_vertices : (V, 3) float
        Reference (CAD) mesh vertices in the reference frame, mm.
    ref_faces : (F, 3) int
        Triangles of the reference mesh, indices into ``ref_vertices``; the mesh
        is expected to be watertight.
    voxel_mm : float, default 1.0
        Voxel size of the subsample used by the fine fit, mm (one point kept per
        voxel). Also the voxel of the coarse (hypothesis) subsample, enlarged
        to keep it near 400 points or reduced to keep it above about 100.
    inlier_mm : float, default 1.0
        Distance under which a point counts as an inlier for ``fitness`` and
        ``rmse_mm``, mm. The Tukey cutoff of the fine fit starts at
        ``max(inlier_mm, 3 coarse voxels)`` and adapts to the residuals down to
        no less than ``inlier_mm / 10``.
    seed : int, default 0
        Seed of the reference surface sampling and of the RANSAC hypothesis.
    index : MeshDistance, optional
        The reference's exact distance index (:class:`~inspector.kernels.meshdist.MeshDistance`
        built on ``ref_vertices``, ``ref_faces``; e.g. ``Reference.distance``): closest
        points come from it instead of a new Open3D scene.

    Returns
    -------
    Alignment
        ``pose`` (4, 4) reference -> world; ``fitness`` the fraction of ``points``
        within ``inlier_mm`` of the posed reference; ``rmse_mm`` the RMS distance
        of those inliers, mm; ``method="global+icp"``.

    Raises
    ------
    ValueError
        On malformed shapes, non-finite values, zero normals, a degenerate mesh
        or non-positive parameters.
    """
    pts = _as_points("points", points, min_rows=10)
    nrm = _as_points("normals", normals)
    if nrm.shape != pts.shape:
        raise ValueError(f"normals must have the shape of points {pts.shape}, got {nrm.shape}")
    nlen = np.linalg.norm(nrm, axis=1)
    if np.any(nlen <= 0):
        raise ValueError("normals contains zero-length vectors")
    nrm = nrm / nlen[:, None]
    verts, faces = _as_mesh(ref_vertices, ref_faces)
    voxel_mm = _positive("voxel_mm", voxel_mm)
    inlier_mm = _positive("inlier_mm", inlier_mm)

    ref = _Reference(verts, faces, index)
    rng = np.random.default_rng(seed)

    # Coarse subsamples of the reconstruction and of the reference surface.
    lo, hi = np.sqrt(ref.area / _COARSE_POINTS), np.sqrt(ref.area / _COARSE_MIN_POINTS)
    voxel_c = float(np.clip(voxel_mm, lo, hi))
    pick = _voxel_pick(pts, voxel_c)
    if len(pick) < 10:
        pick = np.arange(len(pts))
    xs, ns = pts[pick], nrm[pick]
    ref_pts, ref_nrm = ref.sample(_REF_SAMPLES, rng)
    pick = _voxel_pick(ref_pts, voxel_c)
    xt, nt = ref_pts[pick], ref_nrm[pick]

    # Hypotheses (world -> internal reference), centroids matched.
    rots = _rotation_hypotheses(xs, xt)
    cs, ct = xs.mean(axis=0), xt.mean(axis=0)
    W = np.zeros((len(rots), 4, 4))
    W[:, :3, :3] = rots
    W[:, :3, 3] = ct - rots @ cs
    W[:, 3, 3] = 1.0
    T_ransac = _ransac_hypothesis(_cloud(xs, ns), _cloud(xt, nt), voxel_c, seed)
    if T_ransac is not None:
        W = np.concatenate([W, T_ransac[None]])
    best = _coarse_search(ref, xs, ns, W, voxel_c)

    # Fine fit: converge on a voxel subsample, then polish at full resolution.
    pick = _voxel_pick(pts, voxel_mm)
    floor = inlier_mm / 10.0
    cutoff = max(inlier_mm, _COARSE_CUTOFF * voxel_c)
    tol = 1e-5 * ref.diag
    fit = dict(floor_mm=floor, tol=tol, shrink=_FINE_SHRINK)
    polish = 30
    if 10 <= len(pick) <= len(pts) // 2:
        best, _, cutoff = _robust_fit(ref, pts[pick], best, start_mm=cutoff, iterations=30, normals=nrm[pick], **fit)
        polish = 4
    best, dist, _ = _robust_fit(ref, pts, best, start_mm=cutoff, iterations=polish, normals=nrm, **fit)
    fitness, rmse = _summary(dist, inlier_mm)
    return Alignment(pose=ref.pose_from_w(best), fitness=fitness, rmse_mm=rmse, method="global+icp")


# --------------------------------------------------------------------------- refinement


def refine_on_points(
    points: np.ndarray,
    ref_vertices: np.ndarray,
    ref_faces: np.ndarray,
    pose: np.ndarray,
    *,
    robust_mm: float = 0.3,
    iterations: int = 20,
    index: Any = None,
    start_mm: float | None = None,
    axis_turns_deg: tuple[float, ...] = (),
    axis_scan: bool = False,
    hull_points: np.ndarray | None = None,
    hull_mm: float = 1.0,
) -> Alignment:
    """Robustly re-fit the reference pose on points that lie on its surface.

    Minimises ``sum_i rho(dist(p_i, pose(reference)))`` with Tukey's biweight
    ``rho`` by iteratively reweighted Gauss-Newton on se(3), with exact closest
    points on the reference triangles (queried in the reference frame after
    mapping the points by the inverse pose). The Tukey cutoff starts at
    ``max(robust_mm, 4.685 * 1.4826 * median distance)`` and shrinks with the
    residuals down to ``robust_mm``, so points farther than ``robust_mm`` from
    the converged surface (defects) have no influence.

    Parameters
    ----------
    points : (N, 3) float
        World points expected on the reference surface (e.g. BCPS points), mm;
        N >= 6.
    ref_vertices : (V, 3) float
        Reference mesh vertices, reference frame, mm.
    ref_faces : (F, 3) int
        Reference triangles.
    pose : (4, 4) float
        Initial reference -> world pose (a proper rigid transform), close to the
        solution (within about ``robust_mm`` and a degree).
    robust_mm : float, default 0.3
        Final Tukey cutoff, mm; also the inlier distance for ``fitness`` and
        ``rmse_mm``.
    iterations : int, default 20
        Maximum Gauss-Newton iterations (stops earlier on convergence); 0 only
        evaluates ``pose``.
    index : MeshDistance, optional
        The reference's exact distance index (:class:`~inspector.kernels.meshdist.MeshDistance`
        built on ``ref_vertices``, ``ref_faces``; e.g. ``Reference.distance``): closest
        points come from it instead of a new Open3D scene.
    start_mm : float, optional
        Initial Tukey cutoff, mm (default: the data-driven value). A wide start (e.g.
        1 mm) lets the few points that pin a near-symmetry (the flat of a shaft, off by
        tenths of a millimetre while the rotation about the axis is wrong) act before
        the cutoff shrinks to ``robust_mm``.
    axis_turns_deg : tuple of float
        For a reference with an axis of near-symmetry (a shaft with a flat, a nut), also
        start from ``pose`` turned about that axis by these angles, degrees, and keep the
        start whose fit has the lowest robust cost: the features that fix the rotation
        about such an axis are small, and a pose turned by ten degrees is a local minimum
        that a single fit does not leave.
    axis_scan : bool, default False
        For a reference with an axis of near-symmetry, scan every turn about it (spaced
        so that its outermost point moves one start cutoff between two turns), start
        fits from the lowest local minima of the points' robust loss as well, and keep
        the fit with the lowest loss at the start cutoff (``min(start_mm, 10 robust_mm)``),
        not at ``robust_mm``: a part a few percent off in size keeps its keying features
        (bolt holes, a keyway) tenths of a millimetre off the nominal at the right turn,
        beyond ``robust_mm``, and judged there a wrong turn can win (flange at scale 0.98,
        holes 90 degrees apart: 14 degrees off).
    hull_points : (H, 3) float, optional
        Surface points of the part's visual hull, world, mm. The part lies inside its
        hull; a start whose fit puts more of these points deeper than ``hull_mm`` inside
        the reference than the best start does is not chosen (a flange turned so that its
        bolt holes sit where the hull has material).
    hull_mm : float, default 1.0
        Depth beyond which a hull point inside the reference counts, mm (the reference may
        be larger than the part by a few percent and the hull is voxelised).

    Returns
    -------
    Alignment
        Refined ``pose`` (4, 4); ``fitness`` the fraction of ``points`` within
        ``robust_mm``; ``rmse_mm`` the RMS distance of those, mm;
        ``method="bcps-refine"``.

    Raises
    ------
    ValueError
        On malformed shapes, non-finite values, an improper ``pose``, a
        degenerate mesh or non-positive parameters.
    """
    pts = _as_points("points", points, min_rows=6)
    verts, faces = _as_mesh(ref_vertices, ref_faces)
    P = _as_pose(pose)
    robust_mm = _positive("robust_mm", robust_mm)
    start = np.inf if start_mm is None else _positive("start_mm", start_mm)
    if isinstance(iterations, bool) or int(iterations) != iterations or iterations < 0:
        raise ValueError(f"iterations must be a non-negative integer, got {iterations!r}")

    ref = _Reference(verts, faces, index)
    W0 = ref.w_from_pose(P)
    turns = _axis_turns(ref, tuple(axis_turns_deg))
    wide = min(start, 10.0 * robust_mm)
    judge = None
    if axis_scan:
        scan = _scan(ref, pts, W0, wide)
        near = _near_axis(ref)
        if scan is not None and near is not None:
            # Starts act on the points: the reference's turn, backwards.
            extra = turns_about_axis(near[0], near[1], -scan.angles_deg[scan.minima(_SCAN_STARTS)])
            turns, judge = np.concatenate([turns, extra]), wide
    if len(turns) > 1:
        hull = None if hull_points is None else (_as_points("hull_points", hull_points), _positive("hull_mm", hull_mm))
        W0 = _best_start(ref, pts, turns @ W0, floor_mm=robust_mm, start_mm=wide, iterations=int(iterations),
                         judge_mm=judge, hull=hull)
    W, dist, _ = _robust_fit(
        ref, pts, W0, floor_mm=robust_mm, start_mm=start, iterations=int(iterations), tol=1e-6 * ref.diag,
    )
    fitness, rmse = _summary(dist, robust_mm)
    return Alignment(pose=ref.pose_from_w(W), fitness=fitness, rmse_mm=rmse, method="bcps-refine")


def scan_about_axis(
    points: np.ndarray,
    ref_vertices: np.ndarray,
    ref_faces: np.ndarray,
    pose: np.ndarray,
    *,
    cutoff_mm: float,
    index: Any = None,
    hull_points: np.ndarray | None = None,
    hull_mm: float = 1.0,
) -> AxisScan | None:
    """How well ``points`` fit the reference at ``pose`` turned about its near-symmetry axis.

    Parameters
    ----------
    points : (N, 3) float
        World points on the part's surface (e.g. BCPS points), mm; N >= 6.
    ref_vertices, ref_faces : (V, 3) float, (F, 3) int
        Reference mesh, reference frame, mm.
    pose : (4, 4) float
        Reference -> world pose.
    cutoff_mm : float
        Tukey cutoff of the loss, mm; also sets the spacing of the turns (the reference's
        outermost point moves one cutoff between two).
    index : MeshDistance, optional
        The reference's exact distance index (needed for ``hull_points``).
    hull_points : (H, 3) float, optional
        Surface points of the part's visual hull, world, mm: the scan also says which turns
        keep the reference inside the hull (:attr:`AxisScan.poke`).
    hull_mm : float
        Depth inside the reference beyond which a hull point counts, mm.

    Returns
    -------
    AxisScan or None
        None for a reference with no single axis of near-symmetry.
    """
    pts = _as_points("points", points, min_rows=6)
    verts, faces = _as_mesh(ref_vertices, ref_faces)
    ref = _Reference(verts, faces, index)
    hull = None if hull_points is None else (_as_points("hull_points", hull_points), _positive("hull_mm", hull_mm))
    return _scan(ref, pts, ref.w_from_pose(_as_pose(pose)), _positive("cutoff_mm", cutoff_mm), hull)


#: A runner-up turn pinned by fewer points than this (margin x points) is ambiguous.
AMBIGUOUS_POINTS = 30


def pose_confidence(scan: AxisScan | None) -> PoseConfidence:
    """What an :class:`AxisScan` about the final pose says of the pose's turn.

    The runner-up is the lowest local minimum of the loss among the turns that are
    neither within two cutoffs (at the outermost radius) of the pose or of a symmetry of
    the reference, nor put the reference out of the visual hull. Its margin is a lower
    bound of the evidence for the pose: the points were selected against it.
    """
    if scan is None:
        return PoseConfidence()
    sym = scan.angles_deg[scan.symmetric & (scan.angles_deg > 0)]
    a = (scan.angles_deg + 180.0) % 360.0 - 180.0
    inside = scan.inside_hull
    # The hull range: the turns about the pose, both ways, before the first one out of it.
    order_pos = np.flatnonzero(a >= 0)[np.argsort(a[a >= 0])]
    order_neg = np.flatnonzero(a <= 0)[np.argsort(-a[a <= 0])]

    def reach(order: np.ndarray) -> float:
        out = np.flatnonzero(~inside[order])
        return float(a[order[out[0] - 1]]) if len(out) and out[0] > 0 else float(a[order[-1]])

    hull_range = (reach(order_neg), reach(order_pos))
    c = scan.cost
    is_min = (c <= np.roll(c, 1)) & (c <= np.roll(c, -1))
    cand = np.flatnonzero(is_min & scan.distinct() & inside)
    base = PoseConfidence(axis=(float(scan.axis[0]), float(scan.axis[1]), float(scan.axis[2])),
                          symmetry_deg=tuple(float(v) for v in sym), hull_range_deg=hull_range,
                          cutoff_mm=scan.cutoff_mm)
    if not len(cand):
        return base
    best = cand[np.argmin(c[cand])]
    margin = float(c[best] - c[0])
    points = int(round(margin * scan.n_points))
    return replace(base, runner_up_deg=float(a[best]), margin=margin, margin_points=points,
                   ambiguous=points < AMBIGUOUS_POINTS)
