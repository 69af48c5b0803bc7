"""Sharp edges from contour rays: the line fit (against SciPy's least squares), the reference's
plane-plane edges, and a cube's thicknesses measured from rays whose points the visual hull
placed outside the faces."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from inspector.characteristics.edges import FIT_RAYS, plane_edges, snap_to_edges
from inspector.characteristics.measure import Characteristic, measure
from inspector.kernels.edges import (
    closest_on_rays,
    fit_line_to_rays,
    fit_lines_to_rays,
    line_ray_distances,
    lines_jackknife,
)
from inspector.kernels.features import find_features
from inspector.parts import make_part
from inspector.reference import Reference


def _rays_at(line_point, line_dir, centres, n, rng, noise_mm=0.0):
    """Rays from each centre through ``n`` random points of the line (+-14 mm), each passing
    ``noise_mm`` (standard deviation) beside it."""
    O, D = [], []
    for c in centres:
        q = line_point + rng.uniform(-14, 14, n)[:, None] * line_dir
        d = q - c
        d /= np.linalg.norm(d, axis=1)[:, None]
        side = np.cross(d, line_dir)
        side /= np.linalg.norm(side, axis=1)[:, None]
        q = q + noise_mm * rng.standard_normal(n)[:, None] * side
        d = q - c
        O.append(np.repeat(c[None], n, 0))
        D.append(d / np.linalg.norm(d, axis=1)[:, None])
    return np.concatenate(O), np.concatenate(D)


def test_line_from_rays_matches_scipy_least_squares():
    rng = np.random.default_rng(5)
    p0, u0 = np.array([3.0, -2.0, 15.0]), np.array([0.6, 0.8, 0.0])
    centres = rng.normal(size=(4, 3)) * 300
    O, D = _rays_at(p0, u0, centres, 150, rng, noise_mm=0.003)
    start_p, start_u = p0 + [0.4, -0.3, 0.2], u0 + [0.02, -0.01, 0.03]
    got = fit_line_to_rays(O, D, point=start_p, direction=start_u)
    assert got.determined

    def res(x):  # an independent parameterisation: point (3) and two direction angles
        th, ph = x[3], x[4]
        u = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
        return line_ray_distances(x[:3], u, O, D)

    su = start_u / np.linalg.norm(start_u)
    ref = least_squares(res, np.r_[start_p, np.arccos(su[2]), np.arctan2(su[1], su[0])], xtol=1e-14, ftol=1e-14)
    th, ph = ref.x[3], ref.x[4]
    ref_u = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
    assert abs(abs(float(got.direction @ ref_u)) - 1.0) < 1e-12
    d = got.point - ref.x[:3]
    assert np.linalg.norm(d - (d @ ref_u) * ref_u) < 1e-7
    assert np.sum(got.residuals ** 2) == pytest.approx(np.sum(ref.fun ** 2), rel=1e-8)
    # The truth within a few standard errors; the 3 um scatter of the rays recovered.
    d = got.point - p0
    assert np.linalg.norm(d - (d @ u0) * u0) < 5 * np.sqrt(got.cov[0, 0] + got.cov[1, 1])
    assert got.s == pytest.approx(0.003, rel=0.15)
    # Each ray's point where it meets the line: on the ray, and on the line within the noise.
    Q = closest_on_rays(O, D, got.point, got.direction)
    w = Q - O
    assert np.abs(np.linalg.norm(np.cross(w, D), axis=1)).max() < 1e-9
    off = Q - p0
    assert np.median(np.linalg.norm(off - (off @ u0)[:, None] * u0, axis=1)) < 0.005


def test_lines_fitted_together_and_without_each_camera():
    """Several lines fitted at once equal each fitted alone; each line's jackknife replica
    (one Gauss-Newton step without a camera's rays) equals that line refitted without them;
    a line two cameras show is not fixed without either of them."""
    rng = np.random.default_rng(9)
    lines = [(np.array([0.0, 15.0, 15.0]), np.array([1.0, 0.0, 0.0])),
             (np.array([15.0, 0.0, -15.0]), np.array([0.0, 1.0, 0.0]))]
    centres = [rng.normal(size=(4, 3)) * 300, rng.normal(size=(2, 3)) * 300]
    O, D, li, cam = [], [], [], []
    for j, ((p0, u0), cs) in enumerate(zip(lines, centres)):
        for k, c in enumerate(cs):
            o, d = _rays_at(p0, u0, [c], 80, rng, noise_mm=0.003)
            O.append(o), D.append(d), li.append(np.full(80, j)), cam.append(np.full(80, k))
    O, D, li, cam = (np.concatenate(x) for x in (O, D, li, cam))
    starts = np.array([p0 + 0.3 for p0, _ in lines]), np.array([u0 + 0.02 for _, u0 in lines])
    both = fit_lines_to_rays(O, D, li, *starts)
    for j in range(2):
        alone = fit_line_to_rays(O[li == j], D[li == j], point=starts[0][j], direction=starts[1][j])
        assert np.allclose(both.point[j], alone.point, atol=1e-9)
        assert np.allclose(both.direction[j], alone.direction, atol=1e-12)
    labels, Ck, Uk, fixed, present = lines_jackknife(O, D, li, cam, both)
    assert present[0].all() and present[1].tolist() == [True, True, False, False]
    for g, label in enumerate(labels.tolist()):
        out = (li == 0) & (cam != label)
        refit = fit_line_to_rays(O[out], D[out], point=both.point[0], direction=both.direction[0])
        d = Ck[0, g] - refit.point
        assert np.linalg.norm(d - (d @ refit.direction) * refit.direction) < 1e-6  # mm; the camera moves it 50-1000 nm
        assert abs(abs(float(Uk[0, g] @ refit.direction)) - 1.0) < 1e-9
    assert fixed[0].all() and not fixed[1, :2].any()


def test_rays_of_one_camera_do_not_fix_a_line():
    rng = np.random.default_rng(6)
    p0, u0 = np.zeros(3), np.array([1.0, 0.0, 0.0])
    O, D = _rays_at(p0, u0, [np.array([0.0, 300.0, 100.0])], 200, rng)
    assert not fit_line_to_rays(O, D, point=p0, direction=u0).determined
    O2, D2 = _rays_at(p0, u0, [np.array([0.0, 300.0, 100.0]), np.array([0.0, -100.0, 300.0])], 200, rng)
    assert fit_line_to_rays(O2, D2, point=p0 + 0.2, direction=u0).determined


def test_plane_edges_of_a_cube_and_of_the_bracket():
    cube = Reference.from_mesh("builtin:cube30", make_part("cube30"))
    edges = plane_edges(cube.vertices, cube.faces, find_features(cube.vertices, cube.faces))
    assert len(edges) == 12
    for e in edges:
        assert len(e.spans) == 1 and np.ptp(e.spans) == pytest.approx(30.0)
        assert np.abs(np.abs(e.point) - 15.0).min() < 1e-9  # on the cube's edges
    # The bracket's L: the inner corner between the base's top and the wall is concave (no
    # contour ray touches it): not an edge. Its outer corner is.
    br = Reference.from_mesh("builtin:bracket", make_part("bracket"))
    feats = find_features(br.vertices, br.faces)
    got = {(e.a, e.b) for e in plane_edges(br.vertices, br.faces, feats)}
    by = {f.id: f for f in feats}

    def plane(normal, at):
        hits = [f.id for f in feats if f.kind == "plane" and np.allclose(f.nominal["normal"], normal, atol=1e-6)
                and abs((np.asarray(f.nominal["point"]) - at) @ np.asarray(normal)) < 1e-6]
        assert len(hits) == 1, hits
        return hits[0]

    lo = br.vertices.min(axis=0)
    base_bottom = plane((0, 0, -1), lo)
    wall_back = plane((0, -1, 0), lo)
    base_top = plane((0, 0, 1), lo + [0, 0, 6])
    wall_front = plane((0, 1, 0), lo + [0, 6, 0])
    assert tuple(sorted((base_bottom, wall_back))) in got
    assert tuple(sorted((base_top, wall_front))) not in got
    assert all(by[a].kind == by[b].kind == "plane" for a, b in got)


def _cube_rig_points(rng, shared_um: float, noise_um: float = 2.0, hull_mm: float = 0.25):
    """What the bcps stage gives for a 30 mm cube in a 16-camera rig: for each camera, rays
    through its silhouette edges (the cube's edges between a face it sees and one it does
    not), each ray passing ``noise_um`` beside the edge and all of a camera's rays
    ``shared_um`` (its contour placed off), and each point placed on its ray anywhere within
    ``hull_mm`` of where the ray grazes the edge (the visual hull's wedge). Returns points,
    their cameras, the cameras' centres per point."""
    n = 16
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (1 + 5 ** 0.5) * k
    C = 400.0 * np.column_stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z])
    normals = np.vstack([np.eye(3), -np.eye(3)])
    P, cams, origins = [], [], []
    for cam, c in enumerate(C):
        front = [(c - 15.0 * nm) @ nm > 0 for nm in normals]
        shift = shared_um * 1e-3 * rng.standard_normal()
        for i in range(6):
            for j in range(i + 1, 6):
                if abs(normals[i] @ normals[j]) > 0.5 or front[i] == front[j]:
                    continue
                u = np.cross(normals[i], normals[j])
                base = 15.0 * (normals[i] + normals[j])
                q = base + rng.uniform(-13.5, 13.5, 60)[:, None] * u
                d = q - c
                d /= np.linalg.norm(d, axis=1)[:, None]
                out = np.cross(d, u)  # across the ray and the edge, turned away from the cube
                out /= np.linalg.norm(out, axis=1)[:, None]
                out *= np.sign(out @ (normals[i] + normals[j]))[:, None]
                q = q + (shift + noise_um * 1e-3 * rng.standard_normal(60))[:, None] * out
                d = q - c
                d /= np.linalg.norm(d, axis=1)[:, None]
                P.append(q + rng.uniform(-hull_mm, hull_mm, 60)[:, None] * d)
                cams.append(np.full(60, cam))
                origins.append(np.repeat(c[None], 60, 0))
    return np.concatenate(P), np.concatenate(cams), np.concatenate(origins)


