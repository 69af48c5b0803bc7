"""Simulated rig geometry and the exact anti-aliased silhouette renderer."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
import trimesh
from scipy.spatial import ConvexHull

from inspector.kernels import camera as camk
from inspector.model import Camera, Rig
from inspector_drivers.sim.render import make_scene, render_coverage, to_image
from inspector_drivers.sim.rig import (
    look_at_rotation,
    min_antipode_angle_deg,
    sphere_directions,
    sphere_rig,
)

# ------------------------------------------------------------------------ helpers


def _camera(f=4000.0, size=(512, 512), pp=None, dist=None, R=None, t=(0.0, 0.0, 400.0), name="c"):
    w, h = size
    cx, cy = pp if pp is not None else ((w - 1) / 2, (h - 1) / 2)
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
    return Camera(name, w, h, K, np.zeros(5) if dist is None else dist, np.eye(3) if R is None else R, t)


def _rot(axis, deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return trimesh.transformations.rotation_matrix(np.radians(deg), axis)


def _hull_polygon(cam: Camera, mesh: trimesh.Trimesh, densify: int = 1) -> shapely.Polygon:
    """Exact silhouette of a convex mesh: hull of the undistorted projections of its
    vertices (a pinhole maps straight edges to straight lines), each hull edge sampled
    ``densify`` times and then distorted + mapped to pixels (curved edges)."""
    Xc = mesh.vertices @ cam.R.T + cam.t
    xy = Xc[:, :2] / Xc[:, 2:3]
    hull = xy[ConvexHull(xy).vertices]
    nxt = np.roll(hull, -1, axis=0)
    s = np.arange(densify)[:, None, None] / densify
    pts = (hull[None] + s * (nxt - hull)[None]).transpose(1, 0, 2).reshape(-1, 2)
    pts = camk.distort_normalized(pts, cam.dist)
    u = cam.K[0, 0] * pts[:, 0] + cam.K[0, 2]
    v = cam.K[1, 1] * pts[:, 1] + cam.K[1, 2]
    return shapely.Polygon(np.stack([u, v], 1))


def _expected_coverage(poly: shapely.Polygon, cam: Camera, pad: int = 3):
    """Exact pixel-area fractions of ``poly`` on every in-image pixel of its bbox."""
    x0, y0, x1, y1 = poly.bounds
    us = np.arange(max(int(np.floor(x0)) - pad, 0), min(int(np.ceil(x1)) + pad + 1, cam.width))
    vs = np.arange(max(int(np.floor(y0)) - pad, 0), min(int(np.ceil(y1)) + pad + 1, cam.height))
    uu, vv = np.meshgrid(us, vs)
    boxes = shapely.box(uu - 0.5, vv - 0.5, uu + 0.5, vv + 0.5)
    return vv, uu, shapely.area(shapely.intersection(boxes, poly))


# -------------------------------------------------------------------------- rig


@pytest.fixture(scope="module")
def rig16() -> Rig:
    return sphere_rig()


def _directions(rig: Rig) -> np.ndarray:
    c = np.array([cam.centre for cam in rig])
    return c / np.linalg.norm(c, axis=1, keepdims=True)


def test_rig_basic(rig16):
    assert len(rig16) == 16
    assert rig16.names == tuple(f"cam{i:02d}" for i in range(16))
    d = _directions(rig16)
    np.testing.assert_allclose(d, sphere_directions(16, seed=0), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(sphere_directions(16), axis=1), 1.0, atol=1e-12)
    for cam in rig16:
        assert (cam.width, cam.height) == (1024, 1024)
        assert camk.is_rotation(cam.R)
        assert np.linalg.norm(cam.centre) == pytest.approx(400.0)
        assert cam.footprint_mm() == pytest.approx(0.1, rel=1e-12)
        uv, z = cam.project(np.zeros((1, 3)))
        np.testing.assert_allclose(uv[0], [511.5, 511.5], atol=1e-9)
        assert z[0] == pytest.approx(400.0)
        # optical axis points at the origin
        np.testing.assert_allclose(cam.R[2], -cam.centre / 400.0, atol=1e-12)
    assert rig16.footprint_mm() == pytest.approx(0.1)


def test_rig_no_antipodal_pairs(rig16):
    d = _directions(rig16)
    ang = min_antipode_angle_deg(d)
    assert ang > 35.0  # documented: ~37 deg for n=16, seed=0
    # brute force cross-check of the helper
    brute = min(
        np.degrees(np.arccos(np.clip(d[i] @ -d[j], -1, 1))) for i in range(16) for j in range(16) if i != j
    )
    assert ang == pytest.approx(brute)
    # and cameras are not bunched either
    c = d @ d.T
    np.fill_diagonal(c, -1)
    assert np.degrees(np.arccos(c.max())) > 35.0
    # the helper does detect an antipodal pair
    assert min_antipode_angle_deg(np.array([[0, 0, 1.0], [1, 0, 0], [0, 0, -1]])) == pytest.approx(0.0, abs=1e-6)


def test_rig_balanced_over_the_sphere(rig16):
    d = _directions(rig16)
    assert np.linalg.norm(d.sum(axis=0)) < 0.5  # of a possible 16
    # not all in one (closed) hemisphere <=> origin strictly inside the hull of directions
    hull = ConvexHull(d)
    assert np.all(hull.equations[:, 3] < -0.3)
    for k in range(3):  # both sides of every coordinate plane
        assert np.sum(d[:, k] > 0.1) >= 4 and np.sum(d[:, k] < -0.1) >= 4


def test_rig_parameters_and_determinism():
    a = sphere_rig(8, radius_mm=300.0, width=640, height=480, mm_per_px=0.05, dist=[0.1, 0.01], seed=3)
    b = sphere_rig(8, radius_mm=300.0, width=640, height=480, mm_per_px=0.05, dist=[0.1, 0.01], seed=3)
    c = sphere_rig(8, radius_mm=300.0, width=640, height=480, mm_per_px=0.05, seed=4)
    for ca, cb in zip(a, b):
        np.testing.assert_array_equal(ca.R, cb.R)
        np.testing.assert_array_equal(ca.t, cb.t)
    assert not np.allclose(a.cameras[0].R, c.cameras[0].R)
    cam = a.cameras[0]
    assert cam.K[0, 0] == pytest.approx(6000.0) and cam.K[1, 1] == pytest.approx(6000.0)
    np.testing.assert_allclose(cam.K[:2, 2], [319.5, 239.5])
    np.testing.assert_allclose(cam.dist, [0.1, 0.01, 0, 0, 0])
    assert cam.footprint_mm() == pytest.approx(0.05)
    assert min_antipode_angle_deg(_directions(a)) > 45.0
    assert not np.any(c.cameras[0].dist)


def test_look_at_rotation_proper_everywhere():
    for d in ([0, 0, 1.0], [0, 0, -1.0], [1, 0, 0], [0.3, -0.2, 0.93]):
        d = np.array(d) / np.linalg.norm(d)
        for roll in (0.0, 1.0, -2.5):
            R = look_at_rotation(d, roll)
            assert camk.is_rotation(R)
            np.testing.assert_allclose(R[2], -d, atol=1e-12)


# --------------------------------------------------------------------- renderer


@pytest.fixture(scope="module")
def sphere_render():
    """A fine sphere (r = 10 mm) at the origin seen from 400 mm by 2 rig cameras."""
    r = 10.0
    mesh = trimesh.creation.icosphere(subdivisions=6, radius=r)
    rig = sphere_rig(width=256, height=256)
    rig = Rig(rig.cameras[:2])
    return r, mesh, rig, render_coverage(mesh, rig)


def test_render_output_format(sphere_render):
    _, _, rig, cov = sphere_render
    assert set(cov) == set(rig.names)
    for c in cov.values():
        assert c.dtype == np.float32 and c.shape == (256, 256)
        assert c.min() >= 0.0 and c.max() <= 1.0
        assert np.any((c > 0.01) & (c < 0.99))  # anti-aliased edge


def test_sphere_area_matches_analytic_disc(sphere_render):
    r, mesh, rig, cov = sphere_render
    for cam in rig:
        d = np.linalg.norm(cam.centre)
        f = cam.K[0, 0]
        R_img = f * r / np.sqrt(d * d - r * r)  # ~100 px
        disc = np.pi * R_img**2
        total = float(cov[cam.name].sum(dtype=np.float64))
        assert total == pytest.approx(disc, rel=5e-4)
        # The icosphere is inscribed in the sphere: its silhouette (the hull of the
        # projected vertices, exact for a convex mesh) is ~1e-4 smaller than the disc,
        # which is why the tight check is against the mesh's own silhouette.
        poly = _hull_polygon(cam, mesh)
        assert poly.area == pytest.approx(disc, rel=2e-4)
        assert total == pytest.approx(poly.area, rel=2e-5)


def test_sphere_edge_crossing_along_centre_row(sphere_render):
    r, _, rig, cov = sphere_render
    for cam in rig:
        d = np.linalg.norm(cam.centre)
        f, cx, cy = cam.K[0, 0], cam.K[0, 2], cam.K[1, 2]
        R_img = f * r / np.sqrt(d * d - r * r)
        row = int(np.floor(cy))  # 127; cy = 127.5
        prof = cov[cam.name][row].astype(float)
        # exact mean half-chord over the pixel row [row - 0.5, row + 0.5]
        ys = np.linspace(row - 0.5 - cy, row + 0.5 - cy, 2001)
        half = np.sqrt(R_img**2 - ys**2).mean()
        # the 0.5-crossing of the box-filtered profile = start of a fully covered run +
        # the summed coverage beyond it (exact for a straight edge across the row)
        inner = int(round(cx))
        assert prof[inner - 90 : inner + 91].min() == 1.0
        right = inner - 0.5 + prof[inner:].sum()
        left = inner + 0.5 - prof[: inner + 1].sum()
        assert right == pytest.approx(cx + half, abs=0.02)
        assert left == pytest.approx(cx - half, abs=0.02)
        # and the profile crosses 0.5 between the two pixels around the edge
        ur = int(np.floor(cx + half + 0.5))
        assert prof[ur - 1] >= 0.5 >= prof[ur + 1]


@pytest.mark.parametrize(
    "transform",
    [
        # generic: tilted and turned
        _rot([1, 0.3, 0], 55) @ _rot([0, 0, 1], 23),
        # near-axis-aligned edges (worst case for plain point sampling) and a tilt
        _rot([1, 0, 0], 50) @ _rot([0, 0, 1], 0.3),
    ],
    ids=["generic", "near-axis-aligned"],
)
def test_planar_square_edge_fractions(transform):
    mesh = trimesh.creation.box((30.0, 30.0, 0.02))
    mesh.apply_transform(transform)
    cam = _camera(pp=(250.3, 260.7))
    cov = render_coverage(mesh, Rig((cam,)))["c"]
    poly = _hull_polygon(cam, mesh)
    vv, uu, exp = _expected_coverage(poly, cam)
    got = cov[vv, uu]
    straddle = (exp > 0.01) & (exp < 0.99)
    assert straddle.sum() > 500
    assert np.abs(got - exp)[straddle].max() < 0.02
    assert np.abs(got - exp).max() < 0.02  # everywhere, corners included
    # nothing outside the silhouette's bounding box
    assert cov.sum() == pytest.approx(got.sum())


def test_silhouette_cut_by_image_border():
    mesh = trimesh.creation.box((30.0, 30.0, 0.02))
    mesh.apply_transform(_rot([1, 0.3, 0], 55) @ _rot([0, 0, 1], 23))
    cam = _camera(size=(200, 160), pp=(20.4, 150.2))  # the square spills over 2 borders
    cov = render_coverage(mesh, Rig((cam,)))["c"]
    vv, uu, exp = _expected_coverage(_hull_polygon(cam, mesh), cam)
    assert np.abs(cov[vv, uu] - exp).max() < 0.02
    assert cov[:, 0].max() == 1.0 and cov[-1, :].max() == 1.0


def test_object_outside_or_behind():
    mesh = trimesh.creation.box((10.0, 10.0, 10.0))
    behind = _camera(size=(64, 64), t=(0.0, 0.0, -400.0))
    aside = _camera(size=(64, 64), t=(200.0, 0.0, 400.0), name="d")
    cov = render_coverage(mesh, Rig((behind, aside)))
    assert cov["c"].max() == 0.0 and cov["d"].max() == 0.0


def test_straddling_the_camera_plane():
    """A vertex behind the camera disables the crop; the visible part is still right."""
    mesh = trimesh.creation.box((400.0, 400.0, 0.02))  # a wall, perpendicular to x
    mesh.apply_transform(_rot([0, 1, 0], 90))
    mesh.apply_translation([4.0, 0.0, 0.0])
    cam = _camera(size=(64, 48), f=100.0, t=(0.0, 0.0, 0.0))
    cov = render_coverage(mesh, Rig((cam,)))["c"]
    # visible part: 0 < z <= 200, x = 3.99 -> u = cx + f * 3.99 / z >= cx + 1.995
    cx = cam.K[0, 2]  # 31.5: the edge is at u = 33.495
    assert cov[:, :33].max() == 0.0
    np.testing.assert_allclose(cov[:, 33], 0.005, atol=0.002)
    assert cov[:, 34:].min() == 1.0
    assert cx == 31.5


def test_distortion_matches_projection():
    f = 1000.0
    dist = np.array([-0.25, 0.08, 0.001, -0.0015, 0.0])
    cam = _camera(f=f, size=(512, 512), pp=(255.5, 255.5), dist=dist)
    plain = _camera(f=f, size=(512, 512), pp=(255.5, 255.5), name="plain")

    # a small sphere far off-axis: the coverage centroid is the projection of its centre
    centre = np.array([0.18, -0.12, 1.0]) * 400.0 - [0, 0, 400.0]
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=4.0)
    sphere.apply_translation(centre)
    cov = render_coverage(sphere, Rig((cam, plain)))
    uv_d, _ = cam.project(centre[None])
    uv_p, _ = plain.project(centre[None])
    shift = np.linalg.norm(uv_d - uv_p)
    assert shift > 2.0  # the lens moves the blob by a few pixels
    for name, uv in (("c", uv_d), ("plain", uv_p)):
        c = cov[name].astype(float)
        vv, uu = np.mgrid[: c.shape[0], : c.shape[1]]
        cen = np.array([(c * uu).sum(), (c * vv).sum()]) / c.sum()
        assert np.linalg.norm(cen - uv[0]) < 0.1

    # a cube off-axis: pixel fractions of its curved (distorted) silhouette
    cube = trimesh.creation.box((40.0, 40.0, 40.0))
    cube.apply_transform(_rot([1, 2, 3], 40))
    cube.apply_translation([-60.0, 50.0, 0.0])
    cov = render_coverage(cube, Rig((cam,)))["c"]
    poly = _hull_polygon(cam, cube, densify=64)
    vv, uu, exp = _expected_coverage(poly, cam)
    assert np.abs(cov[vv, uu] - exp).max() < 0.02
    assert cov.sum(dtype=np.float64) == pytest.approx(poly.area, rel=1e-4)
    # the silhouette's vertices are the distorted projections of mesh vertices
    uv, _ = cam.project(cube.vertices)
    ext = np.asarray(poly.exterior.coords)
    on_hull = [np.min(np.linalg.norm(ext - p, axis=1)) < 1e-6 for p in uv]
    assert sum(on_hull) >= 5


def test_scene_reuse_and_supersample():
    mesh = trimesh.creation.box((20.0, 20.0, 20.0))
    mesh.apply_transform(_rot([1, 1, 0], 30))
    cam = _camera(size=(320, 320))
    rig = Rig((cam,))
    a = render_coverage(mesh, rig)["c"]
    b = render_coverage(mesh, rig, scene=make_scene(mesh))["c"]
    np.testing.assert_array_equal(a, b)
    c = render_coverage(mesh, rig, supersample=4)["c"]
    vv, uu, exp = _expected_coverage(_hull_polygon(cam, mesh), cam)
    err8 = np.abs(a[vv, uu] - exp).max()
    err4 = np.abs(c[vv, uu] - exp).max()
    assert err8 < 0.01 and err4 < 0.05


# ---------------------------------------------------------------------- to_image


def test_to_image_levels_8bit():
    cov = np.array([[0.0, 0.5, 1.0, 0.25]], np.float32)
    img = to_image(cov, rng=np.random.default_rng(0), noise_sigma=0.0)
    assert img.dtype == np.uint8
    np.testing.assert_array_equal(img, [[200, 120, 40, 160]])
    bright = to_image(cov, rng=np.random.default_rng(0), noise_sigma=0.0, background=40, foreground=200)
    np.testing.assert_array_equal(bright, [[40, 120, 200, 80]])


def test_to_image_noise_and_clipping():
    cov = np.zeros((256, 256), np.float32)
    img = to_image(cov, rng=np.random.default_rng(1), noise_sigma=2.0).astype(float)
    assert img.mean() == pytest.approx(200.0, abs=0.05)
    assert img.std() == pytest.approx(np.sqrt(2.0**2 + 1 / 12), rel=0.03)  # + rounding
    again = to_image(cov, rng=np.random.default_rng(1), noise_sigma=2.0)
    np.testing.assert_array_equal(again, img.astype(np.uint8))
    hot = to_image(cov, rng=np.random.default_rng(2), background=250.0, noise_sigma=20.0)
    assert hot.max() == 255 and hot.min() > 150  # clipped, no wrap-around
    assert np.mean(hot == 255) > 0.3


def test_to_image_impulses():
    cov = np.full((200, 200), 0.5, np.float32)
    img = to_image(cov, rng=np.random.default_rng(3), noise_sigma=0.0, impulse_fraction=0.05)
    salt = img == 255
    pepper = img == 0
    assert (salt | pepper).sum() == 2000
    assert 800 < salt.sum() < 1200
    assert np.all(img[~(salt | pepper)] == 120)


def test_to_image_16bit():
    cov = np.zeros((256, 256), np.float32)
    cov[:, 128:] = 1.0
    img = to_image(cov, rng=np.random.default_rng(4), noise_sigma=2.0, bit_depth=16, impulse_fraction=0.01)
    assert img.dtype == np.uint16
    bg = img[:, :128].astype(float)
    fg = img[:, 128:].astype(float)
    ok_bg = (bg > 0) & (bg < 65535)
    ok_fg = (fg > 0) & (fg < 65535)
    assert np.median(bg[ok_bg]) == pytest.approx(200 * 257, abs=20)
    assert np.median(fg[ok_fg]) == pytest.approx(40 * 257, abs=20)
    assert bg[ok_bg].std() == pytest.approx(2.0 * 257, rel=0.05)
    assert ((img == 0) | (img == 65535)).sum() == round(0.01 * img.size)
    exact = to_image(cov, rng=np.random.default_rng(4), noise_sigma=0.0, bit_depth=16)
    assert set(np.unique(exact)) == {40 * 257, 200 * 257}
    with pytest.raises(ValueError):
        to_image(cov, rng=np.random.default_rng(0), bit_depth=12)
