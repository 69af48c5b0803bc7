"""Tests of :mod:`inspector.kernels.carving` (coarse-to-fine visual hull).

Silhouettes are ray-cast with Open3D through the pixel centres of a synthetic rig of
16 cameras on a sphere of radius 400 mm (Fibonacci directions) looking at the origin.
The "hi" rig has 1024x1024 images and f = 4000 px (0.1 mm/px at the origin), the "lo"
rig 512x512 and f = 2000 px (0.2 mm/px), cheaper for the tests that do not need 0.1 mm.
"""

from __future__ import annotations

import numpy as np
import pytest

o3d = pytest.importorskip("open3d")
trimesh = pytest.importorskip("trimesh")
cv2 = pytest.importorskip("cv2")

from inspector.kernels import carving as ck  # noqa: E402
from inspector.model import Camera, Reconstruction  # noqa: E402

RADIUS = 15.0  # sphere radius, mm
HALF = 15.0  # cube half edge, mm
RIG_RADIUS = 400.0


# --------------------------------------------------------------------------------------
# helpers: rig and ray-cast silhouettes
# --------------------------------------------------------------------------------------


def fibonacci_dirs(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    th = np.pi * (1 + 5**0.5) * i
    return np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], 1)


def look_at(name, centre, f, size, *, dist=None, cx=None, cy=None) -> Camera:
    """Camera at ``centre`` looking at the origin (x right, y down, z forward)."""
    centre = np.asarray(centre, float)
    z = -centre / np.linalg.norm(centre)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    y = -up + (up @ z) * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R = np.stack([x, y, z])
    K = np.array([[f, 0, (size - 1) / 2 if cx is None else cx], [0, f, (size - 1) / 2 if cy is None else cy], [0, 0, 1]])
    return Camera(name, size, size, K, np.zeros(5) if dist is None else dist, R, -R @ centre)


def make_rig(n=16, f=4000.0, size=1024, dist=None) -> list[Camera]:
    return [look_at(f"cam{i:02d}", RIG_RADIUS * d, f, size, dist=dist) for i, d in enumerate(fibonacci_dirs(n))]


def render_mask(mesh, cam: Camera) -> np.ndarray:
    """(H, W) bool: True where the ray through the pixel centre hits ``mesh``."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)), o3d.core.Tensor(np.asarray(mesh.faces, np.uint32))
    )
    uv, _ = cam.project(np.asarray(mesh.vertices))  # only cast rays near the object
    lo = np.maximum(np.floor(uv.min(0)) - 4, 0).astype(int)
    hi = np.minimum(np.ceil(uv.max(0)) + 4, [cam.width - 1, cam.height - 1]).astype(int)
    mask = np.zeros((cam.height, cam.width), bool)
    if np.any(hi < lo):
        return mask
    us, vs = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
    pix = np.stack([us.ravel(), vs.ravel()], 1).astype(np.float64)
    if cam.has_distortion:
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
        xy = cv2.undistortPoints(pix.reshape(-1, 1, 2), cam.K, cam.dist, None, np.eye(3), np.eye(3), crit).reshape(-1, 2)
    else:
        xy = np.stack([(pix[:, 0] - cam.K[0, 2]) / cam.K[0, 0], (pix[:, 1] - cam.K[1, 2]) / cam.K[1, 1]], 1)
    d = np.concatenate([xy, np.ones((len(xy), 1))], 1) @ cam.R
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rays = np.concatenate([np.broadcast_to(cam.centre, d.shape), d], 1).astype(np.float32)
    hit = np.isfinite(scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy())
    mask[vs.ravel(), us.ravel()] = hit
    return mask


def sphere_mesh():
    return trimesh.creation.icosphere(subdivisions=5, radius=RADIUS)


def cube_rotation() -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.random(random_state=7).as_matrix()


def cube_mesh():
    m = trimesh.creation.box(extents=(2 * HALF,) * 3)
    T = np.eye(4)
    T[:3, :3] = cube_rotation()
    m.apply_transform(T)
    return m


def sphere_cone_sd(cams, X) -> np.ndarray:
    """Exact visual hull of the sphere: min over cameras of the distance to the tangent
    cone (positive inside), mm."""
    out = np.full(len(X), np.inf)
    for c in cams:
        C = c.centre
        a = -C / np.linalg.norm(C)
        alpha = np.arcsin(RADIUS / np.linalg.norm(C))
        V = X - C
        n = np.linalg.norm(V, axis=1)
        beta = np.arccos(np.clip(V @ a / n, -1, 1))
        out = np.minimum(out, n * np.sin(alpha - beta))
    return out


def sphere_samples(n: int, seed: int) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return RADIUS * d / np.linalg.norm(d, axis=1, keepdims=True)


def cube_samples(n: int, seed: int) -> np.ndarray:
    """Points on the true cube surface (faces, edges and corners included)."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-HALF, HALF, (n, 3))
    axis = rng.integers(0, 3, n)
    p[np.arange(n), axis] = rng.choice([-HALF, HALF], n)
    corners = np.array([[sx, sy, sz] for sx in (-HALF, HALF) for sy in (-HALF, HALF) for sz in (-HALF, HALF)])
    return np.concatenate([p, corners]) @ cube_rotation().T


