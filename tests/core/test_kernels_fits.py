"""Fits with uncertainty (issue 28): against an independent SciPy least-squares implementation
and analytic values, ill-posed cases, and the coverage of measured +- 2u over noisy draws."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from inspector.kernels import fits as F


def _basis(a):
    a = np.asarray(a, float) / np.linalg.norm(a)
    h = np.eye(3)[np.argmin(np.abs(a))]
    u = np.cross(a, h)
    u /= np.linalg.norm(u)
    return a, u, np.cross(a, u)


def cylinder_points(rng, n, R, axis, p0, length, arc_deg=360.0, sigma=0.0, phase=0.0):
    a, u, v = _basis(axis)
    th = np.radians(phase + rng.uniform(0.0, arc_deg, n))
    h = rng.uniform(-length / 2, length / 2, n)
    radial = np.cos(th)[:, None] * u + np.sin(th)[:, None] * v
    return np.asarray(p0) + h[:, None] * a + (R + sigma * rng.standard_normal(n))[:, None] * radial


def sphere_points(rng, n, centre, R, sigma=0.0):
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    return np.asarray(centre) + (R + sigma * rng.standard_normal(n))[:, None] * d


def plane_points(rng, n, point, normal, size, sigma=0.0):
    nrm, u, v = _basis(normal)
    s, t = rng.uniform(-size / 2, size / 2, (2, n))
    return np.asarray(point) + s[:, None] * u + t[:, None] * v + (sigma * rng.standard_normal(n))[:, None] * nrm


# ----------------------------------------------------------------- independent SciPy fits


def scipy_cylinder(P, x0):
    """Cylinder as (x0, y0) on the plane z = 0 of the axis, direction (dx, dy, 1), radius: an
    independent parametrisation (valid for an axis not perpendicular to z)."""
    def res(x):
        p = np.array([x[0], x[1], 0.0])
        a = np.array([x[2], x[3], 1.0])
        a /= np.linalg.norm(a)
        d = P - p
        return np.linalg.norm(d - (d @ a)[:, None] * a, axis=1) - x[4]

    sol = least_squares(res, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    J = sol.jac
    s2 = np.sum(sol.fun ** 2) / (len(P) - 5)
    cov = s2 * np.linalg.inv(J.T @ J)
    return sol.x, cov


def scipy_sphere(P, x0, w=None):
    w = np.ones(len(P)) if w is None else w
    sw = np.sqrt(w)

    def res(x):
        return sw * (np.linalg.norm(P - x[:3], axis=1) - x[3])

    sol = least_squares(res, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    s2 = np.sum(sol.fun ** 2) / (len(P) - 4)
    return sol.x, s2 * np.linalg.inv(sol.jac.T @ sol.jac)


def scipy_cone(P, x0):
    """Cone as apex (3), axis angles (theta, phi), half-angle."""
    def res(x):
        ap = x[:3]
        a = np.array([np.sin(x[3]) * np.cos(x[4]), np.sin(x[3]) * np.sin(x[4]), np.cos(x[3])])
        d = P - ap
        h = d @ a
        rho = np.linalg.norm(d - h[:, None] * a, axis=1)
        return rho * np.cos(x[5]) - h * np.sin(x[5])

    sol = least_squares(res, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    s2 = np.sum(sol.fun ** 2) / (len(P) - 6)
    return sol.x, s2 * np.linalg.inv(sol.jac.T @ sol.jac)


def test_cylinder_matches_scipy_and_its_radius_uncertainty():
    rng = np.random.default_rng(1)
    axis = np.array([0.1, -0.2, 1.0])
    P = cylinder_points(rng, 400, 18.0, axis, [1.0, 2.0, 3.0], 20.0, sigma=0.003)
    fit = F.fit_cylinder(P)
    assert fit.ok
    a = axis / axis[2]
    p_z0 = np.array([1.0, 2.0, 3.0]) - 3.0 * a  # the axis where it crosses z = 0
    x, cov = scipy_cylinder(P, [p_z0[0], p_z0[1], a[0], a[1], 18.0])
    assert fit.params["radius"] == pytest.approx(x[4], abs=1e-9)
    d = fit.params["direction"] / fit.params["direction"][2]
    assert d[:2] == pytest.approx(x[2:4], abs=1e-9)
    # the radius is a parameter of both: its standard uncertainty must agree
    assert fit.u["radius"] == pytest.approx(np.sqrt(cov[4, 4]), rel=1e-3)
    assert abs(fit.params["radius"] - 18.0) < 4 * fit.u["radius"]


def test_sphere_weighted_matches_scipy():
    rng = np.random.default_rng(2)
    sig = rng.uniform(0.001, 0.01, 300)
    d = rng.standard_normal((300, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    P = np.array([1.0, -2.0, 0.5]) + (15.0 + sig * rng.standard_normal(300))[:, None] * d
    w = 1.0 / sig ** 2
    fit = F.fit_sphere(P, w / w.max())
    x, cov = scipy_sphere(P, [1, -2, 0.5, 15], w / w.max())
    assert fit.params["centre"] == pytest.approx(x[:3], abs=1e-9)
    assert fit.params["radius"] == pytest.approx(x[3], abs=1e-9)
    assert fit.u["radius"] == pytest.approx(np.sqrt(cov[3, 3]), rel=1e-6)


def test_cone_matches_scipy():
    rng = np.random.default_rng(3)
    alpha, apex = np.radians(30.0), np.array([0.5, -0.3, -5.0])
    th = np.radians(25.0)
    a = np.array([np.sin(th), 0.0, np.cos(th)])
    _, u, v = _basis(a)
    h = rng.uniform(5.0, 15.0, 500)
    ang = rng.uniform(0, 2 * np.pi, 500)
    radial = np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v
    n_out = np.cos(alpha) * radial - np.sin(alpha) * a
    P = apex + h[:, None] * a + (h * np.tan(alpha))[:, None] * radial + (0.002 * rng.standard_normal(500))[:, None] * n_out
    fit = F.fit_cone(P)
    assert fit.ok
    x, cov = scipy_cone(P, [*apex, th, 0.0, alpha])
    assert fit.params["half_angle_deg"] == pytest.approx(np.degrees(x[5]), abs=1e-7)
    assert fit.params["apex"] == pytest.approx(x[:3], abs=1e-6)
    assert fit.u["half_angle_deg"] == pytest.approx(np.degrees(np.sqrt(cov[5, 5])), rel=1e-3)
    assert abs(fit.params["half_angle_deg"] - 30.0) < 4 * fit.u["half_angle_deg"]


def test_exact_points_give_exact_parameters():
    rng = np.random.default_rng(4)
    P = cylinder_points(rng, 60, 6.0, [0, 1, 1], [0, 0, 0], 10.0)
    f = F.fit_cylinder(P)
    assert f.params["radius"] == pytest.approx(6.0, abs=1e-10)
    assert abs(abs(f.params["direction"] @ np.array([0, 1, 1]) / np.sqrt(2)) - 1) < 1e-12
    s = F.fit_sphere(sphere_points(rng, 50, [3, 2, 1], 7.5))
    assert s.params["radius"] == pytest.approx(7.5, abs=1e-10)
    c = F.fit_circle(cylinder_points(rng, 40, 4.0, [0, 0, 1], [1, 1, 0], 0.0), normal=[0, 0, 1])
    assert c.params["radius"] == pytest.approx(4.0, abs=1e-10)
    assert c.params["centre"][:2] == pytest.approx([1, 1], abs=1e-10)
    pl = F.fit_plane(plane_points(rng, 30, [0, 0, 5], [0, 0, 1], 10.0))
    assert pl.params["normal"] == pytest.approx([0, 0, 1], abs=1e-12)
    ln = F.fit_line(np.outer(np.linspace(0, 10, 20), [1, 2, 2]) / 3.0 + [1, 0, 0])
    assert abs(ln.params["direction"] @ np.array([1, 2, 2]) / 3.0) == pytest.approx(1.0, abs=1e-12)


def test_minimum_zone_form_against_analytic_values():
    rng = np.random.default_rng(5)
    # flatness: points on two parallel planes 0.02 apart, tilted: the zone is 0.02 whatever the tilt
    P = plane_points(rng, 500, [0, 0, 0], [0.1, 0.05, 1.0], 30.0)
    nrm = np.array([0.1, 0.05, 1.0]) / np.linalg.norm([0.1, 0.05, 1.0])
    P += np.where(rng.random(500) < 0.5, 0.0, 0.02)[:, None] * nrm
    assert F.flatness(P) == pytest.approx(0.02, abs=1e-9)
    # roundness: a 3-lobed circle r = 10 + 0.01 cos 3t: minimum zone 0.02 (a least-squares
    # circle gives the same here by symmetry; an off-centre start must still find it)
    t = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    r = 10.0 + 0.01 * np.cos(3 * t)
    Q = np.column_stack([r * np.cos(t) + 0.3, r * np.sin(t) - 0.2, np.zeros_like(t)])
    assert F.roundness(Q, normal=[0, 0, 1]) == pytest.approx(0.02, abs=1e-7)
    mcc, _ = F.circle_mcc(Q, normal=[0, 0, 1])
    mic, _ = F.circle_mic(Q, normal=[0, 0, 1])
    assert mcc == pytest.approx(10.01, abs=1e-7) and mic == pytest.approx(9.99, abs=1e-7)
    # cylindricity of a cylinder with a 0.015 radial step halfway along it
    C = cylinder_points(rng, 800, 5.0, [0, 0, 1], [0, 0, 0], 20.0)
    C[C[:, 2] > 0, :2] *= (5.015 / 5.0)
    assert F.cylindricity(C) == pytest.approx(0.015, abs=1e-6)


def test_ill_posed_fits_say_so():
    rng = np.random.default_rng(6)
    arc = F.fit_cylinder(cylinder_points(rng, 300, 18.0, [0, 0, 1], [0, 0, 0], 20.0, arc_deg=10.0, sigma=0.003),
                         axis=[0, 0, 1])
    assert arc.problem is not None and "radius" in arc.problem
    assert arc.amplification > 100
    full = F.fit_cylinder(cylinder_points(rng, 300, 18.0, [0, 0, 1], [0, 0, 0], 20.0, sigma=0.003))
    assert full.ok and full.amplification < 3
    # a plane seen only along one rim edge: its tilt about the edge is unconstrained
    x = rng.uniform(-15, 15, 200)
    rim = np.column_stack([x, np.full(200, 15.0) + 0.002 * rng.standard_normal(200), 0.002 * rng.standard_normal(200)])
    assert F.fit_plane(rim).problem is not None
    exact_line = np.column_stack([x, np.full(200, 15.0), np.zeros(200)])
    assert "singular" in F.fit_plane(exact_line).problem
    # the same plane seen at its whole rim (four edges) is fine
    e = rng.uniform(-15, 15, 400)
    side = rng.integers(0, 4, 400)
    ring = np.column_stack([np.where(side < 2, e, np.where(side == 2, -15.0, 15.0)),
                            np.where(side < 2, np.where(side == 0, -15.0, 15.0), e), 0.002 * rng.standard_normal(400)])
    assert F.fit_plane(ring).ok
    assert "too few points" in F.fit_sphere(sphere_points(rng, 5, [0, 0, 0], 3.0)).problem
    assert "too few points" in F.fit_cylinder(cylinder_points(rng, 3, 3.0, [0, 0, 1], [0, 0, 0], 5.0)).problem
    with pytest.raises(F.FitError):
        F.fit_plane(np.zeros((5, 2)))
    with pytest.raises(F.FitError):
        F.fit_sphere(np.full((5, 3), np.nan))


def _coverage(errors_over_u):
    return float(np.mean(np.abs(errors_over_u) <= 2.0))


def test_coverage_of_two_u_over_noisy_draws():
    """measured +- 2u holds the truth in about 95 % of draws, for a radius, a thickness and an angle;
    |error| / u is about half-normal (median ~0.67), neither too small nor ten times too large."""
    rng = np.random.default_rng(7)
    rad, thick, ang = [], [], []
    for _ in range(200):
        P = cylinder_points(rng, 150, 8.0, [0.2, 0.1, 1.0], [0, 0, 0], 12.0, sigma=0.004)
        f = F.fit_cylinder(P, axis=[0.2, 0.1, 1.0])  # the nominal as the start, as measure() does
        rad.append((f.params["radius"] - 8.0) / f.u["radius"])
        A = plane_points(rng, 120, [0, 0, -3.0], [0, 0, -1], 20.0, sigma=0.004)
        B = plane_points(rng, 120, [2.0, 1.0, 3.0], [0, 0, 1], 10.0, sigma=0.004)
        d, u = F.distance_between(F.fit_plane(A), F.fit_plane(B))
        thick.append((d - 6.0) / u)
        C = plane_points(rng, 120, [0, 0, 0], [1, 0, 0], 20.0, sigma=0.004)
        g, ug = F.angle_between(F.fit_plane(A), F.fit_plane(C))
        ang.append((g - 90.0) / ug)
    for name, z in (("radius", rad), ("thickness", thick), ("angle", ang)):
        z = np.asarray(z)
        assert 0.91 <= _coverage(z) <= 0.99, (name, _coverage(z))
        assert 0.5 < np.median(np.abs(z)) < 0.85, (name, np.median(np.abs(z)))


def test_weights_shift_the_fit_towards_the_confident_points():
    rng = np.random.default_rng(8)
    P = sphere_points(rng, 400, [0, 0, 0], 10.0, sigma=0.002)
    bad = rng.random(400) < 0.3
    P[bad] *= 1.01  # 0.1 mm off: low-confidence points
    w = np.where(bad, 1e-4, 1.0)
    assert abs(F.fit_sphere(P, w).params["radius"] - 10.0) < 0.001
    assert abs(F.fit_sphere(P).params["radius"] - 10.0) > 0.02
    assert F.fit_sphere(P, np.where(bad, 0.0, 1.0)).n == int((~bad).sum())


def test_distances_between_axes_and_to_a_plane():
    rng = np.random.default_rng(9)
    a = F.fit_cylinder(cylinder_points(rng, 300, 3.0, [0, 0, 1], [0, 0, 0], 10.0, sigma=0.002))
    b = F.fit_cylinder(cylinder_points(rng, 300, 4.0, [0, 0, 1], [30.0, 0, 5], 10.0, sigma=0.002))
    d, u = F.distance_between(a, b)
    assert abs(d - 30.0) < 4 * u and u < 0.001
    pl = F.fit_plane(plane_points(rng, 200, [0, 0, -7.0], [0, 0, 1], 20.0, sigma=0.002))
    s = F.fit_sphere(sphere_points(rng, 300, [1, 2, 3], 2.0, sigma=0.002))
    d2, u2 = F.distance_between(pl, s)
    assert abs(d2 - 10.0) < 4 * u2
    ang, ua = F.angle_between(a, pl)
    assert abs(ang - 90.0) < 4 * ua + 1e-9


def test_between_groups_f_is_the_anova_ratio():
    """The unweighted ratio is SciPy's one-way ANOVA F; weights of one value change nothing."""
    from scipy.stats import f_oneway

    rng = np.random.default_rng(11)
    g = rng.integers(0, 7, 500)
    r = 0.004 * rng.standard_normal(500) + 0.003 * rng.standard_normal(7)[g]
    expected = f_oneway(*[r[g == k] for k in range(7)]).statistic
    assert F.between_groups_f(r, g) == pytest.approx(expected, rel=1e-9)
    assert F.between_groups_f(r, g, np.full(500, 3.0)) == pytest.approx(expected, rel=1e-9)
    assert np.isnan(F.between_groups_f(r, np.zeros(500, int)))  # one group: nothing to tell
    # The design effect: the variance of the groups' means over what independent points give.
    m, rho = 50, 0.3
    deff = [F.design_effect(np.repeat(rng.standard_normal(40), m) * np.sqrt(rho)
                            + np.sqrt(1 - rho) * rng.standard_normal(40 * m), np.repeat(np.arange(40), m))
            for _ in range(50)]
    assert np.median(deff) == pytest.approx(1 + (m - 1) * rho, rel=0.25)
    with pytest.raises(F.FitError):
        F.between_groups_f(r, g[:10])