@pytest.fixture(scope="module")
def cube():
    ref = Reference.from_mesh("builtin:cube30", make_part("cube30"))
    feats = find_features(ref.vertices, ref.faces)
    ids = {tuple(np.round(f.nominal["normal"]).astype(int)): f.id for f in feats}
    chars = [Characteristic(str(a), "distance", (ids[tuple(-np.eye(3, dtype=int)[a])], ids[tuple(np.eye(3, dtype=int)[a])]),
                            -0.1, 0.1) for a in range(3)]
    return ref, feats, chars, plane_edges(ref.vertices, ref.faces, feats)


def test_points_on_the_hull_snap_onto_the_edges_their_rays_show(cube):
    """The hull's points lie up to tens of microns outside the faces and the thicknesses fitted
    to them are too large; moved along their rays onto the fitted edges, they measure 30 mm."""
    ref, feats, chars, edges = cube
    P, cams, O = _cube_rig_points(np.random.default_rng(11), 0.0)
    plain = measure(chars, feats, P, None, ref, groups=cams)
    snapped = measure(chars, feats, P, None, ref, groups=cams, origins=O, edges=edges)
    for a, b in zip(plain, snapped):
        assert a.verdict != "not_measurable" or "camera" in a.reason
        if a.measured is not None:
            assert a.measured - 30.0 > 0.004  # the hull's outward bias
        assert b.verdict == "ok" and abs(b.measured - 30.0) < 0.001, b
    snap = snap_to_edges(P, O, edges, 0.5, groups=cams)
    assert snap.edges == 12 and len(snap.index) + len(snap.dropped) > 0.8 * len(P)
    # Each edge represented by at most FIT_RAYS moved points; the rest of its points left out.
    assert np.bincount(snap.edge).max() <= FIT_RAYS and not set(snap.index) & set(snap.dropped)
    # Each moved point lies on its ray and on the cube's edge.
    on_edge = np.sort(np.abs(snap.points), axis=1)[:, 1:]
    assert np.abs(on_edge - 15.0).max() < 0.02
    # Candidates taken only among the points nearest one of an edge's two planes (as the
    # stage does): the same points move to the same places.
    tri = ref.distance.closest(P, parallel=False)[1]
    face_owner = np.full(len(ref.faces), -1)
    for k, f in enumerate(feats):
        face_owner[f.faces] = k
    fast = snap_to_edges(P, O, edges, 0.5, groups=cams, nearest=face_owner[tri])
    assert np.array_equal(np.sort(fast.index), np.sort(snap.index))
    assert np.allclose(fast.points[np.argsort(fast.index)], snap.points[np.argsort(snap.index)], atol=1e-9)
    # Without the rays' origins nothing moves (the points alone cannot say where the edge is).
    assert [r.measured for r in measure(chars, feats, P, None, ref, groups=cams, edges=edges)] == \
        [r.measured for r in plain]