def mesh_volume(rec: Reconstruction) -> float:
    v = rec.vertices[rec.faces]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


# --------------------------------------------------------------------------------------
# fixtures
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rig_hi():
    return make_rig(f=4000.0, size=1024)


@pytest.fixture(scope="module")
def rig_lo():
    return make_rig(f=2000.0, size=512)


@pytest.fixture(scope="module")
def sphere_hi(rig_hi):
    m = sphere_mesh()
    return [render_mask(m, c) for c in rig_hi]


@pytest.fixture(scope="module")
def sphere_lo(rig_lo):
    m = sphere_mesh()
    return [render_mask(m, c) for c in rig_lo]


@pytest.fixture(scope="module")
def cube_lo(rig_lo):
    m = cube_mesh()
    return [render_mask(m, c) for c in rig_lo]


# --------------------------------------------------------------------------------------
# signed distance and classification
# --------------------------------------------------------------------------------------


def test_signed_distance_zero_level_on_pixel_boundary():
    mask = np.zeros((8, 10), bool)
    mask[:, :5] = True  # object on columns 0..4, touches the left border
    s = ck.signed_distance(mask)
    assert s.dtype == np.float32 and s.shape == mask.shape
    np.testing.assert_allclose(s[4, 4], 0.5)
    np.testing.assert_allclose(s[4, 5], -0.5)
    np.testing.assert_allclose(s[4, 9], -4.5)
    # closed border: the pixel on the image edge is next to "background"
    np.testing.assert_allclose(s[4, 0], 0.5)
    # open border: outside the image counts as object
    so = ck.signed_distance(mask, open_border=True)
    np.testing.assert_allclose(so[4, 0], 4.5)
    np.testing.assert_allclose(so[4, 9], -0.5)  # the right edge is next to the outside


def test_hull_function_zero_on_mask_boundary_and_outside_image():
    cam = look_at("c", [0.0, 0.0, -400.0], 400.0, 21)  # 1 px = 1 mm at the origin
    mask = np.zeros((21, 21), bool)
    mask[:, :11] = True  # u <= 10 is object: boundary at u = 10.5, touches the left border
    sdt = ck.signed_distance(mask)
    # world points on the plane z = 0 project to u = 10 + x * (f / 400) (x right)
    uv_edge = np.array([[10.5, 10.0]])
    _, d = cam.rays(uv_edge)
    X = cam.centre + 400.0 * d / d[0, 2]
    assert abs(ck.hull_function([cam], [sdt], X)[0]) < 1e-6
    # beyond the left image edge (u < -0.5): carved when closed, kept when open
    _, d = cam.rays(np.array([[-3.0, 10.0]]))
    Xo = cam.centre + 400.0 * d / d[0, 2]
    assert ck.hull_function([cam], [sdt], Xo)[0] < 0
    sdt_open = ck.signed_distance(mask, open_border=True)
    assert ck.hull_function([cam], [sdt_open], Xo, open_border=[True])[0] > 0
    # behind the camera: always carved
    Xb = np.array([[0.0, 0.0, -800.0]])
    assert ck.hull_function([cam], [sdt_open], Xb, open_border=[True])[0] < 0
    f, g = ck.hull_gradient([cam], [sdt], X)
    _, d2 = cam.rays(np.array([[10.6, 10.0], [10.4, 10.0]]))
    right = d2[0] / d2[0, 2] - d2[1] / d2[1, 2]  # world direction of +u on the plane
    assert g.shape == (1, 3) and g[0] @ right < 0  # f decreases towards the background
    assert abs(f[0]) < 1e-6