def test_points_that_err_together_are_not_counted_as_independent():
    """Each camera's points share an offset (its contour placed off by a few um): least squares
    alone gives a thickness u far too small (the truth mostly outside +-2u); with the cameras
    as groups the coverage is about 95 %. Independent points keep their u."""
    rng = np.random.default_rng(12)
    plain, grouped, independent = [], [], []
    for _ in range(150):
        fits_ = []
        for centre, normal in (([0, 0, -3.0], [0, 0, -1]), ([1.0, 0.5, 3.0], [0, 0, 1])):
            P = plane_points(rng, 600, centre, normal, 20.0, sigma=0.004)
            cam = rng.integers(0, 12, len(P))
            P = P + (0.004 * rng.standard_normal(12))[cam][:, None] * np.asarray(normal, float)
            fits_.append((F.fit_plane(P), cam))
        d, u = F.distance_between(fits_[0][0], fits_[1][0])
        plain.append((d - 6.0) / u)
        a, b = (F.grouped(f, cam) for f, cam in fits_)
        assert a.design_effect > 5 and b.design_effect > 5
        d2, u2 = F.distance_between(a, b)
        grouped.append((d2 - 6.0) / u2)
        Q = plane_points(rng, 600, [0, 0, 0], [0, 0, 1], 20.0, sigma=0.004)
        f = F.fit_plane(Q)
        independent.append(F.grouped(f, rng.integers(0, 12, len(Q))).u["offset"] / f.u["offset"])
    assert _coverage(np.asarray(plain)) < 0.6
    assert 0.9 <= _coverage(np.asarray(grouped)) <= 0.995, _coverage(np.asarray(grouped))
    assert 0.5 < np.median(np.abs(grouped)) < 0.9
    assert np.median(independent) < 1.2  # no shared error: u about as before (never smaller)
    assert min(independent) >= 1.0


