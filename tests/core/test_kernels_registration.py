"""Registration kernels on synthetic reconstructions of known parts in known poses.

Each "reconstruction" is sampled on the true posed surface (+ 0.01 mm noise), then
optionally corrupted like a visual hull (outward bulges near sharp edges) and by
defects (a dent and a bump). A recovered pose is judged by the mean distance of
true-surface samples to the reference posed by it, so that the equivalent poses
of symmetric parts (box, sphere) all pass.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from inspector.kernels.registration import align_reference, refine_on_points
from inspector.model import Alignment

N_POINTS = 20_000
NOISE_MM = 0.01


# --------------------------------------------------------------------------- helpers


def _box() -> trimesh.Trimesh:
    return trimesh.creation.box((30.0, 30.0, 30.0))


def _part() -> trimesh.Trimesh:
    """Asymmetric part: a 30 mm box with an off-centre cylinder on top."""
    cyl = trimesh.creation.cylinder(radius=6.0, height=20.0, sections=48)
    cyl.apply_translation([8.0, 5.0, 12.0])
    return trimesh.boolean.union([_box(), cyl], engine="manifold")


def _sphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=4, radius=15.0)


@pytest.fixture(scope="module")
def shapes() -> dict[str, trimesh.Trimesh]:
    out = {"box": _box(), "part": _part(), "sphere": _sphere()}
    for m in out.values():
        assert m.is_watertight
    return out


def random_pose(rng: np.random.Generator, t_max: float = 10.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()
    d = rng.normal(size=3)
    T[:3, 3] = d / np.linalg.norm(d) * rng.uniform(0.0, t_max)
    return T


def posed(mesh: trimesh.Trimesh, T: np.ndarray) -> trimesh.Trimesh:
    m = mesh.copy()
    m.apply_transform(T)
    return m


def sample_surface(mesh: trimesh.Trimesh, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform samples (n, 3) and their face normals (n, 3)."""
    area = mesh.area_faces
    idx = rng.choice(len(area), size=n, p=area / area.sum())
    r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
    tri = mesh.triangles[idx]
    pts = (1 - r1)[:, None] * tri[:, 0] + (r1 * (1 - r2))[:, None] * tri[:, 1] + (r1 * r2)[:, None] * tri[:, 2]
    return pts, mesh.face_normals[idx]