@pytest.mark.parametrize("kind", ["plain", "open", "distorted"])
def test_classification_is_conservative(kind):
    """A ball classified "outside" has no point with g >= 0, "inside" none with g <= 0."""
    rng = np.random.default_rng(11)
    size = 96
    dist = np.array([-0.25, 0.08, 0.002, -0.001, 0.0]) if kind == "distorted" else None
    cam = look_at("c", [0.0, 0.0, -60.0], 120.0, size, dist=dist)
    mask = np.zeros((size, size), bool)
    yy, xx = np.mgrid[:size, :size]
    mask |= (xx - 40) ** 2 + (yy - 50) ** 2 < 20**2
    mask |= (xx > 70) & (yy > 30) & (yy < 45)  # a bar through the right border
    mask[10:14, 10:80] = True
    is_open = kind == "open"
    sdt = ck.signed_distance(mask, open_border=is_open)
    v = ck._prepare(cam, sdt, is_open)
    n_balls, n_pts = 4000, 48
    centres = np.stack(
        [rng.uniform(-45, 45, n_balls), rng.uniform(-45, 45, n_balls), rng.uniform(-70, 40, n_balls)]
    )
    total = 0
    for r in (0.05, 0.5, 3.0, 12.0):
        out, inn = ck._classify(v, centres, r)
        assert not np.any(out & inn)
        d = rng.normal(size=(3, n_balls, n_pts))
        d *= r * rng.uniform(0, 1, (1, n_balls, n_pts)) ** (1 / 3) / np.linalg.norm(d, axis=0, keepdims=True)
        d[:, :, 0] = 0.0  # the centre
        pts = (centres[:, :, None] + d).reshape(3, -1)
        f = ck._f_camera(v, pts).reshape(n_balls, n_pts)
        assert np.all(f[out] < 0), "carved a ball that contains points inside the silhouette cone"
        assert np.all(f[inn] > 0), "a ball classified inside contains points outside the cone"
        total += int(out.sum() + inn.sum())
    assert total > n_balls  # the bounds decide most small balls


# --------------------------------------------------------------------------------------
# carving
# --------------------------------------------------------------------------------------


def test_sphere_fine_voxel(rig_hi, sphere_hi):
    st: dict = {}
    rec = ck.carve(rig_hi, sphere_hi, voxel_mm=0.1, stats=st)
    P, N = rec.points, rec.normals
    assert isinstance(rec, Reconstruction) and rec.voxel_mm == 0.1
    assert P.shape == N.shape and P.shape[1] == 3
    # about one point per voxel**2 of surface
    area = 4 * np.pi * RADIUS**2
    assert 0.5 * area / 0.01 < len(P) < 2.0 * area / 0.01
    # only cells near the surface were refined
    assert st["n_finest_evaluated"] < 0.1 * st["n_dense_finest"]
    assert st["levels"][-1]["cell_mm"] == pytest.approx(0.1)
    assert st["residual_mm_max"] <= 0.002
    fp = 0.1  # pixel footprint, mm
    r = np.linalg.norm(P, axis=1)
    # conservative: no hull point inside the sphere by more than a pixel
    assert r.min() > RADIUS - fp
    # on average within a pixel + a voxel of the sphere (the hull bulges between views)
    assert np.mean(r - RADIUS) < fp + 0.1
    # on the exact visual hull of the sphere to sub-pixel accuracy
    cone = np.abs(sphere_cone_sd(rig_hi, P))
    assert np.mean(cone) < 0.35 * fp
    assert np.percentile(cone, 99) < 0.75 * fp
    # outward unit normals
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, atol=1e-9)
    assert np.all(np.einsum("ij,ij->i", N, P / r[:, None]) > 0.3)
    # the display mesh is closed around the sphere and outward-oriented
    assert len(rec.faces) > 1000
    vol = mesh_volume(rec)
    assert 1.0 < vol / (4 / 3 * np.pi * RADIUS**3) < 1.06


