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

All fits are the same iteratively reweighted Gauss-Newton on se(3)
(:func:`~inspector.kernels.rigid.robust_fit`), vectorised
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

The turns about a reference's axis of near-symmetry (the re-fit's ``axis_scan``) are
:mod:`~inspector.kernels.axis`'s; the shared geometry and fit, :mod:`~inspector.kernels.rigid`'s.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
import open3d as o3d

from inspector.kernels.axis import DEGENERATE, axis_turns, near_axis, scan_turns
from inspector.kernels.extent import bounds_of
from inspector.kernels.rigid import (
    POKE_TOLERANCE,
    REF_SAMPLES,
    GaussNewtonStep,
    RefMesh,
    as_mesh,
    as_points,
    as_pose,
    poking,
    positive,
    robust_fit,
    rodrigues,
    transform,
    turns_about_axis,
)
from inspector.kernels.robust import tukey_loss
from inspector.model import Alignment

__all__ = ["align_reference", "refine_on_points"]

_REG = o3d.pipelines.registration

#: Number of points aimed at in the coarse subsample (sets its voxel size), and
#: the fewest it may have whatever ``voxel_mm``.
_COARSE_POINTS = 400
_COARSE_MIN_POINTS = 100
#: Variance ratio above which two principal axes are treated as interchangeable (above
#: :data:`~inspector.kernels.axis.DEGENERATE` they are also sampled at intermediate angles).
_SIMILAR = 0.7
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
#: The Tukey cutoff of the fine stage of the global alignment, which starts from a
#: converged pose, shrinks by at most this factor per iteration (faster than the other
#: fits' default, :func:`~inspector.kernels.rigid.robust_fit`'s ``shrink``).
_FINE_SHRINK = 0.25
#: Local minima of the axis scan kept as fit starts (:func:`refine_on_points`).
_SCAN_STARTS = 6


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


# --------------------------------------------------------------------------- geometry helpers


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
    cell = np.floor((points - bounds_of(points)[0]) / voxel).astype(np.int64)
    dims = bounds_of(cell)[1] + 1
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    _, first = np.unique(key, return_index=True)
    return np.sort(first)