def _distance_to_segments(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty(len(p))
    ab = b - a
    ab2 = np.einsum("ij,ij->i", ab, ab)
    for s in range(0, len(p), 2000):
        ap = p[s : s + 2000, None, :] - a[None]
        t = np.clip(np.einsum("nkj,kj->nk", ap, ab) / ab2, 0.0, 1.0)
        out[s : s + 2000] = np.linalg.norm(ap - t[..., None] * ab[None], axis=2).min(axis=1)
    return out


def reconstruction(
    mesh: trimesh.Trimesh,
    rng: np.random.Generator,
    *,
    n: int = N_POINTS,
    bulge_mm: float = 0.0,
    defects: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Points and normals on ``mesh`` (already posed), corrupted on request.

    ``bulge_mm``: points within 3 mm of a sharp edge are pushed outward by up to
    ``bulge_mm`` (most at the edge), as a visual hull does; a part without sharp
    edges gets 6 bulging patches of radius 5 mm instead. ``defects``: the points
    in a 3 mm ball are moved 1.5 mm inside (a dent) and those within 4 mm of
    another point are pushed out by up to 3 mm (a bump).
    """
    p, nrm = sample_surface(mesh, n, rng)
    p = p.copy()
    if bulge_mm > 0:
        sharp = mesh.face_adjacency_angles > np.radians(30.0)
        if np.any(sharp):
            e = mesh.vertices[mesh.face_adjacency_edges[sharp]]
            d = _distance_to_segments(p, e[:, 0], e[:, 1])
            p += nrm * (bulge_mm * np.clip(1.0 - d / 3.0, 0.0, None) ** 2)[:, None]
        else:
            for c in p[rng.choice(len(p), 6, replace=False)]:
                d = np.linalg.norm(p - c, axis=1)
                p += nrm * (bulge_mm * np.clip(1.0 - d / 5.0, 0.0, None) ** 2)[:, None]
    if defects:
        c_dent, c_bump = p[rng.choice(len(p), 2, replace=False)]
        dent = np.linalg.norm(p - c_dent, axis=1) < 3.0
        p[dent] -= 1.5 * nrm[dent]
        d = np.linalg.norm(p - c_bump, axis=1)
        p += nrm * (3.0 * 0.5 * (1.0 + np.cos(np.pi * np.clip(d / 4.0, 0.0, 1.0))))[:, None]
    p += rng.normal(0.0, NOISE_MM, p.shape)
    return p, nrm


def mean_surface_error(true_mesh: trimesh.Trimesh, ref: trimesh.Trimesh, pose: np.ndarray, seed: int = 0) -> float:
    """Mean |distance| of samples of the true surface to the reference posed by ``pose``, mm."""
    s, _ = sample_surface(true_mesh, 4000, np.random.default_rng(seed))
    m = posed(ref, pose)
    tm = o3d.t.geometry.TriangleMesh()
    tm.vertex.positions = o3d.core.Tensor(m.vertices.astype(np.float32))
    tm.triangle.indices = o3d.core.Tensor(m.faces.astype(np.int32))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(tm)
    return float(scene.compute_distance(o3d.core.Tensor(s.astype(np.float32))).numpy().mean())


def rotation_error_deg(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.degrees(Rotation.from_matrix(A[:3, :3].T @ B[:3, :3]).magnitude()))


def perturb(T: np.ndarray, rng: np.random.Generator, deg: float = 0.5, mm: float = 0.3) -> np.ndarray:
    axis, shift = rng.normal(size=3), rng.normal(size=3)
    D = np.eye(4)
    D[:3, :3] = Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.radians(deg)).as_matrix()
    D[:3, 3] = shift / np.linalg.norm(shift) * mm
    return D @ T


def _check_alignment(a: Alignment, method: str) -> None:
    assert isinstance(a, Alignment)
    assert a.method == method
    assert a.pose.shape == (4, 4)
    R = a.pose[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(R) > 0
    np.testing.assert_array_equal(a.pose[3], [0, 0, 0, 1])
    assert 0.0 <= a.fitness <= 1.0
    assert a.rmse_mm >= 0.0


# --------------------------------------------------------------------------- align_reference


@pytest.mark.parametrize("name", ["box", "part", "sphere"])
def test_align_exact_data_any_orientation(shapes, name):
    mesh = shapes[name]
    rng = np.random.default_rng({"box": 1, "part": 2, "sphere": 3}[name])
    for _ in range(3):
        T = random_pose(rng)
        true = posed(mesh, T)
        pts, nrm = reconstruction(true, rng)
        a = align_reference(pts, nrm, mesh.vertices, mesh.faces)
        _check_alignment(a, "global+icp")
        assert mean_surface_error(true, mesh, a.pose) < 0.02
        assert a.fitness > 0.999
        assert a.rmse_mm < 3 * NOISE_MM
        if name == "sphere":  # any rotation is right, the centre must be
            assert np.linalg.norm(a.pose[:3, 3] - T[:3, 3]) < 0.02


def test_align_asymmetric_part_recovers_the_pose(shapes):
    mesh = shapes["part"]
    rng = np.random.default_rng(11)
    for _ in range(3):
        T = random_pose(rng)
        pts, nrm = reconstruction(posed(mesh, T), rng)
        a = align_reference(pts, nrm, mesh.vertices, mesh.faces)
        assert rotation_error_deg(a.pose, T) < 0.2
        assert np.linalg.norm(a.pose[:3, 3] - T[:3, 3]) < 0.05


def test_align_far_translation(shapes):
    mesh = shapes["part"]
    rng = np.random.default_rng(12)
    T = random_pose(rng)
    T[:3, 3] = [14.0, -12.0, 8.0]  # ~20 mm
    pts, nrm = reconstruction(posed(mesh, T), rng)
    a = align_reference(pts, nrm, mesh.vertices, mesh.faces)
    assert rotation_error_deg(a.pose, T) < 0.2
    assert np.linalg.norm(a.pose[:3, 3] - T[:3, 3]) < 0.05


@pytest.mark.parametrize("name", ["box", "part", "sphere"])
def test_align_robust_to_bulges_and_defects(shapes, name):
    mesh = shapes[name]
    rng = np.random.default_rng({"box": 21, "part": 22, "sphere": 23}[name])
    for bulge in (1.0, 2.0):
        T = random_pose(rng)
        true = posed(mesh, T)
        pts, nrm = reconstruction(true, rng, bulge_mm=bulge, defects=True)
        a = align_reference(pts, nrm, mesh.vertices, mesh.faces)
        _check_alignment(a, "global+icp")
        assert mean_surface_error(true, mesh, a.pose) < 0.1
        if name == "part":
            assert rotation_error_deg(a.pose, T) < 1.0


@pytest.mark.parametrize("scale", [0.95, 1.05])
def test_align_part_with_scale_error(shapes, scale):
    """A part a few percent off in size is still centred and oriented."""
    mesh = shapes["part"]
    rng = np.random.default_rng(31 if scale < 1 else 32)
    T = random_pose(rng)
    c = mesh.center_mass
    scaled = mesh.copy()
    scaled.apply_translation(-c)
    scaled.apply_scale(scale)
    scaled.apply_translation(c)
    pts, nrm = reconstruction(posed(scaled, T), rng, bulge_mm=1.0)
    a = align_reference(pts, nrm, mesh.vertices, mesh.faces)
    assert rotation_error_deg(a.pose, T) < 1.0
    assert np.linalg.norm((a.pose[:3, :3] - T[:3, :3]) @ c + a.pose[:3, 3] - T[:3, 3]) < 0.25


def test_align_is_deterministic(shapes):
    mesh = shapes["box"]
    rng = np.random.default_rng(41)
    pts, nrm = reconstruction(posed(mesh, random_pose(rng)), rng, n=5000, bulge_mm=1.0, defects=True)
    a = align_reference(pts, nrm, mesh.vertices, mesh.faces, seed=3)
    b = align_reference(pts, nrm, mesh.vertices, mesh.faces, seed=3)
    np.testing.assert_array_equal(a.pose, b.pose)
    assert (a.fitness, a.rmse_mm) == (b.fitness, b.rmse_mm)


def test_align_reference_frame_off_origin(shapes):
    """CAD coordinates far from the origin: the pose still maps reference -> world."""
    mesh = shapes["part"].copy()
    mesh.apply_translation([500.0, -300.0, 120.0])
    rng = np.random.default_rng(51)
    T = random_pose(rng)
    T[:3, 3] -= T[:3, :3] @ mesh.center_mass  # keep the part near the world origin
    true = posed(mesh, T)
    pts, nrm = reconstruction(true, rng)
    a = align_reference(pts, nrm, mesh.vertices, mesh.faces)
    assert mean_surface_error(true, mesh, a.pose) < 0.02
    assert rotation_error_deg(a.pose, T) < 0.2


# --------------------------------------------------------------------------- refine_on_points


@pytest.mark.parametrize("name", ["box", "part", "sphere"])
def test_refine_recovers_from_perturbed_pose(shapes, name):
    mesh = shapes[name]
    rng = np.random.default_rng({"box": 61, "part": 62, "sphere": 63}[name])
    for _ in range(2):
        T = random_pose(rng)
        true = posed(mesh, T)
        pts, _ = sample_surface(true, 5000, rng)
        start = perturb(T, rng)
        assert mean_surface_error(true, mesh, start) > 0.05
        a = refine_on_points(pts, mesh.vertices, mesh.faces, start)
        _check_alignment(a, "bcps-refine")
        assert mean_surface_error(true, mesh, a.pose) < 0.005
        assert a.fitness == 1.0
        assert a.rmse_mm < 0.005


@pytest.mark.parametrize("name", ["box", "part"])
def test_refine_ignores_inward_outliers(shapes, name):
    mesh = shapes[name]
    rng = np.random.default_rng({"box": 71, "part": 72}[name])
    T = random_pose(rng)
    true = posed(mesh, T)
    pts, nrm = sample_surface(true, 5000, rng)
    bad = rng.random(len(pts)) < 0.05
    pts[bad] -= 1.0 * nrm[bad]
    a = refine_on_points(pts, mesh.vertices, mesh.faces, perturb(T, rng))
    assert mean_surface_error(true, mesh, a.pose) < 0.005
    assert 0.93 < a.fitness < 0.97  # the outliers are > robust_mm away (bar a few near edges)


def test_refine_zero_iterations_keeps_the_pose(shapes):
    mesh = shapes["box"]
    rng = np.random.default_rng(81)
    T = random_pose(rng)
    pts, _ = sample_surface(posed(mesh, T), 500, rng)
    start = perturb(T, rng)
    a = refine_on_points(pts, mesh.vertices, mesh.faces, start, iterations=0)
    np.testing.assert_allclose(a.pose, start, atol=1e-12)


# --------------------------------------------------------------------------- bad inputs


@pytest.fixture(scope="module")
def small_case(shapes):
    mesh = shapes["box"]
    pts, nrm = sample_surface(mesh, 200, np.random.default_rng(91))
    return pts, nrm, mesh.vertices.copy(), mesh.faces.copy()


def _with_nan(a: np.ndarray) -> np.ndarray:
    b = np.array(a, dtype=float)
    b.flat[1] = np.nan
    return b


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda p, n, v, f: (p[:, :2], n, v, f), "points"),
        (lambda p, n, v, f: (p[:5], n[:5], v, f), "points"),
        (lambda p, n, v, f: (_with_nan(p), n, v, f), "points"),
        (lambda p, n, v, f: (p, n[:-1], v, f), "normals"),
        (lambda p, n, v, f: (p, _with_nan(n), v, f), "normals"),
        (lambda p, n, v, f: (p, np.zeros_like(n), v, f), "normals"),
        (lambda p, n, v, f: (p, n, v[:, :2], f), "ref_vertices"),
        (lambda p, n, v, f: (p, n, _with_nan(v), f), "ref_vertices"),
        (lambda p, n, v, f: (p, n, v, f[:, :2]), "ref_faces"),
        (lambda p, n, v, f: (p, n, v, f + len(v)), "ref_faces"),
        (lambda p, n, v, f: (p, n, v, f + 0.5), "ref_faces"),
    ],
)
def test_align_rejects_bad_arrays(small_case, change, match):
    with pytest.raises(ValueError, match=match):
        align_reference(*change(*small_case))


@pytest.mark.parametrize("kw", [{"voxel_mm": 0.0}, {"inlier_mm": -1.0}, {"voxel_mm": np.nan}])
def test_align_rejects_bad_parameters(small_case, kw):
    with pytest.raises(ValueError):
        align_reference(*small_case, **kw)


def test_refine_rejects_bad_inputs(small_case):
    pts, _, v, f = small_case
    pose = np.eye(4)
    with pytest.raises(ValueError, match="points"):
        refine_on_points(pts[:, :2], v, f, pose)
    with pytest.raises(ValueError, match="points"):
        refine_on_points(_with_nan(pts), v, f, pose)
    with pytest.raises(ValueError, match="ref_vertices"):
        refine_on_points(pts, _with_nan(v), f, pose)
    with pytest.raises(ValueError, match="ref_faces"):
        refine_on_points(pts, v, f[:, :2], pose)
    with pytest.raises(ValueError, match="pose"):
        refine_on_points(pts, v, f, np.eye(3))
    with pytest.raises(ValueError, match="pose"):
        refine_on_points(pts, v, f, _with_nan(pose))
    with pytest.raises(ValueError, match="pose"):
        refine_on_points(pts, v, f, np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="robust_mm"):
        refine_on_points(pts, v, f, pose, robust_mm=0.0)
    with pytest.raises(ValueError, match="iterations"):
        refine_on_points(pts, v, f, pose, iterations=-1)


def _shaft_contour_points():
    """A shaft with a flat and its contour-like points (the cylinder's side and the flat's
    two long edges)."""
    cyl = trimesh.creation.cylinder(radius=10.0, height=30.0, sections=128)
    cut = trimesh.creation.box((10.0, 30.0, 20.0))
    cut.apply_translation((13.0, 0.0, 5.0))  # a flat 2 mm deep over the upper 15 mm
    shaft = trimesh.boolean.difference([cyl, cut], engine="manifold")
    pts, fi = trimesh.sample.sample_surface(shaft, 40000, seed=5)
    nrm = shaft.face_normals[fi]
    on_flat = np.abs(nrm[:, 0] - 1.0) < 1e-6
    edges = on_flat & (np.abs(np.abs(pts[:, 1]) - 6.0) < 0.4)
    side = (np.abs(nrm[:, 2]) < 1e-6) & ~on_flat
    return shaft, np.concatenate([pts[side][:8000], pts[edges]])


def test_refine_wide_start_fixes_the_rotation_of_a_shaft_with_a_flat():
    """Contour-like points (the cylinder's side and the flat's two long edges) of a
    shaft turned 3 degrees about its axis: only the edge points, about 0.3 mm off,
    pin the rotation. With the cutoff at ``robust_mm`` from the start they are ignored
    and the fit stays turned; a 1 mm start lets them act first."""
    shaft, P = _shaft_contour_points()
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", 3.0, degrees=True).as_matrix()
    narrow = refine_on_points(P, shaft.vertices, shaft.faces, T, robust_mm=0.1)
    wide = refine_on_points(P, shaft.vertices, shaft.faces, T, robust_mm=0.1, start_mm=1.0)
    assert rotation_error_deg(narrow.pose, np.eye(4)) > 1.0
    assert rotation_error_deg(wide.pose, np.eye(4)) < 0.05
    assert wide.fitness == 1.0
    with pytest.raises(ValueError, match="start_mm"):
        refine_on_points(P, shaft.vertices, shaft.faces, T, start_mm=0.0)


def test_refine_axis_turns_get_a_shaft_out_of_a_ten_degree_minimum():
    """Turned 11 degrees about its axis, the flat's edges are 2 mm off, beyond even a
    1 mm start: one fit stays turned. Extra starts turned about the axis of near-symmetry
    find the basin of the right pose."""
    shaft, P = _shaft_contour_points()
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", 11.0, degrees=True).as_matrix()
    one = refine_on_points(P, shaft.vertices, shaft.faces, T, robust_mm=0.1, start_mm=1.0)
    turned = refine_on_points(P, shaft.vertices, shaft.faces, T, robust_mm=0.1, start_mm=1.0,
                              axis_turns_deg=(-15.0, -7.5, 7.5, 15.0))
    assert rotation_error_deg(one.pose, np.eye(4)) > 1.0
    assert rotation_error_deg(turned.pose, np.eye(4)) < 0.05
    assert turned.fitness == 1.0


def test_axis_turns_only_for_a_reference_with_one_axis_of_near_symmetry():
    from inspector.kernels.axis import axis_turns as _axis_turns
    from inspector.kernels.rigid import RefMesh as _Reference

    shaft, _ = _shaft_contour_points()
    box = trimesh.creation.box((26.0, 20.0, 14.0))
    cube = trimesh.creation.box((30.0, 30.0, 30.0))
    turns = _axis_turns(_Reference(np.asarray(shaft.vertices), np.asarray(shaft.faces)), (-10.0, 10.0))
    assert turns.shape == (3, 4, 4)
    np.testing.assert_allclose(turns[0], np.eye(4))
    # about the shaft's axis (z): z is kept, the turn is 10 degrees
    np.testing.assert_allclose(np.abs(turns[1, :3, 2]), [0, 0, 1], atol=0.02)
    assert rotation_error_deg(turns[1], np.eye(4)) == pytest.approx(10.0, abs=1e-6)
    for m in (box, cube):
        assert len(_axis_turns(_Reference(np.asarray(m.vertices), np.asarray(m.faces)), (-10.0, 10.0))) == 1


# --------------------------------------------------------------------------- turns about the axis


def _disc(holes: int = 4, notch: bool = False) -> trimesh.Trimesh:
    """Disc Ø40 x 6 (axis z) with ``holes`` Ø5 holes on a Ø28 circle, the first on +x, and
    optionally a 4 x 3 mm notch in the rim on +y between two holes (it keys the turn)."""
    disc = trimesh.creation.cylinder(radius=20.0, height=6.0, sections=128)
    cut = []
    for k in range(holes):
        a = 2 * np.pi * k / holes
        h = trimesh.creation.cylinder(radius=2.5, height=8.0, sections=64)
        h.apply_translation((14.0 * np.cos(a), 14.0 * np.sin(a), 0.0))
        cut.append(h)
    if notch:
        n = trimesh.creation.box((4.0, 6.0, 8.0))
        n.apply_translation((0.0, 20.0, 0.0))
        cut.append(n)
    return trimesh.boolean.difference([disc, *cut], engine="manifold")


def _turn_z(deg: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", deg, degrees=True).as_matrix()
    return T


def test_scan_finds_a_flange_s_own_symmetries_and_its_geometric_axis():
    from inspector.kernels.axis import scan_about_axis

    disc = _disc(4)
    pts, _ = trimesh.sample.sample_surface(disc, 6000, seed=1)
    scan = scan_about_axis(pts, disc.vertices, disc.faces, np.eye(4), cutoff_mm=1.0)
    np.testing.assert_allclose(np.abs(scan.axis), [0, 0, 1], atol=1e-6)
    assert sorted(scan.angles_deg[scan.symmetric].round(6)) == [0.0, 90.0, 180.0, 270.0]
    # the points fit at the pose and at the symmetries, not half way between
    at = {float(a): c for a, c in zip(scan.angles_deg, scan.cost)}
    assert at[0.0] < 0.01 and at[90.0] < 0.01 and at[45.0] > 0.02
    assert scan_about_axis(pts, *_cube_mesh(), np.eye(4), cutoff_mm=1.0) is None


def _cube_mesh():
    m = trimesh.creation.box((30.0, 30.0, 30.0))
    return np.asarray(m.vertices), np.asarray(m.faces)


def test_axis_scan_recovers_a_keyed_disc_turned_far_about_its_axis():
    """A disc keyed by one rim notch, its points on the true surface, the pose turned 130
    degrees: one fit (even with turns of +-15 degrees) stays off; the scan over every turn
    finds the right one."""
    disc = _disc(4, notch=True)
    P, _ = trimesh.sample.sample_surface(disc, 20000, seed=2)
    start = _turn_z(130.0)
    local = refine_on_points(P, disc.vertices, disc.faces, start, robust_mm=0.1, start_mm=1.0,
                             axis_turns_deg=(-15.0, -7.5, 7.5, 15.0))
    scanned = refine_on_points(P, disc.vertices, disc.faces, start, robust_mm=0.1, start_mm=1.0, axis_scan=True)
    assert rotation_error_deg(local.pose, np.eye(4)) > 1.0
    assert rotation_error_deg(scanned.pose, np.eye(4)) < 0.05
    assert scanned.fitness > 0.99


def test_hull_points_veto_turns_that_put_the_reference_out_of_the_hull():
    """Hull points on a disc with four holes: turns by 90 degrees keep the reference inside
    the hull, 45 degrees puts it into the holes' space."""
    from inspector.kernels.axis import scan_about_axis
    from inspector.kernels.meshdist import MeshDistance

    disc = _disc(4)
    V, F = np.asarray(disc.vertices), np.asarray(disc.faces)
    hull, _ = trimesh.sample.sample_surface(disc, 8000, seed=3)
    scan = scan_about_axis(hull, V, F, np.eye(4), cutoff_mm=1.0, index=MeshDistance(V, F), hull_points=hull,
                           hull_mm=0.5)
    at = {float(a): ok for a, ok in zip(scan.angles_deg, scan.inside_hull)}
    assert at[0.0] and at[90.0] and at[180.0]
    assert not at[45.0]


def test_pose_confidence_tells_a_keyed_part_from_an_unpinned_one():
    """At the true pose of the keyed disc the runner-up turn (a quarter turn: the holes
    match, the notch does not) fits clearly worse; the plain disc's quarter turns are its
    own symmetries, not runner-ups; face points away from holes and notch pin nothing."""
    from inspector.kernels.axis import pose_confidence, scan_about_axis

    keyed = _disc(4, notch=True)
    P, fi = trimesh.sample.sample_surface(keyed, 20000, seed=4)
    conf = pose_confidence(scan_about_axis(P, keyed.vertices, keyed.faces, np.eye(4), cutoff_mm=1.0))
    assert not conf.ambiguous and conf.margin_points > 100
    assert abs(abs(conf.runner_up_deg) % 90.0) < 5.0 or abs(abs(conf.runner_up_deg) % 90.0) > 85.0
    plain = _disc(4)
    Q, _ = trimesh.sample.sample_surface(plain, 20000, seed=4)
    sym = pose_confidence(scan_about_axis(Q, plain.vertices, plain.faces, np.eye(4), cutoff_mm=1.0))
    assert sym.symmetry_deg == (90.0, 180.0, 270.0) and not sym.ambiguous and sym.margin_points > 100
    assert 5.0 < abs(sym.runner_up_deg) % 90.0 < 85.0
    # the keyed disc seen only by its faces (z = +-3, away from holes and notch): nothing pins the turn
    r = np.hypot(P[:, 0], P[:, 1])
    faces = (np.abs(np.abs(P[:, 2]) - 3.0) < 1e-6) & (r < 9.0)
    blind = pose_confidence(scan_about_axis(P[faces], keyed.vertices, keyed.faces, np.eye(4), cutoff_mm=1.0))
    assert blind.ambiguous


def test_turn_zone_marks_only_where_a_turn_changes_the_distance():
    """A Ø20 shaft with a notch on one side over z in [-5, 5]: a turn about its axis changes
    the distance only near the notch's heights and radii; the plain shaft has no such zone."""
    from inspector.kernels.axis import turn_zone
    from inspector.kernels.meshdist import MeshDistance

    shaft = trimesh.creation.cylinder(radius=10.0, height=40.0, sections=128)
    notch = trimesh.creation.box((4.0, 6.0, 10.0))
    notch.apply_translation((9.5, 0.0, 0.0))
    keyed = trimesh.boolean.difference([shaft, notch], engine="manifold")
    axis, centre = np.array([0.0, 0.0, 1.0]), np.zeros(3)
    zone = turn_zone(MeshDistance(keyed.vertices, keyed.faces).near, keyed.vertices, axis, centre)
    pts = np.array([[0.0, 10.0, 0.0],     # on the rim at the notch's height: a turn brings the notch here
                    [-9.0, 0.0, 3.0],      # inside, within the band of the notch's floor
                    [0.0, 10.0, 12.0],     # on the rim above the notch
                    [0.0, 10.0, -15.0],    # below it
                    [0.0, 0.0, 0.0],       # on the axis, far from any surface
                    [0.0, 30.0, 0.0]])     # far outside
    np.testing.assert_array_equal(zone.hits(pts), [True, True, False, False, False, False])
    plain = turn_zone(MeshDistance(shaft.vertices, shaft.faces).near, shaft.vertices, axis, centre)
    assert not plain.variable.any()