def test_snapped_thickness_uncertainty_covers_the_truth(cube):
    """Every camera's contour off by a few microns: the edges move with the cameras that show
    them, and the thickness's U must cover the truth about 95 % of the time (the jackknife
    over the cameras, with the edges refitted without each camera in turn)."""
    ref, feats, chars, edges = cube
    rng = np.random.default_rng(12)
    z = []
    for _ in range(25):
        P, cams, O = _cube_rig_points(rng, 5.0)
        for r in measure(chars, feats, P, None, ref, groups=cams, origins=O, edges=edges, max_u_fraction=10.0):
            assert r.verdict != "not_measurable", r.reason
            z.append(r.deviation / r.u)
    z = np.abs(np.asarray(z))
    assert 0.9 <= float(np.mean(z <= 2.0)) <= 1.0, np.mean(z <= 2.0)
    assert np.median(z) > 0.25, np.median(z)


def test_snapped_without_cameras_and_a_part_without_plane_edges(cube):
    """Without the points' cameras (``per_camera = false``) the points still move onto the
    edges (no jackknife to refit them for); a reference without two planes meeting at a
    convex edge has no edge, and its measurement is the points' own."""
    ref, feats, chars, edges = cube
    P, cams, O = _cube_rig_points(np.random.default_rng(14), 0.0)
    for r in measure(chars, feats, P, None, ref, origins=O, edges=edges):
        assert r.verdict == "ok" and abs(r.measured - 30.0) < 0.001, r
    ball = Reference.from_mesh("builtin:sphere30", make_part("sphere30"))
    assert plane_edges(ball.vertices, ball.faces, find_features(ball.vertices, ball.faces)) == ()
