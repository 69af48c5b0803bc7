"""Tori (issue 28): :func:`fit_torus` against an independent SciPy fit and the truth (its
uncertainty honest over noisy draws, a short arc of the tube refused), a fillet found on a
turned part's mesh, its radius measured from points on the true surface, and the recipe's
checks of what applies to a torus."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.optimize import least_squares

from inspector.characteristics.measure import Characteristic, measure
from inspector.errors import RecipeError
from inspector.kernels import fits
from inspector.kernels.features import Feature, find_features
from inspector.recipe import load_recipe
from inspector.reference import Reference
from inspector_frontends.cli import main

CENTRE = np.array([3.0, -2.0, 7.0])
AXIS = np.array([0.2, -0.1, 1.0]) / np.linalg.norm([0.2, -0.1, 1.0])
R_MAJOR, R_MINOR = 12.0, 3.0


def _torus_points(rng: np.random.Generator, n: int, phi: tuple[float, float], noise: float,
                  theta: tuple[float, float] = (0.0, 2 * np.pi)) -> np.ndarray:
    """``n`` points on the torus (CENTRE, AXIS, R_MAJOR, R_MINOR) at angles ``theta`` round the
    axis and ``phi`` round the tube (0: outermost, pi/2: towards +AXIS), moved along the
    surface's normal by Gaussian noise of ``noise`` mm."""
    bu, bv = fits.orthonormal_basis(AXIS)
    t = rng.uniform(*theta, n)
    p = rng.uniform(*phi, n)
    e = np.cos(t)[:, None] * bu + np.sin(t)[:, None] * bv
    nrm = np.cos(p)[:, None] * e + np.sin(p)[:, None] * AXIS
    return CENTRE + R_MAJOR * e + (R_MINOR + noise * rng.standard_normal(n))[:, None] * nrm


