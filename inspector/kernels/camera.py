"""Pinhole camera kernels (OpenCV model), pure and vectorised.

Conventions (CONTRACT): millimetres; ``x_cam = R @ x_world + t``; pixel ``(u, v)``
with ``(0, 0)`` the centre of the top-left pixel, ``u`` right, ``v`` down;
distortion ``[k1, k2, p1, p2, k3]``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "camera_centre",
    "distort_normalized",
    "project",
    "pixel_rays",
    "undistort_pixels",
    "is_rotation",
]


def camera_centre(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Optical centre in world coordinates, ``-R.T @ t``, shape (3,) in mm."""
    return -np.asarray(R, float).T @ np.asarray(t, float)


def is_rotation(R: np.ndarray, tol: float = 1e-6) -> bool:
    """True when ``R`` (3, 3) is a proper rotation (orthonormal, det +1) within ``tol``."""
    R = np.asarray(R, float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        return False
    return bool(np.allclose(R @ R.T, np.eye(3), atol=tol) and abs(np.linalg.det(R) - 1.0) < tol)


def distort_normalized(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply OpenCV radial/tangential distortion to normalized coordinates.

    Parameters
    ----------
    xy : (..., 2) float
        Undistorted normalized image coordinates ``(x/z, y/z)``.
    dist : (5,) float
        ``[k1, k2, p1, p2, k3]``.

    Returns
    -------
    (..., 2) float
        Distorted normalized coordinates.
    """
    k1, k2, p1, p2, k3 = (float(d) for d in dist)
    if k1 == k2 == p1 == p2 == k3 == 0.0:
        return xy
    x = xy[..., 0]
    y = xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def project(
    X: np.ndarray,
    K: np.ndarray,
    dist: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Project world points to pixels.

    Parameters
    ----------
    X : (N, 3) float
        World points, mm.
    K, dist, R, t
        Intrinsics (3, 3), distortion (5,), rotation (3, 3) and translation (3,) mm.

    Returns
    -------
    uv : (N, 2) float
        Pixel coordinates (OpenCV convention).
    z : (N,) float
        Depth in the camera frame, mm (points with ``z <= 0`` are behind the camera).
    """
    X = np.asarray(X, float)
    xc = X @ np.asarray(R, float).T + np.asarray(t, float)
    z = xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = xc[:, :2] / z[:, None]
    xy = distort_normalized(xy, dist)
    K = np.asarray(K, float)
    u = K[0, 0] * xy[:, 0] + K[0, 1] * xy[:, 1] + K[0, 2]
    v = K[1, 1] * xy[:, 1] + K[1, 2]
    return np.stack([u, v], axis=1), z


def undistort_pixels(uv: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Pixels to undistorted normalized coordinates, (N, 2) -> (N, 2).

    Uses OpenCV's iterative ``undistortPoints`` when there is distortion.
    """
    uv = np.asarray(uv, float).reshape(-1, 2)
    K = np.asarray(K, float)
    dist = np.asarray(dist, float)
    if not np.any(dist):
        x = (uv[:, 0] - K[0, 2] - K[0, 1] * (uv[:, 1] - K[1, 2]) / K[1, 1]) / K[0, 0]
        y = (uv[:, 1] - K[1, 2]) / K[1, 1]
        return np.stack([x, y], axis=1)
    import cv2

    # OpenCV's model has no skew: remove it here, so K[0, 1] means the same in both ways.
    skew = K[0, 1]
    if skew != 0.0:
        uv = np.stack([uv[:, 0] - skew * (uv[:, 1] - K[1, 2]) / K[1, 1], uv[:, 1]], axis=1)
        K = K.copy()
        K[0, 1] = 0.0
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
    pts = uv.reshape(-1, 1, 2)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
        out = cv2.undistortPointsIter(pts, K, dist, None, None, criteria)
    else:  # OpenCV 5 takes the criteria in undistortPoints
        out = cv2.undistortPoints(pts, K, dist, None, None, None, criteria)
    return out.reshape(-1, 2)


def pixel_rays(
    uv: np.ndarray,
    K: np.ndarray,
    dist: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """World rays through pixels.

    Parameters
    ----------
    uv : (N, 2) float
        Pixel coordinates (distorted image).

    Returns
    -------
    origin : (3,) float
        Optical centre, mm.
    directions : (N, 3) float
        Unit ray directions in the world frame.
    """
    xy = undistort_pixels(uv, K, dist)
    d_cam = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    d = d_cam @ np.asarray(R, float)  # R.T @ d for each row
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return camera_centre(R, t), d