def test_plane_jackknife_is_fit_plane_without_each_group():
    """Each leave-one-group-out plane from the group sums is fit_plane of the remaining points
    (far from the origin: the moments are taken about the centroid)."""
    rng = np.random.default_rng(13)
    P = plane_points(rng, 900, [500.0, -300.0, 200.0], [0.2, 0.3, 1.0], 30.0, sigma=0.01)
    g = rng.integers(0, 9, len(P))
    w = rng.uniform(0.2, 1.0, len(P))
    nrm = np.array([0.2, 0.3, 1.0]) / np.linalg.norm([0.2, 0.3, 1.0])
    out = F.plane_jackknife(P, w, g, nrm)
    assert sorted(out) == list(range(9))
    for k in range(9):
        ref = F.fit_plane(P[g != k], w[g != k])
        n = ref.params["normal"] * np.sign(ref.params["normal"] @ nrm)
        np.testing.assert_allclose(out[k]["normal"], n, atol=1e-9)
        np.testing.assert_allclose(out[k]["point"], ref.params["point"], atol=1e-9)
        assert out[k]["normal"] @ nrm > 0
    few = F.plane_jackknife(P[:15], None, np.r_[np.zeros(10, int), np.ones(5, int)], nrm)
    assert few[0] is None and few[1] is not None  # without group 0, 5 points: too few