def _best_start(ref: RefMesh, points: np.ndarray, W: np.ndarray, *, floor_mm: float, start_mm: float,
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
        step = GaussNewtonStep(ref, points, W, cutoff, floor, None)
        W, cutoff = step.W, step.cutoff
        if step.settled.all() and float(step.move.max()) < 1e-3 * floor_mm:
            break
    r = ref.distance(transform(W, points))
    cost = np.sum(tukey_loss(r, judge_mm if judge_mm is not None else floor_mm), axis=1)
    if hull is not None:
        poke = poking(ref, hull[0], W, hull[1])
        cost = np.where(poke <= poke.min() + POKE_TOLERANCE, cost, np.inf)
    return W[int(np.argmin(cost))]


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
    (ratio above ``DEGENERATE``) the axes are ill-defined, so the candidates are
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
    degenerate = [(i, j) for i, j in pairs if close(i, j, DEGENERATE)]
    offsets = [np.eye(3)]
    if len(degenerate) >= 2:
        offsets += [rodrigues(np.eye(3)[a] * (np.pi / 4)) for a in range(3)]
    elif len(degenerate) == 1:
        axis = 3 - sum(degenerate[0])
        # 7.5 degree steps: from 22.5, the hull fit could stay 11 degrees off about a
        # shaft's axis (1.7 mm at its flat), too far for the BCPS re-fit.
        offsets += [rodrigues(np.eye(3)[axis] * (k * np.pi / 24)) for k in range(1, 12)]
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
    ref: RefMesh, x: np.ndarray, nx: np.ndarray, W: np.ndarray, voxel: float
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
        step = GaussNewtonStep(ref, x[::stride], W, cutoff, cutoff, nx[::stride], n_keep=n_keep, cap=cap)
        W, cutoff = step.W, cutoff[step.keep]
        if len(W) <= _KEEP_MIN and float(step.move.max()) < 1e-3 * voxel:
            break
    step = GaussNewtonStep(ref, x, W, cutoff, cutoff, nx, n_keep=len(W), cap=cap)
    return W[int(np.argmin(step.score))]


def _coarse_pose(ref: RefMesh, pts: np.ndarray, nrm: np.ndarray, voxel_mm: float, seed: int) -> tuple[np.ndarray, float]:
    """The best hypothesis of the global alignment after the coarse search: world ->
    internal transform (4, 4), and the coarse voxel, mm (see :func:`align_reference`)."""
    rng = np.random.default_rng(seed)

    # Coarse subsamples of the reconstruction and of the reference surface.
    lo, hi = np.sqrt(ref.area / _COARSE_POINTS), np.sqrt(ref.area / _COARSE_MIN_POINTS)
    voxel_c = float(np.clip(voxel_mm, lo, hi))
    pick = _voxel_pick(pts, voxel_c)
    if len(pick) < 10:
        pick = np.arange(len(pts))
    xs, ns = pts[pick], nrm[pick]
    ref_pts, ref_nrm = ref.sample(REF_SAMPLES, rng)
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
    return _coarse_search(ref, xs, ns, W, voxel_c), voxel_c


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
    pts = as_points("points", points, min_rows=10)
    nrm = as_points("normals", normals)
    if nrm.shape != pts.shape:
        raise ValueError(f"normals must have the shape of points {pts.shape}, got {nrm.shape}")
    nlen = np.linalg.norm(nrm, axis=1)
    if np.any(nlen <= 0):
        raise ValueError("normals contains zero-length vectors")
    nrm = nrm / nlen[:, None]
    verts, faces = as_mesh(ref_vertices, ref_faces)
    voxel_mm = positive("voxel_mm", voxel_mm)
    inlier_mm = positive("inlier_mm", inlier_mm)

    ref = RefMesh(verts, faces, index)
    best, voxel_c = _coarse_pose(ref, pts, nrm, voxel_mm, seed)

    # Fine fit: converge on a voxel subsample, then polish at full resolution.
    pick = _voxel_pick(pts, voxel_mm)
    floor = inlier_mm / 10.0
    cutoff = max(inlier_mm, _COARSE_CUTOFF * voxel_c)
    tol = 1e-5 * ref.diag
    fit = dict(floor_mm=floor, tol=tol, shrink=_FINE_SHRINK)
    polish = 30
    if 10 <= len(pick) <= len(pts) // 2:
        best, _, cutoff = robust_fit(ref, pts[pick], best, start_mm=cutoff, iterations=30, normals=nrm[pick], **fit)
        polish = 4
    best, dist, _ = robust_fit(ref, pts, best, start_mm=cutoff, iterations=polish, normals=nrm, **fit)
    fitness, rmse = _summary(dist, inlier_mm)
    return Alignment(pose=ref.pose_from_w(best), fitness=fitness, rmse_mm=rmse, method="global+icp")


# --------------------------------------------------------------------------- refinement


def _refit_start(ref: RefMesh, pts: np.ndarray, W0: np.ndarray, angles_deg: tuple[float, ...], axis_scan: bool,
                 wide: float, robust_mm: float, iterations: int, hull_points: np.ndarray | None,
                 hull_mm: float) -> np.ndarray:
    """Where :func:`refine_on_points` starts its fit (world -> internal, 4 x 4): ``W0``, or
    the best of it turned about the reference's axis by ``angles_deg`` and, with
    ``axis_scan``, to the scan's lowest minima, each judged at the cutoff ``wide``, mm."""
    turns = axis_turns(ref, angles_deg)
    judge = None
    if axis_scan:
        scan = scan_turns(ref, pts, W0, wide)
        near = near_axis(ref)
        if scan is not None and near is not None:
            # Starts act on the points: the reference's turn, backwards.
            extra = turns_about_axis(near[0], near[1], -scan.angles_deg[scan.minima(_SCAN_STARTS)])
            turns, judge = np.concatenate([turns, extra]), wide
    if len(turns) > 1:
        hull = None if hull_points is None else (as_points("hull_points", hull_points), positive("hull_mm", hull_mm))
        W0 = _best_start(ref, pts, turns @ W0, floor_mm=robust_mm, start_mm=wide, iterations=iterations,
                         judge_mm=judge, hull=hull)
    return W0


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
        World points expected on the reference surface (e.g. BCPS points), mm; N >= 6.
    ref_vertices, ref_faces : (V, 3) float, (F, 3) int
        Reference mesh vertices (reference frame, mm) and triangles.
    pose : (4, 4) float
        Initial reference -> world pose (a proper rigid transform), close to the
        solution (within about ``robust_mm`` and a degree).
    robust_mm : float, default 0.3
        Final Tukey cutoff, mm; also the inlier distance for ``fitness`` and
        ``rmse_mm``.
    iterations : int, default 20
        Maximum Gauss-Newton iterations (fewer on convergence); 0 only evaluates ``pose``.
    index : MeshDistance, optional
        The reference's exact distance index (e.g. ``Reference.distance``): closest points
        come from it instead of a new Open3D scene.
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
    pts = as_points("points", points, min_rows=6)
    verts, faces = as_mesh(ref_vertices, ref_faces)
    P = as_pose(pose)
    robust_mm = positive("robust_mm", robust_mm)
    start = np.inf if start_mm is None else positive("start_mm", start_mm)
    if isinstance(iterations, bool) or int(iterations) != iterations or iterations < 0:
        raise ValueError(f"iterations must be a non-negative integer, got {iterations!r}")

    ref = RefMesh(verts, faces, index)
    W0 = _refit_start(ref, pts, ref.w_from_pose(P), tuple(axis_turns_deg), axis_scan, min(start, 10.0 * robust_mm),
                      robust_mm, int(iterations), hull_points, hull_mm)
    W, dist, _ = robust_fit(
        ref, pts, W0, floor_mm=robust_mm, start_mm=start, iterations=int(iterations), tol=1e-6 * ref.diag,
    )
    fitness, rmse = _summary(dist, robust_mm)
    return Alignment(pose=ref.pose_from_w(W), fitness=fitness, rmse_mm=rmse, method="bcps-refine")


