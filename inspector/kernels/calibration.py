"""Multi-camera calibration kernels: one bundle adjustment over all cameras and target poses.

Pure numerics (arrays in, arrays out), used by ``inspector calibrate``
(:mod:`inspector.calibration.solve`) and by whoever checks a calibration against the truth.

Model (CONTRACT camera, :mod:`inspector.kernels.camera`): a target corner ``X_b`` (body frame,
mm) at pose ``p`` and camera ``c``::

    X_w = R_p X_b + t_p            # pose p: target body -> world
    X_c = R_c X_w + t_c            # camera c: world -> camera
    (x, y) = X_c[:2] / X_c[2]
    (x', y') = OpenCV distortion of (x, y) with [k1, k2, p1, p2, k3]
    (u, v) = (fx x' + cx, fy y' + cy)

Parameters (:class:`BundleProblem`): per camera the 9 intrinsics :data:`INTRINSICS` then its
Rodrigues vector and translation (15 values), per pose a Rodrigues vector and translation
(6 values); any of them may be held fixed (``free`` mask): k3 (and k2) for long lenses, one
pose for the gauge (the world frame), the metric scale coming from the target's corners.
The Jacobian is analytic and sparse (each residual touches one camera's 15 and one pose's 6
values), so :func:`bundle_adjust` gives :func:`scipy.optimize.least_squares` ('trf', LSMR,
robust loss, ``x_scale='jac'``) exact derivatives instead of finite differences (the sparsity
pattern ``jac_sparsity`` would describe is the one :meth:`BundleProblem.jacobian` fills), in
variables whitened block by block (:func:`block_preconditioner`) so that LSMR's steps are good
ones despite the strong correlations within a camera (focal length and distance).

Also here: the covariance of the solution (:func:`normal_covariance`), each camera's standard
uncertainty of position and orientation in the frame of the cameras themselves
(:func:`camera_uncertainty`: the gauge freedom of the target's pose removed by an
S-transformation onto the camera centres), outlier rejection by group (:func:`reject_groups`),
the point nearest all optical axes (:func:`nearest_point_to_lines`), and the comparison of an
estimated rig with the true one after a similarity alignment (:func:`umeyama`,
:func:`compare_rigs`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from inspector.kernels import camera as camk

__all__ = [
    "INTRINSICS",
    "N_CAM",
    "N_POSE",
    "rodrigues",
    "rodrigues_jacobian",
    "rotvec",
    "BundleProblem",
    "BundleResult",
    "bundle_adjust",
    "block_preconditioner",
    "normal_covariance",
    "camera_uncertainty",
    "reject_groups",
    "group_rms",
    "nearest_point_to_lines",
    "umeyama",
    "compare_rigs",
]

#: Intrinsic parameters of a camera, in the order of a camera's block of parameters.
INTRINSICS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
#: Parameters per camera (intrinsics, Rodrigues vector, translation mm) and per target pose.
N_CAM, N_POSE = len(INTRINSICS) + 6, 6


class CameraLike(Protocol):
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray


# --------------------------------------------------------------------------- rotations


def _skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    v = np.asarray(v, float)
    z = np.zeros(v.shape[:-1])
    return np.stack([
        np.stack([z, -v[..., 2], v[..., 1]], -1),
        np.stack([v[..., 2], z, -v[..., 0]], -1),
        np.stack([-v[..., 1], v[..., 0], z], -1),
    ], -2)


def rodrigues(r: np.ndarray) -> np.ndarray:
    """Rotation matrices of Rodrigues vectors: (..., 3) -> (..., 3, 3)."""
    r = np.asarray(r, float)
    th = np.linalg.norm(r, axis=-1)[..., None, None]
    K = _skew(r)
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0, np.sin(ths) / ths)
    b = np.where(small, 0.5, (1.0 - np.cos(ths)) / (ths * ths))
    return np.eye(3) + a * K + b * (K @ K)


def rodrigues_jacobian(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotations and their derivatives: ``R`` (..., 3, 3) and ``dR`` (..., 3, 3, 3) with
    ``dR[..., k, :, :] = dR / dr_k`` (Gallego & Yezzi's formula, ``[e_k]x`` at ``r = 0``)."""
    r = np.asarray(r, float)
    R = rodrigues(r)
    th2 = np.sum(r * r, axis=-1)
    eye = np.eye(3)
    out = np.empty(r.shape[:-1] + (3, 3, 3))
    small = th2 < 1e-16
    IR = eye - R
    for k in range(3):
        ek = eye[k]
        # r x ((I - R) e_k)
        v = np.cross(r, IR[..., :, k])
        num = r[..., k, None, None] * _skew(r) + _skew(v)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = (num / np.where(small, 1.0, th2)[..., None, None]) @ R
        out[..., k, :, :] = np.where(small[..., None, None], _skew(ek), d)
    return R, out