def test_sphere_coarse_voxel_is_still_sub_pixel(rig_hi, sphere_hi):
    st: dict = {}
    rec = ck.carve(rig_hi, sphere_hi, voxel_mm=0.5, stats=st)
    cone = np.abs(sphere_cone_sd(rig_hi, rec.points))
    assert np.mean(cone) < 0.035  # mm: the Newton projection, not the voxel, sets the accuracy
    assert np.linalg.norm(rec.points, axis=1).min() > RADIUS - 0.1
    # every true surface point is inside the hull
    S = sphere_samples(3000, seed=1)
    sdts = [ck.signed_distance(m) for m in sphere_hi]
    assert ck.hull_function(rig_hi, sdts, S).min() > -0.1
    assert st["mesh_voxel_mm"] == 0.5 and st["mesh_evaluated"] < st["mesh_grid"]


def test_cube_is_contained(rig_lo, cube_lo):
    fp = 0.2  # mm per pixel
    st: dict = {}
    rec = ck.carve(rig_lo, cube_lo, voxel_mm=0.25, stats=st)
    P, N = rec.points, rec.normals
    assert len(P) > 0.5 * 6 * (2 * HALF) ** 2 / 0.25**2
    # every point of the true cube surface (corners included) is inside the hull
    sdts = [ck.signed_distance(m) for m in cube_lo]
    f = ck.hull_function(rig_lo, sdts, cube_samples(4000, seed=3))
    assert f.min() > -fp
    # the hull's surface points are outside or on the cube
    local = P @ cube_rotation()
    depth = HALF - np.max(np.abs(local), axis=1)  # > 0 inside the cube
    assert depth.max() < fp
    # outward normals (the hull is convex and contains the origin)
    assert np.all(np.einsum("ij,ij->i", N, P) > 0)
    assert mesh_volume(rec) > (2 * HALF) ** 3


def test_open_border(rig_lo):
    """Camera 0 sees the sphere half out of its image (left border)."""
    m = sphere_mesh()
    c0 = rig_lo[0]
    uv, _ = c0.project(np.zeros((1, 3)))
    cam0 = look_at("cut", c0.centre, 2000.0, 512, cx=c0.K[0, 2] - uv[0, 0], cy=c0.K[1, 2])  # centre on u = 0
    cams = [cam0, *rig_lo[1:]]
    masks = [render_mask(m, c) for c in cams]
    assert masks[0][:, 0].any()  # touches the border
    S = sphere_samples(2000, seed=5)
    uvS, _ = cam0.project(S)
    beyond = uvS[:, 0] < -2.0  # sphere points outside camera 0's image
    assert 0.2 < beyond.mean() < 0.8

    # open: camera 0 does not carve what it cannot see, the whole sphere is kept
    rec = ck.carve(cams, masks, voxel_mm=0.5, open_border=[True] + [False] * 15)
    sdts = [ck.signed_distance(mk, open_border=o) for mk, o in zip(masks, [True] + [False] * 15)]
    f = ck.hull_function(cams, sdts, S, open_border=[True] + [False] * 15)
    assert f.min() > -0.2
    # the points lie on the exact hull where camera 0's cone is ignored outside its image
    u0 = cam0.project(rec.points)[0][:, 0]
    exact = np.minimum(sphere_cone_sd(cams[1:], rec.points), np.where(u0 >= -0.5, sphere_cone_sd([cam0], rec.points), np.inf))
    assert np.abs(exact).max() < 0.2
    assert np.abs(exact).mean() < 0.05
    assert (u0 < -2.0).mean() > 0.2

    # closed: outside the image counts as background, the unseen half is carved away
    rec_c = ck.carve(cams, masks, voxel_mm=0.5)
    sdts_c = [ck.signed_distance(mk) for mk in masks]
    f_c = ck.hull_function(cams, sdts_c, S)
    assert np.all(f_c[beyond] < 0)
    assert f_c[~beyond & (uvS[:, 0] > 2.0)].min() > -0.2
    assert cam0.project(rec_c.points)[0][:, 0].min() > -0.5 - 0.05
    assert len(rec_c.points) < len(rec.points)


def test_lens_distortion(rig_lo):
    dist = np.array([-0.2, 0.1, 0.001, -0.001, 0.0])
    cams = [look_at(c.name, c.centre, 2000.0, 512, dist=dist) for c in rig_lo]
    masks = [render_mask(sphere_mesh(), c) for c in cams]
    rec = ck.carve(cams, masks, voxel_mm=0.5)
    assert len(rec.points) > 1000
    cone = np.abs(sphere_cone_sd(cams, rec.points))
    assert np.mean(cone) < 0.07  # a third of a pixel
    sdts = [ck.signed_distance(mk) for mk in masks]
    assert ck.hull_function(cams, sdts, sphere_samples(2000, seed=9)).min() > -0.2


