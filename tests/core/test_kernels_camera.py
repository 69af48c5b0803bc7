"""Camera kernels and the reference's signed distances, against analytic cases."""

from __future__ import annotations

import numpy as np
import pytest

from inspector.kernels import camera as ck
from inspector.model import Camera
from inspector.reference import Reference


def _camera(dist=(0, 0, 0, 0, 0), skew=0.5):
    from scipy.spatial.transform import Rotation

    R = Rotation.from_euler("xyz", [20, -35, 10], degrees=True).as_matrix()
    t = np.array([3.0, -2.0, 400.0])
    K = np.array([[4000.0, skew, 511.5], [0, 3990.0, 509.0], [0, 0, 1]])
    return Camera("c", 1024, 1024, K, dist, R, t)


@pytest.mark.parametrize("dist", [(0, 0, 0, 0, 0), (-0.2, 0.05, 0.001, -0.002, 0.01)])
def test_projection_round_trip(dist):
    cam = _camera(dist)
    rng = np.random.default_rng(0)
    X = rng.uniform(-20, 20, size=(500, 3))
    uv, z = cam.project(X)
    o, d = cam.rays(uv)
    # each world point lies on the ray back-projected from its pixel
    v = X - o
    along = np.einsum("ij,ij->i", v, d)
    off = np.linalg.norm(v - along[:, None] * d, axis=1)
    assert np.all(z > 0) and off.max() < 1e-6
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)


def test_pixel_convention_and_centre():
    cam = _camera()
    assert np.allclose(cam.centre, -cam.R.T @ cam.t)
    # a point on the optical axis projects to the principal point (pixel centres at integers)
    uv, _ = cam.project(cam.centre[None] + 100.0 * cam.R[2][None])
    assert np.allclose(uv, [[511.5, 509.0]])


def test_distortion_matches_opencv():
    import cv2

    cam = _camera((-0.2, 0.05, 0.001, -0.002, 0.01), skew=0.0)  # OpenCV has no skew
    rng = np.random.default_rng(1)
    X = rng.uniform(-20, 20, size=(50, 3))
    ours, _ = cam.project(X)
    rvec, _ = cv2.Rodrigues(cam.R)
    theirs, _ = cv2.projectPoints(X, rvec, cam.t, cam.K, cam.dist)
    assert np.allclose(ours, theirs.reshape(-1, 2), atol=1e-6)


def test_short_dist_is_zero_padded():
    cam = Camera("c", 10, 10, np.eye(3), [0.1, 0.01], np.eye(3), [0, 0, 1])
    assert list(cam.dist) == [0.1, 0.01, 0.0, 0.0, 0.0]


def test_is_rotation():
    assert ck.is_rotation(np.eye(3))
    assert not ck.is_rotation(np.diag([1.0, 1.0, -1.0]))
    assert not ck.is_rotation(np.full((3, 3), np.nan))


def test_signed_distance_to_a_posed_cube():
    from scipy.spatial.transform import Rotation

    ref = Reference.load("builtin:cube30")
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("zyx", [30, 20, 10], degrees=True).as_matrix()
    pose[:3, 3] = [4.0, -3.0, 2.0]
    local = np.array([[0, 0, 0], [14.0, 0, 0], [16.0, 0, 0], [0, 0, 25.0], [16.0, 16.0, 0]])
    world = local @ pose[:3, :3].T + pose[:3, 3]
    sd = ref.signed_distance(world, pose)
    assert np.allclose(sd, [-15.0, -1.0, 1.0, 10.0, np.sqrt(2.0)], atol=1e-5)
    assert np.allclose(ref.to_reference_frame(world, pose), local, atol=1e-9)