def rotvec(R: np.ndarray) -> np.ndarray:
    """Rodrigues vector of a rotation matrix (3, 3) -> (3,)."""
    from scipy.spatial.transform import Rotation

    return np.asarray(Rotation.from_matrix(np.asarray(R, float)).as_rotvec(), float)


# --------------------------------------------------------------------------- the problem


@dataclass
class BundleProblem:
    """Observations of target corners and the parameters that explain them.

    Attributes
    ----------
    object_points : (P, 3) float
        The target's corners in its body frame, mm.
    cam, pose, point : (N,) int
        Camera, target pose and corner (row of ``object_points``) of each observation.
    uv : (N, 2) float
        Observed pixel positions.
    n_cams, n_poses : int
    params : (n_cams * 15 + n_poses * 6,) float
        Every parameter (fixed ones too): camera blocks first, then pose blocks.
    free : (same,) bool
        Which parameters are adjusted.
    weight : (N,) float
        Weight of each observation (its residuals are multiplied by ``sqrt(weight)``).
    """

    object_points: np.ndarray
    cam: np.ndarray
    pose: np.ndarray
    point: np.ndarray
    uv: np.ndarray
    n_cams: int
    n_poses: int
    params: np.ndarray
    free: np.ndarray
    weight: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        self.object_points = np.asarray(self.object_points, float).reshape(-1, 3)
        self.cam = np.asarray(self.cam, np.int64).ravel()
        self.pose = np.asarray(self.pose, np.int64).ravel()
        self.point = np.asarray(self.point, np.int64).ravel()
        self.uv = np.asarray(self.uv, float).reshape(-1, 2)
        self.params = np.asarray(self.params, float).copy()
        self.free = np.asarray(self.free, bool).copy()
        n = self.n_cams * N_CAM + self.n_poses * N_POSE
        if self.params.shape != (n,) or self.free.shape != (n,):
            raise ValueError(f"params and free must have {n} values")
        if not (len(self.cam) == len(self.pose) == len(self.point) == len(self.uv)):
            raise ValueError("cam, pose, point and uv must have one row per observation")
        if self.weight.size == 0:
            self.weight = np.ones(len(self.cam))
        self.weight = np.asarray(self.weight, float).ravel()
        self._structure: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    # -- layout -------------------------------------------------------------------------------
    @staticmethod
    def pack(intrinsics: np.ndarray, cam_rvec: np.ndarray, cam_t: np.ndarray,
             pose_rvec: np.ndarray, pose_t: np.ndarray) -> np.ndarray:
        """The parameter vector of (C, 9) intrinsics, (C, 3) + (C, 3) camera extrinsics and
        (Q, 3) + (Q, 3) pose parameters."""
        cams = np.concatenate([np.asarray(intrinsics, float).reshape(-1, 9), np.asarray(cam_rvec, float).reshape(-1, 3),
                               np.asarray(cam_t, float).reshape(-1, 3)], axis=1)
        poses = np.concatenate([np.asarray(pose_rvec, float).reshape(-1, 3), np.asarray(pose_t, float).reshape(-1, 3)], axis=1)
        return np.concatenate([cams.ravel(), poses.ravel()])

    def cam_block(self, params: np.ndarray | None = None) -> np.ndarray:
        """(C, 15) camera parameters."""
        p = self.params if params is None else params
        return p[: self.n_cams * N_CAM].reshape(self.n_cams, N_CAM)

    def pose_block(self, params: np.ndarray | None = None) -> np.ndarray:
        """(Q, 6) pose parameters."""
        p = self.params if params is None else params
        return p[self.n_cams * N_CAM:].reshape(self.n_poses, N_POSE)

    def cam_index(self, c: int, name: str) -> int:
        """Index in ``params`` of camera ``c``'s parameter ``name`` (an intrinsic, ``r0..2``, ``t0..2``)."""
        names = list(INTRINSICS) + ["r0", "r1", "r2", "t0", "t1", "t2"]
        return c * N_CAM + names.index(name)

    def pose_index(self, p: int) -> int:
        """Index in ``params`` of pose ``p``'s first parameter."""
        return self.n_cams * N_CAM + p * N_POSE

    def full(self, x: np.ndarray) -> np.ndarray:
        """All parameters with the free ones set to ``x``."""
        p = self.params.copy()
        p[self.free] = x
        return p

    @property
    def x0(self) -> np.ndarray:
        return self.params[self.free].copy()

    # -- model --------------------------------------------------------------------------------
    def _evaluate(self, params: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        cb, pb = self.cam_block(params), self.pose_block(params)
        c, p = self.cam, self.pose
        Xb = self.object_points[self.point]
        if jac:
            Rc_all, dRc_all = rodrigues_jacobian(cb[:, 9:12])
            Rp_all, dRp_all = rodrigues_jacobian(pb[:, :3])
        else:
            Rc_all, Rp_all = rodrigues(cb[:, 9:12]), rodrigues(pb[:, :3])
        Rp, Rc = Rp_all[p], Rc_all[c]
        Xw = np.einsum("nij,nj->ni", Rp, Xb) + pb[p, 3:]
        Xc = np.einsum("nij,nj->ni", Rc, Xw) + cb[c, 12:]
        z = Xc[:, 2]
        iz = 1.0 / z
        x, y = Xc[:, 0] * iz, Xc[:, 1] * iz
        fx, fy, cx, cy, k1, k2, p1, p2, k3 = (cb[c, i] for i in range(9))
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        u = fx * xd + cx
        v = fy * yd + cy
        sw = np.sqrt(self.weight)
        res = np.stack([(u - self.uv[:, 0]) * sw, (v - self.uv[:, 1]) * sw], axis=1).ravel()
        if not jac:
            return res, None
        n = len(c)
        Jc = np.zeros((n, 2, N_CAM))
        Jp = np.zeros((n, 2, N_POSE))
        # intrinsics
        Jc[:, 0, 0] = xd
        Jc[:, 1, 1] = yd
        Jc[:, 0, 2] = 1.0
        Jc[:, 1, 3] = 1.0
        r4 = r2 * r2
        for col, g in ((4, r2), (5, r4), (8, r4 * r2)):
            Jc[:, 0, col] = fx * x * g
            Jc[:, 1, col] = fy * y * g
        Jc[:, 0, 6] = fx * 2.0 * x * y
        Jc[:, 1, 6] = fy * (r2 + 2.0 * y * y)
        Jc[:, 0, 7] = fx * (r2 + 2.0 * x * x)
        Jc[:, 1, 7] = fy * 2.0 * x * y
        # distortion Jacobian d(xd, yd)/d(x, y)
        dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
        dxd_dx = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
        dxd_dy = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
        dyd_dx = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
        dyd_dy = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
        # d(u, v)/d(x, y) then d(x, y)/d Xc
        A = np.empty((n, 2, 2))
        A[:, 0, 0], A[:, 0, 1] = fx * dxd_dx, fx * dxd_dy
        A[:, 1, 0], A[:, 1, 1] = fy * dyd_dx, fy * dyd_dy
        B = np.zeros((n, 2, 3))
        B[:, 0, 0] = iz
        B[:, 1, 1] = iz
        B[:, 0, 2] = -x * iz
        B[:, 1, 2] = -y * iz
        D = A @ B  # d(u, v) / d Xc, (n, 2, 3)
        # camera extrinsics
        dXc_drc = np.einsum("nkij,nj->nik", dRc_all[c], Xw)  # (n, 3, 3): column k = dRc_k Xw
        Jc[:, :, 9:12] = D @ dXc_drc
        Jc[:, :, 12:15] = D
        # pose
        DR = D @ Rc
        dXw_drp = np.einsum("nkij,nj->nik", dRp_all[p], Xb)
        Jp[:, :, 0:3] = DR @ dXw_drp
        Jp[:, :, 3:6] = DR
        Jc *= sw[:, None, None]
        Jp *= sw[:, None, None]
        return res, np.concatenate([Jc, Jp], axis=2)  # (n, 2, 21)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """(2N,) weighted residuals (projected - observed, px) at free parameters ``x``."""
        return self._evaluate(self.full(x), jac=False)[0]

    def _build_structure(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Column of every one of the (2N, 21) dense entries, which of them are kept, indptr."""
        col_of = np.full(self.params.size, -1, np.int64)
        col_of[self.free] = np.arange(int(self.free.sum()))
        n = len(self.cam)
        cols = np.empty((n, 21), np.int64)
        cols[:, :N_CAM] = self.cam[:, None] * N_CAM + np.arange(N_CAM)
        cols[:, N_CAM:] = self.n_cams * N_CAM + self.pose[:, None] * N_POSE + np.arange(N_POSE)
        cols = col_of[cols]
        cols2 = np.repeat(cols[:, None, :], 2, axis=1).reshape(2 * n, 21)
        keep = cols2 >= 0
        indptr = np.concatenate([[0], np.cumsum(keep.sum(axis=1))])
        return cols2[keep], keep, indptr

    def jacobian(self, x: np.ndarray) -> Any:
        """Sparse (2N, n_free) CSR Jacobian of :meth:`residuals` at ``x`` (analytic)."""
        from scipy.sparse import csr_matrix

        if self._structure is None:
            self._structure = self._build_structure()
        indices, keep, indptr = self._structure
        _, J = self._evaluate(self.full(x), jac=True)
        assert J is not None
        data = J.reshape(-1, 21)[keep]
        return csr_matrix((data, indices, indptr), shape=(2 * len(self.cam), int(self.free.sum())))

    def subset(self, keep: np.ndarray) -> BundleProblem:
        """The same problem with only the observations ``keep`` (bool or indices)."""
        return BundleProblem(self.object_points, self.cam[keep], self.pose[keep], self.point[keep], self.uv[keep],
                             self.n_cams, self.n_poses, self.params, self.free, self.weight[keep])

    def project(self, params: np.ndarray | None = None) -> np.ndarray:
        """(N, 2) projected pixels of every observation (unweighted)."""
        p = self.params if params is None else params
        w, self.weight = self.weight, np.ones(len(self.cam))
        try:
            r = self._evaluate(p, jac=False)[0].reshape(-1, 2)
        finally:
            self.weight = w
        return r + self.uv


# --------------------------------------------------------------------------- solving


@dataclass
class BundleResult:
    """What :func:`bundle_adjust` found.

    Attributes
    ----------
    params : (n,) float
        Every parameter at the solution (fixed ones unchanged).
    residuals : (N, 2) float
        Projected minus observed pixel, unweighted.
    rms_px : float
        RMS of the residual vectors' length.
    nfev, njev : int
    status : int
        :func:`scipy.optimize.least_squares`'s status (> 0: converged).
    message : str
    """

    params: np.ndarray
    residuals: np.ndarray
    rms_px: float
    nfev: int
    njev: int
    status: int
    message: str


def block_preconditioner(problem: BundleProblem, x: np.ndarray) -> Any:
    """Sparse block-diagonal ``P`` (n_free x n_free) whitening each camera's and each pose's
    free parameters at ``x``: ``(J_b P_b)^T (J_b P_b) = I`` for each block ``b``.

    The change of variables ``x = x0 + P y`` leaves the problem the same but makes its
    Jacobian's blocks orthonormal: the correlations within a camera (focal length and
    distance, principal point and rotation, k1 and the focal length) no longer slow LSMR.
    """
    from scipy.sparse import block_diag

    J = problem.jacobian(x).tocsc()
    col = np.cumsum(problem.free) - 1
    blocks: list[np.ndarray] = []
    for c in range(problem.n_cams):
        sl = slice(c * N_CAM, (c + 1) * N_CAM)
        if problem.free[sl].any():
            blocks.append(col[sl][problem.free[sl]])
    for q in range(problem.n_poses):
        sl = slice(problem.pose_index(q), problem.pose_index(q) + N_POSE)
        if problem.free[sl].any():
            blocks.append(col[sl][problem.free[sl]])
    mats = []
    for idx in blocks:
        Jb = J[:, idx].toarray()
        A = Jb.T @ Jb
        A += np.eye(len(idx)) * max(1e-12 * float(np.trace(A)) / len(idx), 1e-12)
        L = np.linalg.cholesky(A)
        mats.append(np.linalg.inv(L.T))
    return block_diag(mats, format="csr")


def bundle_adjust(problem: BundleProblem, *, loss: str = "soft_l1", f_scale: float = 0.3, max_nfev: int = 200,
                  ftol: float = 1e-8, xtol: float = 1e-10, gtol: float = 1e-10, precondition: bool = True) -> BundleResult:
    """Minimise the robust reprojection error over the free parameters.

    ``scipy.optimize.least_squares(method='trf', tr_solver='lsmr', x_scale='jac')`` with the
    analytic sparse Jacobian of :meth:`BundleProblem.jacobian` and ``loss`` at ``f_scale`` px
    (residuals beyond it weigh less). Returns the solution; ``problem.params`` is not changed.

    With ``precondition`` (default) the problem is solved in the variables ``y`` of
    :func:`block_preconditioner` (``x = x0 + P y``): measured on 16 cameras x 30 cube poses
    (398 parameters, 28k residuals), 20 evaluations and 2.8 s to the minimum, where the plain
    problem took 200 evaluations (41 s) and stopped short of it (its inexact LSMR steps crawl
    along the focal length / distance valley).
    """
    from scipy.optimize import least_squares

    x0 = problem.x0
    if precondition and x0.size:
        P = block_preconditioner(problem, x0)

        def fun(y: np.ndarray) -> np.ndarray:
            return problem.residuals(x0 + P @ y)

        def jac(y: np.ndarray) -> Any:
            return (problem.jacobian(x0 + P @ y) @ P).tocsr()

        sol = least_squares(fun, np.zeros(x0.size), jac=jac, method="trf", tr_solver="lsmr", x_scale="jac", loss=loss,
                            f_scale=f_scale, max_nfev=max_nfev, ftol=ftol, xtol=xtol, gtol=gtol)
        x = x0 + P @ sol.x
    else:
        sol = least_squares(problem.residuals, x0, jac=problem.jacobian, method="trf", tr_solver="lsmr", x_scale="jac",
                            loss=loss, f_scale=f_scale, max_nfev=max_nfev, ftol=ftol, xtol=xtol, gtol=gtol)
        x = sol.x
    params = problem.full(x)
    uvp = problem.project(params)
    res = uvp - problem.uv
    rms = float(np.sqrt(np.mean(np.sum(res * res, axis=1)))) if len(res) else 0.0
    return BundleResult(params, res, rms, int(sol.nfev), int(sol.njev or 0), int(sol.status), str(sol.message))


def normal_covariance(J: Any, residuals: np.ndarray, n_params: int | None = None) -> tuple[np.ndarray, float]:
    """Covariance ``(J^T J)^-1 sigma^2`` of least-squares parameters and ``sigma`` (px).

    ``J`` is the (M, n) Jacobian (sparse or dense) at the solution, ``residuals`` the (M,)
    residuals; ``sigma^2 = |r|^2 / (M - n)``. The normal matrix is inverted densely (a few
    hundred parameters: milliseconds); a singular one is pseudo-inverted.
    """
    import scipy.linalg as sla

    JtJ = J.T @ J
    JtJ = JtJ.toarray() if hasattr(JtJ, "toarray") else np.asarray(JtJ)
    n = JtJ.shape[0] if n_params is None else n_params
    r = np.asarray(residuals, float).ravel()
    dof = max(r.size - n, 1)
    sigma2 = float(r @ r) / dof
    # scale columns to unit diagonal: the inverse is then well conditioned numerically
    d = np.sqrt(np.maximum(np.diag(JtJ), 1e-300))
    S = JtJ / d[:, None] / d[None, :]
    try:
        inv = sla.cho_solve(sla.cho_factor(S), np.eye(len(S)))
    except np.linalg.LinAlgError:
        inv = np.linalg.pinv(S)
    return inv / d[:, None] / d[None, :] * sigma2, float(np.sqrt(sigma2))


def camera_uncertainty(rvecs: np.ndarray, ts: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each camera's standard uncertainty of position (mm) and orientation (degrees).

    Parameters
    ----------
    rvecs, ts : (C, 3) float
        Each camera's world -> camera Rodrigues vector and translation, mm.
    cov : (6C, 6C) float
        Covariance of ``[r_0, t_0, r_1, t_1, ...]`` (any gauge: e.g. one target pose fixed).

    Returns
    -------
    centre_mm : (C,) float
        ``sqrt(trace)`` of the covariance of each optical centre (3D, 1 sigma), mm.
    angle_deg : (C,) float
        ``sqrt(trace)`` of the covariance of each camera's small rotation, degrees.
    cov_y : (6C, 6C) float
        Covariance of ``[centre_0, angle_0, ...]`` (mm, radians) in the cameras' own datum.

    The datum is that of the cameras themselves: the covariance is S-transformed so that
    the mean (least-squares) rigid motion of the camera centres is zero, each centre weighing
    ``1 / max(1, variance / median variance)`` (a camera seen too little does not define the
    others' datum). What stays is how well each camera is placed relative to the others, not
    how well the target's pose that fixed the frame was known.

    In a long lens the orientation trades off with the principal point (10 px of principal
    point is 0.14 degrees at f = 4000 px), so ``angle_deg`` is mostly that of ``cx, cy``: it
    does not move the projection of the working volume by as much.
    """
    rvecs = np.asarray(rvecs, float).reshape(-1, 3)
    ts = np.asarray(ts, float).reshape(-1, 3)
    C = len(rvecs)
    R, dR = rodrigues_jacobian(rvecs)
    D = np.zeros((6 * C, 6 * C))
    G = np.zeros((6 * C, 6))
    centres = -np.einsum("nji,nj->ni", R, ts)
    for c in range(C):
        o = 6 * c
        # centre = -R^T t
        for k in range(3):
            D[o:o + 3, o + k] = -dR[c, k].T @ ts[c]
        D[o:o + 3, o + 3:o + 6] = -R[c].T
        # world-frame small rotation psi: R(r + dr) = R exp([psi]x), [psi]x = R^T dR
        for k in range(3):
            W = R[c].T @ dR[c, k]
            D[o + 3:o + 6, o + k] = [W[2, 1], W[0, 2], W[1, 0]]
        # a rigid motion of the world (omega, tau): centre -> centre + omega x centre + tau;
        # R -> R exp(-[omega]x): psi -> psi - omega
        G[o:o + 3, 0:3] = -_skew(centres[c])
        G[o:o + 3, 3:6] = np.eye(3)
        G[o + 3:o + 6, 0:3] = -np.eye(3)
    cov_y = D @ np.asarray(cov, float) @ D.T
    # each camera's centre weighs the inverse of its variance (in the given gauge): a camera
    # seen too little, its place hardly known, does not drag the others' datum with it
    var = np.array([np.trace(cov_y[6 * c:6 * c + 3, 6 * c:6 * c + 3]) for c in range(C)])
    ref = float(np.median(var[np.isfinite(var)])) if np.any(np.isfinite(var)) else 1.0
    Wd = np.zeros(6 * C)
    for c in range(C):
        v = var[c] if np.isfinite(var[c]) else np.inf
        Wd[6 * c:6 * c + 3] = 1.0 / max(v / max(ref, 1e-300), 1.0)
    GW = G.T * Wd
    P = np.eye(6 * C) - G @ np.linalg.solve(GW @ G, GW)
    cov_y = P @ cov_y @ P.T
    diag = np.diag(cov_y).reshape(C, 6)
    centre = np.sqrt(np.maximum(diag[:, :3].sum(axis=1), 0.0))
    angle = np.degrees(np.sqrt(np.maximum(diag[:, 3:].sum(axis=1), 0.0)))
    return centre, angle, cov_y


# --------------------------------------------------------------------------- outliers


def group_rms(residuals: np.ndarray, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RMS residual length per group: ``(group ids, rms px, observations)``."""
    res = np.asarray(residuals, float).reshape(-1, 2)
    g = np.asarray(groups).ravel()
    ids, inv, counts = np.unique(g, return_inverse=True, return_counts=True)
    ss = np.bincount(inv, weights=np.sum(res * res, axis=1), minlength=len(ids))
    return ids, np.sqrt(ss / np.maximum(counts, 1)), counts


def reject_groups(residuals: np.ndarray, groups: np.ndarray, factor: float = 3.0,
                  floor_px: float = 0.0) -> tuple[np.ndarray, float]:
    """Groups of observations (a board in a view) whose residual RMS is far above the rest.

    A group is rejected when its RMS exceeds ``max(factor * median, floor_px)``, the median
    taken over the groups. Returns ``(rejected group ids, threshold px)``.
    """
    ids, rms, _ = group_rms(residuals, groups)
    if not len(ids):
        return ids, 0.0
    thr = max(factor * float(np.median(rms)), float(floor_px))
    return ids[rms > thr], thr


# --------------------------------------------------------------------------- frames


def nearest_point_to_lines(origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """The point nearest (least squares) to lines through ``origins`` along ``directions``, (3,)."""
    o = np.asarray(origins, float).reshape(-1, 3)
    d = np.asarray(directions, float).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = P.sum(axis=0)
    b = np.einsum("nij,nj->i", P, o)
    return np.asarray(np.linalg.lstsq(A, b, rcond=None)[0], float)


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """The similarity ``dst ~ s R src + t`` of least squares (Umeyama 1991): ``(s, R, t)``."""
    X = np.asarray(src, float).reshape(-1, 3)
    Y = np.asarray(dst, float).reshape(-1, 3)
    mx, my = X.mean(axis=0), Y.mean(axis=0)
    Xc, Yc = X - mx, Y - my
    Sxy = Yc.T @ Xc / len(X)
    U, S, Vt = np.linalg.svd(Sxy)
    E = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        E[2, 2] = -1.0
    R = U @ E @ Vt
    s = float(np.trace(np.diag(S) @ E) / (np.sum(Xc * Xc) / len(X))) if with_scale else 1.0
    t = my - s * R @ mx
    return s, R, t


def _project_cam(cam: CameraLike, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return camk.project(X, np.asarray(cam.K, float), np.asarray(cam.dist, float), np.asarray(cam.R, float),
                        np.asarray(cam.t, float))


def compare_rigs(est: Sequence[CameraLike], true: Sequence[CameraLike], *, centre: np.ndarray | None = None,
                 radius_mm: float = 30.0, n_points: int = 4000, seed: int = 0,
                 align: str = "reprojection") -> dict[str, Any]:
    """How far an estimated rig projects from the true one, after a similarity alignment.

    Parameters
    ----------
    est, true : sequences of cameras (``K``, ``dist``, ``R``, ``t``), in the same order
    centre : (3,) float, optional
        Centre of the working volume in the true frame (default: the point nearest the true
        cameras' optical axes).
    radius_mm : float
        Radius of the working volume (a ball); ``n_points`` points uniform in it (``seed``).
    align : ``"centres"`` or ``"reprojection"``
        The 7-dof similarity (estimated frame -> true frame): Umeyama on the camera centres;
        or that, refined to minimise the reprojection differences of the working volume's
        points over all cameras (what silhouettes see: the rig up to a similarity).

    Returns
    -------
    dict
        ``scale`` (the similarity's, 1 + scale error), ``rms_px`` / ``max_px`` (C,) per camera
        and ``rms_px_all``, ``f_err`` (C, 2) relative errors of fx and fy, ``pp_err_px`` (C, 2),
        ``centre_err_mm`` (C,) after the alignment, ``angle_err_deg`` (C,), ``dist_err`` (C, 5),
        ``similarity`` ``(s, R, t)``.
    """
    from scipy.optimize import least_squares

    if len(est) != len(true) or not len(est):
        raise ValueError("est and true must list the same cameras")
    ce = np.array([camk.camera_centre(np.asarray(c.R, float), np.asarray(c.t, float)) for c in est])
    ct = np.array([camk.camera_centre(np.asarray(c.R, float), np.asarray(c.t, float)) for c in true])
    s, Rs, ts = umeyama(ce, ct)
    if centre is None:
        dirs = np.array([np.asarray(c.R, float)[2] for c in true])
        centre = nearest_point_to_lines(ct, dirs)
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_points, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    X = np.asarray(centre, float) + d * radius_mm * rng.uniform(size=(n_points, 1)) ** (1.0 / 3.0)
    uv_true = [_project_cam(c, X)[0] for c in true]

    def diffs(s_: float, R_: np.ndarray, t_: np.ndarray) -> list[np.ndarray]:
        Xe = (X - t_) @ R_ / s_  # true frame -> estimated frame
        return [_project_cam(c, Xe)[0] - u for c, u in zip(est, uv_true)]

    if align == "reprojection":
        def fun(q: np.ndarray) -> np.ndarray:
            R_ = rodrigues(q[:3]) @ Rs
            return np.concatenate([e.ravel() for e in diffs(s * np.exp(q[6]), R_, ts + q[3:6])])

        q = least_squares(fun, np.zeros(7), method="lm", x_scale=np.array([1e-3] * 3 + [1e-2] * 3 + [1e-4])).x
        Rs, ts, s = rodrigues(q[:3]) @ Rs, ts + q[3:6], s * float(np.exp(q[6]))
    elif align != "centres":
        raise ValueError(f"align must be 'centres' or 'reprojection', not {align!r}")
    err = diffs(s, Rs, ts)
    rms = np.array([float(np.sqrt(np.mean(np.sum(e * e, axis=1)))) for e in err])
    mx = np.array([float(np.max(np.linalg.norm(e, axis=1))) for e in err])
    Ke = np.array([np.asarray(c.K, float) for c in est])
    Kt = np.array([np.asarray(c.K, float) for c in true])
    f_err = np.stack([Ke[:, 0, 0] / Kt[:, 0, 0] - 1.0, Ke[:, 1, 1] / Kt[:, 1, 1] - 1.0], axis=1)
    pp = np.stack([Ke[:, 0, 2] - Kt[:, 0, 2], Ke[:, 1, 2] - Kt[:, 1, 2]], axis=1)
    ce_t = s * ce @ Rs.T + ts
    ang = []
    for c_e, c_t in zip(est, true):
        Rrel = np.asarray(c_e.R, float) @ Rs.T @ np.asarray(c_t.R, float).T
        ang.append(float(np.degrees(np.arccos(np.clip((np.trace(Rrel) - 1.0) / 2.0, -1.0, 1.0)))))
    return {
        "scale": float(s),
        "rms_px": rms,
        "max_px": mx,
        "rms_px_all": float(np.sqrt(np.mean(rms ** 2))),
        "f_err": f_err,
        "pp_err_px": pp,
        "centre_err_mm": np.linalg.norm(ce_t - ct, axis=1),
        "angle_err_deg": np.array(ang),
        "dist_err": np.array([np.asarray(a.dist, float) - np.asarray(b.dist, float) for a, b in zip(est, true)]),
        "similarity": (float(s), Rs, ts),
    }