def test_default_bounds(rig_lo, sphere_lo):
    b = ck.default_bounds(rig_lo, sphere_lo)
    assert b.shape == (2, 3)
    assert np.all(b[0] < -RADIUS) and np.all(b[1] > RADIUS)
    assert np.all(b[0] > -RADIUS - 2.0) and np.all(b[1] < RADIUS + 2.0)  # tight
    # all borders open: nothing constrains the box but the rig
    b_open = ck.default_bounds(rig_lo, sphere_lo, open_border=[True] * 16)
    assert np.all(b_open[0] < -RIG_RADIUS) and np.all(b_open[1] > RIG_RADIUS)
    empty = [np.zeros_like(sphere_lo[0])] + list(sphere_lo[1:])
    with pytest.raises(ValueError):
        ck.default_bounds(rig_lo, empty)


def test_empty_hull(rig_lo, sphere_lo):
    st: dict = {}
    empty = [np.zeros_like(sphere_lo[0])] + list(sphere_lo[1:])
    rec = ck.carve(rig_lo, empty, voxel_mm=0.5, stats=st)
    assert rec.points.shape == (0, 3) and rec.normals.shape == (0, 3) and rec.faces.shape == (0, 3)
    assert st["n_points"] == 0 and "empty_reason" in st
    # cones that do not meet: one silhouette moved far from the others
    moved = list(sphere_lo)
    moved[0] = np.roll(sphere_lo[0], 200, axis=1)
    rec = ck.carve(rig_lo, moved, voxel_mm=0.5)
    assert len(rec.points) == 0


def test_explicit_bounds_and_coarse(rig_lo, sphere_lo):
    st: dict = {}
    bounds = np.array([[-20.0, -20.0, -20.0], [20.0, 20.0, 20.0]])
    rec = ck.carve(rig_lo, sphere_lo, voxel_mm=0.5, bounds=bounds, coarse_mm=4.0, mesh_voxel_mm=1.0, stats=st)
    assert st["coarse_mm"] == 4.0 and len(st["levels"]) == 4
    assert np.abs(sphere_cone_sd(rig_lo, rec.points)).mean() < 0.07
    assert np.linalg.norm(rec.vertices, axis=1).max() < RADIUS + 2.0


def test_bad_arguments(rig_lo, sphere_lo):
    with pytest.raises(ValueError):
        ck.carve(rig_lo, sphere_lo[:-1], voxel_mm=0.5)
    with pytest.raises(ValueError):
        ck.carve(rig_lo, sphere_lo, voxel_mm=0.0)
    with pytest.raises(ValueError):
        ck.carve(rig_lo, sphere_lo, voxel_mm=0.5, open_border=[True])
    with pytest.raises(ValueError):
        ck.carve(rig_lo, [m[:, :-1] for m in sphere_lo], voxel_mm=0.5)
    with pytest.raises(ValueError):
        ck.carve(rig_lo, sphere_lo, voxel_mm=0.5, bounds=np.zeros((2, 3)))


