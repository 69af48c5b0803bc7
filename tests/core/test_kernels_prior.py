"""The size prior: fit of scale, offset and shift, and its signed distance (kernels.prior)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from inspector.kernels.meshdist import MeshDistance
from inspector.kernels.prior import SizePrior, fit_size_prior


def _housing_like() -> trimesh.Trimesh:
    """A box 26 x 20 x 14 with a through bore: faces at different distances from the
    centre (so a scale is not a uniform offset) and a concave surface."""
    box = trimesh.creation.box(extents=(26.0, 20.0, 14.0))
    bore = trimesh.creation.cylinder(radius=3.0, height=20.0, sections=48)
    mesh = box.difference(bore)
    mesh.apply_translation((1.5, -2.0, 4.0))  # the scale centre is the box's centre, not the origin
    return mesh


@pytest.fixture(scope="module")
def part():
    mesh = _housing_like()
    return mesh, MeshDistance(mesh.vertices, mesh.faces), mesh.bounds.mean(axis=0)


def _samples(mesh: trimesh.Trimesh, n: int, seed: int) -> np.ndarray:
    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.asarray(pts)


def _sized(mesh: trimesh.Trimesh, centre: np.ndarray, scale: float, shift=(0.0, 0.0, 0.0),
           rotation=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    from scipy.spatial.transform import Rotation

    m = mesh.copy()
    m.apply_translation(-centre)
    m.apply_scale(scale)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotation).as_matrix()
    m.apply_transform(T)
    m.apply_translation(centre + np.asarray(shift))
    return m


def test_placement_gives_the_distance_to_the_sized_mesh(part):
    mesh, index, c0 = part
    prior = SizePrior(scale=0.97, shift_mm=(0.2, -0.1, 0.05), rotation=(0.004, -0.01, 0.007), centre=tuple(c0))
    pose = np.eye(4)
    pose[:3, :3] = trimesh.transformations.rotation_matrix(0.7, [1, 2, 3])[:3, :3]
    pose[:3, 3] = [5.0, -3.0, 40.0]
    truth = _sized(mesh, c0, 0.97, prior.shift_mm, prior.rotation)
    truth.apply_transform(pose)
    want = MeshDistance(truth.vertices, truth.faces)
    rng = np.random.default_rng(0)
    X = _samples(truth, 500, 1) + rng.normal(scale=0.3, size=(500, 3))
    A = prior.placement(pose)
    inv = np.linalg.inv(A)
    got = prior.scale * index(X @ inv[:3, :3].T + inv[:3, 3])
    np.testing.assert_allclose(got, want(X), atol=1e-9)


@pytest.mark.parametrize("scale", [0.98, 1.015])
def test_a_scaled_part_is_recovered(part, scale):
    mesh, index, c0 = part
    P = _samples(_sized(mesh, c0, scale), 4000, 2)
    prior = fit_size_prior(P, index, centre=c0, robust_mm=0.05)
    assert prior.scale == pytest.approx(scale, abs=2e-4)
    assert np.abs(prior.shift_mm).max() < 5e-3
    assert prior.inliers > 0.99


def test_a_scaled_and_turned_part_is_recovered_with_its_pose_correction(part):
    mesh, index, c0 = part
    rot = np.radians([0.3, -0.5, 0.6])
    P = _samples(_sized(mesh, c0, 0.98, (0.05, -0.03, 0.02), rot), 4000, 9)
    prior = fit_size_prior(P, index, centre=c0, robust_mm=0.05)
    assert prior.scale == pytest.approx(0.98, abs=2e-4)
    np.testing.assert_allclose(prior.rotation, rot, atol=2e-4)
    np.testing.assert_allclose(prior.shift_mm, (0.05, -0.03, 0.02), atol=5e-3)
    # rigid(): the nominal reference placed on the part, centred on it.
    want = _sized(mesh, c0, 1.0, (0.05, -0.03, 0.02), rot)
    got = mesh.copy()
    got.apply_transform(prior.rigid(np.eye(4)))
    np.testing.assert_allclose(got.vertices, want.vertices, atol=5e-3)


def test_local_defects_and_outliers_do_not_move_the_fit(part):
    mesh, index, c0 = part
    P = _samples(_sized(mesh, c0, 0.98), 4000, 3)
    rng = np.random.default_rng(4)
    # 8 % of the points pushed 0.3-1.5 mm outwards in one corner (a bulge or a bump).
    corner = np.argsort(np.linalg.norm(P - (c0 + [13.0, 10.0, 7.0]), axis=1))[:320]
    P[corner] += rng.uniform(0.3, 1.5, size=(320, 1)) * np.array([[0.577, 0.577, 0.577]])
    prior = fit_size_prior(P, index, centre=c0, robust_mm=0.05)
    assert prior.scale == pytest.approx(0.98, abs=5e-4)


def test_a_nominal_part_keeps_the_nominal_prior(part):
    mesh, index, c0 = part
    rng = np.random.default_rng(5)
    P = _samples(mesh, 4000, 6)
    P += rng.normal(scale=0.005, size=P.shape)
    assert fit_size_prior(P, index, centre=c0, robust_mm=0.05).is_identity


def test_a_uniform_offset_is_not_mistaken_for_a_scale(part):
    mesh, index, c0 = part
    P = _samples(mesh, 4000, 7)
    _, tid = index.closest(P)
    P = P - 0.08 * index.pn[tid, 0]  # 0.08 mm of material missing everywhere
    prior = fit_size_prior(P, index, centre=c0, robust_mm=0.05)
    # The rule is exact for a uniform offset: no scale may be made up to mimic it.
    assert prior.is_identity


def test_too_few_or_unusable_points_give_the_identity(part):
    mesh, index, c0 = part
    assert fit_size_prior(np.zeros((5, 3)), index, centre=c0).is_identity
    far = _samples(_sized(mesh, c0, 0.8), 2000, 8)  # 20 %: not a size error
    assert fit_size_prior(far, index, centre=c0).is_identity


def test_to_json_is_plain():
    j = SizePrior(0.98, (0.1, 0.0, 0.0), (0.0, 0.0, np.radians(0.5)), (0.0, 0.0, 0.0), 0.97).to_json()
    assert j == {"scale": 0.98, "shift_mm": [0.1, 0.0, 0.0], "rotation_deg": pytest.approx(0.5), "inliers": 0.97}
