"""Characteristics in the product (issue 28): ``[[characteristics]]`` validated when the recipe
is loaded (one line naming the file and the entry, exit 2), the faster minimum-zone form
checked against an independent linear programme on every point, and the SPC figures
against hand-computed values."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import linprog

from inspector.characteristics.spc import capability
from inspector.errors import RecipeError
from inspector.kernels import fits
from inspector.recipe import load_recipe
from inspector_frontends.cli import main

HEAD = """
[recipe]
name = "bracket"
reference = "builtin:bracket"
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
"""
STAGE = """
[[stages]]
name = "characteristics"
use = "evaluate.characteristics"
"""


def _char(cid: str, kind: str, feats: str, lower: float = -0.05, upper: float = 0.05, extra: str = "") -> str:
    return (f'\n[[characteristics]]\nid = "{cid}"\nkind = "{kind}"\nfeatures = [{feats}]\nlower = {lower}\n'
            f"upper = {upper}\n{extra}")


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "r.toml"
    p.write_text(text)
    return p


def test_a_valid_recipe_keeps_its_characteristics_for_the_stage(tmp_path, pm):
    text = HEAD + STAGE + _char("1", "diameter", '"F14"', extra='criticality = "key"\n') + _char("2", "distance", '"F01", "F04"')
    rec = load_recipe(_write(tmp_path, text), pm)
    assert [c.id for c in rec.characteristics] == ["1", "2"]
    assert rec.characteristics[0].criticality == "key" and rec.characteristics[1].features == ("F01", "F04")
    assert rec.plugins["characteristics"] == rec.characteristics  # what the stage reads from context.settings


@pytest.mark.parametrize(("body", "text"), [
    (_char("1", "diameter", '"F99"'), "characteristics[0]: characteristic '1': feature 'F99' does not exist in the reference"),
    (_char("1", "diameter", '"F01"'), "characteristics[0]: characteristic '1': a diameter of a plane (F01)"),
    (_char("7", "distance", '"F01", "F02"'), "characteristics[0]: characteristic '7': a distance between non-parallel "
                                             "planes F01 and F02"),
    (_char("1", "diameter", '"F14"') + _char("1", "radius", '"F14"'), "characteristics[1]: id '1' is already used"),
    (_char("1", "diameter", "") , "characteristics[0]: characteristic '1': a diameter names 1 feature, got none"),
    (_char("1", "volume", '"F14"'), "unknown kind 'volume'"),
    ('\n[[characteristics]]\nid = "1"\nkind = "diameter"\nfeature = "F14"\nlower = -0.1\nupper = 0.1\ntol = 1\n',
     "characteristics[0]: unknown key 'tol'"),
])
def test_bad_characteristics_are_one_line_naming_the_file_and_entry(tmp_path, pm, body, text):
    with pytest.raises(RecipeError) as e:
        load_recipe(_write(tmp_path, HEAD + STAGE + body), pm)
    msg = str(e.value)
    assert msg.startswith("r.toml: characteristics") and text in msg and "\n" not in msg, msg


def test_characteristics_without_a_stage_that_measures_them_are_refused(tmp_path, pm):
    with pytest.raises(RecipeError, match=r"r.toml: characteristics: no stage measures them .*evaluate.characteristics"):
        load_recipe(_write(tmp_path, HEAD + _char("1", "diameter", '"F14"')), pm)


def test_the_stage_must_come_after_an_evaluate_stage(tmp_path, pm):
    text = HEAD.replace('[[stages]]\nuse = "evaluate.tolerance"\n', "") + STAGE + _char("1", "diameter", '"F14"')
    with pytest.raises(RecipeError, match=r"stages.characteristics: evaluate.characteristics needs a 'evaluate' stage"):
        load_recipe(_write(tmp_path, text), pm)


def test_a_feature_gone_from_a_changed_reference_exits_2_naming_it(tmp_path, capsys):
    # Written for the bracket (F14: a hole); run against a cube, whose features are F01..F06.
    p = _write(tmp_path, HEAD + STAGE + _char("4", "diameter", '"F14"'))
    assert main(["recipe", "check", str(p)]) == 0
    capsys.readouterr()
    assert main(["recipe", "check", str(p), "--reference", "builtin:cube30"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "characteristic '4': feature 'F14' does not exist in the reference (features F01..F06" in err
    assert "[reference builtin:cube30]" in err


def test_run_refuses_dfq_without_characteristics(tmp_path, capsys):
    p = _write(tmp_path, HEAD)
    rc = main(["run", str(p), "--capture", str(tmp_path), "--out", str(tmp_path / "out"), "--dfq", str(tmp_path / "x.dfq")])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert "--dfq: the recipe 'bracket' defines no [[characteristics]]" in err and "\n" not in err
    p = _write(tmp_path, HEAD + STAGE + _char("1", "diameter", '"F14"'))
    rc = main(["run", str(p), "--capture", str(tmp_path), "--out", str(tmp_path / "out"), "--qif", str(tmp_path / "no" / "x.qif")])
    assert rc == 2 and "--qif" in capsys.readouterr().err and not (tmp_path / "out").exists()


# --------------------------------------------------------------------------- minimum zone


def _zone_lp(base: np.ndarray, G: np.ndarray) -> float:
    """The linearised minimum zone on every point, by SciPy's LP directly (no active set,
    no hull): min U - L with L <= base + G x <= U."""
    n, k = G.shape
    A = np.block([[G, -np.ones((n, 1)), np.zeros((n, 1))], [-G, np.zeros((n, 1)), np.ones((n, 1))]])
    res = linprog(np.r_[np.zeros(k), 1.0, -1.0], A_ub=A, b_ub=np.r_[-base, base], bounds=[(None, None)] * (k + 2),
                  method="highs")
    assert res.success
    return float(res.fun)


def test_flatness_on_the_hull_equals_the_zone_of_every_point():
    rng = np.random.default_rng(11)
    n = 3000
    uv = rng.uniform(-20, 20, (n, 2))
    z = 0.004 * rng.standard_normal(n) + 0.01 * np.sin(uv[:, 0] / 5)  # waviness + noise
    R = fits.orthonormal_basis(np.array([0.2, -0.3, 0.93]) / np.linalg.norm([0.2, -0.3, 0.93]))
    nrm = np.cross(R[0], R[1])
    P = uv[:, :1] * R[0] + uv[:, 1:] * R[1] + z[:, None] * nrm + np.array([3.0, -2.0, 7.0])
    got = fits.flatness(P)
    fit = fits.fit_plane(P)
    d = P - fit.params["point"]
    ref = _zone_lp(d @ fit.params["normal"], np.column_stack([d @ fit.params["u"], d @ fit.params["v"]]))
    assert got == pytest.approx(ref, abs=1e-6)
    assert got <= np.ptp(d @ fit.params["normal"]) + 1e-12  # never wider than the least-squares zone


def test_roundness_of_sections_solved_together_equals_each_alone():
    rng = np.random.default_rng(5)
    sections, truth = [], []
    for k, lobes in enumerate((3, 4, 5, 2)):
        t = rng.uniform(0, 2 * np.pi, 400)
        amp = 0.002 * (k + 1)
        r = 6.0 + amp * np.cos(lobes * t) + 0.0005 * rng.standard_normal(400)
        sections.append(np.column_stack([r * np.cos(t) + 0.01 * k, r * np.sin(t) - 0.02, np.full(400, 2.0 * k)]))
        truth.append(fits.roundness(sections[-1], normal=[0, 0, 1]))
    got = fits.roundness_sections(sections, np.array([0.0, 0.0, 1.0]))
    assert got == pytest.approx(truth, abs=2e-7)
    assert got.max() > 0.016  # the 2-lobed section: 2 x 0.008 plus its noise


# --------------------------------------------------------------------------- SPC


def test_capability_against_hand_computed_values():
    x = [10.01, 9.99, 10.02, 10.00, 9.98, 10.03, 10.01, 9.97]  # mean 10.00125
    c = capability(x, lower=9.95, upper=10.05, reference=10.0)
    mean = sum(x) / 8
    s = math.sqrt(sum((v - mean) ** 2 for v in x) / 7)
    assert c.n == 8 and c.mean == pytest.approx(mean) and c.s == pytest.approx(s)
    assert c.cp == pytest.approx(0.1 / (6 * s))
    assert c.cpk == pytest.approx(min(10.05 - mean, mean - 9.95) / (3 * s))
    assert c.out_of_tolerance == 0
    assert c.cg == pytest.approx(0.2 * 0.1 / (6 * s)) and c.cgk == pytest.approx((0.1 * 0.1 - abs(mean - 10.0)) / (3 * s))
    # values outside the limits are counted; a bias lowers Cgk but not Cg
    c2 = capability([*x, 10.06, 9.94], lower=9.95, upper=10.05, reference=10.0)
    assert c2.out_of_tolerance == 2
    c3 = capability(np.asarray(x) + 0.004, lower=9.95, upper=10.05, reference=10.0)
    assert c3.cg == pytest.approx(c.cg) and c3.cgk < c.cgk
    # undefined figures are nan, never made up
    one = capability([10.0], lower=9.95, upper=10.05, reference=10.0)
    assert one.n == 1 and math.isnan(one.s) and math.isnan(one.cp) and math.isnan(one.cgk)
    with pytest.raises(ValueError, match="upper > lower"):
        capability(x, lower=1.0, upper=1.0)


def test_tolerance_for_a_capable_gauge_inverts_cgk():
    from inspector.characteristics.spc import capable_tolerance

    rng = np.random.default_rng(2)
    x = 5.0 + 0.001 + 0.0008 * rng.standard_normal(30)
    T = capable_tolerance(x, reference=5.0)
    c = capability(x, lower=5.0 - T / 2, upper=5.0 + T / 2, reference=5.0)
    assert c.cgk == pytest.approx(1.33, abs=1e-9) and c.cg > 1.33


def test_points_are_assigned_as_by_the_closest_triangle_of_every_point():
    """The bounding-box prefilter of assign_points changes nothing: the owner of each point
    is that of its closest reference triangle (asked for every point here), within the band."""
    import trimesh

    from inspector.characteristics.definitions import features_for
    from inspector.characteristics.measure import assign_points
    from inspector.parts import make_part
    from inspector.reference import Reference

    ref = Reference.from_mesh("builtin:bracket", make_part("bracket"))
    feats = features_for(ref.vertices, ref.faces)
    mesh = trimesh.Trimesh(ref.vertices, ref.faces, process=False)
    rng = np.random.default_rng(4)
    P, fid = trimesh.sample.sample_surface(mesh, 6000, seed=5)
    P = P + rng.uniform(-0.8, 0.8, len(P))[:, None] * mesh.face_normals[fid]  # some beyond the 0.5 mm band
    q, tri = ref.distance.closest(P)
    for subset in (feats, [feats[0], feats[13]], [feats[16]]):
        owner = np.full(len(ref.faces), -1)
        for k, f in enumerate(subset):
            owner[f.faces] = k
        want = np.where(np.linalg.norm(P - q, axis=1) <= 0.5, owner[tri], -1)
        got = assign_points(P, subset, ref, 0.5)
        assert np.array_equal(got, want) and (got >= 0).any() and (got == -1).any()