def _assert_backends_agree(cams, masks, **kw):
    st_a: dict = {}
    st_b: dict = {}
    a = ck.carve(cams, masks, backend="numba", stats=st_a, **kw)
    b = ck.carve(cams, masks, backend="numpy", stats=st_b, **kw)
    assert len(b.points) > 100
    assert st_a["levels"] == st_b["levels"]  # the same cells carved, inside and boundary
    np.testing.assert_array_equal(st_a["occupied_bounds"], st_b["occupied_bounds"])
    assert a.points.shape == b.points.shape
    np.testing.assert_allclose(a.points, b.points, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.normals, b.normals, rtol=0, atol=1e-9)
    assert a.faces.shape == b.faces.shape
    np.testing.assert_allclose(a.vertices, b.vertices, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(a.faces, b.faces)


def test_numba_backend_matches_numpy(rig_lo, cube_lo):
    pytest.importorskip("numba")
    _assert_backends_agree(rig_lo, cube_lo, voxel_mm=0.4)


def test_numba_backend_matches_numpy_distortion_open_border(rig_lo, sphere_lo):
    pytest.importorskip("numba")
    dist = np.array([-0.2, 0.1, 0.001, -0.001, 0.0])
    cams = [look_at(c.name, c.centre, 2000.0, 512, dist=dist) for c in rig_lo]
    ob = [i % 5 == 0 for i in range(len(cams))]
    _assert_backends_agree(cams, sphere_lo, voxel_mm=0.5, open_border=ob, mesh_voxel_mm=0.7)


def test_bad_backend(rig_lo, sphere_lo):
    with pytest.raises(ValueError):
        ck.carve(rig_lo, sphere_lo, voxel_mm=0.5, backend="cuda")


# --------------------------------------------------------------------------------------
# SDT windows, display mesh, Newton points (second optimization round)
# --------------------------------------------------------------------------------------


def _window_masks() -> dict[str, tuple[np.ndarray, bool]]:
    """Masks with the object away from / touching the border, closed and open."""
    yy, xx = np.mgrid[:96, :96]
    away = (xx - 45) ** 2 + (yy - 50) ** 2 < 18**2
    near = away | ((xx > 70) & (yy > 30) & (yy < 45))  # a bar through the right border
    corner = (xx < 20) & (yy < 12)  # in the top-left corner
    tiny = np.zeros((96, 96), bool)
    tiny[40, 60] = True
    return {"away": (away, False), "near": (near, False), "corner": (corner, False), "tiny": (tiny, False),
            "open": (near, True), "empty": (np.zeros((96, 96), bool), False)}


@pytest.mark.parametrize("name", ["away", "near", "corner", "tiny", "open", "empty"])
@pytest.mark.parametrize("margin", [1, 3, 16])
def test_signed_distance_window_is_the_whole_images(name, margin):
    mask, is_open = _window_masks()[name]
    full = ck.signed_distance(mask, open_border=is_open)
    win, u0, v0 = ck._signed_distance_window(mask, is_open, margin)
    h, w = win.shape
    assert h >= 2 and w >= 2 and 0 <= u0 and 0 <= v0 and u0 + w <= 96 and v0 + h <= 96
    if is_open:
        assert (u0, v0, w, h) == (0, 0, 96, 96)
    if mask.any():
        ys, xs = np.nonzero(mask)  # every object pixel in the window, with the margin
        assert u0 <= max(xs.min() - margin, 0) and u0 + w >= min(xs.max() + 1 + margin, 96)
        assert v0 <= max(ys.min() - margin, 0) and v0 + h >= min(ys.max() + 1 + margin, 96)
    # the same values (cv2's distance transform may differ by an ulp from call to call)
    np.testing.assert_array_max_ulp(win, full[v0 : v0 + h, u0 : u0 + w], maxulp=2)
    out = np.full(h * w, np.nan, np.float32)
    win2, _, _ = ck._signed_distance_window(mask, is_open, margin, out=out)
    assert np.shares_memory(win2, out) and not np.isnan(out).any()


@pytest.mark.parametrize("name", ["away", "near", "corner", "open"])
def test_window_classification_is_conservative_and_exact_near_the_silhouette(name):
    """Cells tested on the window: never carved where the whole image's SDT has a point
    >= 0, never inside where it has a point <= 0, and classified as on the whole image
    wherever their disk stays in the window (near the silhouette)."""
    mask, is_open = _window_masks()[name]
    cam = look_at("c", [0.0, 0.0, -60.0], 120.0, 96)
    full = ck._prepare(cam, ck.signed_distance(mask, open_border=is_open), is_open)
    win, u0, v0 = ck._signed_distance_window(mask, is_open, 3)
    v = ck._prepare(cam, win, is_open, (u0, v0))
    rng = np.random.default_rng(5)
    n_balls, n_pts = 3000, 32
    centres = np.stack([rng.uniform(-30, 30, n_balls), rng.uniform(-30, 30, n_balls), rng.uniform(-30, 30, n_balls)])
    same = 0
    for r in (0.1, 0.5, 2.0, 8.0):
        out, inn = ck._classify(v, centres, r)
        out_f, inn_f = ck._classify(full, centres, r)
        d = rng.normal(size=(3, n_balls, n_pts))
        d *= r * rng.uniform(0, 1, (1, n_balls, n_pts)) ** (1 / 3) / np.linalg.norm(d, axis=0, keepdims=True)
        d[:, :, 0] = 0.0
        f = ck._f_camera(full, (centres[:, :, None] + d).reshape(3, -1)).reshape(n_balls, n_pts)
        assert np.all(f[out] < 0) and np.all(f[inn] > 0)
        # disks inside the window: the same decisions
        u, w, z, xn, yn = ck._project(v, centres)
        rho = 2.0 * r * 120.0 / np.maximum(z - r, 1e-9)  # generous disk radius, px
        inside_win = (z > r) & (u - rho >= 0) & (u + rho <= v.W - 1) & (w - rho >= 0) & (w + rho <= v.H - 1)
        np.testing.assert_array_equal(out[inside_win], out_f[inside_win])
        np.testing.assert_array_equal(inn[inside_win], inn_f[inside_win])
        same += int(inside_win.sum())
    assert same > 50


def _carve_whole_images(monkeypatch, *args, **kw):
    """carve() with windows as large as the images (the SDT of the whole images)."""
    with monkeypatch.context() as m:
        m.setattr(ck, "_WINDOW_MARGIN_PX", 10**6)
        return ck.carve(*args, **kw)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_carve_on_windows_equals_whole_images(monkeypatch, rig_lo, sphere_lo, backend):
    if backend == "numba":
        pytest.importorskip("numba")
    c0 = rig_lo[0]
    uv, _ = c0.project(np.zeros((1, 3)))
    # camera 0 sees the sphere across its left border (closed, then open)
    cam0 = look_at("cut", c0.centre, 2000.0, 512, cx=c0.K[0, 2] - uv[0, 0] + 40.0, cy=c0.K[1, 2])
    cams = [cam0, *rig_lo[1:]]
    masks = [render_mask(sphere_mesh(), c) for c in cams]
    assert masks[0][:, 0].any()
    for ob in (None, [True] + [False] * 15):
        a = ck.carve(cams, masks, voxel_mm=0.5, open_border=ob, backend=backend)
        b = _carve_whole_images(monkeypatch, cams, masks, voxel_mm=0.5, open_border=ob, backend=backend)
        assert len(a.points) > 1000 and a.points.shape == b.points.shape
        np.testing.assert_allclose(a.points, b.points, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.normals, b.normals, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(a.faces, b.faces)
        np.testing.assert_allclose(a.vertices, b.vertices, rtol=0, atol=1e-9)


def test_carve_with_the_masks_supports_equals_without(rig_lo, sphere_lo):
    """Supports (boxes outside which each mask is False) only say where to look: the same
    hull, and a support that cuts the object is seen as such (a smaller hull)."""
    sup = []
    for m in sphere_lo:
        ys, xs = np.nonzero(m)
        sup.append((int(ys.min()) - 7, int(ys.max()) + 5, int(xs.min()) - 3, int(xs.max()) + 9))
    a = ck.carve(rig_lo, sphere_lo, voxel_mm=0.5)
    b = ck.carve(rig_lo, sphere_lo, voxel_mm=0.5, supports=sup)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.faces, b.faces)
    assert ck._object_box(sphere_lo[0], sup[0]) == ck._object_box(sphere_lo[0])
    assert ck._object_box(np.zeros((20, 30), bool), (2, 9, 3, 8)) == (0, 0, 0, 0)
    with pytest.raises(ValueError, match="2 supports for 16 masks"):
        ck.carve(rig_lo, sphere_lo, voxel_mm=0.5, supports=sup[:2])


def test_mesh_is_marching_cubes_of_the_exact_hull_function(rig_lo, sphere_lo):
    """The narrow-band grid gives the marching cubes of f evaluated on every node."""
    from skimage.measure import marching_cubes

    st: dict = {}
    rec = ck.carve(rig_lo, sphere_lo, voxel_mm=0.5, mesh_voxel_mm=0.7, stats=st)
    mv = st["mesh_voxel_mm"]
    lo, hi = st["occupied_bounds"][0] - mv, st["occupied_bounds"][1] + mv
    n = np.maximum(np.ceil((hi - lo) / mv - 1e-9).astype(np.int64) + 1, 2)
    gi = np.stack(np.meshgrid(*[np.arange(k) for k in n], indexing="ij")).reshape(3, -1)
    sdts = [ck.signed_distance(m) for m in sphere_lo]
    f = ck.hull_function(rig_lo, sdts, (lo[:, None] + gi * mv).T).reshape(tuple(n))
    vol = np.pad(np.clip(f, -1e3, 1e3).astype(np.float32), 1, constant_values=-1.0)
    verts, faces, _, _ = marching_cubes(vol, level=0.0, spacing=(mv, mv, mv))
    verts = verts + (lo - mv)
    assert st["mesh_evaluated"] < 0.3 * st["mesh_grid"]
    assert faces.shape == rec.faces.shape
    np.testing.assert_array_equal(np.sort(rec.faces, axis=1), np.sort(faces, axis=1))
    np.testing.assert_allclose(rec.vertices, verts, rtol=0, atol=1e-6)


def _exact_normals(cams, P: np.ndarray) -> np.ndarray:
    h = 1e-4
    g = np.stack([(sphere_cone_sd(cams, P + h * e) - sphere_cone_sd(cams, P - h * e)) / (2 * h) for e in np.eye(3)], 1)
    return -g / np.linalg.norm(g, axis=1, keepdims=True)


@pytest.mark.parametrize("voxel", [0.1, 0.5])
def test_normals_match_the_exact_hull(rig_hi, sphere_hi, voxel):
    """Normals within the documented accuracy (about 4.4 deg median on this sphere), the
    points on f = 0 within 0.1 % of a voxel."""
    st: dict = {}
    rec = ck.carve(rig_hi, sphere_hi, voxel_mm=voxel, stats=st)
    cos = np.einsum("ij,ij->i", rec.normals, _exact_normals(rig_hi, rec.points))
    ang = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    assert np.median(ang) < 5.0 and np.percentile(ang, 90) < 10.5 and np.percentile(ang, 99) < 17.0
    assert st["residual_mm_max"] <= 1e-3 * voxel * (1 + 1e-9)


def test_default_bounds_match_the_linear_programs(monkeypatch, rig_lo, sphere_lo, cube_lo):
    """The box from the polytope's vertices (Qhull) is the one of six linear programs."""
    ob = [i % 4 == 0 for i in range(16)]
    for masks, border in ((sphere_lo, None), (cube_lo, ob)):
        a = ck.default_bounds(rig_lo, masks, open_border=border)
        with monkeypatch.context() as m:
            m.setattr(ck, "_polytope_box", lambda *args: None)
            b = ck.default_bounds(rig_lo, masks, open_border=border)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)


