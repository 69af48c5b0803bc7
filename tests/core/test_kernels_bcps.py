"""BCPS kernels against analytic cases: a sphere seen by a ring of cameras."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest

from inspector.kernels import bcps as bk
from inspector.kernels.silhouette import inside_map
from inspector.model import Camera


def _look_at(centre):
    z = -centre / np.linalg.norm(centre)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ centre


def sphere_views(radius=10.0, n=6, size=256, f=1000.0, dist=400.0, ss=8, dist_coeffs=None, only=None):
    """Cameras around the origin and exact anti-aliased sphere silhouettes (as inside-maps);
    ``only``: just that camera's view."""
    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    views = []
    for i, d in enumerate(dirs):
        if only is not None and i != only:
            continue
        R, t = _look_at(d * dist)
        K = np.array([[f, 0, (size - 1) / 2], [0, f, (size - 1) / 2], [0, 0, 1]])
        cam = Camera(f"c{i}", size, size, K, dist_coeffs if dist_coeffs is not None else np.zeros(5), R, t)
        # coverage by supersampling rays against the analytic sphere
        off = (np.arange(ss) + 0.5) / ss - 0.5
        uu, vv = np.meshgrid(np.arange(size, dtype=float), np.arange(size, dtype=float))
        cov = np.zeros((size, size))
        for dy in off:
            for dx in off:
                uv = np.stack([(uu + dx).ravel(), (vv + dy).ravel()], axis=1)
                o, rd = cam.rays(uv)
                tc = rd @ (-o)
                miss = np.linalg.norm(o + tc[:, None] * rd, axis=1)
                cov += (miss <= radius).reshape(size, size)
        views.append(bk.View(cam, inside_map((cov / ss**2).astype(np.float32))))
    return views


@pytest.fixture(scope="module")
def views():
    return sphere_views()


def test_numba_kernel_matches_numpy_reference(views):
    from inspector.kernels.hull_jit import CLAMP_PX, stack_views, violation

    rng = np.random.default_rng(0)
    X = rng.uniform(-14, 14, size=(5000, 3))
    ref = bk.hull_violation(X, views, skip=2)
    jit = violation(X, stack_views(views), skip=2)
    # exact up to CLAMP_PX - 1.5 px (the compiled maps are clamped beyond), at least that beyond
    exact = ref < CLAMP_PX - 1.5
    assert exact.mean() > 0.3 and (~exact).sum() > 100
    assert np.allclose(ref[exact], jit[exact], atol=1e-4)
    assert np.all(jit[~exact] >= CLAMP_PX - 1.5)
    limited = violation(X, stack_views(views), limit=1.0, skip=2)
    assert np.all((limited > 1.0) == (ref > 1.0))


def test_sphere_hull_membership(views):
    rng = np.random.default_rng(1)
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    inside = bk.hull_membership(d * 9.9, views, 0.0)
    assert inside.all()
    # 6 views leave bulges between their cones: most points 0.6 mm out are outside, all at 15 mm.
    assert (bk.hull_violation(d * 10.6, views) > 0).mean() > 0.8
    assert np.all(bk.hull_violation(d * 15.0, views) > 1.0)


@pytest.mark.parametrize("scale", [0.97, 1.0])
@pytest.mark.parametrize("use_jit", [True, False])
def test_ray_selection_finds_the_rim_of_a_sphere(views, scale, use_jit):
    """Reference = sphere of radius 10/scale: BCPS points lie on the true sphere (radius 10),
    and their signed deviation is the true difference of radii."""
    from inspector.kernels.hull_jit import stack_views

    r_ref = 10.0 / scale
    cam = views[0].camera
    # exact sub-pixel contour: project rim points of the true sphere
    c = cam.centre
    dcen = np.linalg.norm(c)
    axis = -c / dcen
    rim_r = 10.0 * np.sqrt(dcen**2 - 100.0) / dcen
    rim_c = c + axis * (dcen - 100.0 / dcen)
    e1 = np.cross(axis, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    ang = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    rim = rim_c + rim_r * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2)
    uv, _ = cam.project(rim)
    origin, dirs = cam.rays(uv)

    def sd(X):
        return np.linalg.norm(X, axis=1) - r_ref

    bounds = np.array([[-12.0] * 3, [12.0] * 3])
    pts, dev, seg, ok = bk.select_on_rays(
        origin, dirs, views, 0, sd, bounds, step_mm=0.25, stack=stack_views(views) if use_jit else None
    )
    assert ok.mean() > 0.95
    err = np.abs(np.linalg.norm(pts[ok], axis=1) - 10.0)
    px = 400.0 / 1000.0  # mm per px at the centre
    assert err.mean() < 0.05 * px, err.mean()
    assert np.allclose(dev[ok], 10.0 - r_ref, atol=0.1 * px)
    assert np.all(seg[ok] > 0)