def test_compiled_cylinder_residual_is_the_numpy_one():
    """The fit's compiled residual and Jacobian (fits_jit) equal the numpy reference."""
    fits_jit = pytest.importorskip("inspector.kernels.fits_jit")
    rng = np.random.default_rng(21)
    a, bu, bv = _basis([0.3, -0.1, 1.0])
    p = np.array([4.0, -2.0, 7.0])
    P = cylinder_points(rng, 300, 9.0, a, p, 30.0, sigma=0.01)
    r_ref, J_ref = F.cylinder_residual_numpy(P, p, a, bu, bv, 9.0)
    r, J = np.empty(len(P)), np.empty((len(P), 5))
    fits_jit.cylinder_residual(P, p, a, bu, bv, 9.0, r, J, True)
    np.testing.assert_allclose(r, r_ref, atol=1e-12)
    np.testing.assert_allclose(J, J_ref, atol=1e-12)
    r2 = np.zeros(len(P))
    J2 = np.full((len(P), 5), 7.0)
    fits_jit.cylinder_residual(P, p, a, bu, bv, 9.0, r2, J2, False)  # the residual only: J untouched
    np.testing.assert_allclose(r2, r_ref, atol=1e-12)
    assert (J2 == 7.0).all()


def test_compiled_cylinder_fit_loop_is_the_numpy_one():
    """fits_jit.cylinder_lm (what fit_cylinder runs) ends where the numpy loop on the
    reference residual ends, from a start 0.5 mm and 3 degrees off, with uneven weights."""
    fits_jit = pytest.importorskip("inspector.kernels.fits_jit")
    rng = np.random.default_rng(22)
    axis = np.array([0.05, 0.02, 1.0])
    P = cylinder_points(rng, 250, 4.0, axis, [10.0, 20.0, 30.0], 6.0, arc_deg=200.0, sigma=0.004)
    w = rng.uniform(0.3, 1.0, len(P))
    cw = (w[:, None] * P).sum(0) / w.sum()
    a0 = np.array([0.0, 0.05, 1.0]) / np.linalg.norm([0.0, 0.05, 1.0])
    start = np.r_[[10.5, 19.8, 30.0], a0, 4.4]
    compiled, reference = start.copy(), start.copy()
    fits_jit.cylinder_lm(P, w, cw, compiled, F._RTOL, F._MAX_ITER)
    F.cylinder_lm_numpy(P, w, cw, reference)
    np.testing.assert_allclose(compiled, reference, atol=1e-9)
    assert abs(compiled[6] - 4.0) < 0.01 and compiled[3:6] @ (axis / np.linalg.norm(axis)) > 0.9999