def test_numba_backend_matches_numpy_without_levels(rig_lo, cube_lo):
    """The coarse cells are the finest ones (no parent level: the separate Newton kernel)."""
    pytest.importorskip("numba")
    _assert_backends_agree(rig_lo, cube_lo, voxel_mm=1.0, coarse_mm=1.0)


def test_the_display_mesh_grid_is_coarsened_to_fit_its_memory_bound(rig_lo, sphere_lo, monkeypatch):
    # A reconstruction as large as the rig (a background taken for the object) once asked
    # for a 24 GiB display grid; the grid is now capped, the points are untouched.
    st: dict = {}
    full = ck.carve(rig_lo, sphere_lo, voxel_mm=0.5, stats=st)
    assert st["mesh_voxel_mm"] == 0.5
    monkeypatch.setattr(ck, "MAX_MESH_NODES", st["mesh_grid"] // 8)
    capped: dict = {}
    rec = ck.carve(rig_lo, sphere_lo, voxel_mm=0.5, stats=capped)
    assert capped["mesh_grid"] <= st["mesh_grid"] // 8
    assert capped["mesh_voxel_mm"] > 1.0
    assert len(rec.faces) > 100 and np.array_equal(rec.points, full.points)


def test_without_the_mesh_the_same_points_and_no_mesh(rig_lo, sphere_lo):
    st: dict = {}
    full = ck.carve(rig_lo, sphere_lo, voxel_mm=0.5)
    bare = ck.carve(rig_lo, sphere_lo, voxel_mm=0.5, mesh=False, stats=st)
    assert np.array_equal(bare.points, full.points) and np.array_equal(bare.normals, full.normals)
    assert bare.vertices.shape == (0, 3) and bare.faces.shape == (0, 3) and len(full.faces) > 100
    assert st["mesh_voxel_mm"] is None and st["mesh_grid"] == 0 and st["mesh_evaluated"] == 0