def _scipy_torus(P: np.ndarray, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An independent least-squares torus: centre (3), axis as polar angles (2), R, r; the
    orthogonal residual ``sqrt((rho - R)^2 + h^2) - r``. Returns the parameters and their
    covariance ``s^2 (J^T J)^-1``."""
    def res(x: np.ndarray) -> np.ndarray:
        a = np.array([np.sin(x[3]) * np.cos(x[4]), np.sin(x[3]) * np.sin(x[4]), np.cos(x[3])])
        d = P - x[:3]
        h = d @ a
        rho = np.linalg.norm(d - h[:, None] * a, axis=1)
        return np.hypot(rho - x[5], h) - x[6]

    sol = least_squares(res, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    J = sol.jac
    s2 = float(sol.fun @ sol.fun) / (len(P) - 7)
    return sol.x, s2 * np.linalg.inv(J.T @ J)


def test_fit_torus_matches_an_independent_scipy_fit_and_the_truth():
    rng = np.random.default_rng(5)
    P = _torus_points(rng, 600, (-0.3, np.pi / 2), 0.005)  # a fillet's quarter of the tube, and a little more
    f = fits.fit_torus(P, axis=AXIS + 0.01, centre=CENTRE + 0.05, major_radius=11.9, minor_radius=3.1)
    assert f.ok and f.kind == "torus" and f.n == 600
    x0 = np.r_[CENTRE + 0.05, np.arccos(AXIS[2]), np.arctan2(AXIS[1], AXIS[0]), 11.9, 3.1]
    x, cov = _scipy_torus(P, x0)
    a = f.params["axis"] * np.sign(f.params["axis"] @ AXIS)
    assert f.params["centre"] == pytest.approx(x[:3], abs=1e-7)
    assert a == pytest.approx([np.sin(x[3]) * np.cos(x[4]), np.sin(x[3]) * np.sin(x[4]), np.cos(x[3])], abs=1e-9)
    assert f.params["major_radius"] == pytest.approx(x[5], abs=1e-8)
    assert f.params["minor_radius"] == pytest.approx(x[6], abs=1e-8)
    # the radii's variances do not depend on how the other parameters are written
    assert f.u["major_radius"] == pytest.approx(np.sqrt(cov[5, 5]), rel=1e-4)
    assert f.u["minor_radius"] == pytest.approx(np.sqrt(cov[6, 6]), rel=1e-4)
    assert f.s == pytest.approx(0.005, rel=0.1)
    assert abs(f.params["minor_radius"] - R_MINOR) < 3 * f.u["minor_radius"] < 5e-3
    assert abs(f.params["major_radius"] - R_MAJOR) < 3 * f.u["major_radius"]
    assert np.linalg.norm(f.params["centre"] - CENTRE) < 3 * np.sqrt(3) * f.u["centre"]
    assert (f.residuals > 0).mean() == pytest.approx(0.5, abs=0.1)  # signed: as many outside the tube as in
    js = f.to_json()
    assert js["kind"] == "torus" and set(js["params"]) == {"centre", "axis", "major_radius", "minor_radius"}


def test_fit_torus_without_a_start_finds_a_whole_ring():
    rng = np.random.default_rng(6)
    P = _torus_points(rng, 800, (0.0, 2 * np.pi), 0.002)
    f = fits.fit_torus(P)
    assert f.ok and f.amplification < 2  # the whole tube: the minor radius as well fixed as the points allow
    assert f.params["minor_radius"] == pytest.approx(R_MINOR, abs=1e-3)
    assert f.params["major_radius"] == pytest.approx(R_MAJOR, abs=1e-3)
    assert f.params["centre"] == pytest.approx(CENTRE, abs=1e-3)
    assert abs(f.params["axis"] @ AXIS) == pytest.approx(1.0, abs=1e-7)
    assert f.params["axis"][np.argmax(np.abs(f.params["axis"]))] > 0  # the sign convention
    # the derived quantities read a torus by its centre and its axis
    geo = f.perturbed(np.zeros(len(f.names)))
    assert fits.direction_of(geo) == pytest.approx(f.params["axis"])
    plane = {"kind": "plane", "point": np.zeros(3), "normal": np.array([0.0, 0.0, 1.0])}
    assert fits.geometric_distance(geo, plane) == pytest.approx(abs(f.params["centre"][2]))
    assert fits.geometric_distance(plane, geo) == pytest.approx(abs(f.params["centre"][2]))
    cyl = {"kind": "cylinder", "point": CENTRE + 5 * AXIS, "direction": AXIS}
    assert fits.geometric_distance(geo, cyl) == pytest.approx(0.0, abs=1e-3)  # coaxial
    assert fits.geometric_angle(geo, cyl) == pytest.approx(0.0, abs=0.01)


def test_fit_torus_uncertainty_is_honest_over_noisy_draws():
    """+-2u of the minor and major radii hold the truth in about 95 % of draws (a fillet's
    quarter of the tube all round the axis, 0.01 mm noise, 200 points; 400 draws)."""
    rng = np.random.default_rng(7)
    hits = np.zeros(3)
    draws = 400
    for _ in range(draws):
        P = _torus_points(rng, 200, (0.0, np.pi / 2), 0.01)
        f = fits.fit_torus(P, axis=AXIS, centre=CENTRE, major_radius=R_MAJOR, minor_radius=R_MINOR)
        assert f.ok
        hits += [abs(f.params["minor_radius"] - R_MINOR) <= 2 * f.u["minor_radius"],
                 abs(f.params["major_radius"] - R_MAJOR) <= 2 * f.u["major_radius"],
                 abs((f.params["centre"] - CENTRE) @ AXIS) <= 2 * np.sqrt(f.cov[2, 2])]
    coverage = hits / draws
    assert np.all((coverage >= 0.9) & (coverage <= 0.99)), coverage


def test_fit_torus_refuses_a_short_arc_of_the_tube_and_too_few_points():
    rng = np.random.default_rng(8)
    P = _torus_points(rng, 400, (0.0, np.radians(10.0)), 0.005)
    f = fits.fit_torus(P, axis=AXIS, centre=CENTRE, major_radius=R_MAJOR, minor_radius=R_MINOR)
    assert not f.ok and "do not constrain the torus's minor radius" in f.problem
    assert f.amplification > 100
    good = fits.fit_torus(_torus_points(rng, 400, (0.0, np.pi / 2), 0.005), axis=AXIS, centre=CENTRE,
                          major_radius=R_MAJOR, minor_radius=R_MINOR)
    assert good.ok and good.amplification < fits.MAX_AMPLIFICATION
    few = fits.fit_torus(P[:10], axis=AXIS, centre=CENTRE, major_radius=R_MAJOR, minor_radius=R_MINOR)
    assert not few.ok and "too few points (10 < 14)" in few.problem
    assert fits.fit_torus(P[:5]).problem == "too few points (5 < 14)"
    with pytest.raises(fits.FitError):
        fits.fit_torus(np.full((20, 3), np.nan))


# --------------------------------------------------------------------------- features


def _arc(cx: float, cz: float, r: float, t0: float, t1: float, n: int) -> np.ndarray:
    t = np.linspace(t0, t1, n + 1)
    return np.column_stack([cx + r * np.cos(t), cz + r * np.sin(t)])


def _filleted_cylinder() -> trimesh.Trimesh:
    """A cylinder Ø30 x 20 along z, its top edge rounded with r 3: a torus R 12, r 3 centred
    at z 17 (8 facets over the quarter round, 128 round the axis)."""
    profile = np.vstack([[0.0, 0.0], [15.0, 0.0], _arc(12.0, 17.0, 3.0, 0.0, np.pi / 2, 8), [0.0, 20.0]])
    return trimesh.creation.revolve(profile, sections=128)


def _of(feats: list[Feature], kind: str) -> list[Feature]:
    return [f for f in feats if f.kind == kind]


def test_a_fillet_is_a_convex_torus_next_to_its_plane_and_cylinder():
    m = _filleted_cylinder()
    feats = find_features(m.vertices, m.faces)
    assert [(f.id, f.kind) for f in feats] == [("F01", "plane"), ("F02", "plane"), ("F03", "cylinder"), ("F04", "torus")]
    assert sum(f.triangles for f in feats) == len(m.faces)
    (tor,) = _of(feats, "torus")
    nm = tor.nominal
    assert set(nm) == {"centre", "axis", "major_radius", "minor_radius", "convex"}
    assert nm["minor_radius"] == pytest.approx(3.0, abs=1e-3) and nm["major_radius"] == pytest.approx(12.0, abs=1e-3)
    assert nm["convex"] is True
    assert np.asarray(nm["centre"]) == pytest.approx([0.0, 0.0, 17.0], abs=1e-3)
    assert np.asarray(nm["axis"]) == pytest.approx([0.0, 0.0, 1.0], abs=1e-9)
    assert tor.triangles == 128 * 8 * 2 and tor.direction == pytest.approx([0.0, 0.0, 1.0], abs=1e-9)
    (cyl,) = _of(feats, "cylinder")
    assert cyl.nominal["radius"] == pytest.approx(15.0, abs=1e-6) and cyl.nominal["length"] == pytest.approx(17.0, abs=1e-6)
    assert cyl.nominal["convex"] is True
    tops = sorted(f.nominal["point"][2] for f in _of(feats, "plane"))
    assert tops == pytest.approx([0.0, 20.0], abs=1e-9)
    js = tor.to_json()
    assert js["kind"] == "torus" and isinstance(js["nominal"]["centre"], list) and js["nominal"]["convex"] is True


def test_an_inner_fillet_and_a_groove_are_concave_tori():
    # a shaft r 10 on a shoulder r 20, the inner corner rounded with r 2
    shaft = np.vstack([[0, -5], [20, -5], [20, 0], _arc(12, 2, 2, -np.pi / 2, -np.pi, 8), [10, 20], [0, 20]])
    # a cylinder r 15 with a semicircular groove r 2 round it at z 15
    groove = np.vstack([[0, 0], [15, 0], _arc(15, 15, 2, -np.pi / 2, -1.5 * np.pi, 16), [15, 30], [0, 30]])
    for profile, R, r, z in ((shaft, 12.0, 2.0, 2.0), (groove, 15.0, 2.0, 15.0)):
        m = trimesh.creation.revolve(np.asarray(profile, float), sections=128)
        feats = find_features(m.vertices, m.faces)
        (tor,) = _of(feats, "torus")
        assert tor.nominal["convex"] is False
        assert (tor.nominal["major_radius"], tor.nominal["minor_radius"]) == pytest.approx((R, r), abs=1e-3)
        assert tor.nominal["centre"][2] == pytest.approx(z, abs=1e-3)
        assert sum(f.triangles for f in feats) == len(m.faces)
        assert not _of(feats, "cone")  # the rings of the fillet next to its faces are the torus's


# --------------------------------------------------------------------------- measurement

SCALE = 1.002


def _true_fillet_points(rng: np.random.Generator, n: int, noise: float) -> np.ndarray:
    """Points on the exact surface of :func:`_filleted_cylinder`'s part scaled by SCALE about
    the origin, area-weighted over its four faces, with ``noise`` mm along the normal."""
    z = np.array([0.0, 0.0, 1.0])
    areas = np.array([np.pi * 15 ** 2, 2 * np.pi * 15 * 17, 2 * np.pi * 3 * (12 * np.pi / 2 + 3), np.pi * 12 ** 2])
    counts = rng.multinomial(n, areas / areas.sum())
    out = []
    for face, k in enumerate(counts):
        t = rng.uniform(0, 2 * np.pi, k)
        e = np.column_stack([np.cos(t), np.sin(t), np.zeros(k)])
        if face in (0, 3):  # bottom disc r 15, top disc r 12
            rad = (15.0 if face == 0 else 12.0) * np.sqrt(rng.uniform(0, 1, k))
            p, nrm = rad[:, None] * e + (0.0 if face == 0 else 20.0) * z, np.tile(z * (-1 if face == 0 else 1), (k, 1))
        elif face == 1:  # the cylinder
            p, nrm = 15.0 * e + rng.uniform(0, 17, k)[:, None] * z, e
        else:  # the fillet: phi round the tube, its area element proportional to R + r cos(phi)
            phi = rng.uniform(0, np.pi / 2, 4 * k)
            phi = phi[rng.uniform(0, 15.0, 4 * k) < 12.0 + 3.0 * np.cos(phi)][:k]
            e = e[:len(phi)]
            nrm = np.cos(phi)[:, None] * e + np.sin(phi)[:, None] * z
            p = 12.0 * e + 17.0 * z + 3.0 * nrm
        out.append(SCALE * p + noise * rng.standard_normal(len(p))[:, None] * nrm)
    return np.vstack(out)


def test_the_fillet_radius_is_measured_within_its_uncertainty():
    m = _filleted_cylinder()
    ref = Reference.from_mesh("fillet", m)
    feats = find_features(ref.vertices, ref.faces)
    P = _true_fillet_points(np.random.default_rng(9), 20000, 0.003)
    chars = [Characteristic("1", "radius", ("F04",), -0.05, 0.05, description="fillet R3"),
             Characteristic("2", "position", ("F04",), 0.0, 0.2),
             Characteristic("3", "diameter", ("F03",), -0.1, 0.1)]
    r1, r2, r3 = measure(chars, feats, P, None, ref, u_surface_mm=0.001)
    assert r1.nominal == pytest.approx(3.0, abs=1e-6) and r1.verdict == "ok" and r1.points > 1000
    assert abs(r1.measured - 3.0 * SCALE) <= r1.U, (r1.measured, r1.U)
    assert r1.deviation == pytest.approx(r1.measured - r1.nominal)
    assert 1e-4 < r1.u < 2e-3 and r1.U == pytest.approx(2 * r1.u)
    # the centre moved from z 17 to 17 SCALE: a position zone of twice that
    assert abs(r2.measured - 2 * 17 * (SCALE - 1)) <= r2.U, (r2.measured, r2.U)
    assert abs(r3.measured - 30.0 * SCALE) <= r3.U
    # a surface offset common to the part moves a fillet's radius by as much (sensitivity 1)
    without = measure(chars[:1], feats, P, None, ref)[0]
    assert r1.u == pytest.approx(np.hypot(without.u, 0.001), rel=1e-6)


# --------------------------------------------------------------------------- recipe

HEAD = """
[recipe]
name = "fillet"
reference = "{ref}"
[[stages]]
use = "segment.threshold"
[[stages]]
use = "carve.hull"
[[stages]]
use = "align.global_icp"
[[stages]]
use = "bcps.ray"
[[stages]]
use = "evaluate.tolerance"
[[stages]]
name = "characteristics"
use = "evaluate.characteristics"
"""


def _char(cid: str, kind: str, feat: str) -> str:
    return f'\n[[characteristics]]\nid = "{cid}"\nkind = "{kind}"\nfeature = "{feat}"\nlower = -0.05\nupper = 0.05\n'


@pytest.fixture(scope="module")
def fillet_stl(tmp_path_factory: pytest.TempPathFactory) -> Path:
    p = tmp_path_factory.mktemp("torus") / "fillet.stl"
    _filleted_cylinder().export(p)
    return p


def test_the_recipe_accepts_a_torus_radius_and_refuses_its_flatness(tmp_path, pm, fillet_stl):
    text = HEAD.format(ref=fillet_stl.as_posix()) + _char("1", "radius", "F04") + _char("2", "position", "F04")
    recipe = tmp_path / "r.toml"
    recipe.write_text(text)
    rec = load_recipe(recipe, pm)
    assert [(c.kind, c.features) for c in rec.characteristics] == [("radius", ("F04",)), ("position", ("F04",))]
    for kind, applies in (("flatness", "plane"), ("diameter", "cylinder, sphere")):
        recipe.write_text(HEAD.format(ref=fillet_stl.as_posix()) + _char("1", "radius", "F04") + _char("2", kind, "F04"))
        with pytest.raises(RecipeError) as e:
            load_recipe(recipe, pm)
        msg = str(e.value)
        assert "\n" not in msg and msg.startswith("r.toml: characteristics[1]: characteristic '2': ")
        assert f"a {kind} of a torus (F04) is not defined (a {kind} applies to: {applies})" in msg


def test_the_features_command_lists_the_torus(fillet_stl, capsys):
    assert main(["features", str(fillet_stl)]) == 0
    out = capsys.readouterr().out
    assert "4 features, 2560 of 2560 triangles" in out
    line = next(x for x in out.splitlines() if "F04" in x)
    assert "torus" in line and "major_radius 12" in line and "minor_radius 3" in line and "convex yes" in line
    assert main(["features", str(fillet_stl), "--json"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert js[3]["kind"] == "torus" and js[3]["nominal"]["minor_radius"] == pytest.approx(3.0, abs=1e-5)


@pytest.mark.shared
def test_a_torus_radius_in_a_qif_document_is_valid(tmp_path):
    """The fillet's radius in a QIF 3.0 Results document: a TorusFeatureDefinition (its minor
    and major diameters), valid against the official schema (../shared)."""
    from datetime import datetime

    from inspector.characteristics.formats import PartRecord, write_qif

    xmlschema = pytest.importorskip("xmlschema", reason="xmlschema is not installed")
    xsd = Path(__file__).resolve().parents[3] / "shared" / "data" / "qif-3.0" / "QIFApplications" / "QIFDocument.xsd"
    if not xsd.is_file():
        pytest.skip(f"the QIF 3.0 schema is not at {xsd} (../shared absent)")
    m = _filleted_cylinder()
    ref = Reference.from_mesh("fillet", m)
    feats = find_features(ref.vertices, ref.faces)
    chars = [Characteristic("1", "radius", ("F04",), -0.05, 0.05, description="fillet R3")]
    res = measure(chars, feats, _true_fillet_points(np.random.default_rng(9), 6000, 0.003), None, ref)
    path = write_qif(tmp_path / "fillet.qif", chars, feats, [PartRecord("p1", datetime(2026, 12, 3, 21, 0), res)],
                     part_number="fillet")
    import xml.etree.ElementTree as ET

    ns = {"q": "http://qifstandards.org/xsd/qif3"}
    torus = ET.parse(path).getroot().find(".//q:TorusFeatureDefinition", ns)
    assert torus is not None and torus.findtext("q:InternalExternal", namespaces=ns) == "EXTERNAL"
    assert float(torus.findtext("q:MinorDiameter", namespaces=ns)) == pytest.approx(6.0, abs=1e-6)
    assert float(torus.findtext("q:MajorDiameter", namespaces=ns)) == pytest.approx(24.0, abs=1e-6)
    errors = [e for e in xmlschema.XMLSchema(str(xsd)).iter_errors(str(path)) if "FeatureItemIdKey" not in str(e.reason)]
    assert errors == [], [e.reason for e in errors[:5]]