def test_surface_selection_takes_the_signed_minimum():
    cam = Camera("c", 10, 10, np.array([[10.0, 0, 4.5], [0, 10.0, 4.5], [0, 0, 1]]), np.zeros(5), np.eye(3), np.array([0, 0, 100.0]))
    # three points on the ray through pixel (5, 5) at different depths, one elsewhere
    pts = np.array([[0.05, 0.05, 0.0], [0.1, 0.1, 10.0], [0.0, 0.0, -10.0], [-3.0, -3.0, 0.0]])
    pts[:3, :2] = (np.array([5.0, 5.0]) - 4.5) / 10.0 * (pts[:3, 2:3] + 100.0)
    sd = np.array([0.3, -0.2, 0.1, -5.0])
    contour = np.zeros((10, 10), bool)
    contour[5, 5] = True
    idx, pix, seg, dev = bk.select_on_surface(pts, sd, cam, contour)
    assert list(idx) == [1] and dev[0] == -0.2 and tuple(pix[0]) == (5.0, 5.0)
    assert seg[0] == pytest.approx(20.0)


def test_confidence_from_segment_length():
    c = bk.confidence(np.array([0.0, 1.0, 9.0]), 0.1)
    assert np.allclose(c, [1.0, 0.5, 0.1])


def _rim_rays(cam, n, radius=10.0, noise=0.0, seed=0):
    """Rays of camera ``cam`` through the sphere's rim (``noise`` px on the contour)."""
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    axis = -cam.centre / np.linalg.norm(cam.centre)
    e1 = np.cross(axis, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    uv, _ = cam.project(radius * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2))
    uv += np.random.default_rng(seed).normal(scale=noise, size=uv.shape)
    return cam.rays(uv)


@pytest.mark.parametrize("band_mm", [None, 0.3])
@pytest.mark.parametrize("segments", [True, False])
def test_compiled_search_equals_numpy_search(views, band_mm, segments):
    """The fused per-ray kernel selects exactly what the level-by-level numpy search does
    (with a narrow band some rays leave it and take the numpy path), also when it skips
    measuring the segments (``segments=False``: the coarse samples tested by distance)."""
    import trimesh

    from inspector.kernels.hull_jit import stack_views
    from inspector.kernels.meshdist import MeshDistance

    ref = trimesh.creation.icosphere(subdivisions=4, radius=10.2)
    md = MeshDistance(ref.vertices, ref.faces, band_mm=band_mm)
    if band_mm is not None:
        import open3d as o3d

        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(np.asarray(ref.vertices, np.float32)), o3d.core.Tensor(np.asarray(ref.faces, np.uint32)))
        calls = []

        def fallback(X):
            calls.append(len(X))
            return scene.compute_signed_distance(o3d.core.Tensor(X.astype(np.float32))).numpy().astype(float)

        md.fallback = fallback
    pose = np.eye(4)
    pose[:3, 3] = [0.05, -0.03, 0.02]
    angle = 0.01
    pose[:3, :3] = [[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]]

    def sd(X):
        return md((X - pose[:3, 3]) @ pose[:3, :3])

    origin, dirs = _rim_rays(views[1].camera, 300)
    bounds = np.array([[-12.0] * 3, [12.0] * 3])
    stack = stack_views(views)
    kw = dict(step_mm=0.25, refine_levels=3, stack=stack)
    a = bk.select_on_rays(origin, dirs, views, 1, sd, bounds, **kw)
    b = bk.select_on_rays(origin, dirs, views, 1, sd, bounds, mesh=md, pose=pose, segments=segments, **kw)
    assert a[3].mean() > 0.8
    np.testing.assert_array_equal(a[3], b[3])
    np.testing.assert_allclose(b[0], a[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(b[1], a[1], rtol=0, atol=1e-12)
    if segments:
        np.testing.assert_allclose(b[2], a[2], rtol=0, atol=1e-12)
    else:
        assert np.isnan(b[2]).all()
    if band_mm is not None:
        assert sum(calls) > 0  # some rays left the band and took the numpy path


class _FourCameras(NamedTuple):
    md: object  # MeshDistance of the box, 0.6 mm band
    views: list
    stack: object
    bounds: np.ndarray
    rays: list  # (camera, Rays)
    calls: list  # sizes of the exact fallback's calls


def _four_cameras(views):
    """Rim rays of cameras 4 (nearer than the others: its bound of the projection's rate,
    and with it its tolerance and violation weight, differ from theirs), 0, 2 and 5 (every
    7th range empty) and of camera 1 (none), around a box whose distance index's narrow
    band some of them leave (the exact fallback counts its calls)."""
    import trimesh

    from inspector.kernels.hull_jit import stack_views
    from inspector.kernels.meshdist import MeshDistance

    ref = trimesh.creation.box(extents=(19.0, 20.5, 19.5))
    md = MeshDistance(ref.vertices, ref.faces, band_mm=0.6)
    views = [*views[:4], *sphere_views(dist=300.0, only=4), *views[5:]]
    rays = []
    for k, i in enumerate([4, 0, 2, 5]):
        origin, dirs = _rim_rays(views[i].camera, 150 + 40 * k, noise=0.3, seed=k)
        near = np.linalg.norm(origin)
        t0, t1 = np.full(len(dirs), near - 20.0), np.full(len(dirs), near + 20.0)
        t1[::7] = t0[::7] - 1.0  # an empty range
        rays.append((i, bk.Rays(origin, dirs, t0, t1)))
    rays.append((1, bk.Rays(views[1].camera.centre, np.zeros((0, 3)), np.zeros(0), np.zeros(0))))
    calls = []

    def box_distance(X):  # exact, beyond the band
        calls.append(len(X))
        q = np.abs(X) - np.array([19.0, 20.5, 19.5]) / 2
        return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)

    md.fallback = box_distance
    return _FourCameras(md, views, stack_views(views), np.array([[-12.0] * 3, [12.0] * 3]), rays, calls)


def _placed(md, shift):
    """The pose (4, 4) of the reference moved by ``shift`` mm, and its signed distance."""
    pose = np.eye(4)
    pose[:3, 3] = shift
    return pose, lambda X: md(X - pose[:3, 3])


@pytest.mark.parametrize("segments", [True, False])
def test_all_cameras_in_one_call_select_what_each_camera_alone_selects(views, segments):
    """One compiled call for several cameras' rays (each skipping its own silhouette, with its
    own bound and weight) gives each camera exactly what a call for that camera alone gives;
    rays that leave the distance index's band take the numpy path, camera by camera; a
    camera without rays and rays with an empty range give no point."""
    s = _four_cameras(views)
    pose, sd = _placed(s.md, [0.1, -0.05, 0.0])
    kw = dict(step_mm=0.25, refine_levels=3, stack=s.stack, mesh=s.md, pose=pose, segments=segments)
    together = bk.select_on_camera_rays(s.rays, s.views, sd, s.bounds, **kw)
    assert sum(s.calls) > 0  # some rays left the band
    assert len(together) == len(s.rays)
    for (i, r), got in zip(s.rays, together):
        alone = bk.select_on_rays(r.origin, r.dirs, s.views, i, sd, s.bounds, t_range=(r.t0, r.t1), **kw)
        for a, b in zip(alone, got):
            np.testing.assert_array_equal(b, a)
        if len(r.dirs):
            assert got[3].mean() > 0.5 and not got[3][::7].any()
    assert len(together[-1][0]) == 0


@pytest.mark.parametrize("segments", [True, False])
def test_coarse_samples_hull_tested_once_select_what_testing_them_selects(views, segments):
    """The coarse samples hull-tested once (:func:`coarse_hull`) and read by selections at
    two poses, on all the rays and on a sparse take of them, give exactly what testing them
    gives (rays leaving the band still take the numpy path). The table is read: emptied, no
    ray has a point. One made for another step is refused."""
    s = _four_cameras(views)
    tables = bk.coarse_hull(s.rays, s.views, s.bounds, s.stack, step_mm=0.25, accept_px=0.2)  # the stage's
    assert np.isfinite(tables[0].values).any() and not np.isfinite(tables[0].values).all()
    for shift in ([0.1, -0.05, 0.0], [-0.4, 0.3, 0.2]):
        pose, sd = _placed(s.md, shift)
        kw = dict(step_mm=0.25, refine_levels=3, accept_px=0.2, stack=s.stack, mesh=s.md, pose=pose, segments=segments)
        for rows in (slice(None), slice(1, None, 3)):
            rays = [(i, r.take(rows)) for i, r in s.rays]
            tested = bk.select_on_camera_rays(rays, s.views, sd, s.bounds, **kw)
            del s.calls[:]
            read = bk.select_on_camera_rays(rays, s.views, sd, s.bounds, coarse=[t.take(rows) for t in tables], **kw)
            assert sum(s.calls) > 0
            for a, b in zip(tested, read):
                for x, y in zip(a, b):
                    np.testing.assert_array_equal(y, x)
            assert sum(int(r[3].sum()) for r in read) > 100
    rejected = np.full_like(tables[0].values, np.inf)
    empty = [t._replace(values=rejected) for t in tables]
    got = bk.select_on_camera_rays(s.rays, s.views, sd, s.bounds, coarse=empty, **kw)
    assert not any(r[3].any() for r in got)
    with pytest.raises(ValueError, match="camera 4: its coarse hull table was made for another step"):
        bk.select_on_camera_rays(s.rays, s.views, sd, s.bounds, coarse=tables, **{**kw, "step_mm": 0.3})


def test_search_by_distance_selects_what_the_scan_selects(views):
    """Without the segments' lengths the compiled search tests the coarse samples by
    increasing distance and stops where none left can win: the same points as the full
    scan, also where contours off the true rim (0.4 px of noise) leave only penalised
    candidates on many rays and a reference off the sphere puts the best elsewhere."""
    import trimesh

    from inspector.kernels.hull_jit import stack_views
    from inspector.kernels.meshdist import MeshDistance

    ref = trimesh.creation.box(extents=(19.0, 20.5, 19.5))  # not the sphere: minima along the rays vary
    md = MeshDistance(ref.vertices, ref.faces)
    pose = np.eye(4)

    def sd(X):
        return md(X)

    origin, dirs = _rim_rays(views[2].camera, 400, noise=0.4, seed=7)
    bounds = np.array([[-12.0] * 3, [12.0] * 3])
    kw = dict(step_mm=0.25, refine_levels=3, stack=stack_views(views), mesh=md, pose=pose, tolerance_px=0.05)
    full = bk.select_on_rays(origin, dirs, views, 2, sd, bounds, **kw)
    fast = bk.select_on_rays(origin, dirs, views, 2, sd, bounds, segments=False, **kw)
    assert full[3].mean() > 0.5
    np.testing.assert_array_equal(fast[3], full[3])
    np.testing.assert_array_equal(fast[0], full[0])
    np.testing.assert_array_equal(fast[1], full[1])
    assert np.isnan(fast[2]).all() and np.isfinite(full[2][full[3]]).all()


def test_compiled_ray_ranges_equal_numpy(views):
    cam = views[0].camera
    rng = np.random.default_rng(5)
    pts = rng.normal(size=(4000, 3))
    pts = 10.0 * pts / np.linalg.norm(pts, axis=1, keepdims=True)
    uv = rng.uniform(95, 160, size=(500, 2))
    origin, dirs = cam.rays(uv)
    a = bk.ray_ranges(cam, uv, origin, dirs, pts, 1.0)
    b = bk.ray_ranges(cam, uv, origin, dirs, pts, 1.0, compiled=True)
    assert np.isfinite(a[0]).mean() > 0.3 and (~np.isfinite(a[0])).sum() > 10
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def test_a_true_point_in_a_hull_sliver_thinner_than_the_coarse_step_is_found(views, monkeypatch):
    """One ray along z: its true point (sd 0) sits in a 20 um sliver of the hull whose coarse
    neighbours are penalised, while a wide hull region 3 mm on is 0.15 mm out. The coarse
    round prefers the wide region; refining from the deepest accepted sample too finds the
    true point (the binary shaft's false reject)."""
    others = [v for i, v in enumerate(views) if i != 0]
    bounds = np.array([[-1.0, -1.0, 0.0], [1.0, 1.0, 12.0]])
    lip = max(bk._view_speeds(others, bounds))
    centre, wide = 5.125, (8.0, 10.0)  # coarse samples at 5.0 and 5.25: 0.125 mm from the sliver

    def gap(t):
        return np.maximum(0.0, np.maximum(wide[0] - t, t - wide[1]))

    def fake_violation(X, views, limit=np.inf, skip=-1):
        t = X[:, 2]
        return np.minimum(lip * np.maximum(0.0, np.abs(t - centre) - 0.01), lip * gap(t))

    def sd(X):
        t = X[:, 2]
        return np.minimum(np.abs(t - centre), 0.15 + gap(t))

    monkeypatch.setattr(bk, "hull_violation", fake_violation)
    pts, dev, seg, ok = bk.select_on_rays(np.zeros(3), np.array([[0.0, 0.0, 1.0]]), views, 0, sd, bounds,
                                          step_mm=0.25, refine_levels=3)
    assert ok[0]
    assert abs(pts[0, 2] - centre) < 0.01 and dev[0] < 0.005, (pts[0], dev[0])


def test_ray_min_distance_is_the_silhouette_residual_of_a_sphere():
    """Rays passing a sphere of radius 10 at known distances from its centre: the smallest
    signed distance along each is that distance minus the radius (a ray through the sphere
    goes as deep as its closest approach)."""
    origin = np.array([0.0, 0.0, -100.0])
    offsets = np.array([7.0, 9.5, 9.99, 10.0, 10.03, 10.4, 12.0])
    targets = np.stack([offsets, np.zeros_like(offsets), np.zeros_like(offsets)], axis=1)
    dirs = targets - origin
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    closest = np.linalg.norm(np.cross(dirs, -origin), axis=1)  # distance of the centre from each ray
    sd = lambda X: np.linalg.norm(X, axis=1) - 10.0  # noqa: E731
    t0, t1 = np.full(len(dirs), 80.0), np.full(len(dirs), 120.0)
    r = bk.ray_min_distance(origin, dirs, t0, t1, sd, step_mm=0.25, levels=3)
    np.testing.assert_allclose(r, closest - 10.0, atol=2e-4)
    # No range: NaN; a far range: the distance there, not the closest approach.
    t0[0], t1[0] = 1.0, 0.0
    t0[1], t1[1] = 20.0, 50.0
    r = bk.ray_min_distance(origin, dirs, t0, t1, sd)
    assert np.isnan(r[0]) and r[1] > 5.0
    # NaN from the distance (beyond an index's band) counts as far, not as a minimum.
    r = bk.ray_min_distance(origin, dirs[2:3], t0[2:3], t1[2:3], lambda X: np.where(sd(X) > 1.0, np.nan, sd(X)))
    assert abs(r[0] - (closest[2] - 10.0)) < 1e-3
    with pytest.raises(ValueError, match="one row per ray"):
        bk.ray_min_distance(origin, dirs, t0[:2], t1, sd)
    with pytest.raises(ValueError, match="step_mm"):
        bk.ray_min_distance(origin, dirs, t0, t1, sd, step_mm=0.0)


def test_cropped_maps_hold_the_whole_maps_numbers(views):
    """Issue 26: the compiled kernels' inside-maps are stored cropped to each silhouette's
    neighbourhood; put back in a whole image they are exactly the whole maps (a silhouette
    in the middle, one touching the border, an empty one), and the kernel reads the same
    violations as from whole maps (the padded layout of before)."""
    from inspector.kernels.hull_jit import _with_depth, _with_depth_crop, stack_views, violation
    from inspector.kernels.silhouette import inside_map

    soft = np.zeros((120, 160), np.float32)
    soft[0:30, 40:90] = 1.0  # touches the top border
    soft[30, 40:90] = 0.4
    empty = np.zeros((50, 60), np.float32)
    insides = [v.inside for v in views] + [inside_map(soft), inside_map(empty)]
    for inside in insides:
        whole = np.empty(inside.shape, np.float32)
        _with_depth(inside, whole)
        crop, y0, x0, fill = _with_depth_crop(inside)
        back = np.full(inside.shape, -float(fill), np.float32)
        back[y0:y0 + crop.shape[0], x0:x0 + crop.shape[1]] = crop
        np.testing.assert_array_equal(back, whole)
    crop, *_ = _with_depth_crop(views[0].inside)
    assert crop.size < 0.2 * views[0].inside.size  # the sphere's neighbourhood, not the image
    stack = stack_views(views)
    assert stack.maps.shape[1] * stack.maps.shape[2] < 0.2 * views[0].inside.size
    rng = np.random.default_rng(3)
    X = rng.uniform(-14, 14, size=(4000, 3))
    # the whole maps, as the kernel read them before (one crop = the whole image)
    H, W = views[0].inside.shape
    whole = stack_views(views)
    whole.maps = np.empty((len(views), H, W), np.float32)
    for i, v in enumerate(views):
        _with_depth(v.inside, whole.maps[i])
        whole.sizes[i] = (W, H, 0, 0, W, H, 0)
    np.testing.assert_array_equal(violation(X, stack, skip=2), violation(X, whole, skip=2))


def test_maps_packed_from_their_regions_equal_the_whole_maps_packed(views):
    """Issue 26: the bcps stage packs each inside-map from its computed region
    (:func:`inside_region`), never writing the whole image; the packed maps, their layout
    and the violations read are those packed from the whole maps, and a region put back in
    its image is the whole map (a silhouette in the middle, one touching the border, an
    empty one)."""
    from inspector.kernels.hull_jit import _with_depth_crop, stack_views, violation
    from inspector.kernels.silhouette import InsideRegion, inside_map, inside_region

    soft = np.zeros((120, 160), np.float32)
    soft[0:30, 40:90] = 1.0  # touches the top border
    soft[30, 40:90] = 0.4
    soft[60:70, 10:20] = 0.7
    empty = np.zeros((50, 60), np.float32)
    for s in (soft, empty):
        region = inside_region(s)
        np.testing.assert_array_equal(region.full(), inside_map(s))
        assert region.values.size < s.size or not region.values.size
        a, b = _with_depth_crop(region), _with_depth_crop(inside_map(s))
        np.testing.assert_array_equal(a[0], b[0])
        assert a[1:] == b[1:]
    assert inside_region(empty, support=(10, 20, 10, 20)).values.size == 0
    # Looking for the object on a support only (a silhouette's: a box around it, coverage
    # below 0.5 outside) finds the same region.
    for s, supports in ((soft, [(0, 75, 5, 95), (0, 120, 0, 160)]), (soft[::-1].copy(), [(45, 120, 5, 95)])):
        noisy = np.full(s.shape, 0.45, np.float32)
        for y0, y1, x0, x1 in supports:
            noisy[y0:y1, x0:x1] = s[y0:y1, x0:x1]
            got, want = inside_region(noisy, support=(y0, y1, x0, x1)), inside_region(s)
            assert (got.y0, got.x0) == (want.y0, want.x0)
            np.testing.assert_array_equal(got.values, want.values)

    def region_of(inside):
        ys, xs = np.nonzero(inside > -1e5)
        y0, x0 = int(ys.min()), int(xs.min())
        return InsideRegion(inside[y0:ys.max() + 1, x0:xs.max() + 1], y0, x0, inside.shape)

    regions = [bk.View(v.camera, region_of(v.inside), v.open_border) for v in views]
    assert all(r.inside.values.size < 0.5 * v.inside.size for r, v in zip(regions, views))
    a, b = stack_views(regions), stack_views(views)
    np.testing.assert_array_equal(a.maps, b.maps)
    np.testing.assert_array_equal(a.sizes, b.sizes)
    X = np.random.default_rng(4).uniform(-14, 14, size=(2000, 3))
    np.testing.assert_array_equal(violation(X, a, skip=1), violation(X, b, skip=1))
    # the numpy reference reads a region as its whole map
    np.testing.assert_array_equal(bk.hull_violation(X, regions, skip=1), bk.hull_violation(X, views, skip=1))


def test_sparse_stride_keeps_the_rays_per_fit_flat_as_cameras_are_added():
    from inspector.params import build_params
    from inspector_plugins.bcps import RayParams

    p = build_params(RayParams, {}, "bcps.ray")

    def stride(counts):
        return bk.sparse_stride(counts, p.refine_stride, p.refine_rays)

    # 16 cameras of 1 MP on the 30 mm cube (20 875 contour points) and on the 60 mm bracket
    # (33 828): the configured stride, 7 000 and 11 300 rays per fit.
    assert stride([1305] * 16) == 3
    assert stride([2114] * 16) == 3
    # 32 cameras on the cube (40 706): every 4th, 10 200 rays, not 13 600.
    assert stride([1272] * 32) == 4
    for cams in (8, 16, 32, 64, 128):
        counts = [2000] * cams
        s = stride(counts)
        assert s >= p.refine_stride and sum(counts) / s <= p.refine_rays
    # never below the configured stride, however few the points
    assert bk.sparse_stride([10] * 4, 5, 12000) == 5
    assert bk.sparse_stride([1000] * 16, 3, 1000) == 16


def test_a_camera_without_silhouette_is_packed_whole(views):
    """A camera whose map holds no inside pixel is packed as its whole map (the layout the
    kernel reads for it: crop at 0, 0, fill 0) and the others as their crops, exactly as each
    camera packed alone."""
    from inspector.kernels.hull_jit import _with_depth_crop, stack_views
    from inspector.kernels.silhouette import inside_map

    H, W = views[0].inside.shape
    empty = bk.View(views[0].camera, inside_map(np.zeros((H, W), np.float32)), False)
    mixed = [*views, empty]
    stack = stack_views(mixed)
    for i, v in enumerate(mixed):
        crop, y0, x0, fill = _with_depth_crop(v.inside)
        h, w = crop.shape
        assert tuple(stack.sizes[i]) == (W, H, x0, y0, w, h, fill)
        np.testing.assert_array_equal(stack.maps[i, :h, :w], crop)
    assert tuple(stack.sizes[-1][2:]) == (0, 0, W, H, 0)


def test_ray_box_is_where_the_ray_is_inside_the_box():
    """Entry and exit of rays in a box, also for rays along an axis, along a face's plane and
    starting inside: the box holds the ray's points between them and none beyond."""
    rng = np.random.default_rng(7)
    bounds = np.array([[-10.0, -12.0, -9.0], [11.0, 10.0, 12.0]])
    for origin in (np.array([100.0, 50.0, -30.0]), np.array([-10.0, 0.0, 0.0]), np.array([1.0, 2.0, 3.0])):
        aim = rng.uniform(bounds[0] - 5, bounds[1] + 5, (3000, 3))
        aim[:300, 0] = origin[0]  # no x motion: inside the x slab only if the origin is
        aim[300:400, :2] = origin[:2]  # along z
        dirs = aim - origin
        dirs /= np.linalg.norm(dirs, axis=1)[:, None]
        t0, t1 = bk.ray_box(origin, dirs, bounds)
        assert t0.min() >= 0.0

        def inside(t, rows, origin=origin, dirs=dirs):
            p = origin + np.asarray(t)[rows, None] * dirs[rows]
            return np.all((p >= bounds[0] - 1e-9) & (p <= bounds[1] + 1e-9), axis=1)

        hit = t1 > t0
        assert hit.any() and (~hit).any() != bool(np.all((bounds[0] < origin) & (origin < bounds[1])))
        # an axis the ray does not move along: it meets the box only within that slab (a face's plane included)
        assert hit[:300].any() == bool(bounds[0, 0] <= origin[0] <= bounds[1, 0])
        assert hit[300:400].any() == bool(np.all((bounds[0, :2] <= origin[:2]) & (origin[:2] <= bounds[1, :2])))
        for f in np.linspace(0.0, 1.0, 7):
            assert inside(np.where(hit, t0, 0.0) + f * np.where(hit, t1 - t0, 0.0), hit).all()
        assert not inside(np.where(hit, t1, 0.0) + 1e-6, hit).any()
        entered = hit & (t0 > 0)
        assert not inside(t0 - 1e-6, entered).any()
        assert not any(inside(np.full(len(dirs), t), ~hit).any() for t in np.linspace(1e-6, 400.0, 801))
